"""The discovery environment: keep a graph on this machine unless the user chose otherwise.

DDS discovery spans every process on a machine. rmw reads these variables at
``rclpy.init``; :func:`localhost_environment` sets
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` when none of them is set, so a run
never talks to another machine by accident. ``ROS_DOMAIN_ID`` separates runs
on one machine (docs/architecture.md, "Environment").
"""

from __future__ import annotations

import os

__all__ = ["DISCOVERY_VARS", "localhost_environment"]

#: the variables that choose who a process discovers
DISCOVERY_VARS = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY")


def localhost_environment(env: dict[str, str] | None = None) -> dict[str, str]:
    """Keep discovery on this machine unless the user set a discovery variable.

    Parameters
    ----------
    env : dict, optional
        The environment to update (a child process's); ``None`` updates
        ``os.environ`` in place.

    Returns
    -------
    dict
        The (possibly updated) mapping.
    """
    target = os.environ if env is None else env
    if not any(v in target for v in DISCOVERY_VARS):
        target["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    return target
