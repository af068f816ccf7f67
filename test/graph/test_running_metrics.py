"""A graph run's metrics from running sums (core/analysis/running_metrics.py) equal the trajectory's metrics.

The graph no longer keeps an episode's messages to compute its metrics at the
end (memory grew 1.5 kB per step); it feeds each step to an
EpisodeAccumulator. Fed the steps of a batch-engine trajectory, the
accumulator must give what episode_report computes from the whole trajectory,
for every metrics mode (step, regulation with and without a step, tracking)
and through a scheduled swap (segments). The sums run in another order than
numpy's: rtol 1e-12.
"""

import math

import numpy as np
import pytest

from attitude_sil.core.analysis.metrics import episode_report
from attitude_sil.core.analysis.running_metrics import EpisodeAccumulator
from attitude_sil.core.sim.build import schedule_from_scenario
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.graph.session import GraphSession
from conftest import CONFIG


def _feed(scn, tr, controller, schedule):
    acc = EpisodeAccumulator(scn.values["scenario"], scn.param("guidance", "step_time"), controller, schedule)
    for k in range(tr.t.size):
        acc.add(tr.t[k], tr.q_BN[0, k], tr.q_RN[0, k], tr.tau_c_B[0, k], tr.u_cmd[0, k])
    return acc


def _same(a, b):
    if a is None or b is None:
        assert a is None and b is None
    elif isinstance(a, float):
        assert math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-15), (a, b)
    else:
        assert a == b


@pytest.mark.parametrize("preset, duration, swap", [
    ("hst_roll_step.yaml", 12.0, "5:fuzzy_pid"),  # step metrics and two segments
    ("hst_roll_step.yaml", 12.0, None),
    ("cubesat_1u.yaml", None, None),
    ("flexible_axis.yaml", 20.0, None),  # regulation, a step
    ("pitch_axis.yaml", None, None),  # regulation, no step: settled within the band of the peak
    ("hawaiisat_lvlh.yaml", 60.0, None),  # tracking
])
def test_running_metrics_equal_the_trajectory_metrics(preset, duration, swap):
    scn = load_scenario(CONFIG / preset)
    if duration is not None:
        scn = scn.with_values("plant", duration=duration)
    if swap:
        t, kind = swap.split(":")
        scn = scn.with_values("scenario", **{"schedule.times": [float(t)], "schedule.controller_types": [kind]})
    tr = simulate(scn, 1)
    controller = scn.param("controller", "controller_type")
    steps = schedule_from_scenario(scn)
    schedule = [(k * scn.dt, k, kind) for k, kind in steps]
    expected = episode_report(scn, tr, controller, scn.duration, 1.0, schedule or None)
    got = _feed(scn, tr, controller, schedule).report(scn.name, scn.duration, 1.0)
    assert got.keys() == expected.keys()
    for key in expected:
        if key == "segments":
            assert len(got[key]) == len(expected[key]) == 2
            for a, b in zip(got[key], expected[key], strict=True):
                assert a.keys() == b.keys()
                for k in a:
                    _same(a[k], b[k])
        else:
            _same(got[key], expected[key])
    finite = [k for k, v in expected.items() if isinstance(v, float) and k not in ("sim_time_s", "wall_time_s")]
    assert len(finite) >= 4  # the comparison covered real figures


def test_memory_does_not_grow_with_the_run():
    # a regulation run (the one figure that looks back) keeps the samples of its transient only
    scn = load_scenario(CONFIG / "pitch_axis.yaml")
    rng = np.random.default_rng(0)
    acc = EpisodeAccumulator(scn.values["scenario"], 0.0, "ga_flc")
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for k in range(200_000):  # a long run of small noise after one big error: nothing accumulates
        angle = (0.5 if k == 10 else 1e-4 * rng.standard_normal())
        acc.add(k * 0.01, [0.0, np.sin(angle / 2), 0.0, np.cos(angle / 2)], q, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert len(acc.candidates) <= 2
    assert acc.metrics()["settling_time_s"] == pytest.approx(0.11)


def test_a_graph_run_reports_from_running_sums_what_the_batch_engine_reports():
    # the graph keeps no messages for its metrics now: they come from the accumulator fed live, and equal
    # the batch engine's trajectory metrics (graph == batch to 1e-9), through a scheduled swap
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values(
        "scenario", **{"schedule.times": [2.0], "schedule.controller_types": ["fuzzy_pid"]})
    with GraphSession(scn, duration=4.0) as graph:
        result = graph.run_episode()
        assert result.trajectory is None
        assert all(not kept for kept in graph.recorder.kept.values())  # nothing held
    batch = scn.with_values("plant", duration=4.0)
    tr = simulate(batch, 1)
    schedule = [(k * scn.dt, k, kind) for k, kind in schedule_from_scenario(batch)]
    expected = episode_report(batch, tr, "pid", 4.0, 1.0, schedule)
    for key in ("time_constant_s", "overshoot_pct", "iae", "ise", "itae", "control_effort_Nms",
                "steady_state_error_rad"):
        assert result.metrics[key] == pytest.approx(expected[key], rel=1e-9, abs=1e-12), key
    assert [s["controller_type"] for s in result.metrics["segments"]] == ["pid", "fuzzy_pid"]
    for got, want in zip(result.metrics["segments"], expected["segments"], strict=True):
        assert got["iae"] == pytest.approx(want["iae"], rel=1e-9)
