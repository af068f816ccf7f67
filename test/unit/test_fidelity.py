"""``attitude-sil fidelity``: each published number, recomputed from the presets, within its tolerance.

One test per row of :data:`attitude_sil.tuning.fidelity.ROWS` (its id names the
paper, the place and the quantity), so a row that drifts names itself. The
computations a group of rows shares run once per session (one
:class:`~attitude_sil.tuning.fidelity.Presets`). A row is PASS, or EXPLAINED
with its section in docs/fidelity.md; the published values the module holds
are checked against the copies in test/data/.
"""

from __future__ import annotations

import csv
import json
import math

import pytest

from attitude_sil.cli import main
from attitude_sil.tuning import fidelity
from conftest import CONFIG, ROOT

DATA = ROOT / "test" / "data"


@pytest.fixture(scope="module")
def presets() -> fidelity.Presets:
    return fidelity.Presets(CONFIG)


@pytest.mark.parametrize("row", fidelity.ROWS, ids=[r.id for r in fidelity.ROWS])
def test_row(row, presets):
    result = fidelity.evaluate_row(row, presets)
    assert result.status in ("PASS", "EXPLAINED"), (
        f"paper {row.paper} {row.where}, {row.quantity}: paper {row.paper_value}, project {result.value} "
        f"({row.kind} {row.tolerance})")
    if result.status == "EXPLAINED":
        assert f'<a id="{row.explained}"></a>' in (ROOT / "docs" / "fidelity.md").read_text()


def test_row_ids_are_unique():
    ids = [r.id for r in fidelity.ROWS]
    assert len(ids) == len(set(ids))


def _csv(name: str) -> list[dict]:
    with open(DATA / name, newline="") as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def test_published_values_match_the_copies_in_test_data():
    t1 = _csv("paper_000_table_1.csv")
    assert [int(r["angle_deg"]) for r in t1] == list(fidelity.PAPER_000_TABLE_1)
    for r in t1:
        assert fidelity.PAPER_000_TABLE_1[int(r["angle_deg"])] == (float(r["roll"]), float(r["pitch"]),
                                                                   float(r["yaw"]))
    designs = _csv("paper_001_designs.csv")
    assert [r["design"] for r in designs] == list(fidelity.PAPER_001_DESIGNS)
    for r in designs:
        k, l, ts, ce = fidelity.PAPER_001_DESIGNS[r["design"]]  # noqa: E741 - the paper's L
        assert k == (float(r["k1"]), float(r["k2"]), float(r["k3"]))
        assert l == (float(r["l1"]), float(r["l2"]), float(r["l3"]))
        assert ts == float(r["ts_s"]) and math.isclose(ce, float(r["ce_nms"]))
    settling = _csv("paper_002_settling.csv")
    for r in settling:
        paper = fidelity.PAPER_002_SETTLING[r["pid"]][r["case"]]
        assert paper == (float(r["flexible_s"]), float(r["rigid_s"]))
    assert len(settling) == 10


def test_fidelity_json_is_one_object_alone_on_stdout(capsys):
    code = main(["fidelity", "--paper", "004", "--json"])
    captured = capsys.readouterr()
    report = json.loads(captured.out)  # the whole of stdout: it pipes
    rows = report["rows"]
    assert {r["paper"] for r in rows} == {"004"}
    assert code == (1 if any(r["status"] == "FAIL" for r in rows) else 0)
    assert all(r["status"] in fidelity.STATUSES for r in rows)
    assert sum(report["status_counts"].values()) == len(rows)
    assert "paper 004" in captured.err  # the progress goes to stderr
