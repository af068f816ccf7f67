"""A broken law plugin is skipped in one line naming it, its distribution and the reason; the rest works on.

Each break below was made on purpose to a law written from
docs/writing-a-law.md (issue 40): a default outside its own range, a
``record`` that returns a dict, a default of the wrong shape, a step that
does not compile on its record. Each plugin here is ``quat_pd`` (the example
law) with one line changed, written to a temporary folder and registered
through an entry point, so the registry reads it as it reads any plugin.
"""

from __future__ import annotations

from importlib.metadata import EntryPoint

import numpy as np
import pytest

from attitude_sil.core.control import registry
from attitude_sil.core.sim.build import law_bank
from conftest import BREAKS, write_plugin


@pytest.fixture
def plugins(monkeypatch, tmp_path):
    """``plugins(*names)``: the registry rebuilt with these laws (BREAKS, or ``good``) as entry points."""
    monkeypatch.syspath_prepend(str(tmp_path))

    def use(*names):
        for name in names:
            write_plugin(tmp_path, name)
        eps = [EntryPoint(n, f"{n}:LAW", registry.ENTRY_POINT_GROUP) for n in names]
        monkeypatch.setattr(registry, "entry_points", lambda group: [e for e in eps if e.group == group])
        monkeypatch.setattr(registry, "_PROBLEMS", [])
        registry.refresh()
    yield use
    registry.refresh()


def test_each_break_is_skipped_in_one_line_naming_it(plugins, capsys):
    plugins("good", *BREAKS)
    registry.dispatch_module()  # the first compiled table: the compile checks run
    assert registry.names() == ("bdot", "fuzzy_pid", "ga_flc", "geometric", "pid", "good")
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == len(BREAKS), lines
    by_law = {name: next(x for x in lines if f"law plugin {name!r}" in x) for name in BREAKS}
    assert "its default controller.bad_default.kp[0] must be >= 0.0, got -1.0; skipped" in by_law["bad_default"]
    assert "record() must return a NamedTuple of the law's parameters, got dict" in by_law["dict_record"]
    assert "raised ValueError (on bad_shape.kd): a value of shape (2,) fits neither (3,)" in by_law["bad_shape"]
    assert "its step does not compile on its record" in by_law["no_compile"]
    assert "gain" in by_law["no_compile"] and "no_compile.py" in by_law["no_compile"]  # what and where
    assert all(x.startswith("attitude-sil: law plugin ") for x in lines)


def test_a_run_that_does_not_use_them_works_on(plugins, capsys):
    plugins(*BREAKS)
    bank = law_bank("pid", n_episodes=1)
    q = np.array([[0.0, 0.0, np.sin(0.05), np.cos(0.05)]])
    u = bank.compute(q, np.zeros((1, 3)), np.array([[0.0, 0.0, 0.0, 1.0]]), np.zeros((1, 3)), 0)
    assert np.all(np.isfinite(u)) and abs(u[0, 2]) > 0.0
    assert bank.names == ("bdot", "fuzzy_pid", "ga_flc", "geometric", "pid")


def test_asking_for_a_skipped_law_says_why(plugins, capsys):
    plugins("no_compile")
    registry.dispatch_module()
    with pytest.raises(ValueError, match="unknown controller_type 'no_compile' \\(law plugin 'no_compile'.*does "
                                         "not compile.*\\); known: bdot, fuzzy_pid"):
        registry.get("no_compile")


def test_the_whole_error_is_behind_the_verbose_flag(plugins, capsys, monkeypatch):
    monkeypatch.setenv("ATTITUDE_SIL_VERBOSE", "1")
    plugins("no_compile")
    registry.dispatch_module()
    err = capsys.readouterr().err
    assert err.splitlines()[0].endswith("; skipped") and "TypingError" in err and len(err.splitlines()) > 3


def test_the_batch_engine_refuses_law_values_as_the_node_does():
    """Per-episode gains get the controller node's own check and words (range, shape, rule), with the episode."""
    from attitude_sil.core.sim.engine import simulate_summary
    from attitude_sil.core.sim.params import spec_for
    from attitude_sil.core.sim.scenario import load_scenario
    from attitude_sil.errors import ScenarioError
    from conftest import CONFIG

    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    kp = np.array([[1.0, 2.0, 3.0], [1.0, -2.0, 3.0], [1.0, 2.0, 3.0]])
    with pytest.raises(ValueError) as node:  # what the node answers to a parameter set of episode 1's value
        spec_for("controller", "pid.kp").validate(kp[1].tolist(), "controller")
    with pytest.raises(ScenarioError) as batch:
        simulate_summary(scn, 3, duration=0.1, controller_params={"pid.kp": kp})
    assert str(batch.value) == f"{node.value} (episode 1)" == "controller.pid.kp[1] must be >= 0.0, got -2.0 " \
                                                               "(episode 1)"
    with pytest.raises(ScenarioError, match=r"^controller.pid.kp must have 3 elements, got 2 \(episode 0\)$"):
        simulate_summary(scn, 3, duration=0.1, controller_params={"pid.kp": np.ones((3, 2))})
    with pytest.raises(ScenarioError, match=r"controller.pid.kp: a value of shape \(2, 3\) is neither a list for "
                                            r"every episode nor one per episode \(3, ...\)"):
        simulate_summary(scn, 3, duration=0.1, controller_params={"pid.kp": np.ones((2, 3))})
    with pytest.raises(ScenarioError, match=r"controller.geometric.k entries must be distinct .* \(episode 2\)"):
        simulate_summary(scn, 3, duration=0.1, controller="geometric",
                         episode_values={"controller.geometric.k": np.array([[1.0, 2, 3], [1, 2, 4], [2, 2, 2]])})
    with pytest.raises(ScenarioError, match="controller has no parameter 'pid.kq'"):
        simulate_summary(scn, 3, duration=0.1, controller_params={"pid.kq": kp})
    s = simulate_summary(scn, 3, duration=0.1, controller_params={"pid.kp": np.abs(kp)})  # in range: it runs
    assert s.finite.all()
