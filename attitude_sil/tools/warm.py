"""Compile the step kernels once, into numba's on-disk cache, before anything else needs them.

The kernels (:mod:`attitude_sil.core.plant.kernels`, the laws' steps and the batch loop
generated for the registered laws, :mod:`attitude_sil.core.control.compiled`)
are compiled on first use and cached next to their modules (``cache=True``). On
a fresh install that first use is typically a graph run: five node processes
and the runner, started together on a machine with fewer cores, each
compiling the same kernels before the cache exists. ``python -m
attitude_sil.tools.warm`` (run by ``make`` right after installing) compiles
them first: every preset through both batch drivers and every control law,
which are the signatures the nodes, the engine and the tuner use. Where the
machine has two cores or more, a second process compiles the stepwise
driver's kernels (the nodes' own) while the first compiles the compiled
loop, then takes the laws' compiled-driver work from the other end of the
list, so the two end together: the first item, each preset's own law
first, builds the loop in its two forms (for one episode and for a
block), each other law its own loops.
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


def warm(config_dir: str | Path | None = None, say=None, drivers: tuple[str, ...] = ("auto", "stepwise"),
         claim=None, reverse: bool = False) -> float:
    """Compile and cache the kernels; returns the wall seconds it took.

    Parameters
    ----------
    config_dir : path, optional
        Where the preset scenarios are (default: :func:`~attitude_sil.core.sim.scenario.default_config_dir`).
    say : callable(str), optional
        Told of each preset as it starts (a cold cache takes minutes).
    drivers : tuple of str
        The batch drivers whose kernels to compile (``auto``: the compiled loop where it runs the preset).
    claim : callable(int) -> bool, optional
        Asked before each (preset, law) item of the list, by its index: False, another process has it.
    reverse : bool
        Take the list from its end.
    """
    folder = Path(config_dir) if config_dir is not None else default_config_dir()
    t0 = time.perf_counter()
    scenarios = {name: load_scenario(folder / f"{name}.yaml") for name in PRESETS}
    # each preset's own law first: the first item builds the compiled loop with its law's own loops, and the
    # preset's law (the PID for the HST) has cheaper ones than the first by name (the fuzzy PID: 18 s more
    # before the loop, on the path every other compiled item waits on)
    own = {name: scn.param("controller", "controller_type") for name, scn in scenarios.items()}
    items = list(enumerate((name, law) for name in PRESETS
                           for law in sorted(registry.names(), key=lambda x, n=name: x != own[n])))
    said: set[str] = set()
    for i, (name, controller) in reversed(items) if reverse else items:
        if claim is not None and not claim(i):
            continue
        if name not in said and say is not None:
            say(f"  compiling the kernels: preset {PRESETS.index(name) + 1} of {len(PRESETS)} ({name}), "
                f"{time.perf_counter() - t0:.0f} s")
        said.add(name)
        scn = scenarios[name]
        first = own[name]
        for driver in drivers:
            # the compiled loop's block form (chunk) takes two episodes on one thread; its one-episode form
            # (chunk_one), the same for every law, is compiled once by warm_one_episode
            n, threads = (2, 1) if driver == "auto" else (1, None)
            try:  # the law alone, then a swap to it (the bumpless entry)
                simulate(scn, n, duration=2 * scn.dt, controller=controller, driver=driver, threads=threads)
                if controller != first:
                    simulate(scn, n, duration=2 * scn.dt, controller=first, driver=driver, threads=threads,
                             schedule=[(1, controller)])
            except ScenarioError:  # a law the preset's plant cannot take: nothing to compile for it
                break
    return time.perf_counter() - t0


def warm_one_episode(config_dir: str | Path | None = None) -> None:
    """Compile the compiled loop's one-episode form (``chunk_one``: every run of a single episode)."""
    folder = Path(config_dir) if config_dir is not None else default_config_dir()
    scn = load_scenario(folder / f"{PRESETS[0]}.yaml")
    simulate(scn, 1, duration=2 * scn.dt, driver="auto")


def _claimer(flags):
    """claim(i): True the first time any process asks for item i (flags: a shared byte per item)."""
    def claim(i: int) -> bool:
        with flags.get_lock():
            if flags[i]:
                return False
            flags[i] = 1
            return True
    return claim


def _helper(flags, loop_ready) -> None:
    # the second core: the stepwise driver's kernels and the compiled loop's one-episode form, then, once the
    # loop's block form is in the cache (built by the first process's first item: compiled twice at once it would
    # cost the most), the compiled driver's laws from the end of the list
    warm(drivers=("stepwise",))
    warm_one_episode()  # beside the first process's block form: both take about a minute from nothing
    loop_ready.wait()
    warm(drivers=("auto",), claim=_claimer(flags), reverse=True)


def main() -> int:
    print("attitude_sil: compiling the numba kernels into their cache (a few minutes the first time; cached after)",
          file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    say = lambda line: print(line, file=sys.stderr, flush=True)  # noqa: E731
    if (os.cpu_count() or 1) < 2:
        warm(say=say)
        warm_one_episode()
    else:
        ctx = multiprocessing.get_context("spawn")
        flags, loop_ready = ctx.Array("b", len(PRESETS) * len(registry.names())), ctx.Event()
        helper = ctx.Process(target=_helper, args=(flags, loop_ready), name="attitude_sil-warm")
        helper.start()
        claim = _claimer(flags)

        def first(i: int) -> bool:  # the first item builds the compiled loop: the helper may start after it
            took = claim(i)
            if i > 0:
                loop_ready.set()
            return took

        try:
            warm(say=say, drivers=("auto",), claim=first)
        finally:
            loop_ready.set()  # never leave the helper waiting
            helper.join()
        if helper.exitcode != 0:
            print(f"attitude_sil: compiling the kernels in the second process failed (exit {helper.exitcode})",
                  file=sys.stderr)
            return 1
    print(f"attitude_sil kernels compiled and cached in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
