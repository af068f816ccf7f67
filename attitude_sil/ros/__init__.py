"""The ROS-side foundation every node and tool stands on.

* :mod:`~attitude_sil.ros.contract` - topic names, message types, who publishes and listens;
* :mod:`~attitude_sil.ros.qos` - QoS profiles (and their rosbag2 form);
* :mod:`~attitude_sil.ros.environment` - the discovery environment;
* :mod:`~attitude_sil.ros.convert` - message <-> numpy conversions;
* :mod:`~attitude_sil.ros.parameters` - parameter descriptors from the schema;
* :mod:`~attitude_sil.ros.node` - :class:`SchemaNode`, the base of every graph node, and ``run_node``;
* :mod:`~attitude_sil.ros.services` - client side of the parameter and reset services;
* :mod:`~attitude_sil.ros.signals` - Ctrl-C, SIGTERM and SIGHUP as a flag checked at a clean point.

Above: :mod:`attitude_sil.nodes`, :mod:`attitude_sil.graph`, :mod:`attitude_sil.tools`.
Below: :mod:`attitude_sil.core` and :mod:`attitude_sil.storage` (both ROS-free).
See docs/architecture.md.
"""
