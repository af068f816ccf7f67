"""Recording of simulator runs as rosbag2 bags with MCAP storage.

:class:`BagWriter` writes already-serialized (CDR) messages to
``bags/<run>/<run>_0.mcap`` plus ``metadata.yaml`` in the layout of
``ros2 bag record -s mcap`` (ROS 2 Jazzy), readable by ``ros2 bag``, Foxglove,
PlotJuggler, mcap-ros2-support and rosbags.  :func:`message_definition` builds
the ``ros2msg`` schema text of a message type as rosbag2 does.  Nothing here
imports rclpy.
"""

from .msgdefs import message_definition, normalize_type_name, type_description_hash
from .writer import (
    DEFAULT_QOS_PROFILES_YAML,
    ROSBAG2_FORMAT_VERSION,
    BagClosedError,
    BagWriteError,
    BagWriter,
    parse_qos_profiles,
    qos_profiles_yaml,
)

__all__ = [
    'DEFAULT_QOS_PROFILES_YAML',
    'ROSBAG2_FORMAT_VERSION',
    'BagClosedError',
    'BagWriteError',
    'BagWriter',
    'message_definition',
    'normalize_type_name',
    'parse_qos_profiles',
    'qos_profiles_yaml',
    'type_description_hash',
]
