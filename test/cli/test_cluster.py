"""A real Dask cluster on 127.0.0.1: a ``dask scheduler`` and two ``dask worker`` processes.

A small campaign (through the ``attitude-sil montecarlo --scheduler`` command) and
a small tuning run through the cluster give the local results bit for bit; a
worker killed (SIGKILL) while it holds chunks has them re-run by Dask and the
campaign is still complete and identical. Everything is shut down in a finally.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys

import numpy as np
import pytest
from distributed import Client

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


@pytest.fixture(scope="module")
def cluster():
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    procs = [_dask("scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard")]
    try:
        for _ in range(2):  # no nanny: the process we kill is the worker itself
            procs.append(_dask("worker", address, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny",
                               "--no-dashboard", "--death-timeout", "60"))
        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
        yield address, procs
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


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
        assert len(ex.client.scheduler_info()["workers"]) == 1  # the scheduler saw the worker go
    assert seen and seen[0] > 0 and victim.returncode == -signal.SIGKILL  # it died holding chunks
    assert not result.interrupted and sorted(result.table["run"].tolist()) == list(range(48))
    local_spec = load_mc_spec(_spec_file(tmp_path, "local", runs=48, chunk=48, duration=4.0))
    with InProcess() as ex:
        local = run_campaign(local_spec, ex)
    _same(local.table, result.table)
