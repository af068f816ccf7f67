"""The lockstep protocol as plain code (core/sim/lockstep.py): sequencing, hold, pacing, timeout, autostart.

These rules used to be testable only through a live rclpy graph; here each one
is checked directly, with the wall clock passed in.
"""

import numpy as np

from attitude_sil.core.sim.lockstep import Action, PlantLockstep, StepSequencer

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
