#!/usr/bin/env bash
# Wall time of `attitude-sil --help` as a whole process (start-up and imports included), measured with
# farm-bench against a bare interpreter start of the same venv (the floor). Not a test: run it by hand,
#   bash bench/bench_cli_help.sh
# Target (issue 20): under 0.3 s. The verbs import their dependencies in execute(), so the parser is built
# without numba, rclpy, pymoo or matplotlib.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=.venv/bin
if ! command -v farm-bench >/dev/null; then
  echo "farm-bench is not on this machine; timing 10 runs with bash's time instead" >&2
  time (for _ in $(seq 10); do "$BIN/attitude-sil" --help >/dev/null; done)
  exit 0
fi
farm-bench -n 15 --warmup 2 --vs "$BIN/python -c pass" -- "$BIN/attitude-sil" --help
