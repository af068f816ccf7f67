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

import numpy as np
import pytest

from attitude_sil.core.sensing import registry
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario
from attitude_sil.errors import ScenarioError
from conftest import GYRO_ONLY

SENSORS = default_config_dir() / "hst_roll_step_sensors.yaml"

def test_the_mekf_is_a_builtin_found_by_itself_and_an_unknown_type_is_one_line():
    assert registry.names()[0] == "mekf" and registry.plugin_fault(registry.get("mekf")) == ""
    with pytest.raises(ScenarioError, match=r"^estimator.type must name an estimator \(mekf\), got 'ukf'$"):
        load_scenario(SENSORS).with_values("estimator", type="ukf")


def test_a_plugin_filter_flies_in_the_stepwise_driver_as_selected(estimator_plugins):
    estimator_plugins(gyro_only=GYRO_ONLY)
    assert registry.names() == ("mekf", "gyro_only")
    scn = load_scenario(SENSORS)  # on the estimate: the filter closes the loop
    mine = simulate(scn.with_values("estimator", type="gyro_only"), 1, duration=2.0)
    blind = simulate(scn.with_values("sensors", faults=["star_tracker off"]), 1, duration=2.0)
    nominal = simulate(scn, 1, duration=2.0)
    for name in ("q_BN", "q_BN_est", "omega_BN_B"):
        np.testing.assert_array_equal(getattr(mine, name), getattr(blind, name))
    assert np.max(np.abs(mine.q_BN_est - nominal.q_BN_est)) > 1e-9  # the MEKF's updates show


def test_a_filters_own_parameter_reaches_it_without_its_prefix(estimator_plugins):
    estimator_plugins(gyro_only=GYRO_ONLY)
    values = {**load_scenario(SENSORS).values["estimator"], "type": "gyro_only", "gyro_only.bias_deg_h": [36, 0, 0]}
    filt = registry.build_filter(values, 1e-6, np.full(3, 1e-5), 0.01, 2, 0)
    est = filt.step(0, np.zeros((2, 3)))
    np.testing.assert_allclose(est.omega_BN_B, [[-np.radians(0.01), 0, 0]] * 2, rtol=1e-12)  # 36 deg/h off


def test_a_plugin_that_fails_its_check_is_skipped_in_one_line_and_the_mekf_flies_on(estimator_plugins, capsys):
    estimator_plugins(bad_shape=GYRO_ONLY.replace('"gyro_only"', '"bad_shape"').replace(
        "np.full((self.n, 3), self.sigma)", "np.full(3, self.sigma)"),
        no_load="raise RuntimeError('broken on import')\n")
    assert registry.names() == ("mekf",)
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 2 and all(x.startswith("attitude-sil: estimator plugin ") for x in lines), lines
    assert "its estimate's attitude_sigma is (3,), not finite (1, 3)" in lines[0]
    assert "could not be loaded: RuntimeError: broken on import" in lines[1]
    assert simulate(load_scenario(SENSORS), 1, duration=0.1).q_BN_est.shape == (1, 11, 4)
