"""The fault model (issue 43, item 1): a scenario's ``faults`` list, one line per fault.

Checked here: the line's grammar (``TARGET MODE [VALUE] [at T] [for D]``)
reads back as written; every fault that cannot fly (an unknown target, a
mode its target cannot take, a time outside the
run, a wheel the geometry lacks) is one line naming it, in a file under
``/**`` as the guide says to set it; and today's ``wheels.failure.*`` keys
are the same fault: a run with either is the same run, bit for bit, in both
drivers, and not the run without it.
"""

from __future__ import annotations

import numpy as np
import pytest

from attitude_sil.cli import main
from attitude_sil.core.faults import (
    Fault,
    changes_at,
    foreign_line,
    parse_fault,
    parse_faults,
)
from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import default_config_dir, load_scenario
from attitude_sil.errors import ScenarioError

CONFIG = default_config_dir()


@pytest.mark.parametrize("text, fault", [
    ("wheel1 stuck at 2", Fault("wheel", 1, "stuck", None, 2.0)),
    ("wheel3 lost", Fault("wheel", 3, "lost", None, 0.0)),
    ("  wheel12   lost   at 0.25 ", Fault("wheel", 12, "lost", None, 0.25)),
    ("star_tracker off at 30 for 60", Fault("star_tracker", None, "off", None, 30.0, 60.0)),
])
def test_a_fault_line_reads_as_written(text, fault):
    assert parse_fault(text) == fault
    assert parse_fault(str(fault)) == fault  # its canonical line reads back the same


@pytest.mark.parametrize("text, words", [
    ("wheel1", "expected TARGET MODE"),
    ("whel1 lost", "unknown target 'whel1'"),
    ("wheel0 lost", "unknown target 'wheel0'"),
    ("gyro.w stuck", "unknown target 'gyro.w'"),
    ("wheel1 off", "a wheel cannot be 'off'"),
    ("controller stuck", "a controller cannot be 'stuck'"),
    ("wheel1 friction at 2", "friction needs a value"),
    ("star_tracker latency 0 at 3", "a latency must be > 0"),
    ("star_tracker latency at 3 for 60", "latency needs a value"),
    ("wheel1 lost at -1", "'at' must be >= 0 s"),
    ("wheel1 lost at nan", "must be finite"),
    ("wheel1 lost at two", "at 'two' is not a number"),
    ("wheel1 lost when 2", "unexpected 'when'"),
    ("wheel1 lost for 3", "lasts to the end of the run; drop 'for'"),
    ("star_tracker off at 1 for 0", "'for' must be > 0 s"),
])
def test_a_fault_that_cannot_fly_is_one_line_naming_it(text, words):
    with pytest.raises(ScenarioError) as err:
        parse_fault(text)
    message = str(err.value)
    assert "\n" not in message and words in message and message.startswith(f"fault {text!r}"), message


def test_the_run_bounds_a_fault():
    assert parse_faults(["wheel4 lost at 20"], 20.0, 4)[0].index == 4  # the last step is in the run
    assert parse_faults(["wheel4 lost at 99"], 0.0, 4)  # a run until stopped has no end to be after
    for lines, n, words in ((["wheel1 lost at 20.5"], 4, "after the run's end (20 s)"),
                            (["wheel5 lost"], 4, "the geometry has wheels 1..4"),
                            (["wheel1 lost"], None, "needs wheels.actuator reaction_wheels"),
                            (["wheel1 lost", "wheel2 stuck at 3"], 4, "one wheel fault per run")):
        with pytest.raises(ScenarioError, match=words.replace("(", r"\(").replace(")", r"\)")):
            parse_faults(lines, 20.0, n)


@pytest.mark.parametrize("faults, words", [
    ('["wheel5 lost at 1"]', "the geometry has wheels 1..4"),
    ('["wheel1 lost at 25"]', "after the run's end (20 s)"),
    ('["star_tracker latency 0.1 at 1"]', "needs the sensing loop"),
    ('["wheel1 stuck at 1", "wheel2 lost at 2"]', "one wheel fault per run"),
    ('"wheel1 lost"', "must be a list"),
    ('["controller delay 0.015"]', "not a whole number of 0.01 s control steps"),
    ('["controller gain -1"]', "a gain must be >= 0"),
    ('["controller delay 0"]', "a delay must be > 0"),
    ('["controller gain 2", "controller gain 3 at 1"]', "one controller gain per run"),
])
def test_a_fault_list_that_cannot_fly_stops_the_run_in_one_line(faults, words, tmp_path, capfd):
    over = tmp_path / "faults.yaml"
    over.write_text(f"/**:\n  ros__parameters:\n    faults: {faults}\n")
    assert main(["run", str(CONFIG / "hst_roll_step.yaml"), "--params", str(over), "--no-record", "--quiet"]) == 2
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and words in err, err


def test_a_wheel_fault_in_the_list_is_the_failure_keys_run_bit_for_bit_in_both_drivers():
    base = load_scenario(CONFIG / "hst_roll_step.yaml")
    listed = base.with_values("wheels", faults=["wheel2 stuck at 0.5"])
    keyed = base.with_values("wheels", **{"failure.wheel": 2, "failure.time": 0.5, "failure.mode": "stuck"})
    with pytest.raises(ScenarioError, match="one wheel fault per run; say it in faults"):
        keyed.with_values("wheels", faults=["wheel1 lost at 1"])
    for driver in ("compiled", "stepwise"):
        a, b, nominal = (simulate(s, 1, duration=1.5, driver=driver) for s in (listed, keyed, base))
        for name in ("q_BN", "wheel_speed", "tau_c_B"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=f"{driver} {name}")
        assert not np.array_equal(a.wheel_speed[:, :, 1], nominal.wheel_speed[:, :, 1])  # the fault acts
        assert np.array_equal(a.wheel_speed[:, :51], nominal.wheel_speed[:, :51])  # and not before 0.5 s


def test_a_star_tracker_off_is_the_outage_of_its_window_bit_for_bit():
    base = load_scenario(CONFIG / "hst_roll_step_sensors.yaml")
    listed = base.with_values("sensors", faults=["star_tracker off at 0.5 for 1"])
    scheduled = base.with_values("sensors", **{"star_tracker.outages_s": [0.5, 1.5]})
    a, b, nominal = (simulate(s, 2, duration=2.0, driver="stepwise") for s in (listed, scheduled, base))
    for name in ("q_BN", "q_BN_est", "attitude_sigma"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    sigma = np.max(a.attitude_sigma[0], axis=1)
    grown, nominal_sigma = sigma[149], np.max(nominal.attitude_sigma[0, 149])  # 1.49 s: the filter flew blind
    assert grown > 1.3 * nominal_sigma  # the outage acts: the filter's attitude sigma grows on the gyro alone
    with pytest.raises(ScenarioError, match="needs the sensing loop"):  # the list under /**, no sensing loop
        load_scenario(CONFIG / "hst_roll_step.yaml").with_values("wheels", faults=["star_tracker off at 1"])


def test_a_fault_between_two_steps_is_neither_flown_nor_said_and_each_lasting_one_ends():
    blind = parse_fault("star_tracker off at 1.001 for 0.005")  # no step time in [1.001, 1.006)
    assert all(not changes_at([blind], k, 10_000_000) for k in range(200))
    window = parse_fault("star_tracker off at 1.001 for 0.01")  # the step at 1.01 is in it
    assert [(k, active) for k in range(200) for _, active in changes_at([window], k, 10_000_000)] == \
        [(101, True), (102, False)]


def test_a_fault_set_on_a_node_that_does_not_fly_it_is_one_line():
    scn = load_scenario(CONFIG / "hst_roll_step_sensors.yaml")
    with pytest.raises(ScenarioError, match="set on the sensors but flown by the wheels node"):
        scn.with_values("sensors", faults=["wheel1 lost at 1"])
    assert foreign_line(["wheel1 lost", "star_tracker off"], "wheels") == (
        "fault 'star_tracker off' is flown by the sensors node, not the wheels: set it there (attitude-sil fault does)")
    assert foreign_line(["star_tracker off at 2"], "sensors") == ""
