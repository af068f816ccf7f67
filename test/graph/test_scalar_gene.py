"""Every numeric law parameter can be a gene, scalar as well as per-axis (issue 40, deliverable 5).

The scalar: the geometric law's ``torque_limit`` (one number, N m), on the HST
roll step. A law's parameter record holds a scalar once for all its episodes,
so the tuner runs the candidates of each value as their own batch with the
value in the scenario: checked against independent runs with that value.
What cannot be a gene is refused in one line that says why.
"""

import numpy as np
import pytest
import yaml

from attitude_sil.core.paramspec import ParamSpec
from attitude_sil.core.sim.engine import simulate_summary
from attitude_sil.core.sim.params import spec_for
from attitude_sil.core.sim.scenario import load_scenario, with_parameter_file
from attitude_sil.errors import SpecError
from attitude_sil.storage.reader import open_bag
from attitude_sil.storage.writer import PARAMETERS_KEY
from attitude_sil.tuning.evaluate import PENALTY, evaluate
from attitude_sil.tuning.optimize import run_tuning
from attitude_sil.tuning.spec import load_spec, untunable
from conftest import CONFIG

GENE = "geometric.torque_limit"
LOW, HIGH = 0.05, 0.6


def _spec(tmp_path, genome, name="scalar"):
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump({
        "name": name, "scenarios": [str(CONFIG / "hst_roll_step.yaml")], "controller": "geometric",
        "genome": genome, "cost": {"name": "paper000_j"}, "algorithm": {"name": "ga", "pop_size": 6, "generations": 3},
        "seed": 3, "output": str(tmp_path / name)}))
    return path


def _independent_cost(value: float) -> float:
    """Paper 000's J of one run of the geometric law with ``torque_limit`` = value, set in the scenario."""
    scn = load_scenario(CONFIG / "hst_roll_step.yaml").with_values("controller", **{GENE: value})
    return float(simulate_summary(scn, 1, controller="geometric", schedule=[]).metrics["cost_J"][0])


def test_each_candidate_runs_with_its_own_scalar_value(tmp_path):
    spec = load_spec(_spec(tmp_path, [{"param": GENE, "low": LOW, "high": HIGH}]))
    values = [0.1, 0.45, 0.1, 0.3]  # a repeated value: one batch for both of its candidates
    ev = evaluate(spec, np.array(values)[:, None])
    assert ev.values[:, 0].tolist() == values and not any(ev.reasons)
    expected = [_independent_cost(v) for v in values]
    assert np.allclose(ev.F[:, 0], expected, rtol=1e-12, atol=0.0), (ev.F[:, 0], expected)
    assert len({round(c, 9) for c in expected}) == 3  # the limit matters to J: the values were not all ignored
    assert ev.terms["time_constant_s"].shape == (4,)


def test_a_scalar_gene_tunes_and_its_best_is_a_design_the_controller_takes(tmp_path):
    spec = load_spec(_spec(tmp_path, [{"param": GENE, "low": LOW, "high": HIGH}]))
    start = spec.scenarios[0].param("controller", GENE)
    assert not LOW <= start <= HIGH  # the scenario's own value is outside the search: the tuner must move it
    result = run_tuning(spec)
    best = result.best_params[GENE]
    assert np.ndim(best) == 0 and LOW <= float(best) <= HIGH
    assert result.best_cost[0] < PENALTY
    assert result.best_cost[0] == pytest.approx(_independent_cost(float(best)), rel=1e-12, abs=0.0)
    written = yaml.safe_load((spec.output / "best.yaml").read_text())["/**/controller"]["ros__parameters"]
    assert written == {"controller_type": "geometric", GENE: float(best)}
    scn = with_parameter_file(load_scenario(CONFIG / "hst_roll_step.yaml"), spec.output / "best.yaml")
    assert scn.param("controller", GENE) == float(best)


def test_scalar_and_list_genes_together(tmp_path):
    spec = load_spec(_spec(tmp_path, [{"param": GENE, "low": LOW, "high": HIGH},
                                      {"param": "geometric.k", "low": 10.0, "high": 80.0, "index": 0}]))
    x = np.array([[0.2, 30.0], [0.2, 60.0], [0.5, 30.0]])
    ev = evaluate(spec, x)
    base = load_spec(_spec(tmp_path, [{"param": GENE, "low": LOW, "high": HIGH}], "base")).scenarios[0]
    expected = []
    for limit, k0 in x:
        k = list(base.param("controller", "geometric.k"))
        k[0] = k0
        scn = base.with_values("controller", **{GENE: limit, "geometric.k": k})
        expected.append(float(simulate_summary(scn, 1, controller="geometric", schedule=[]).metrics["cost_J"][0]))
    assert np.allclose(ev.F[:, 0], expected, rtol=1e-12, atol=0.0), (ev.F[:, 0], expected)


@pytest.mark.parametrize("gene, line", [
    ({"param": "geometric.feedforward", "low": 0, "high": 1},
     "genome[0].param 'geometric.feedforward' cannot be a gene: it is a choice of names (gravity_gradient, "
     "aerodynamic), not a number"),
    ({"param": "orbit.mu", "low": 1.0, "high": 2.0},
     "genome[0].param 'orbit.mu' cannot be a gene: it is fixed once the controller runs (not runtime), and the "
     "tuner sets genes on a running controller (graph mode, the best's re-run through the graph)"),
    ({"param": "fuzzy_pid.rules", "low": 1, "high": 7, "count": 49},
     "genome[0].param 'fuzzy_pid.rules' is an integer parameter: its gene needs kind int, got real"),
    ({"param": GENE, "low": LOW, "high": HIGH, "index": 1},
     f"genome[0].param '{GENE}' is one number, not a list: a gene on it takes no index or count"),
])
def test_what_cannot_be_a_gene_is_refused_saying_why(tmp_path, gene, line):
    path = _spec(tmp_path, [gene])
    with pytest.raises(SpecError) as err:
        load_spec(path)
    assert str(err.value) == f"{path}: {line}"


def test_the_reasons_cover_every_kind_that_is_not_a_number():
    assert untunable(ParamSpec("x", "bool", False, "", runtime=True)) == "it is a switch (true or false), not a number"
    assert untunable(ParamSpec("x", "string", "a", "", runtime=True)) == "it is a choice of names, not a number"
    assert untunable(spec_for("controller", GENE)) == ""
    assert untunable(spec_for("controller", "output_limit")) == ""  # the shared scalar every law saturates at


def test_graph_evaluation_sets_a_scalar_gene_and_gives_the_batch_cost(tmp_path):
    from attitude_sil.graph.evaluator import GraphEvaluator

    spec = load_spec(_spec(tmp_path, [{"param": GENE, "low": LOW, "high": HIGH}]))
    spec.scenarios = [s.with_values("plant", duration=5.0) for s in spec.scenarios]
    x = np.array([[0.1], [0.45]])
    batch = evaluate(spec, x)
    with GraphEvaluator(spec, replicas=1, record=tmp_path / "bags") as graph:
        live = graph(x)  # each candidate's value set through the controller's parameter service
    assert batch.F[0, 0] != batch.F[1, 0]
    assert np.allclose(live.F, batch.F, rtol=1e-9, atol=1e-12), (live.F, batch.F)
    # the bag records the value the candidate flew (read as YAML: the text wraps where the parameters fall)
    snapshot = yaml.safe_load(open_bag(tmp_path / "bags" / "g001_c001").custom_data[PARAMETERS_KEY])
    assert snapshot["/**/controller"]["ros__parameters"][GENE] == 0.45
