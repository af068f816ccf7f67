"""An outside controller's timing figures (core/analysis/latency.py), from arrivals given by hand."""

import pytest

from attitude_sil.core.analysis.latency import CommandArrivals, latency_summary


def test_latency_summary_is_in_ms():
    s = latency_summary([0.001, 0.002, 0.003])
    assert s["controller_latency_mean_ms"] == pytest.approx(2.0)
    assert s["controller_latency_max_ms"] == pytest.approx(3.0)
    assert 2.9 < s["controller_latency_p99_ms"] <= 3.0


def test_a_wall_clock_controller_that_skips_periods_shows_stale_steps_and_missed_periods():
    # a 10 ms controller against 10 ms steps: it answers steps 0-3, then is silent for 3 periods (steps 4-6), then
    # answers again; its latency is measured from the newest state
    arr = CommandArrivals(0.010)
    t = 0.0
    for k in range(10):
        arr.step(t)
        arr.attitude(t)
        if not 4 <= k <= 6:
            arr.command(t + 0.002)
        t += 0.010
    s = arr.summary()
    assert s["command_count"] == 7
    # step 0 (no command yet) and steps 5, 6 and 7, whose newest command (step 3's, at 32 ms) is more than 15 ms old
    assert s["command_stale_steps"] == 4
    assert s["command_missed_periods"] == 3  # the 40 ms gap between step 3's and step 7's commands
    assert s["controller_latency_mean_ms"] == pytest.approx(2.0)


def test_a_slower_controller_on_time_is_never_stale():
    # a 100 ms controller against 10 ms steps, answering every tenth step: held, never late
    arr = CommandArrivals(0.100)
    for k in range(100):
        if k % 10 == 0:
            arr.command(k * 0.010 + 0.001)
        arr.step(k * 0.010 + 0.002)
    s = arr.summary()
    assert s["command_stale_steps"] == 0 and s["command_missed_periods"] == 0 and s["command_count"] == 10


def test_commands_before_any_state_have_no_latency():
    arr = CommandArrivals(0.010)
    arr.command(0.0)
    arr.command(0.010)
    s = arr.summary()
    assert s["command_count"] == 2 and s["command_missed_periods"] == 0
    assert "controller_latency_mean_ms" not in s
