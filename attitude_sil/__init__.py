"""attitude_sil: a ROS 2 software-in-the-loop simulator for spacecraft attitude control.

Layers, each importing only from those below it (docs/architecture.md):
``cli`` -> ``tools`` -> ``graph`` -> ``nodes`` -> ``ros`` -> ``core``, ``storage``,
``tuning`` (ROS-free), with :mod:`attitude_sil.errors` at the bottom.
"""
