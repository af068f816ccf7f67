"""The hand-started graph: five node scripts as the README starts them, ``record``, ``episode`` and ``metrics``.

One graph for the module: the five ``*_node`` processes with ``--ros-args
--params-file config/hst_roll_step.yaml`` (and a second file shortening the
episode to 5 s), nothing else given - no ``use_sim_time``, no ``autostart``.
They must wait for ``plant/reset`` (an episode that started by itself would be
gone before ``episode`` asks), run on sim time (``episode`` warns of a node
that does not), and give the metrics of ``attitude-sil run`` on the same
scenario: the lockstep is deterministic, so they agree to 1e-9. ``record``
runs as real processes (one stopped by ``--episode``, one by Ctrl-C);
``episode`` and ``metrics`` run in this process (``cli.main``), which saves
their start-up. Every process runs in its own process group, killed in a
``finally``.

Every wait is for a condition (a line a process prints, a process's exit);
none shares a budget with the others. Each is bounded by :data:`HANG_GUARD`
alone, a bound for a hung process, not a measure of speed: five node
processes, two recorders and a reference run share the machine, and the
reference run may first compile the numba kernels.
"""

from __future__ import annotations

import json
import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time

import yaml

from attitude_sil.cli import main
from attitude_sil.core.analysis.metrics import METRIC_KEYS
from attitude_sil.core.sim.scenario import GRAPH_NODES
from attitude_sil.ros.contract import RECORDED_TOPICS, STEP_TOPICS, VIEW_TOPICS
from attitude_sil.storage.reader import open_bag
from conftest import CONFIG, ROOT

SCENARIO = CONFIG / "hst_roll_step.yaml"
DURATION = 5.0
STEPS = round(DURATION / 0.01) + 1  # t = 0 .. DURATION at the 100 Hz control period
HANG_GUARD = 600.0  # wall s after which any one wait calls the process hung


def _popen(args: list[str], env=None, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, *args], cwd=ROOT, stdin=subprocess.DEVNULL, start_new_session=True,
                            env=env, **kw)


class _Lines:
    """The stderr lines of a process, read by a thread, awaited by condition with a deadline."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.lines: list[str] = []
        self._q: queue.Queue = queue.Queue()
        threading.Thread(target=self._read, args=(proc.stderr,), daemon=True).start()

    def _read(self, stream) -> None:
        for line in stream:
            self._q.put(line)
        self._q.put(None)

    def wait_for(self, done) -> None:
        deadline = time.monotonic() + HANG_GUARD
        while not done(self.lines):
            try:
                item = self._q.get(timeout=max(deadline - time.monotonic(), 0.01))
            except queue.Empty:
                raise AssertionError(f"hung: no such line within {HANG_GUARD:g} s:\n" + "".join(self.lines)) from None
            assert item is not None, "".join(self.lines)
            self.lines.append(item)


def _same(a: dict, b: dict) -> None:
    assert a["scenario"] == b["scenario"] and a["controller_type"] == b["controller_type"]
    assert math.isclose(a["sim_time_s"], b["sim_time_s"], abs_tol=1e-9)
    for key in METRIC_KEYS:
        if a[key] is None or b[key] is None:
            assert a[key] == b[key], key
        else:
            assert math.isclose(a[key], b[key], rel_tol=1e-9, abs_tol=1e-12), (key, a[key], b[key])


def test_hand_started_graph_record_episode_metrics(tmp_path, capfd):
    short = tmp_path / "short.yaml"
    # the plant waits for a step's inputs up to the hang guard, not its default 10 s: a node process's first step
    # loads (or, after an edit of the package's core, compiles) its kernels, which on a loaded machine can take
    # longer; the numbers do not depend on it
    short.write_text(yaml.safe_dump({"/**/plant": {"ros__parameters": {"duration": DURATION,
                                                                        "input_timeout": HANG_GUARD}}}))
    # the reference: attitude-sil run on the same scenario, on a domain of its own, meanwhile
    own = {k: v for k, v in os.environ.items() if k != "ROS_DOMAIN_ID"}
    ref = subprocess.Popen([sys.executable, "-m", "attitude_sil.cli", "run", str(SCENARIO), "--duration",
                            str(DURATION), "--json", "--quiet", "--record", str(tmp_path / "run_bag")], cwd=ROOT,
                           stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           env=own, start_new_session=True)
    procs = [ref]
    try:
        for name in GRAPH_NODES:  # as the README shows: python -m is the console script's module
            procs.append(_popen(["-m", f"attitude_sil.nodes.{name}_node", "--ros-args", "--params-file",
                                 str(SCENARIO), "--params-file", str(short)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        rec_bag, ctrl_c_bag = tmp_path / "live", tmp_path / "ctrl_c"
        recorders = []
        for bag, extra in ((rec_bag, ["--episode"]), (ctrl_c_bag, [])):
            proc = _popen(["-m", "attitude_sil.cli", "record", str(bag), *extra], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True)
            procs.append(proc)
            recorders.append((proc, _Lines(proc)))
        # ready: every step topic subscribed (its publishers found) and the nodes' parameters taken
        for _, lines in recorders:
            lines.wait_for(lambda ls: any("parameter snapshot" in ln for ln in ls)
                           and sum("subscribed to" in ln for ln in ls) >= len(STEP_TOPICS))
        # the nodes waited for the reset (autostart off by default) and run on the plant's clock
        capfd.readouterr()
        assert main(["episode", "--json", "--quiet", "--scenario", str(SCENARIO), "--timeout", str(HANG_GUARD)]) == 0
        out, err = capfd.readouterr()
        assert err == "", err  # no node off sim time
        episode = json.loads(out.splitlines()[-1])
        assert episode["bag"] is None and episode["wall_time_s"] > 0
        # record --episode stops by itself at the episode's end; the other one on Ctrl-C
        rec, _ = recorders[0]
        assert rec.wait(timeout=HANG_GUARD) == 0, rec.stderr.read()
        ctrl_c, ctrl_c_lines = recorders[1]
        # the other one has taken the whole episode (it may lag the graph on a loaded machine): then Ctrl-C
        whole = f"episode recorded to t={DURATION:.3f} s: {STEPS} of {STEPS} steps"
        ctrl_c_lines.wait_for(lambda ls: any(whole in ln for ln in ls))
        ctrl_c.send_signal(signal.SIGINT)
        assert ctrl_c.wait(timeout=HANG_GUARD) == 0
        out, err = ref.communicate(timeout=HANG_GUARD)
        assert ref.returncode == 0, err
        run = json.loads(out.splitlines()[-1])
    finally:
        for proc in procs:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    _same(episode, run)
    # the bags: readable, metadata.yaml, the publishers' QoS, a snapshot; the same metrics
    for bag in (rec_bag, ctrl_c_bag):
        assert (bag / "metadata.yaml").is_file()
        reader = open_bag(bag)
        assert "attitude_sil.parameters" in reader.custom_data
        assert set(reader.topics) <= {n if n.startswith("/") else "/" + n for n in {**RECORDED_TOPICS, **VIEW_TOPICS}}
        assert reader.topics["/attitude"].count == STEPS
        # the 3D view's frames with every attitude recorded, and the body model once the snapshot gave the scene
        assert reader.topics["/tf"].count == STEPS and reader.topics["/body_model"].count == 1
        assert "transient_local" in reader.topics["/attitude"].offered_qos_profiles
    for bag, extra in ((rec_bag, ["--scenario", str(SCENARIO)]), (tmp_path / "run_bag", [])):
        assert main(["metrics", str(bag), "--json", *extra]) == 0
        out, err = capfd.readouterr()
        assert err == "", err  # the run's bag holds its scenario section; --scenario gives the other
        metrics = json.loads(out.splitlines()[-1])
        _same(metrics, run)
        assert metrics["wall_time_s"] is None and metrics["bag"] == str(bag)
    # without --scenario a hand-recorded bag has no metrics settings: said in one note, defaults used
    assert main(["metrics", str(rec_bag)]) == 0
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and "--scenario" in err, err
