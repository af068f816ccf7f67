"""The law registry: built-ins found by their modules, plugins by entry point, broken plugins skipped in one line."""

from importlib.metadata import EntryPoint

import pytest

from attitude_sil.core.control import registry
from attitude_sil.core.control.law import Law
from attitude_sil.core.control.laws import pid
from attitude_sil.errors import ScenarioError


@pytest.fixture
def plugins(monkeypatch):
    """``plugins(*entry_points)``: the registry rebuilt with these entry points in the group (cache cleared)."""
    def use(*eps):
        monkeypatch.setattr(registry, "entry_points", lambda group: [e for e in eps if e.group == group])
        monkeypatch.setattr(registry, "_PROBLEMS", [])
        registry.refresh()
    yield use
    registry.refresh()


def _ep(name: str, value: str) -> EntryPoint:
    return EntryPoint(name, value, registry.ENTRY_POINT_GROUP)


def test_builtins_are_the_modules_of_the_laws_package(plugins):
    plugins()
    assert registry.names() == registry.builtin_names() == ("bdot", "fuzzy_pid", "ga_flc", "geometric", "pid")
    assert registry.get("pid") is pid.LAW
    assert registry.output_of("geometric") == "torque" and registry.output_of("pid") == "command"


def test_a_plugin_is_found_through_its_entry_point(plugins):
    # the example package (make installs it): its law joins the built-ins, after them
    plugins(_ep("quat_pd", "quat_pd:LAW"))
    assert registry.names()[-1] == "quat_pd" and registry.plugin_problems() == []
    assert registry.get("quat_pd").step.py_func.__module__ == "quat_pd"
    assert "quat_pd" not in registry.builtin_names()
    assert "quat_pd.kp" in {s.name for s in registry.parameter_table()}


def test_the_entry_point_must_carry_the_laws_name(plugins):
    plugins(_ep("other", "quat_pd:LAW"))
    assert registry.plugin_problems() == ["law plugin 'other' (quat_pd:LAW) defines the law 'quat_pd'; the entry "
                                          "point must carry the law's name"]
    assert "quat_pd" not in registry.names() and "other" not in registry.names()


def test_broken_plugins_are_skipped_with_one_line_each(plugins, capsys):
    plugins(_ep("missing", "no_such_module_xyz:LAW"), _ep("pid", "attitude_sil.core.control.laws.pid:LAW"),
            _ep("not_a_law", "attitude_sil.core.control.registry:names"))
    assert registry.names() == ("bdot", "fuzzy_pid", "ga_flc", "geometric", "pid")  # the package works on
    problems = registry.plugin_problems()
    assert len(problems) == 3
    assert "could not be loaded: ModuleNotFoundError" in problems[0]
    assert "not a Law" in problems[1]
    assert "which another law already has" in problems[2]
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 3 and all(line.startswith("attitude-sil: law plugin") and line.endswith("skipped")
                                 for line in err)


def test_an_unknown_law_is_refused_naming_the_known_ones(plugins):
    plugins()
    with pytest.raises(ScenarioError, match="unknown controller_type 'bang'; known: bdot, fuzzy_pid, ga_flc"):
        registry.get("bang")


def test_a_law_that_breaks_the_contract_says_what(plugins):
    with pytest.raises(ValueError, match="must be a numba function"):
        Law(name="bad", summary="", params=(), state={}, record=lambda v, n, dt: (), step=lambda *a: None)
    with pytest.raises(ValueError, match="snake_case"):
        Law(name="Bad-Name", summary="", params=(), state={}, record=pid.LAW.record, step=pid.LAW.step)
