"""Monte Carlo disperses faults (issue 43): ``dispersions.faults``, each entry a fault with a probability, a
time window and a size range, drawn per run into the run's own ``faults`` list.

Checked: each run's lines are drawn within their windows and ranges, at about the entry's rate; every run's
metrics are those of the run's own scenario (``run_of``, the scenario a bag of it is flown from) flown
alone, bit for bit; an entry that cannot fly is one line naming it.
"""

from __future__ import annotations

import numpy as np
import pytest

from attitude_sil.core.faults import parse_fault
from attitude_sil.core.sim.engine import simulate_summary
from attitude_sil.core.sim.scenario import default_config_dir
from attitude_sil.errors import SpecError
from attitude_sil.tuning.montecarlo import load_mc_spec, run_chunk, run_of

CONFIG = default_config_dir()
SPEC = f"""
name: faults_drawn
scenario: {CONFIG}/hst_roll_step_sensors.yaml
controller: pid
set: {{plant.duration: 4.0}}
runs: 24
seed: 7
dispersions:
  sensor_seeds: true
  faults:
    - {{fault: gyro.x bias_jump, probability: 0.5, time: [1, 3], value: [100, 1000]}}
    - {{fault: star_tracker off, probability: 0.25, time: [0.5, 2], for: 1.5}}
requirements: {{settling_time_s: {{max: 20.0}}}}
output: {{out}}
"""


def _spec(tmp_path, text: str = SPEC, runs: int | None = None):
    path = tmp_path / "mc.yaml"
    path.write_text(text.replace("{out}", str(tmp_path / "out")))
    return load_mc_spec(path, runs=runs)


def test_each_run_draws_its_faults_within_their_windows_and_ranges(tmp_path):
    spec = _spec(tmp_path)
    table = run_chunk(spec, 0, 24)
    drawn = [[parse_fault(line) for line in text.split("; ") if line] for text in table["faults"]]
    jumps = [f for fs in drawn for f in fs if f.kind == "gyro"]
    blind = [f for fs in drawn for f in fs if f.kind == "star_tracker"]
    assert 6 <= len(jumps) <= 18 and 1 <= len(blind) <= 12  # about 12 and 6 of 24 (binomial: beyond 3 sigma)
    assert all(1.0 <= f.time_s <= 3.0 and 100.0 <= f.value <= 1000.0 and f.index == "x" for f in jumps)
    assert all(0.5 <= f.time_s <= 2.0 and f.duration_s == 1.5 for f in blind)
    for r in (0, 5, 13):  # a run's metrics are those of its own scenario, flown alone
        alone = simulate_summary(run_of(spec, r), 1, controller="pid", warn_nonfinite=False)
        assert alone.metrics["settling_time_s"][0] == table["settling_time_s"][r] or (
            np.isnan(alone.metrics["settling_time_s"][0]) and np.isnan(table["settling_time_s"][r]))
        assert alone.metrics["iae"][0] == table["iae"][r]
    assert len({float(x) for x in table["iae"]}) > 12  # the runs differ


@pytest.mark.parametrize("entry, words", [
    ("{fault: gyro.w bias_jump, value: [1, 2]}", "unknown target 'gyro.w'"),
    ("{fault: gyro.x bias_jump}", "value must be [low, high] where the mode has a size"),
    ("{fault: gyro.x off, value: [1, 2]}", "value must be [low, high] where the mode has a size, and absent"),
    ("{fault: gyro.x off, time: [1, 9]}", "after the run's end (4 s)"),
    ("{fault: gyro.x off, probability: 2}", "probability must be a number in 0..1"),
    ("{fault: controller delay, value: [0.015, 0.02]}", "not a whole number"),
])
def test_a_fault_entry_that_cannot_fly_is_one_line(tmp_path, entry, words):
    text = SPEC.replace("    - {fault: gyro.x bias_jump, probability: 0.5, time: [1, 3], value: [100, 1000]}",
                        f"    - {entry}")
    with pytest.raises(SpecError) as err:
        _spec(tmp_path, text)
    assert "\\n" not in str(err.value) and words in str(err.value) and "dispersions.faults[0]" in str(err.value)
