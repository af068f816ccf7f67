"""A propagated orbit in the ROS graph: the guidance and the disturbance nodes read the same orbit as the engine.

Hawai'iSat's LVLH preset on an eccentric orbit with J2 (``orbit.model:
keplerian_j2``): the graph's episode equals the stepwise engine's to 1e-9,
each node propagating the orbit on its own, in the same blocks.
"""

from __future__ import annotations

import numpy as np

from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.graph.session import run_graph
from conftest import CONFIG

ECCENTRIC = {"orbit.model": "keplerian_j2", "orbit.semi_major_axis": 6.978137e6, "orbit.eccentricity": 0.02,
             "orbit.inclination_deg": 51.6, "orbit.raan_deg": 40.0, "orbit.arg_perigee_deg": 30.0,
             "orbit.true_anomaly_deg": 10.0, "orbit.j2": True}


def test_the_graph_flies_the_propagated_orbit_as_the_engine_does():
    scn = load_scenario(CONFIG / "hawaiisat_lvlh.yaml")
    scn = scn.with_values("/**", **ECCENTRIC)
    graph = run_graph(scn, duration=4.0, keep_trajectory=True, progress=False).trajectory
    engine = simulate(scn, 1, duration=4.0, driver="stepwise")
    assert graph.q_BN.shape == engine.q_BN.shape
    assert np.max(np.abs(graph.q_BN - engine.q_BN)) < 1e-9
    assert np.max(np.abs(graph.q_RN - engine.q_RN)) < 1e-9
    assert np.max(np.abs(graph.omega_RN_R - engine.omega_RN_R)) < 1e-12
    assert np.max(np.abs(graph.tau_ext_B - engine.tau_ext_B)) < 1e-12
    assert np.max(np.abs(engine.omega_RN_R[0, :, 2])) > 0.0  # J2 turns the orbit plane: a rate about the zenith
