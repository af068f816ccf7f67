"""ROS-free tuning: specs, cost functions, batch evaluation of populations, optimisers.

The ``tuner`` node and ``attitude-sil tune`` drive these; see
:mod:`attitude_sil.tuning.optimize`.
"""
