"""Compile the step kernels once, into numba's on-disk cache, before anything else needs them.

The kernels (:mod:`attitude_sil.core.plant.kernels`, the laws' steps and the batch loop
generated for the registered laws, :mod:`attitude_sil.core.control.compiled`)
are compiled on first use and cached next to their modules (``cache=True``). On
a fresh install that first use is typically a graph run: five node processes
and the runner, started together on a machine with fewer cores, each
compiling the same kernels before the cache exists. ``python -m
attitude_sil.tools.warm`` (run by ``make`` right after installing) compiles
them first: every preset through both batch drivers and every control law,
which are the signatures the nodes, the engine and the tuner use. The two
drivers' kernels are compiled in two processes at once where the machine
has two cores or more (they share little: the compiled loop is one large
function, the stepwise driver's kernels the nodes' own).
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
from pathlib import Path

from attitude_sil.core.control import registry
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import PRESETS, ScenarioError, default_config_dir, load_scenario


def warm(config_dir: str | Path | None = None, say=None, drivers: tuple[str, ...] = ("auto", "stepwise")) -> float:
    """Compile and cache the kernels; returns the wall seconds it took.

    Parameters
    ----------
    config_dir : path, optional
        Where the preset scenarios are (default: :func:`~attitude_sil.core.sim.scenario.default_config_dir`).
    say : callable(str), optional
        Told of each preset as it starts (a cold cache takes minutes).
    drivers : tuple of str
        The batch drivers whose kernels to compile (``auto``: the compiled loop where it runs the preset).
    """
    folder = Path(config_dir) if config_dir is not None else default_config_dir()
    t0 = time.perf_counter()
    for i, name in enumerate(PRESETS, start=1):
        if say is not None:
            say(f"  compiling the kernels: preset {i} of {len(PRESETS)} ({name}), {time.perf_counter() - t0:.0f} s")
        scn = load_scenario(folder / f"{name}.yaml")
        first = scn.param("controller", "controller_type")
        for controller in registry.names():
            for driver in drivers:
                try:  # the law alone, then a swap to it (the bumpless entry)
                    simulate(scn, 1, duration=2 * scn.dt, controller=controller, driver=driver)
                    if controller != first:
                        simulate(scn, 1, duration=2 * scn.dt, controller=first, driver=driver,
                                 schedule=[(1, controller)])
                except ScenarioError:  # a law the preset's plant cannot take: nothing to compile for it
                    break
    return time.perf_counter() - t0


def _warm_stepwise() -> None:
    warm(drivers=("stepwise",))


def main() -> int:
    print("attitude_sil: compiling the numba kernels into their cache (a few minutes the first time; cached after)",
          file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    helper = None
    if (os.cpu_count() or 1) >= 2:  # the stepwise driver's kernels in a second process, on the second core
        helper = multiprocessing.get_context("spawn").Process(target=_warm_stepwise, name="attitude_sil-warm")
        helper.start()
    drivers = ("auto",) if helper is not None else ("auto", "stepwise")
    warm(say=lambda line: print(line, file=sys.stderr, flush=True), drivers=drivers)
    if helper is not None:
        helper.join()
        if helper.exitcode != 0:
            print(f"attitude_sil: compiling the stepwise driver's kernels failed (exit {helper.exitcode})",
                  file=sys.stderr)
            return 1
    print(f"attitude_sil kernels compiled and cached in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
