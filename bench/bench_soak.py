"""Soak benchmark (not a test): a long graph run with recording, its memory, bag and steps.

Runs ``attitude-sil run config/hst_roll_step.yaml --duration S --record DIR``
(default one hour of simulated time: 360,001 steps at 100 Hz) as a user would,
samples the run's resident memory once a second from ``/proc``, then reads the
bag back. Prints:

* resident memory after the first tenth of the run and at its end (a graph
  run keeps running sums, not the episode: flat, within 10 %);
* bag size per simulated minute;
* lost or duplicated steps: every step topic must hold exactly one message per
  step, stamped k * dt for k = 0..K.

Run with ``make soak`` (or ``python bench/bench_soak.py --minutes 5`` for a
short one).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from attitude_sil.ros.contract import RECORDED_TOPICS, STEP_TOPICS  # noqa: E402
from attitude_sil.storage.reader import open_bag  # noqa: E402


def _rss_mib(pid: int) -> float | None:
    """Resident memory of one process, MiB (None once it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0, help="simulated minutes (default 60)")
    args = parser.parse_args()
    duration = args.minutes * 60.0
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "soak"
        cmd = [sys.executable, "-m", "attitude_sil.cli", "run", "config/hst_roll_step.yaml", "--duration",
               f"{duration:g}", "--record", str(bag), "--json"]
        env = dict(os.environ)
        t0 = time.monotonic()
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
        samples: list[tuple[float, float]] = []
        while proc.poll() is None:
            rss = _rss_mib(proc.pid)
            if rss is not None:
                samples.append((time.monotonic() - t0, rss))
            time.sleep(1.0)  # a sampling period, not a wait for a condition
        out = proc.stdout.read() if proc.stdout else ""
        wall = time.monotonic() - t0
        if proc.returncode != 0 or not samples:
            sys.exit(f"the run failed (exit {proc.returncode}): {out.strip()[-500:]}")
        # the interpreter re-executes itself once (the ROS wheels' start-up hook): the samples
        # follow the same pid, which is the one that runs the graph
        tenth = [r for t, r in samples if t >= 0.1 * wall] or [samples[0][1]]
        start, end, peak = tenth[0], samples[-1][1], max(r for _, r in samples)
        print(f"soak: {args.minutes:g} simulated min of hst_roll_step through the graph, recording on, "
              f"{wall:.0f} s wall ({duration / wall:.1f}x real time)")
        print(f"resident memory: {start:.0f} MiB after a tenth of the run, {end:.0f} MiB at the end "
              f"({(end - start) / start * 100:+.1f} %), peak {peak:.0f} MiB")
        size = sum(f.stat().st_size for f in bag.iterdir())
        marks = [samples[min(len(samples) - 1, int(f * len(samples)))] for f in (0.1, 0.25, 0.5, 0.75, 1.0)]
        print("resident memory over the run: " + ", ".join(f"{r:.0f} MiB at {t:.0f} s" for t, r in marks))
        print(f"bag: {size / 2**20:.1f} MiB, {size / 2**20 / args.minutes:.2f} MiB per simulated minute")
        reader = open_bag(bag)
        dt_ns = 10_000_000
        steps = int(round(duration * 1e9 / dt_ns)) + 1
        problems = []
        for topic in STEP_TOPICS:
            if topic not in RECORDED_TOPICS:
                continue
            name = "/" + topic.lstrip("/")
            stamps = [m.log_time_ns for m in reader.iter_raw(name)]
            if not stamps:
                continue  # a command topic the run did not use
            unique = set(stamps)
            expected = set(range(0, steps * dt_ns, dt_ns))
            lost, dup = len(expected - unique), len(stamps) - len(unique)
            if lost or dup or unique != expected:
                problems.append(f"{name}: {lost} lost, {dup} duplicated")
        print("steps: " + ("; ".join(problems) if problems else
                           f"every step topic holds exactly {steps:,} messages, one per step (none lost or "
                           "duplicated)"))


if __name__ == "__main__":
    main()
