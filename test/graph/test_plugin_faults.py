"""A law that breaks, installed as a plugin, hurts no other run; a law that commands NaN is named at once.

The broken laws of ``test/unit/test_plugin_checks.py`` are installed here
as a user installs a plugin: a distribution (``.dist-info`` with the entry
point) on the path of an ``attitude-sil`` process. A PID run beside them
exits 0 with each named on stderr. A law that passes every check but
commands NaN stops the graph's episode with one line naming it, the step and
the values (the recorder sees the command the wheels refuse), not at the
plant's input timeout; the batch engine warns naming the episodes and the law.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from attitude_sil.core.sim.engine import simulate, simulate_summary
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.errors import NonFiniteWarning
from conftest import BREAKS, CONFIG, ROOT, write_plugin

#: a law that passes every check and commands NaN from step ``START`` on
NAN_LAW = '''
from typing import NamedTuple

import numpy as np
from numba import njit

from attitude_sil.core.control.law import Law


class Params(NamedTuple):
    u_max: float


@njit(cache=True, inline="always")
def step(q_BN, omega_BN_B, q_RN, omega_RN_R, p, par, st, dt, u):
    for i in range(3):
        u[p, i] = np.nan if st.k[p, 0] >= START else 0.0
    st.k[p, 0] += 1


def record(values, n, dt):
    return Params(float(values["output_limit"]))


LAW = Law(name="nan_law", summary="commands NaN (a test's broken law)", params=(), state={"k": (1, np.int64)},
          record=record, step=step)
'''


def install(folder: Path, names: list[str], start: int = 0) -> dict[str, str]:
    """Each law of ``names`` as a module and a distribution of its own in ``folder``; the environment that
    puts them on an ``attitude-sil`` process's path."""
    for name in names:
        if name == "nan_law":
            (folder / "nan_law.py").write_text(NAN_LAW.replace("START", str(start)))
        else:
            write_plugin(folder, name)
        info = folder / f"test_law_{name}-0.1.dist-info"
        info.mkdir()
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: test-law-{name}\nVersion: 0.1\n")
        (info / "entry_points.txt").write_text(f"[attitude_sil.laws]\n{name} = {name}:LAW\n")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(folder), os.environ.get("PYTHONPATH", "")])}


def run(env: dict, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "attitude_sil.cli", "run", "config/hst_roll_step.yaml",
                           "--no-record", "--quiet", *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout)


def test_a_pid_run_goes_on_beside_every_broken_plugin(tmp_path):
    proc = run(install(tmp_path, list(BREAKS)), "--duration", "0.5", "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout.splitlines()[-1])["controller_type"] == "pid"
    for name in BREAKS:  # each named once per process that loaded the registry, with its distribution
        lines = [x for x in proc.stderr.splitlines() if f"law plugin {name!r}" in x]
        assert lines and all(f"distribution test-law-{name}" in x and x.endswith("skipped") or
                             x.endswith("prints the whole error)") for x in lines), proc.stderr


def test_a_law_that_commands_nan_stops_the_graph_naming_it(tmp_path):
    proc = run(install(tmp_path, ["nan_law"], start=30), "--controller", "nan_law", "--duration", "5")
    assert proc.returncode != 0
    last = proc.stderr.strip().splitlines()[-1]
    assert "controller_type nan_law commanded a non-finite voltage_cmd at step 30 (t=0.300000 s): [nan, nan, nan]; " \
           "the episode stops" in last, proc.stderr
    assert "within" not in last and "stalled" not in proc.stderr  # the NaN stopped it, not the input timeout


@pytest.fixture
def nan_law(monkeypatch, tmp_path):
    """The NaN law registered in this process (it has no parameters of its own, so the schema needs none)."""
    from importlib.metadata import EntryPoint

    from attitude_sil.core.control import registry
    (tmp_path / "nan_law.py").write_text(NAN_LAW.replace("START", "0"))
    monkeypatch.syspath_prepend(str(tmp_path))
    eps = [EntryPoint("nan_law", "nan_law:LAW", registry.ENTRY_POINT_GROUP)]
    monkeypatch.setattr(registry, "entry_points", lambda group: [e for e in eps if e.group == group])
    registry.refresh()
    yield
    registry.refresh()


def test_the_batch_engine_warns_naming_the_episodes_and_the_law(nan_law):
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    laws = ["pid", "nan_law", "pid", "nan_law"]
    with pytest.warns(NonFiniteWarning, match=r"2 of 4 episodes went non-finite .*: episodes 1, 3 under nan_law"):
        s = simulate_summary(scn, 4, duration=0.2, controller=laws)
    assert s.finite.tolist() == [True, False, True, False]
    with pytest.warns(NonFiniteWarning, match=r"1 of 1 episodes .*episodes 0 under pid, nan_law from step 5"):
        simulate(scn, 1, duration=0.2, schedule=[(5, "nan_law")], keep=("q_BN", "u_cmd"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", NonFiniteWarning)  # a finite run warns nothing
        tr = simulate(scn, 2, duration=0.2, keep=("u_cmd",))
    assert np.all(np.isfinite(tr.u_cmd))
