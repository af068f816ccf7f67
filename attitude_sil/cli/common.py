"""Helpers several ``attitude-sil`` verbs share (imported by a verb's ``execute``, never at start-up)."""

from __future__ import annotations

import argparse
import os
import shlex
import sys

import yaml

from attitude_sil.core import yaml12
from attitude_sil.core.sim.scenario import Scenario, load_scenario, with_parameter_file
from attitude_sil.errors import AttitudeSilError
from attitude_sil.ros.environment import isolated_domain
from attitude_sil.tuning.executor import check_scheduler_address

__all__ = ["announce_domain", "load_with_params", "scheduler_address", "set_overrides"]


def announce_domain() -> None:
    """Take a ROS domain of the run's own (unless the user set one) and say which, so tools can reach it."""
    domain, chosen = isolated_domain()
    if chosen:
        print(f"graph on ROS_DOMAIN_ID={domain} (its own; reach it with ROS_DOMAIN_ID={domain} attitude-sil param ...)",
              file=sys.stderr, flush=True)


def load_with_params(scenario: str, params: str | None) -> Scenario:
    """A scenario with a controller parameter file (e.g. a tuner's best.yaml) laid over it."""
    scn = load_scenario(scenario)
    return with_parameter_file(scn, params) if params else scn


def scheduler_address(args: argparse.Namespace) -> str | None:
    """``--scheduler`` or ``$DASK_SCHEDULER_ADDRESS``, checked (one line if malformed), or None."""
    if args.scheduler is not None:
        return check_scheduler_address(args.scheduler)
    address = os.environ.get("DASK_SCHEDULER_ADDRESS") or None
    if address is not None:
        try:
            check_scheduler_address(address)
        except AttitudeSilError as exc:
            raise AttitudeSilError(f"DASK_SCHEDULER_ADDRESS: {exc}") from None
    return address


def set_overrides(items: list[str] | None) -> dict:
    """``--set KEY=VALUE`` items as ``{key: value}``, each value read as YAML (``5``, ``[1, 2]``, ``text``).

    Raises
    ------
    AttitudeSilError
        An item without ``=``, or a value that is not YAML.
    """
    overrides = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise AttitudeSilError(f"--set takes KEY=VALUE, got {item!r}")
        try:
            overrides[key] = yaml12.load(value)
        except yaml.YAMLError:
            raise AttitudeSilError(f"--set {key}: {value!r} is not a YAML value") from None
    return overrides


def resume_command(args: argparse.Namespace) -> str:
    """The command line that continues a stopped campaign or tuning run: the user's own, with ``--resume``.

    Parameters
    ----------
    args : argparse.Namespace
        The verb's parsed arguments; ``args.argv`` is the command line they were parsed from
        (:func:`attitude_sil.cli.main.main` keeps it).

    Returns
    -------
    str
        ``attitude-sil VERB ... --resume``, quoted for a POSIX shell.
    """
    argv = list(args.argv)
    return shlex.join(["attitude-sil", *argv, *([] if "--resume" in argv else ["--resume"])])
