"""Tools on recorded runs and live graphs: replay, verify-controller, the parameter client, bag plots.

The project's stand-ins for ``ros2 bag play``, ``ros2 param`` and a plotter
(``ros2cli`` and ``rosbag2`` are not on PyPI).
"""
