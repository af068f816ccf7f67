"""Bad input reaches the user as one line and a non-zero exit, never a traceback.

Input errors found before anything runs go through ``cli.main`` in this process
(``cli`` fixture: the same code, without 2 s of interpreter and import start-up
per case; test_user_errors.py checks that a real process prints the same one
line). Runs that record, fill a disk or print JSON run as real processes.
"""

import subprocess
import sys

import pytest

from attitude_sil.core.sim.scenario import ScenarioError, load_scenario
from conftest import CONFIG, ROOT

GOOD = (CONFIG / "hst_roll_step.yaml").read_text()


def run_cli(*args, timeout=60):
    return subprocess.run([sys.executable, "-m", "attitude_sil.cli", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout, stdin=subprocess.DEVNULL)


def assert_one_line_error(proc, *needles):
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for n in needles:
        assert n in lines[0], lines[0]


def test_missing_file(cli):
    assert_one_line_error(cli("run", "config/nope.yaml"), "config/nope.yaml", "no such scenario file")


@pytest.mark.parametrize(
    "old,new,needles",
    [
        ("    step_time: 0.0", "    step_tme: 0.0", ("guidance.step_tme", "did you mean 'step_time'")),
        ("    duration: 20.0", "    duration: fast", ("plant.duration", "must be a number")),
        ("    control_period: 0.01          # s, 100 Hz control", "    control_period: -0.01",
         ("control_period", "must be > 0.0")),
        ("    pid.kp: [48.894, 48.894, 48.894]", "    pid.kp: [48.894, 48.894]", ("pid.kp", "3 elements")),
        ("    geometry: hst_pyramid", "    geometry: tetrahedron", ("wheels.geometry", "one of")),
        ("guidance:", "guidanse:", ("unknown section", "did you mean 'guidance'")),
        ("    duration: 20.0", "    duration: 20.005", ("whole number of control periods",)),
    ],
)
def test_bad_scenario_values(tmp_path, old, new, needles, cli):
    assert old in GOOD
    path = tmp_path / "bad.yaml"
    path.write_text(GOOD.replace(old, new))
    with pytest.raises(ScenarioError):
        load_scenario(path)
    assert_one_line_error(cli("run", str(path), "--no-record", "--quiet"), str(path), *needles)


def test_not_yaml(tmp_path, cli):
    path = tmp_path / "broken.yaml"
    path.write_text("plant: [unclosed\n")
    assert_one_line_error(cli("run", str(path)), "not valid YAML")


def test_bad_flags(cli):
    assert_one_line_error(cli("run", "config/hst_roll_step.yaml", "--duration", "-1", "--no-record"),
                          "--duration")
    assert_one_line_error(cli("run", "config/hst_roll_step.yaml", "--controller", "bangbang", "--no-record"),
                          "controller_type")


def test_existing_bag_is_not_overwritten(tmp_path):
    bag = tmp_path / "run1"
    first = run_cli("run", "config/hst_roll_step.yaml", "--duration", "0.5", "--record", str(bag), "--quiet")
    assert first.returncode == 0, first.stderr
    size = (bag / "run1_0.mcap").stat().st_size
    second = run_cli("run", "config/hst_roll_step.yaml", "--duration", "0.5", "--record", str(bag), "--quiet")
    assert_one_line_error(second, "already contains a bag")
    assert (bag / "run1_0.mcap").stat().st_size == size


def test_run_json_is_last_stdout_line(tmp_path):
    import json

    proc = run_cli("run", "config/hst_roll_step.yaml", "--duration", "3", "--json", "--record", str(tmp_path / "b"))
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads(proc.stdout.strip().splitlines()[-1])
    for key in ("controller_type", "sim_time_s", "wall_time_s", "real_time_factor", "time_constant_s",
                "rise_time_s", "settling_time_s", "overshoot_pct", "steady_state_error_rad",
                "control_effort_Nms", "cost_J", "iae", "ise", "itae", "bag"):
        assert key in metrics
    assert metrics["sim_time_s"] == 3.0 and metrics["controller_type"] == "pid"
    assert metrics["bag"] == str(tmp_path / "b")
    assert "real time" in proc.stderr  # the progress line


@pytest.mark.parametrize("name,content,needle", [
    ("list.yaml", "- [1, 2]\n", "got a list"),
    ("broken.yaml", "controller: {ros__parameters: [1\n", "not valid YAML"),
    ("flat.yaml", "controller: 3\n", "ros__parameters"),
    ("badvalue.yaml", "controller:\n  ros__parameters:\n    pid.kp: [1.0, .nan, 1.0]\n", "pid.kp"),
])
def test_bad_parameter_files(tmp_path, name, content, needle, cli):
    path = tmp_path / name
    path.write_text(content)
    assert_one_line_error(cli("run", "config/hst_roll_step.yaml", "--params", str(path), "--no-record"),
                          str(path), needle)


@pytest.mark.parametrize("args,needle", [
    (("run", "config/hst_roll_step.yaml", "--duration", "inf", "--no-record"), "finite"),
    (("run", "config/hst_roll_step.yaml", "--duration", "nan", "--no-record"), "finite"),
    (("tune", "config/tune_hst_pid_ga.yaml", "--set", "algorithm.generations=0"), "algorithm.generations"),
    (("tune", "config/tune_hst_pid_ga.yaml", "--set", "algorithm.pop_size=1.5"), "algorithm.pop_size"),
    (("tune", "config/tune_hst_pid_ga.yaml", "--set", "seed=[1"), "not a YAML value"),
    (("tune", "config/tune_hst_pid_ga.yaml", "--set", "output=config/hst_roll_step.yaml/out", "--no-record"),
     "hst_roll_step.yaml is a file"),
])
def test_bad_values_on_the_command_line(args, needle, cli):
    assert_one_line_error(cli(*args), needle)


def test_tuning_genes_must_lie_inside_the_parameters_range(tmp_path):
    from attitude_sil.tuning.spec import SpecError, load_spec

    spec = (CONFIG / "tune_pitch_flc_ga.yaml").read_text()
    for old, new, needle in (("low: 1, high: 7", "low: 1, high: 100", "<= 7"),
                             ):
        assert old in spec, old
        path = tmp_path / "bad_rules.yaml"
        path.write_text(spec.replace(old, new).replace("scenarios: [", f"scenarios: [{CONFIG}/"))
        with pytest.raises(SpecError, match=needle):
            load_spec(path)
    hst = (CONFIG / "tune_hst_pid_ga.yaml").read_text().replace("scenarios: [", f"scenarios: [{CONFIG}/")
    for old, new, needle in (("{param: pid.kp, low: 1.0, high: 200.0}", "{param: pid.kp, low: 1.0, high: .inf}",
                              "finite"),
                             ("{param: pid.ki, low: 0.0, high: 5.0}", "{param: pid.ki, low: -1.0, high: 5.0}",
                              "outside pid.ki's range")):
        path = tmp_path / "bad_gain.yaml"
        path.write_text(hst.replace(old, new))
        with pytest.raises(SpecError, match=needle):
            load_spec(path)


def test_a_full_disk_stops_the_run_with_one_line_and_a_readable_bag(tmp_path):
    import resource
    import signal

    from attitude_sil.storage.reader import open_bag

    def small_disk():  # a 200 kB file-size limit stands in for a full filesystem
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))

    bag = tmp_path / "full"
    proc = subprocess.run([sys.executable, "-m", "attitude_sil.cli", "run", "config/hst_roll_step.yaml", "--record",
                           str(bag), "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=120,
                          stdin=subprocess.DEVNULL, preexec_fn=small_disk)
    assert_one_line_error(proc, "recording stopped at t=", "File too large", "readable up to there")
    reader = open_bag(bag)  # what was written before the disk filled is a valid bag, metadata included
    assert 0 < reader.end_ns * 1e-9 < 20.0
    assert sum(t.count for t in reader.topics.values()) > 1000
    assert not list(bag.glob("*.tmp"))


def test_an_unwritable_bag_directory_is_found_at_start(tmp_path, cli):
    assert_one_line_error(cli("run", "config/hst_roll_step.yaml", "--record", "config/hst_roll_step.yaml/bag",
                                  "--quiet"), "hst_roll_step.yaml")


@pytest.mark.parametrize("processes", [False, True], ids=["one-process", "processes"])
def test_quiet_runs_print_no_ros_info_lines(processes):
    proc = run_cli("run", "config/hst_roll_step.yaml", "--duration", "0.5", "--no-record", "--quiet",
                   *(["--processes"] if processes else []), timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "[INFO]" not in proc.stderr and "episode complete" not in proc.stderr, proc.stderr
    assert "scenario hst_roll_step" in proc.stdout
