"""``plant`` node: the spacecraft body, owner of simulation time.

Publishes ``/clock``, ``attitude`` and ``body_rate`` for step k (stamp t_k)
(and ``flexible_mode``, alpha and its rate, for paper 002's flexible model),
waits for ``wheel_torque``, ``wheel_momentum`` and ``disturbance_torque``
(and ``magnetic_torque`` where the magnetorquers fly, added to the
disturbance) stamped t_k, integrates to t_k+1 with :class:`attitude_sil.core.sim.models.Plant`
and publishes the next step (docs/architecture.md, "Lockstep"). An input that
does not arrive within ``input_timeout`` (wall time) stops the episode with an
error; one stamped for another step, non-finite, or a second one for a step is
refused with a (throttled) log line and the step waits for its producer's
message: the plant never integrates with a stale or stray input.

Service ``~/reset`` (std_srvs/Trigger) re-initialises the episode from the
current parameters and starts it.

Parameter ``hold_at`` pauses the lockstep at a step boundary: the plant stops
before publishing the first step at or after that sim time, so a tool can
change parameters of other nodes deterministically (the runner applies
scheduled controller swaps this way); setting ``hold_at`` to a later time (or
-1) releases it.

With ``command_timing: sim_timer`` (a controller on a sim-time timer,
docs/flight-software.md) ``/clock`` of step k goes out after the state, once
the step's ``attitude_setpoint`` and ``rate_setpoint`` are in and, at a tick
of the controller's timer (``command_rate``), once every reader has
acknowledged the state: a timer fires when ``/clock`` reaches its tick, and
so finds every input of the tick delivered.

With each step's state it publishes the orbit on ``orbit`` (``nav_msgs/Odometry``,
position and velocity in ``inertial``) and, where the scenario has a field
model, the geomagnetic field at the spacecraft in B on ``magnetic_field``
(:func:`attitude_sil.core.sim.build.build_environment`).

The decisions (which input completes a step, hold, pacing, timeout,
autostart) are :class:`attitude_sil.core.sim.lockstep.PlantLockstep`; this node
carries them out with rclpy timers and publishers.
"""

from __future__ import annotations

import time

import numpy as np
from std_srvs.srv import Trigger

from attitude_sil.core.sim.build import build_environment, build_plant
from attitude_sil.core.sim.lockstep import Action, PlantLockstep, is_tick, tick_period_ns
from attitude_sil.errors import AttitudeSilError
from attitude_sil.ros.contract import (
    ATTITUDE,
    ATTITUDE_SETPOINT,
    BODY_RATE,
    CLOCK,
    DISTURBANCE_TORQUE,
    FLEXIBLE_MODE,
    MAGNETIC_FIELD,
    MAGNETIC_TORQUE,
    ORBIT_TOPIC,
    RATE_SETPOINT,
    WHEEL_MOMENTUM,
    WHEEL_TORQUE,
    plant_inputs,
)
from attitude_sil.ros.convert import magnetic_field_msg, message_to_array, odometry_msg, stamp_to_ns
from attitude_sil.ros.node import SchemaNode, run_node, steady_clock
from attitude_sil.storage.cdr import clock_cdr, stamped_vector_cdr

#: wall s after which a step still waiting for its inputs sends its /clock again (controller on a sim-time timer)
CLOCK_RESEND_S = 0.5
#: at the episode's first tick, every this many resends is the episode's start (/clock 0) instead: a timer that
#: missed the jump back to 0 took its phase from a later /clock (rcl: a timer whose clock jumps back by more than
#: its period next fires one period after the first time it sees) and would tick between the episode's ticks
REPHASE_EVERY = 8  # 4 s: a node in phase but that slow would tick twice (the wheels say so if it answers twice)


class PlantNode(SchemaNode):
    """Spacecraft body in lockstep; see the module docstring."""

    schema_name = "plant"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.pub_clock = self.step_publisher(CLOCK)
        self.pub_attitude = self.step_publisher(ATTITUDE)
        self.pub_rate = self.step_publisher(BODY_RATE)
        self.pub_flex = self.step_publisher(FLEXIBLE_MODE) if self.param("model") == "flexible_axis" else None
        self.pub_orbit = self.step_publisher(ORBIT_TOPIC)
        self.pub_field = self.step_publisher(MAGNETIC_FIELD) \
            if self.param("environment.magnetic_field.model") != "none" else None
        # where the magnetorquers fly, their torque too (added to the disturbance's)
        self.input_names = plant_inputs(self.param("magnetorquers"))
        self.subs = [self.step_subscription(name, lambda m, n=name: self._on_input(n, m)) for name in self.input_names]
        # a controller on a sim-time timer: /clock waits for the step's setpoints
        gate = (ATTITUDE_SETPOINT, RATE_SETPOINT) if self.param("command_timing") == "sim_timer" else ()
        for name in gate:
            self.step_subscription(name, lambda m, n=name: self._on_input(n, m))
        self.create_service(Trigger, "~/reset", self._on_reset)
        self._wall = steady_clock()
        self.lockstep = PlantLockstep(self.input_names, gate)
        self._pace_timer = None
        self._clock_sent = 0.0  # when /clock last went out (monotonic s)
        self._resends = 0  # /clock sent again for the current step
        self._watchdog = self.create_timer(0.05, self._on_watchdog, clock=self._wall)

    # -- state of the lockstep, for the graph tools ----------------------------
    @property
    def running(self) -> bool:
        return self.lockstep.running

    @property
    def done(self) -> bool:
        return self.lockstep.done

    @property
    def error(self) -> str:
        return self.lockstep.error

    # -- episode ---------------------------------------------------------------
    def reset_episode(self) -> None:
        """Rebuild the body from the current parameters and publish step 0."""
        scn = self.scenario()
        self.core = build_plant(scn, 1)
        self.orbit, self.field = build_environment(scn)
        # a controller on a sim-time timer: its ticks (0: none to serve)
        self.tick_ns = tick_period_ns(self.param("command_timing"), self.param("command_rate"),
                                      int(round(scn.dt * 1e9)))
        self._cancel_pacing()
        self._do(self.lockstep.start(scn.steps(), int(round(scn.dt * 1e9)), time.monotonic(),
                                     self.param("hold_at")))

    def _on_reset(self, request, response):
        try:
            self.reset_episode()
        except (AttitudeSilError, ValueError) as exc:
            response.success = False
            response.message = f"reset refused: {exc}"
            return response
        response.success = True
        response.message = (f"episode started: {self.lockstep.n_steps} steps of "
                            f"{self.lockstep.dt_ns * 1e-9:g} s")
        return response

    def _do(self, action: Action) -> None:
        """Carry out what the lockstep decided."""
        ls = self.lockstep
        if action is Action.PUBLISH:
            self._publish_state()
            if ls.published(time.monotonic()):
                wall = time.monotonic() - ls.episode_wall0
                self.get_logger().info(f"episode complete: {ls.t_ns * 1e-9:g} s of sim time in {wall:.2f} s wall")
        elif action is Action.ADVANCE:
            inp = ls.inputs
            tau_ext = inp[DISTURBANCE_TORQUE]
            if MAGNETIC_TORQUE in inp:  # as the stepwise driver adds them
                tau_ext = tau_ext + inp[MAGNETIC_TORQUE]
            self.core.advance(inp[WHEEL_TORQUE], inp[WHEEL_MOMENTUM], tau_ext)
            finite = bool(np.all(np.isfinite(self.core.state.omega_BN_B)))
            self._do(ls.advanced(finite, time.monotonic(), self.param("real_time_factor"), self.param("hold_at")))
        elif action is Action.CLOCK:
            self._publish_clock()
        elif action is Action.PACE:
            self._pace_timer = self.create_timer(max(ls.publish_at - time.monotonic(), 0.0), self._on_paced,
                                                 clock=self._wall)
        elif action is Action.HOLD:
            self.get_logger().info(f"holding before step t={ls.t_ns * 1e-9:.6f} s")
        elif action is Action.FAIL:
            self.get_logger().error(ls.error)
        elif action is Action.REFUSED:
            self.get_logger().warning(ls.refusal, throttle_duration_sec=1.0)
        elif action is Action.START:
            self.get_logger().info("graph wired; starting episode")
            self.reset_episode()

    def _publish_state(self) -> None:
        t_ns = self.lockstep.t_ns
        s = self.core.state
        if not self.lockstep.clock_gate:
            self.pub_clock.publish(clock_cdr(t_ns))
        self.pub_attitude.publish(stamped_vector_cdr(s.q_BN[0], t_ns, "inertial"))
        self.pub_rate.publish(stamped_vector_cdr(s.omega_BN_B[0], t_ns, "body"))
        if self.pub_flex is not None and hasattr(self.core, "alpha"):
            self.pub_flex.publish(stamped_vector_cdr(self.core.alpha[0], t_ns, "body"))
        self._publish_environment(t_ns, s.q_BN)

    def _publish_environment(self, t_ns: int, q_BN: np.ndarray) -> None:
        """The orbit at step ``t_ns`` and the field at the spacecraft, in B for the attitude ``q_BN`` (1, 4)."""
        now = self.orbit.at(t_ns)
        self.pub_orbit.publish(odometry_msg(now.r_N, now.v_N, t_ns))
        if self.pub_field is not None:
            self.pub_field.publish(magnetic_field_msg(self.field.field_B(np.array([t_ns]), q_BN)[0], np.zeros(3),
                                                      t_ns))

    def _publish_clock(self) -> None:
        """The clock gate opened: ``/clock`` of step k; at a tick of the controller's timer, once every reader
        has acknowledged the step's state (the tick then finds it delivered)."""
        t_ns = self.lockstep.t_ns
        if is_tick(t_ns, self.tick_ns):
            self.await_readers([p for p in (self.pub_attitude, self.pub_rate, self.pub_flex) if p is not None], t_ns)
        self.pub_clock.publish(clock_cdr(t_ns))
        self._clock_sent = time.monotonic()
        self._resends = 0
        self._do(self.lockstep.clocked())

    def fail(self, reason: str) -> None:
        """Stop the episode with an error the runner reports."""
        self._do(self.lockstep.fail(reason))

    def _on_input(self, name: str, msg) -> None:
        value = message_to_array(msg)[None]
        self._do(self.lockstep.offer(name, stamp_to_ns(msg.header.stamp), value))

    def _cancel_pacing(self) -> None:
        if self._pace_timer is not None:
            self.destroy_timer(self._pace_timer)
            self._pace_timer = None

    def _on_paced(self) -> None:
        self._cancel_pacing()
        self._do(self.lockstep.paced(self.param("hold_at")))

    def on_parameters_set(self, names: list[str]) -> None:
        if "hold_at" in names:
            self._do(self.lockstep.release(self.param("hold_at"), time.monotonic()))

    # -- watchdog and autostart -----------------------------------------------
    def wired(self) -> bool:
        """Every input has a publisher and every output a subscriber (matched, not merely seen)."""
        return all(s.get_publisher_count() > 0 for s in self.subs) and all(
            p.get_subscription_count() > 0 for p in (self.pub_attitude, self.pub_rate, self.pub_clock)
        )

    def _on_watchdog(self) -> None:
        ls = self.lockstep
        now = time.monotonic()
        if (self.lockstep.clock_gate and ls.running and ls.clock_out and ls.publish_at is None and not ls.holding
                and now - self._clock_sent > CLOCK_RESEND_S):
            self._resend_clock(ls.t_ns, now)
        wired = (not ls.running and not ls.done and not ls.error and self.param("autostart")) and self.wired()
        self._do(ls.watchdog(time.monotonic(), self.param("input_timeout"), self.param("autostart"), wired))

    def _resend_clock(self, t_ns: int, now: float) -> None:
        """A step still waits for its inputs: its ``/clock`` again, or, every :data:`REPHASE_EVERY` th time at the
        episode's first tick, ``/clock`` 0 (the step's own follows at the next resend).

        A controller on a sim-time timer reads ``/clock`` best effort (rclpy's TimeSource, depth 1): a lost
        ``/clock`` is a tick that never fires, and the same time again brings it (a reader that has it sees no
        change). A lost jump back to 0 at a new episode is worse: the timer takes its phase from the first time it
        sees after the jump (t_s + T, not T), and never fires at the tick the wheels wait for. ``/clock`` 0 again
        puts it back in phase (0 + T); one in phase but slow sees no change unless it already fired, and then ticks
        twice at T (after ``REPHASE_EVERY * CLOCK_RESEND_S`` without an answer).
        """
        self._resends += 1
        if self.tick_ns > 0 and t_ns == self.tick_ns and self._resends % REPHASE_EVERY == 0:
            self.get_logger().warning(
                f"no command for the first tick t={t_ns * 1e-9:g} s in {self._resends * CLOCK_RESEND_S:.1f} s: "
                "sending /clock 0 again (a sim-time timer that missed the jump back to 0 ticks out of phase)")
            self.pub_clock.publish(clock_cdr(0))
        else:
            self.pub_clock.publish(clock_cdr(t_ns))
        self._clock_sent = now


def main(args: list[str] | None = None) -> int:
    """Console script ``plant_node``."""
    return run_node(PlantNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
