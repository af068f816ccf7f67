"""A real Dask cluster on 127.0.0.1: a ``dask scheduler`` and two ``dask worker`` processes.

A small campaign (through the ``attitude-sil montecarlo --scheduler`` command) and
a small tuning run through the cluster give the local results bit for bit; a
worker killed (SIGKILL) while it holds chunks has them re-run by Dask and the
campaign is still complete and identical. A scheduler killed mid-campaign is one line naming it and the
``--resume`` command, which finishes the campaign without it, identical to a local run byte for byte; a task's
own error on a live scheduler stays its own. Everything is shut down in a finally.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from distributed import Client

from attitude_sil.errors import SchedulerLostError
from attitude_sil.tuning.evaluate import Evaluator
from attitude_sil.tuning.executor import DaskCluster, InProcess
from attitude_sil.tuning.montecarlo import load_mc_spec, run_campaign
from attitude_sil.tuning.optimize import run_tuning
from attitude_sil.tuning.spec import apply_overrides, load_spec
from conftest import CONFIG, ROOT


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _dask(*args) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    env.pop("DASK_SCHEDULER_ADDRESS", None)
    return subprocess.Popen([sys.executable, "-m", "dask", *args], cwd=ROOT, env=env, stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


def _start_cluster(workers: int) -> tuple[str, list[subprocess.Popen]]:
    """A scheduler and ``workers`` worker processes on 127.0.0.1, the workers connected; stop with _stop."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    procs = [_dask("scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard")]
    try:
        for _ in range(workers):  # no nanny: the process we kill is the worker itself
            procs.append(_dask("worker", address, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny",
                               "--no-dashboard", "--death-timeout", "60"))
        with Client(address, timeout=60) as client:
            client.wait_for_workers(workers, timeout=120)
    except BaseException:
        _stop(procs)
        raise
    return address, procs


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in reversed(procs):
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=5)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


@pytest.fixture(scope="module")
def cluster():
    address, procs = _start_cluster(2)
    try:
        yield address, procs
    finally:
        _stop(procs)


def _spec_file(tmp_path, name: str, runs: int, chunk: int, duration: float):
    text = (CONFIG / "mc_hst_roll_step.yaml").read_text().replace("scenario: ", f"scenario: {CONFIG}/")
    text = text.replace("output: results/mc_hst_roll_step", f"output: {tmp_path}/{name}").replace(
        "runs: 1000", f"runs: {runs}").replace("chunk: 100", f"chunk: {chunk}").replace(
        "disturbance.models: [noise]", f"disturbance.models: [noise]\n  plant.duration: {duration}")
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    return path


def _same(a: dict, b: dict) -> None:
    assert a and a.keys() == b.keys()
    for key in a:
        assert np.array_equal(a[key], b[key], equal_nan=a[key].dtype.kind == "f"), key


def test_campaign_and_tuning_on_the_cluster_equal_the_local_results(cluster, tmp_path):
    address, _ = cluster
    path = _spec_file(tmp_path, "mc", runs=30, chunk=6, duration=3.0)
    cli = subprocess.run([sys.executable, "-m", "attitude_sil.cli", "montecarlo", str(path), "--scheduler", address,
                          "--no-bags", "--json"], cwd=ROOT, capture_output=True, text=True, timeout=300,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}, stdin=subprocess.DEVNULL)
    assert cli.returncode == 0, cli.stderr
    summary = json.loads(cli.stdout.splitlines()[-1])
    assert summary["executor"] == "dask" and summary["completed_runs"] == 30 and summary["workers"] == 2
    remote = json.loads((tmp_path / "mc" / "runs.json").read_text())
    local_spec = load_mc_spec(_spec_file(tmp_path, "mc_local", runs=30, chunk=30, duration=3.0))
    with InProcess() as ex:  # one chunk, every core: cut and run differently, the same numbers
        local = run_campaign(local_spec, ex)
    assert json.loads((tmp_path / "mc_local" / "runs.json").read_text()) == remote
    assert (tmp_path / "mc" / "responses.png").is_file() and (tmp_path / "mc" / "histograms.png").is_file()
    assert local.summary["metrics"] == summary["metrics"]

    spec = apply_overrides(load_spec(CONFIG / "tune_hst_pid_ga.yaml"),
                           {"algorithm.pop_size": 8, "algorithm.generations": 2, "output": str(tmp_path / "t_local")})
    mine = run_tuning(spec)
    with DaskCluster(address) as ex, Evaluator(spec, executor=ex) as ev:
        theirs = run_tuning(apply_overrides(spec, {"output": str(tmp_path / "t_dask")}), evaluator=ev)
    assert np.array_equal(mine.best_x, theirs.best_x) and np.array_equal(mine.best_cost, theirs.best_cost)
    assert (tmp_path / "t_local" / "evaluations.json").read_text() == \
        (tmp_path / "t_dask" / "evaluations.json").read_text()


def test_a_killed_worker_has_its_chunks_rerun_and_the_campaign_is_complete(cluster, tmp_path):
    address, procs = cluster
    spec = load_mc_spec(_spec_file(tmp_path, "mc", runs=48, chunk=4, duration=4.0))
    victim = procs[2]
    seen = []

    def progress(done: int, total: int, wall: float) -> None:
        # once a chunk is back, kill the victim outright at the first progress call that finds it holding
        # chunks (the scheduler hands a worker a chunk or two at a time: between two it holds none)
        held = len(ex.client.processing()[addr]) if done and not seen else 0
        if held:
            seen.append(held)
            os.killpg(victim.pid, signal.SIGKILL)
            victim.wait(timeout=30)

    with DaskCluster(address) as ex:
        assert ex.workers == 2
        addr = next(a for a, pid in ex.client.run(os.getpid).items() if pid == victim.pid)
        result = run_campaign(spec, ex, progress=progress)
        # the scheduler saw the worker go (asked directly: the client's scheduler_info() is a cached copy,
        # refreshed every few seconds)
        assert ex.client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.workers)) == 1
    assert seen and seen[0] > 0 and victim.returncode == -signal.SIGKILL  # it died holding chunks
    assert not result.interrupted and sorted(result.table["run"].tolist()) == list(range(48))
    local_spec = load_mc_spec(_spec_file(tmp_path, "local", runs=48, chunk=48, duration=4.0))
    with InProcess() as ex:
        local = run_campaign(local_spec, ex)
    _same(local.table, result.table)


def test_a_tasks_own_error_on_the_cluster_is_not_a_lost_scheduler(cluster):
    address, _ = cluster
    with DaskCluster(address) as ex:
        # os.stat raises an OSError on the worker, as a connection error would in the client: it stays the task's
        with pytest.raises(FileNotFoundError):
            list(ex.as_completed(os.stat, [("/nonexistent/attitude_sil",)]))
        with pytest.raises(ValueError, match="invalid literal") as raised:
            ex.map(int, [("x",)])
        assert not isinstance(raised.value, SchedulerLostError) and not ex.lost
        assert ex.map(abs, [(-1,), (-2,)]) == [1, 2]  # the scheduler still serves


def test_a_lost_scheduler_is_one_line_and_its_resume_command_finishes_the_campaign(tmp_path):
    # a cluster of its own: the module's is shared with the other tests
    address, procs = _start_cluster(1)
    scheduler = procs[0]
    path = _spec_file(tmp_path, "mc", runs=200, chunk=2, duration=10.0)
    log = tmp_path / "mc" / "chunks.jsonl"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("DASK_SCHEDULER_ADDRESS", None)
    try:
        cli = subprocess.Popen([sys.executable, "-m", "attitude_sil.cli", "montecarlo", str(path), "--scheduler",
                                address, "--no-bags"], cwd=ROOT, env=env, stdin=subprocess.DEVNULL,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            # the scheduler dies once two chunks are back (the header and two lines), with most still to run
            deadline = time.monotonic() + 300
            while cli.poll() is None and not (log.is_file() and len(log.read_text().splitlines()) >= 3):
                assert time.monotonic() < deadline, "no chunk came back from the cluster"
                time.sleep(0.05)
            os.killpg(scheduler.pid, signal.SIGKILL)
            scheduler.wait(timeout=30)
            out, err = cli.communicate(timeout=120)
        finally:
            if cli.poll() is None:
                cli.kill()
                cli.wait()
    finally:
        _stop(procs)
    assert cli.returncode == 2, err
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    line = err.splitlines()[-1]
    found = re.fullmatch(rf"attitude-sil: error: lost the Dask scheduler at {re.escape(address)} "
                         r"\((its connection closed|\w+Error)\) after (\d+) of 100 chunks; nothing finished is lost: "
                         r"(attitude-sil montecarlo .+ --resume) finishes the campaign "
                         r"\(start the scheduler again, or drop --scheduler to finish here\)", line)
    assert found, line
    kept = len(log.read_text().splitlines()) - 1
    assert 2 <= kept < 100 and int(found[2]) == kept  # it names what the log holds; the rest did not run
    command = shlex.split(found[3])
    assert command == ["attitude-sil", "montecarlo", str(path), "--scheduler", address, "--no-bags", "--resume"]

    # the command it gives, without the scheduler, finishes the campaign here
    i = command.index("--scheduler")
    resumed = subprocess.run([sys.executable, "-m", "attitude_sil.cli", *command[1:i], *command[i + 2:], "--json"],
                             cwd=ROOT, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                             timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert json.loads(resumed.stdout.splitlines()[-1])["completed_runs"] == 200
    with InProcess() as ex:  # one chunk, every core, never interrupted
        run_campaign(load_mc_spec(_spec_file(tmp_path, "local", runs=200, chunk=200, duration=10.0)), ex)
    for name in ("runs.csv", "runs.json"):
        assert (tmp_path / "mc" / name).read_bytes() == (tmp_path / "local" / name).read_bytes(), name
