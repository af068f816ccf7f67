"""The lockstep protocol as plain code (core/sim/lockstep.py): sequencing, hold, pacing, timeout, autostart.

These rules used to be testable only through a live rclpy graph; here each one
is checked directly, with the wall clock passed in.
"""

import numpy as np
import pytest

from attitude_sil.core.sim.lockstep import (
    Action,
    CommandHold,
    PlantLockstep,
    StepSequencer,
    command_period_ns,
    is_tick,
    tick_period_ns,
)

DT = 10_000_000  # 10 ms in ns
ZERO = np.zeros((1, 3))
PLANT_INPUTS = ("wheel_torque", "wheel_momentum", "disturbance_torque")


def _feed_all(ls: PlantLockstep, t_ns: int) -> Action:
    action = Action.NONE
    for name in PLANT_INPUTS:
        action = ls.offer(name, t_ns, ZERO)
    return action


def test_sequencer_accepts_next_refuses_skips_and_restarts_on_reset():
    seq = StepSequencer()
    assert seq.classify(DT, DT) == StepSequencer.MISMATCH  # a stray message before the episode starts
    assert seq.last_ns is None
    assert seq.classify(0, DT) == StepSequencer.NEW
    assert seq.classify(DT, DT) == StepSequencer.NEXT
    assert seq.classify(DT, DT) == StepSequencer.DUPLICATE
    assert seq.classify(3 * DT, DT) == StepSequencer.MISMATCH  # a skipped step is refused ...
    assert seq.last_ns == DT  # ... and not taken as the new position
    assert seq.classify(2 * DT, DT) == StepSequencer.NEXT
    assert seq.classify(DT, DT) == StepSequencer.STALE  # a late or foreign old stamp cannot reset it
    assert seq.last_ns == 2 * DT
    assert seq.classify(0, DT) == StepSequencer.NEW  # a reset starts over at 0


def test_a_step_advances_only_when_every_input_of_that_step_is_in():
    ls = PlantLockstep(PLANT_INPUTS)
    assert ls.start(3, DT, now=0.0, hold_at=-1.0) is Action.PUBLISH
    assert ls.published(0.0) is False
    assert ls.offer("wheel_torque", 0, ZERO) is Action.NONE
    assert ls.offer("wheel_momentum", 0, ZERO) is Action.NONE
    # the same message again (an episode restarted at its first step) is taken once: it does not complete the step
    assert ls.offer("wheel_torque", 0, ZERO) is Action.NONE and len(ls.inputs) == 2
    assert ls.offer("wheel_torque", 0, ZERO + 1.0) is Action.REFUSED  # another value for it: the first is kept
    assert ls.offer("disturbance_torque", 0, ZERO) is Action.ADVANCE
    assert ls.advanced(True, now=0.0, real_time_factor=0.0, hold_at=-1.0) is Action.PUBLISH
    assert ls.k == 1 and ls.t_ns == DT and ls.inputs == {}


def test_stale_future_nonfinite_or_second_inputs_are_refused_naming_the_stamp_expected():
    ls = PlantLockstep(PLANT_INPUTS)
    ls.start(10, DT, 0.0, -1.0)
    ls.published(0.0)
    _feed_all(ls, 0)
    ls.advanced(True, 0.0, 0.0, -1.0)
    ls.published(0.0)
    assert ls.offer("wheel_torque", 0, ZERO) is Action.REFUSED  # from step 0: stale, refused with a line
    assert ls.refusal == "plant: wheel_torque stamped 0.000000 s refused (stale); expected 0.010000 s"
    assert ls.offer("wheel_torque", 2 * DT, ZERO) is Action.REFUSED  # a future stamp: refused, the run goes on
    assert ls.refusal == "plant: wheel_torque stamped 0.020000 s refused (ahead of the step); expected 0.010000 s"
    assert ls.running and "wheel_torque" not in ls.inputs
    assert ls.offer("disturbance_torque", DT, np.array([[np.nan, 0.0, 0.0]])) is Action.REFUSED
    assert "not finite" in ls.refusal and "disturbance_torque" not in ls.inputs
    assert ls.offer("wheel_torque", DT, np.ones((1, 3))) is Action.NONE
    assert ls.offer("wheel_torque", DT, 1e9 * np.ones((1, 3))) is Action.REFUSED  # a second one: the first stays
    assert np.array_equal(ls.inputs["wheel_torque"], np.ones((1, 3)))
    # the producers' messages still complete the step
    assert ls.offer("wheel_momentum", DT, ZERO) is Action.NONE
    assert ls.offer("disturbance_torque", DT, ZERO) is Action.ADVANCE
    assert not ls.error
    assert ls.fail("first reason") is Action.FAIL
    assert ls.fail("second reason") is Action.NONE and ls.error == "first reason"  # the first reason stays


def test_episode_ends_after_the_last_step_and_takes_no_more_inputs():
    ls = PlantLockstep(PLANT_INPUTS)
    ls.start(2, DT, 0.0, -1.0)
    for k in range(2):
        assert ls.published(0.0) is False
        assert _feed_all(ls, k * DT) is Action.ADVANCE
        assert ls.advanced(True, 0.0, 0.0, -1.0) is Action.PUBLISH
    assert ls.published(0.0) is True and ls.done and not ls.running
    assert _feed_all(ls, 2 * DT) is Action.NONE


def test_divergence_stops_the_episode():
    ls = PlantLockstep(PLANT_INPUTS)
    ls.start(5, DT, 0.0, -1.0)
    _feed_all(ls, 0)
    assert ls.advanced(False, 0.0, 0.0, -1.0) is Action.FAIL
    assert "diverged at t=0.010000 s" in ls.error


def test_hold_stops_before_the_step_and_release_publishes_it():
    ls = PlantLockstep(PLANT_INPUTS)
    assert ls.start(100, DT, 0.0, hold_at=0.0) is Action.HOLD  # a swap scheduled at t = 0
    assert ls.release(hold_at=0.02, now=1.0) is Action.PUBLISH
    ls.published(1.0)
    _feed_all(ls, 0)
    assert ls.advanced(True, 1.0, 0.0, hold_at=0.02) is Action.PUBLISH
    ls.published(1.0)
    _feed_all(ls, DT)
    assert ls.advanced(True, 1.0, 0.0, hold_at=0.02) is Action.HOLD  # t = 0.02 s reached
    assert ls.k == 2 and ls.holding
    assert ls.release(hold_at=0.02, now=2.0) is Action.NONE  # the same hold: stay
    assert ls.release(hold_at=-1.0, now=2.0) is Action.PUBLISH and not ls.holding
    # a holding plant does not time out, however long the tool takes
    ls2 = PlantLockstep(PLANT_INPUTS)
    ls2.start(10, DT, 0.0, hold_at=0.0)
    assert ls2.watchdog(now=1e6, input_timeout=10.0, autostart=False, wired=True) is Action.NONE


def test_pacing_delays_a_step_until_its_wall_time():
    ls = PlantLockstep(PLANT_INPUTS)
    ls.start(100, DT, now=100.0, hold_at=-1.0)
    ls.published(100.0)
    _feed_all(ls, 0)
    assert ls.advanced(True, now=100.001, real_time_factor=1.0, hold_at=-1.0) is Action.PACE
    assert abs(ls.publish_at - 100.01) < 1e-12  # step 1 is due 10 ms after the start at 1x
    assert ls.watchdog(now=1e6, input_timeout=1.0, autostart=False, wired=True) is Action.NONE  # paced: no timeout
    assert ls.paced(hold_at=-1.0) is Action.PUBLISH and ls.publish_at is None
    ls.published(100.01)
    _feed_all(ls, DT)
    # late already (the graph is slower than real time): publish at once
    assert ls.advanced(True, now=101.0, real_time_factor=1.0, hold_at=-1.0) is Action.PUBLISH
    # at 2x real time step 3 is due 15 ms after the start
    ls.published(101.0)
    _feed_all(ls, 2 * DT)
    assert ls.advanced(True, now=100.0, real_time_factor=2.0, hold_at=-1.0) is Action.PACE
    assert abs(ls.publish_at - 100.015) < 1e-12


def test_watchdog_names_the_missing_inputs_after_the_timeout():
    ls = PlantLockstep(PLANT_INPUTS)
    ls.start(10, DT, 0.0, -1.0)
    ls.published(now=5.0)
    ls.offer("wheel_torque", 0, ZERO)
    assert ls.watchdog(now=14.9, input_timeout=10.0, autostart=False, wired=True) is Action.NONE
    assert ls.watchdog(now=15.1, input_timeout=10.0, autostart=False, wired=True) is Action.FAIL
    assert ls.error == ("plant: no wheel_momentum, disturbance_torque for step t=0.000000 s within 10 s; "
                        "episode stopped")


def test_autostart_only_when_idle_and_wired():
    ls = PlantLockstep(PLANT_INPUTS)
    assert ls.watchdog(0.0, 10.0, autostart=True, wired=False) is Action.NONE
    assert ls.watchdog(0.0, 10.0, autostart=False, wired=True) is Action.NONE
    assert ls.watchdog(0.0, 10.0, autostart=True, wired=True) is Action.START
    ls.start(1, DT, 0.0, -1.0)
    assert ls.watchdog(0.0, 10.0, autostart=True, wired=True) is Action.NONE  # running
    ls.published(0.0)
    _feed_all(ls, 0)
    ls.advanced(True, 0.0, 0.0, -1.0)
    ls.published(0.0)
    assert ls.done
    assert ls.watchdog(1e6, 10.0, autostart=True, wired=True) is Action.NONE  # one episode, not a loop


# -- a controller on a timer of its own (command_timing sim_timer / wall) -------------------------------------------

SETPOINTS = ("attitude_setpoint", "rate_setpoint")
Q = np.array([[0.0, 0.0, 0.0, 1.0]])


def test_a_clock_gate_holds_clock_until_the_steps_setpoints_are_in():
    ls = PlantLockstep(PLANT_INPUTS, SETPOINTS)
    ls.start(2, DT, 0.0, -1.0)
    ls.published(0.0)
    assert not ls.clock_out
    # the wheels' and disturbance's outputs may come first; the step still waits for its /clock
    assert _feed_all(ls, 0) is Action.NONE
    assert ls.offer("attitude_setpoint", 0, Q) is Action.NONE
    assert ls.offer("rate_setpoint", DT, ZERO) is Action.REFUSED  # a setpoint of another step opens nothing
    assert ls.offer("rate_setpoint", 0, ZERO) is Action.CLOCK
    assert ls.offer("rate_setpoint", 0, ZERO) is Action.NONE  # a repeat: /clock went once
    assert ls.clocked() is Action.ADVANCE  # the inputs were in: the step goes on at once
    ls.advanced(True, 0.0, 0.0, -1.0)
    ls.published(0.0)
    assert not ls.clock_out and ls.gate == {}  # each step waits again


def test_the_last_steps_clock_goes_out_after_the_episode_is_done():
    ls = PlantLockstep(PLANT_INPUTS, SETPOINTS)
    ls.start(1, DT, 0.0, -1.0)
    ls.published(0.0)
    ls.offer("attitude_setpoint", 0, Q)
    ls.offer("rate_setpoint", 0, ZERO)
    ls.clocked()
    assert _feed_all(ls, 0) is Action.ADVANCE
    ls.advanced(True, 0.0, 0.0, -1.0)
    assert ls.published(0.0) is True and ls.done
    # a timer of the controller may be due at the last step: its /clock still goes, nothing else is taken
    ls.offer("attitude_setpoint", DT, Q)
    assert ls.offer("rate_setpoint", DT, ZERO) is Action.CLOCK
    assert ls.clocked() is Action.NONE
    assert ls.offer("wheel_torque", DT, ZERO) is Action.NONE


def test_a_late_gate_is_named_first_in_the_timeout_line():
    ls = PlantLockstep(PLANT_INPUTS, SETPOINTS)
    ls.start(3, DT, 0.0, -1.0)
    ls.published(0.0)
    ls.offer("attitude_setpoint", 0, Q)
    assert ls.watchdog(11.0, 10.0, False, False) is Action.FAIL
    assert ls.error.startswith("plant: no rate_setpoint, wheel_torque, wheel_momentum, disturbance_torque for step")


def _hold(timing: str, period_steps: int = 1) -> CommandHold:
    return CommandHold(timing, period_steps * DT, (np.zeros((1, 3)), False))


def test_sim_timer_commands_take_effect_one_period_after_their_tick():
    # logical execution time: tick j's command (stamped j T) acts over [(j + 1) T, (j + 2) T); zero before
    hold = _hold("sim_timer", period_steps=10)
    assert [hold.is_tick(k * DT) for k in (0, 5, 10, 20)] == [False, False, True, True]
    for k in range(10):
        assert not hold.waits_at(k * DT) and np.all(hold.applied(k * DT)[0] == 0.0)
    assert hold.waits_at(10 * DT)  # a tick: the wheels wait for its command
    assert hold.offer(10 * DT, np.full((1, 3), 1.0), False, 10 * DT) == ""
    assert not hold.waits_at(10 * DT)
    assert np.all(hold.applied(10 * DT)[0] == 0.0)  # not yet: one period of delay
    assert np.all(hold.applied(19 * DT)[0] == 0.0)
    assert hold.offer(20 * DT, np.full((1, 3), 2.0), True, 20 * DT) == ""
    value, torque_mode = hold.applied(20 * DT)
    assert np.all(value == 1.0) and torque_mode is False  # tick 1's command, held for a whole period
    assert np.all(hold.applied(29 * DT)[0] == 1.0)
    assert hold.offer(30 * DT, np.full((1, 3), 3.0), False, 30 * DT) == ""
    value, torque_mode = hold.applied(30 * DT)
    assert np.all(value == 2.0) and torque_mode is True


def test_a_clock_0_at_the_unanswered_first_tick_replays_the_start_and_two_in_a_row_start_an_episode():
    # the plant sends /clock 0 again among its first tick's own (a timer out of phase); a reset plant sends a new
    # episode's 0 twice 0.5 s apart: the first 0 right after the first tick's /clock is a replay, whether these
    # wheels have the tick's command yet or not (the plant may wait for another input); a second 0 in a row is not
    hold = _hold("sim_timer", period_steps=10)
    tick = 10 * DT
    assert hold.replays_start(0, previous_ns=tick)
    hold.offer(tick, np.ones((1, 3)), False, tick)
    assert hold.replays_start(0, previous_ns=tick)  # the tick answered here, another input late: still a replay
    assert not hold.replays_start(0, previous_ns=0)  # the second 0 in a row: a new episode
    assert not hold.replays_start(0, previous_ns=None)  # the first /clock these wheels see
    assert not hold.replays_start(0, previous_ns=20 * DT)  # after a later tick: a reset, the timer ticked in phase
    assert not hold.replays_start(DT, previous_ns=tick)  # only a 0 is the start
    assert not _hold("wall").replays_start(0, previous_ns=tick)
    assert hold.offer(tick, np.ones((1, 3)), False, tick) == ""  # the same command again: a repeat, nothing said
    why = hold.offer(tick, np.full((1, 3), 2.0), False, tick)  # a node that ticked twice, its law stepped twice
    assert "second, different command" in why and np.all(hold.applied(2 * tick)[0] == 1.0)  # the first is kept


def test_sim_timer_refuses_stamps_off_its_ticks_or_ahead_of_the_clock():
    hold = _hold("sim_timer", period_steps=10)
    assert "not a tick" in hold.offer(15 * DT, np.ones((1, 3)), False, 15 * DT)
    assert "not a tick" in hold.offer(1_795_746_522_912_842_032, np.ones((1, 3)), False, 15 * DT)  # a wall stamp
    assert "ahead of the clock" in hold.offer(20 * DT, np.ones((1, 3)), False, 15 * DT)
    assert hold.ticks == {}
    # the wheels took /clock of step 19: the tick of step 20 may overtake its /clock, nothing later
    assert hold.offer(20 * DT, np.ones((1, 3)), False, 20 * DT) == "" and 20 * DT in hold.ticks
    assert [hold.next_tick(t * DT) for t in (0, 1, 10, 11, 20)] == [10 * DT, 10 * DT, 10 * DT, 20 * DT, 20 * DT]


def test_wall_applies_the_newest_command_whatever_its_stamp():
    hold = _hold("wall")
    assert not hold.is_tick(10 * DT) and not hold.waits_at(10 * DT)
    assert np.all(hold.applied(0)[0] == 0.0)
    assert hold.offer(1_795_746_522_912_842_032, np.full((1, 3), 4.0), False, None) == ""
    assert hold.offer(7, np.full((1, 3), 5.0), False, None) == ""
    assert np.all(hold.applied(DT)[0] == 5.0)


def test_a_timer_period_is_a_whole_number_of_steps():
    assert command_period_ns(0.0, DT) == DT
    assert command_period_ns(10.0, DT) == 10 * DT
    assert command_period_ns(100.0, DT) == DT
    # the ticks a node serves: a sim-time timer's only; none (0) for the other styles, whose rate may be any
    assert tick_period_ns("sim_timer", 10.0, DT) == 10 * DT
    assert tick_period_ns("wall", 30.0, DT) == 0 and tick_period_ns("stamped", 0.0, DT) == 0
    assert not is_tick(10 * DT, 0)
    for bad in (30.0, 150.0, 1000.0):  # 33.3 ms, 6.7 ms, 1 ms against 10 ms steps
        with pytest.raises(ValueError, match="not a whole number of control periods"):
            command_period_ns(bad, DT)
