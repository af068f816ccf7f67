"""``plant`` node: the spacecraft body, owner of simulation time.

Publishes ``/clock``, ``attitude`` and ``body_rate`` for step k (stamp t_k)
(and ``flexible_mode``, alpha and its rate, for paper 002's flexible model),
waits for ``wheel_torque``, ``wheel_momentum`` and ``disturbance_torque``
stamped t_k, integrates to t_k+1 with :class:`attitude_sil.core.engine.Plant`
and publishes the next step (DESIGN.md section 3, lockstep). An input that
does not arrive within ``input_timeout`` (wall time), or arrives with a wrong
stamp or non-finite values, stops the episode with an error; the plant never
integrates with a stale input.

Service ``~/reset`` (std_srvs/Trigger) re-initialises the episode from the
current parameters and starts it.

Parameter ``hold_at`` pauses the lockstep at a step boundary: the plant stops
before publishing the first step at or after that sim time, so a tool can
change parameters of other nodes deterministically (the runner applies
scheduled controller swaps this way); setting ``hold_at`` to a later time (or
-1) releases it.
"""

from __future__ import annotations

import time

import numpy as np
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from rosgraph_msgs.msg import Clock
from std_srvs.srv import Trigger

from attitude_sil.core.engine import build_plant
from attitude_sil.nodes.common import (
    LOCKSTEP_QOS,
    SchemaNode,
    ns_to_stamp,
    run_node,
    stamp_to_ns,
    steady_clock,
)

INPUTS = ("wheel_torque", "wheel_momentum", "disturbance_torque")


class PlantNode(SchemaNode):
    """Spacecraft body in lockstep; see the module docstring."""

    schema_name = "plant"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.pub_clock = self.create_publisher(Clock, "/clock", LOCKSTEP_QOS)
        self.pub_attitude = self.create_publisher(QuaternionStamped, "attitude", LOCKSTEP_QOS)
        self.pub_rate = self.create_publisher(Vector3Stamped, "body_rate", LOCKSTEP_QOS)
        self.pub_flex = None
        if self.param("model") == "flexible_axis":
            self.pub_flex = self.create_publisher(Vector3Stamped, "flexible_mode", LOCKSTEP_QOS)
        self.subs = [
            self.create_subscription(Vector3Stamped, name, lambda m, n=name: self._on_input(n, m), LOCKSTEP_QOS)
            for name in INPUTS
        ]
        self.create_service(Trigger, "~/reset", self._on_reset)
        self._wall = steady_clock()
        self.running = False
        self.done = False
        self.holding = False
        self.error = ""
        self.k = 0
        self.t_ns = 0
        self._inputs: dict[str, np.ndarray] = {}
        self._pace_timer = None
        self._watchdog = self.create_timer(0.05, self._on_watchdog, clock=self._wall)

    # -- episode ---------------------------------------------------------------
    def reset_episode(self) -> None:
        """Rebuild the body from the current parameters and publish step 0."""
        scn = self.scenario()
        self.core = build_plant(scn, 1)
        self.dt_ns = int(round(scn.dt * 1e9))
        self.n_steps = scn.steps()
        self.k = 0
        self.t_ns = 0
        self._inputs.clear()
        self.running = True
        self.done = False
        self.holding = False
        self.error = ""
        self._episode_wall0 = time.monotonic()
        self._finish_step()

    def _on_reset(self, request, response):
        try:
            self.reset_episode()
        except ValueError as exc:
            response.success = False
            response.message = f"reset refused: {exc}"
            return response
        response.success = True
        response.message = f"episode started: {self.n_steps} steps of {self.dt_ns * 1e-9:g} s"
        return response

    def _publish_state(self) -> None:
        stamp = ns_to_stamp(self.t_ns)
        s = self.core.state
        self.pub_clock.publish(Clock(clock=stamp))
        q = QuaternionStamped()
        q.header.stamp = stamp
        q.header.frame_id = "inertial"
        q.quaternion.x, q.quaternion.y, q.quaternion.z, q.quaternion.w = (float(v) for v in s.q_BN[0])
        self.pub_attitude.publish(q)
        w = Vector3Stamped()
        w.header.stamp = stamp
        w.header.frame_id = "body"
        w.vector.x, w.vector.y, w.vector.z = (float(v) for v in s.omega_BN_B[0])
        self.pub_rate.publish(w)
        if self.pub_flex is not None and hasattr(self.core, "alpha"):
            f = Vector3Stamped()
            f.header.stamp = stamp
            f.header.frame_id = "body"
            f.vector.x, f.vector.y = (float(v) for v in self.core.alpha[0])
            self.pub_flex.publish(f)
        self._step_wall0 = time.monotonic()

    def fail(self, reason: str) -> None:
        """Stop the episode with an error the runner reports."""
        if self.running:
            self.running = False
            self.error = reason
            self.get_logger().error(reason)

    def _on_input(self, name: str, msg: Vector3Stamped) -> None:
        if not self.running:
            return
        t = stamp_to_ns(msg.header.stamp)
        if t < self.t_ns:
            return  # stale: from an earlier step or episode
        if t > self.t_ns:
            self.fail(f"plant: {name} stamped {t * 1e-9:.6f} s while waiting for step {self.t_ns * 1e-9:.6f} s")
            return
        v = np.array([[msg.vector.x, msg.vector.y, msg.vector.z]])
        if not self.finite(v):
            self.fail(f"plant: {name} at t={t * 1e-9:.6f} s is not finite: {v[0].tolist()}")
            return
        self._inputs[name] = v
        if len(self._inputs) == len(INPUTS) and self.k < self.n_steps:
            self._advance()

    def _advance(self) -> None:
        inp = self._inputs
        self.core.advance(inp["wheel_torque"], inp["wheel_momentum"], inp["disturbance_torque"])
        self._inputs = {}
        self.k += 1
        self.t_ns = self.k * self.dt_ns
        if not self.finite(self.core.state.omega_BN_B):
            self.fail(f"plant: state diverged at t={self.t_ns * 1e-9:.6f} s")
            return
        rtf = self.param("real_time_factor")
        if rtf > 0.0:
            delay = self._episode_wall0 + self.t_ns * 1e-9 / rtf - time.monotonic()
            if delay > 0.0:
                self._pace_timer = self.create_timer(delay, self._paced_publish, clock=self._wall)
                return
        self._finish_step()

    def _paced_publish(self) -> None:
        self.destroy_timer(self._pace_timer)
        self._pace_timer = None
        if self.running:
            self._finish_step()

    def _finish_step(self) -> None:
        hold_at = self.param("hold_at")
        if hold_at >= 0.0 and self.t_ns >= round(hold_at * 1e9):
            self.holding = True
            self.get_logger().info(f"holding before step t={self.t_ns * 1e-9:.6f} s")
            return
        self._publish_state()
        if self.k >= self.n_steps > 0:
            self.running = False
            self.done = True
            wall = time.monotonic() - self._episode_wall0
            self.get_logger().info(f"episode complete: {self.t_ns * 1e-9:g} s of sim time in {wall:.2f} s wall")

    def on_parameters_set(self, names: list[str]) -> None:
        if "hold_at" in names and self.holding and self.running:
            hold_at = self.param("hold_at")
            if hold_at < 0.0 or self.t_ns < round(hold_at * 1e9):
                self.holding = False
                self._step_wall0 = time.monotonic()
                self._finish_step()

    # -- watchdog and autostart -----------------------------------------------
    def wired(self) -> bool:
        """Every input has a publisher and every output a subscriber (matched, not merely seen)."""
        return all(s.get_publisher_count() > 0 for s in self.subs) and all(
            p.get_subscription_count() > 0 for p in (self.pub_attitude, self.pub_rate, self.pub_clock)
        )

    def _on_watchdog(self) -> None:
        if not self.running and not self.done and not self.error and self.param("autostart") and self.wired():
            self.get_logger().info("graph wired; starting episode")
            self.reset_episode()
            return
        if self.running and self._pace_timer is None and not self.holding:
            waited = time.monotonic() - self._step_wall0
            if waited > self.param("input_timeout"):
                missing = [n for n in INPUTS if n not in self._inputs]
                self.fail(
                    f"plant: no {', '.join(missing)} for step t={self.t_ns * 1e-9:.6f} s "
                    f"within {self.param('input_timeout'):g} s; episode stopped"
                )


def main(args: list[str] | None = None) -> int:
    """Console script ``plant_node``."""
    return run_node(PlantNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
