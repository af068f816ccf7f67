"""Flight software that commands each wheel: ``wheel_cmd`` (sensor_msgs/JointState, each wheel's motor torque).

The node is ``examples/external_controller/wheel_controller.py``: a PD law
on the attitude error and the body rate, shared among HST's four wheels by the
pseudo-inverse of their axes (the user's own allocation), one ``wheel_cmd``
a step. The reference is the package's models stepped by hand in the
lockstep's order with the example's own law function: the graph's episode
equals it to 1e-12. The bag keeps every ``wheel_cmd``, and a step's body-axis
command in the run's trajectory is the torque the wheels made of it.
"""

from __future__ import annotations

import runpy
import sys

import numpy as np

from attitude_sil.core.sim.build import build_disturbance, build_guidance, build_plant, build_wheels
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.graph.session import run_graph
from attitude_sil.storage.reader import open_bag
from conftest import CONFIG, ROOT
from conftest import start_python as _start
from conftest import stop_processes as _stop

EXAMPLE = ROOT / "examples" / "external_controller" / "wheel_controller.py"
DURATION = 3.0


def _by_hand(scn, duration: float) -> np.ndarray:
    """q_BN (K+1, 4) of the models stepped as the graph steps them, under the example's law."""
    sys.path.insert(0, str(EXAMPLE.parent))  # as when it runs: the PID example beside it on the path
    try:
        pd_wheel_torques = runpy.run_path(str(EXAMPLE))["pd_wheel_torques"]  # the example's own law
    finally:
        sys.path.remove(str(EXAMPLE.parent))
    plant, wheels, guide, dist = (build(scn, 1) for build in (build_plant, build_wheels, build_guidance,
                                                             build_disturbance))
    dt_ns = int(round(scn.dt * 1e9))
    n = int(round(duration * 1e9)) // dt_ns
    q = []
    for k in range(n + 1):
        s = plant.state
        q_RN, _ = guide.setpoint(k * dt_ns * 1e-9)
        tau_ext = dist.torque(s.q_BN, k * dt_ns)
        torques = pd_wheel_torques(s.q_BN[0], s.omega_BN_B[0], q_RN[0], 20.0, 60.0)
        out = wheels.advance(np.zeros((1, 3)), True, wheel_cmd=torques[None])
        q.append(s.q_BN[0].copy())
        if k < n:
            plant.advance(out.tau_c_B, out.h_wheels_B, tau_ext)
    return np.array(q)


def test_flight_software_that_commands_each_wheel_flies_as_the_models_stepped_by_hand(tmp_path):
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    ctrl = _start([str(EXAMPLE)])
    try:
        result = run_graph(scn, duration=DURATION, external=("controller",), record_dir=tmp_path / "bag",
                           keep_trajectory=True, progress=False)
    finally:
        assert _stop([ctrl]) == [0], ctrl.stderr.read()
    tr = result.trajectory
    reference = _by_hand(scn, DURATION)
    assert tr.q_BN.shape[1] == reference.shape[0] and np.max(np.abs(tr.q_BN[0] - reference)) <= 1e-12
    assert np.degrees(2.0 * np.arcsin(tr.q_BN[0, -1, 0])) > 0.3  # the law turns the body towards its 1 deg
    assert set(tr.kind) == {"wheel"} and np.array_equal(tr.u_cmd, tr.tau_c_B)
    bag = open_bag(tmp_path / "bag")
    sent = [m for _, m in bag.iter_decoded(["/wheel_cmd"])]
    assert len(sent) == reference.shape[0] and list(sent[0].name) == ["wheel_1", "wheel_2", "wheel_3", "wheel_4"]


def test_the_wheels_node_refuses_a_wheel_cmd_it_cannot_take_in_one_line():
    import rclpy
    from sensor_msgs.msg import JointState

    from attitude_sil.nodes.wheels_node import WheelsNode

    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    try:
        node = WheelsNode(context=context)
        msg = JointState(name=["wheel_1", "wheel_2"], effort=[0.1, 0.2])
        assert node._wheel_command_problem(msg) == ("expected an effort for each of wheel_1, wheel_2, wheel_3, "
                                                    "wheel_4, got 2 for ['wheel_1', 'wheel_2']")
        msg = JointState(effort=[0.0, float("nan"), 0.0, 0.0])
        assert node._wheel_command_problem(msg).startswith("effort not finite")
        msg = JointState(name=["wheel_4", "wheel_3", "wheel_2", "wheel_1"], effort=[0.4, 0.3, 0.2, 0.1])
        assert node._wheel_command_problem(msg) == ""
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
