"""A bag's recorded controller parameters sorted against the laws installed now (attitude_sil/tools/snapshot.py)."""

import pytest

from attitude_sil.core.control import registry
from attitude_sil.core.sim.scenario import flatten_parameters as flatten
from attitude_sil.errors import BagError
from attitude_sil.tools.snapshot import check_installed, drop_uninstalled, notice, uninstalled_law


def test_a_parameter_of_a_law_not_installed_names_that_law():
    assert "gone_law" not in registry.names()
    assert uninstalled_law("gone_law.kp") == "gone_law"
    assert uninstalled_law("gone_law.gains.kp") == "gone_law"


@pytest.mark.parametrize("name", ["pid.kp", "controller_type", "output_limit", "orbit.mu",
                                  "pid.kq", "orbit.nonsense", "nonsense", ".kp"])
def test_what_the_schema_judges_is_left_to_it(name):
    # declared names, misspellings inside a known group and names without a law prefix are not a missing law:
    # the schema keeps them, or refuses them naming the key
    assert uninstalled_law(name) is None


def test_drop_keeps_the_rest_in_order_and_names_each_law_once():
    kept, laws = drop_uninstalled({"controller_type": "pid", "zz_law.kp": [1.0], "pid.kp": [2.0, 2.0, 2.0],
                                   "aa_law.kd": 3.0, "zz_law.kd": [4.0]})
    assert list(kept) == ["controller_type", "pid.kp"] and kept["pid.kp"] == [2.0, 2.0, 2.0]
    assert laws == ["aa_law", "zz_law"]


def test_nested_parameters_are_read_as_ros_reads_them():
    assert flatten({"pid": {"kp": [1.0], "n": {"x": 2}}, "controller_type": "pid"}) == {
        "pid.kp": [1.0], "pid.n.x": 2, "controller_type": "pid"}


def test_the_notice_is_one_line_naming_the_laws():
    assert notice("bags/a", ["quat_pd"]) == ("note: bags/a: ignoring the recorded parameters of quat_pd, a law not "
                                             "installed here (the bag did not fly it)")
    assert notice("bags/a", ["a_law", "b_law", "c_law"]) == (
        "note: bags/a: ignoring the recorded parameters of a_law, b_law and c_law, laws not installed here (the bag "
        "did not fly them)")


def test_a_flown_law_must_be_installed():
    for law in registry.names():
        check_installed(law, "bags/a")  # nothing to say
    check_installed(None, "bags/a")  # no controller_type recorded: the schema's default
    with pytest.raises(BagError) as err:
        check_installed("gone_law", "bags/a", " (a swap recorded at t=4.990 s)")
    assert str(err.value) == (f"bags/a: the bag flew controller_type gone_law (a swap recorded at t=4.990 s), which "
                              f"is not installed (installed: {', '.join(registry.names())}); install it to verify "
                              "this bag")
    assert "\n" not in str(err.value)


def test_a_flown_law_whose_plugin_did_not_load_says_so(monkeypatch, capsys):
    from importlib.metadata import EntryPoint

    broken = EntryPoint("broken_law", "no_such_module_for_a_test:LAW", registry.ENTRY_POINT_GROUP)
    monkeypatch.setattr(registry, "entry_points", lambda group: [broken] if group == broken.group else [])
    monkeypatch.setattr(registry, "_PROBLEMS", [])
    registry.refresh()
    try:
        assert "broken_law" in registry.declared_names() and "broken_law" not in registry.names()
        with pytest.raises(BagError) as err:
            check_installed("broken_law", "bags/a")
        assert str(err.value) == ("bags/a: the bag flew controller_type broken_law, whose plugin did not load "
                                  "(installed: bdot, fuzzy_pid, ga_flc, geometric, pid); the line above says why")
    finally:
        monkeypatch.undo()
        registry.refresh()
    capsys.readouterr()  # the registry's own line about the skipped plugin
