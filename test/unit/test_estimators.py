"""Estimators as units (issue 44, item 2): the registry finds the built-in MEKF by itself and other packages'
filters through the entry-point group ``attitude_sil.estimators``; ``estimator.type`` selects one.

The plugin here, ``gyro_only``, is written to a temporary folder and registered through an entry point, as the
registry reads any plugin. It integrates the gyro and takes no report, so its reference is the MEKF flown with
its tracker off for the whole run, which propagates exactly so (zero bias, no update): the two runs, on the
estimate, are equal bit for bit, which they could not be if the drivers built another filter than the one
selected. Its own parameter reaches it without its prefix. A plugin that fails its load check is skipped in
one line, and the MEKF flies on.
"""

from __future__ import annotations

import sys
import textwrap
from importlib.metadata import EntryPoint

import numpy as np
import pytest

from attitude_sil.core.sensing import registry
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario
from attitude_sil.errors import ScenarioError

SENSORS = default_config_dir() / "hst_roll_step_sensors.yaml"

GYRO_ONLY = '''
"""A filter that integrates the gyro, less a fixed bias of its own, and takes no star tracker report."""
import numpy as np
from attitude_sil.core.paramspec import ParamSpec
from attitude_sil.core.plant.quaternion import quat_from_euler, quat_multiply, quat_normalize, rotation_quaternion
from attitude_sil.core.sensing.estimator import Estimate, Estimator


class GyroOnly:
    def __init__(self, values, dt, n):
        self.dt, self.n, self.dropped = dt, n, 0
        self.bias = np.radians(np.asarray(values["bias_deg_h"], dtype=float)) / 3600.0
        rpy = np.radians(np.asarray(values["initial_attitude_rpy_deg"], dtype=float))
        self.q = np.array(np.broadcast_to(quat_normalize(quat_from_euler(rpy)), (n, 4)))
        self.sigma = np.radians(values["initial_attitude_sigma_deg"])

    def set_star_tracker_variance(self, variance):
        pass

    def step(self, k, omega_meas_B, star_tracker=None):
        w = omega_meas_B - self.bias
        if k > 0:
            self.q = quat_normalize(quat_multiply(self.q, rotation_quaternion(w * self.dt)))
        cov = np.array(np.broadcast_to(np.diag([self.sigma ** 2] * 3 + [1e-12] * 3), (self.n, 6, 6)))
        return Estimate(self.q, w, np.array(np.broadcast_to(self.bias, (self.n, 3))), np.full((self.n, 3), self.sigma),
                        cov)


ESTIMATOR = Estimator("gyro_only", "integrates the gyro", lambda v, arw, sigma, dt, n, reach: GyroOnly(v, dt, n),
                      params=(ParamSpec("bias_deg_h", "double_array", [0.0, 0.0, 0.0], "its bias, deg/h",
                                        lengths=(3,)),))
'''


@pytest.fixture
def plugins(monkeypatch, tmp_path):
    """``plugins(name=source, ...)``: the registry rebuilt with these modules as entry points."""
    monkeypatch.syspath_prepend(str(tmp_path))

    def use(**sources):
        for name, source in sources.items():
            (tmp_path / f"{name}.py").write_text(textwrap.dedent(source))
            monkeypatch.delitem(sys.modules, name, raising=False)  # a module of that name imported before
        eps = [EntryPoint(n, f"{n}:ESTIMATOR", registry.ENTRY_POINT_GROUP) for n in sources]
        monkeypatch.setattr(registry, "entry_points", lambda group: [e for e in eps if e.group == group])
        registry.refresh()
    yield use
    registry.refresh()


def test_the_mekf_is_a_builtin_found_by_itself_and_an_unknown_type_is_one_line():
    assert registry.names()[0] == "mekf" and registry.plugin_fault(registry.get("mekf")) == ""
    with pytest.raises(ScenarioError, match=r"^estimator.type must name an estimator \(mekf, usque\), got 'ukf'$"):
        load_scenario(SENSORS).with_values("estimator", type="ukf")


def test_a_plugin_filter_flies_in_the_stepwise_driver_as_selected(plugins):
    plugins(gyro_only=GYRO_ONLY)
    assert registry.names() == ("mekf", "gyro_only")
    scn = load_scenario(SENSORS)  # on the estimate: the filter closes the loop
    mine = simulate(scn.with_values("estimator", type="gyro_only"), 1, duration=2.0)
    blind = simulate(scn.with_values("sensors", faults=["star_tracker off"]), 1, duration=2.0)
    nominal = simulate(scn, 1, duration=2.0)
    for name in ("q_BN", "q_BN_est", "omega_BN_B"):
        np.testing.assert_array_equal(getattr(mine, name), getattr(blind, name))
    assert np.max(np.abs(mine.q_BN_est - nominal.q_BN_est)) > 1e-9  # the MEKF's updates show


def test_a_filters_own_parameter_reaches_it_without_its_prefix(plugins):
    plugins(gyro_only=GYRO_ONLY)
    values = {**load_scenario(SENSORS).values["estimator"], "type": "gyro_only", "gyro_only.bias_deg_h": [36, 0, 0]}
    filt = registry.build_filter(values, 1e-6, np.full(3, 1e-5), 0.01, 2, 0)
    est = filt.step(0, np.zeros((2, 3)))
    np.testing.assert_allclose(est.omega_BN_B, [[-np.radians(0.01), 0, 0]] * 2, rtol=1e-12)  # 36 deg/h off


def test_a_plugin_that_fails_its_check_is_skipped_in_one_line_and_the_mekf_flies_on(plugins, capsys):
    plugins(sigma_of_one=GYRO_ONLY.replace('"gyro_only"', '"sigma_of_one"').replace(
        "np.full((self.n, 3), self.sigma)", "np.full(3, self.sigma)"),
        raises_on_import="raise RuntimeError('broken on import')\n",
        uncounted=GYRO_ONLY.replace('"gyro_only"', '"uncounted"').replace(", self.dropped = dt, n, 0", " = dt, n"))
    assert registry.names() == ("mekf",)
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 3 and all(x.startswith("attitude-sil: estimator plugin ") for x in lines), lines
    assert "'raises_on_import'" in lines[0] and "could not be loaded: RuntimeError: broken on import" in lines[0]
    assert "'sigma_of_one'" in lines[1] and "its estimate's attitude_sigma is (3,), not finite (1, 3)" in lines[1]
    assert "'uncounted'" in lines[2] and "needs a count 'dropped'" in lines[2]
    assert simulate(load_scenario(SENSORS), 1, duration=0.1).q_BN_est.shape == (1, 11, 4)


def test_a_campaign_flies_the_estimator_its_scenario_selects():
    # the unscented filter of examples/custom_estimator, installed as a user installs a plugin (the Makefile)
    from attitude_sil.core.sim.engine import simulate_summary
    from attitude_sil.tuning.montecarlo import load_mc_spec, run_chunk, run_of

    mc = default_config_dir() / "mc_hst_roll_step_sensors.yaml"
    usque = load_mc_spec(mc, runs=2, overrides={"set.plant.duration": 12.0, "set.estimator.type": "usque"})
    mekf = load_mc_spec(mc, runs=2, overrides={"set.plant.duration": 12.0})
    table, other = run_chunk(usque, 0, 2), run_chunk(mekf, 0, 2)
    assert run_of(usque, 1).param("estimator", "type") == "usque"
    alone = simulate_summary(run_of(usque, 1), 1)  # run 1 alone, its scenario as the campaign made it
    assert alone.metrics["ake_rms_x_rad"][0] == pytest.approx(table["ake_rms_x_rad"][1], rel=1e-12)
    # another filter, if not by much: on these small errors the unscented filter and the MEKF agree to 2e-10
    assert np.all(table["ake_rms_x_rad"] != other["ake_rms_x_rad"])
