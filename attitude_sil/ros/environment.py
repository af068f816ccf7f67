"""The discovery environment: keep a graph on this machine unless the user chose otherwise.

DDS discovery spans every process on a machine. rmw reads these variables at
``rclpy.init``; :func:`localhost_environment` sets
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless the user chose a discovery
range, so a run never talks to another machine by accident (a domain id alone,
chosen by the user or by :func:`isolated_domain`, does not open it). ``ROS_DOMAIN_ID`` separates runs
on one machine: :func:`isolated_domain` gives a run a domain of its own unless
the user chose one (docs/architecture.md, "Environment"). :func:`discovery_profile`
points Fast DDS at the package's participant profile (re-announce every 0.3 s)
unless the user chose a profile file, so a process that joins a graph finds it
in a fraction of a second.
"""

from __future__ import annotations

import fcntl
import os
import tempfile
from pathlib import Path
from typing import IO

from attitude_sil.errors import RunError

__all__ = ["DISCOVERY_VARS", "RANGE_VARS", "DOMAIN_RANGE", "PROFILE_VARS", "DISCOVERY_PROFILE", "discovery_profile",
           "isolated_domain", "localhost_environment"]

#: Fast DDS's variables naming an XML profile file (3.x reads the first, Jazzy's 2.x the second)
PROFILE_VARS = ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
#: the package's participant profile: announcements every 0.3 s (Fast DDS default 3 s)
DISCOVERY_PROFILE = Path(__file__).with_name("fastdds_discovery.xml")

#: domains handed out, in this order: clear of 0 (ROS's default) and of the small numbers labs give robots;
#: 101 is the highest Fast DDS maps to ports safely on Linux
DOMAIN_RANGE = tuple(range(60, 102)) + tuple(range(1, 60))

_held: list[IO] = []  # the lock files of the domains this process holds (released when it exits)


def isolated_domain(env: dict[str, str] | None = None) -> tuple[int, bool]:
    """Give this process a ROS domain no other attitude-sil process on the machine holds.

    A user who set ``ROS_DOMAIN_ID`` gets exactly that (returned with
    ``False``). Otherwise the first domain of :data:`DOMAIN_RANGE` whose lock
    file (``<tmp>/attitude_sil_domains/<id>.lock``) can be locked is taken and
    written to the environment, where rmw and child processes read it;
    the lock lasts as long as this process, whatever way it ends.

    Returns
    -------
    (int, bool)
        The domain, and whether it was chosen here.

    Raises
    ------
    RunError
        Every domain of the range is held.
    """
    target = os.environ if env is None else env
    if "ROS_DOMAIN_ID" in target:
        return int(target["ROS_DOMAIN_ID"]), False
    folder = Path(tempfile.gettempdir()) / "attitude_sil_domains"
    folder.mkdir(exist_ok=True)
    for domain in DOMAIN_RANGE:
        handle = open(folder / f"{domain}.lock", "a+")  # noqa: SIM115 - held open on purpose
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        _held.append(handle)
        target["ROS_DOMAIN_ID"] = str(domain)
        return domain, True
    raise RunError(f"every ROS domain of {DOMAIN_RANGE[0]}..{DOMAIN_RANGE[-1]} is held by another run; "
                   "set ROS_DOMAIN_ID")

#: the variables that choose who a process discovers
DISCOVERY_VARS = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY")
#: those that choose how far discovery reaches (a domain id alone does not open a run to the network)
RANGE_VARS = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY")


def localhost_environment(env: dict[str, str] | None = None) -> dict[str, str]:
    """Keep discovery on this machine unless the user chose a discovery range (:data:`RANGE_VARS`).

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
    if not any(v in target for v in RANGE_VARS):
        target["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    return discovery_profile(target)


def discovery_profile(env: dict[str, str] | None = None) -> dict[str, str]:
    """Use :data:`DISCOVERY_PROFILE` unless the user named a Fast DDS profile file or another RMW.

    Fast DDS reads the variable when a process creates its first participant,
    so this runs before ``rclpy.init`` (the runner, the tools and every node's
    ``main`` call it; child processes inherit it). With the default 3 s
    announcement period a process joining a graph waited up to 3 s for it.

    Parameters
    ----------
    env : dict, optional
        The environment to update; ``None`` updates ``os.environ`` in place.

    Returns
    -------
    dict
        The (possibly updated) mapping.
    """
    target = os.environ if env is None else env
    rmw = target.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    if rmw.startswith("rmw_fastrtps") and not any(target.get(v) for v in PROFILE_VARS):
        for var in PROFILE_VARS:  # Jazzy's Fast DDS 2.x reads the FASTRTPS_ name, 3.x the FASTDDS_ one
            target[var] = str(DISCOVERY_PROFILE)
    return target
