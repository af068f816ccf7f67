"""Parameter files work under any namespace: the keys written, the keys read, and what rclpy applies.

Every file the project writes keys its node sections ``/**/node`` (rcl applies
that to the node under any namespace; a plain ``node:`` applies to ``/node``
only); the loaders take ``/**/node``, ``/**``, ``node``, ``/node`` and
``/ns/node``; a node given a parameter file with no section for it says so.
"""

import time
from array import array

import numpy as np
import pytest
import rclpy
import yaml

from attitude_sil.core.sim.paramfile import applies_to, node_key, section_node
from attitude_sil.core.sim.scenario import GRAPH_NODES, load_scenario, scenario_from_dict
from attitude_sil.errors import ParamClientError
from attitude_sil.graph import launcher
from attitude_sil.ros.node import params_file_warning
from attitude_sil.tools.paramclient import file_values, format_dump
from attitude_sil.tuning.results import write_best_yaml
from attitude_sil.tuning.spec import load_spec
from conftest import CONFIG

SCENARIOS = ("hst_roll_step", "hst_roll_yaw", "hawaiisat_lvlh", "cubesat_1u", "flexible_axis", "pitch_axis")


@pytest.mark.parametrize("key,fqn,expected", [
    ("/**", "/controller", True), ("/**", "/a/b/controller", True),
    ("/**/controller", "/controller", True), ("/**/controller", "/sat1/controller", True),
    ("/**/controller", "/a/b/controller", True), ("/**/controller", "/sat1/plant", False),
    ("controller", "/controller", True), ("controller", "/sat1/controller", False),
    ("/controller", "/controller", True), ("/sat1/controller", "/sat1/controller", True),
    ("/sat1/controller", "/sat2/controller", False), ("/*/controller", "/sat1/controller", True),
    ("/*/controller", "/controller", False), ("/*/controller", "/a/b/controller", False),
    ("scenario", "/controller", False), ("/**/contr", "/controller", False),
])
def test_section_keys_match_nodes_as_rcl_does(key, fqn, expected):
    assert applies_to(key, fqn) is expected


def test_rclpy_applies_the_written_key_under_any_namespace(tmp_path):
    # the rule above is rcl's: check the written form and the plain one against rclpy itself
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump({node_key("controller"): {"ros__parameters": {"a": 1.5}},
                                    "controller": {"ros__parameters": {"b": 2}}}))
    context = rclpy.Context()
    rclpy.init(args=["--ros-args", "--params-file", str(path)], context=context)
    try:
        for ns in (None, "/sat1", "/a/b"):
            node = rclpy.create_node("controller", namespace=ns, context=context,
                                     automatically_declare_parameters_from_overrides=True)
            fqn = node.get_fully_qualified_name()
            assert node.get_parameter("a").value == 1.5
            assert node.has_parameter("b") is applies_to("controller", fqn)
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize("key", ["/**/controller", "controller", "/controller", "/sat1/controller",
                                 "/*/controller"])
def test_scenario_loader_accepts_every_key_form(key):
    assert section_node(key) == "controller"
    scn = scenario_from_dict({"/**": {"ros__parameters": {"control_period": 0.02}},
                              key: {"ros__parameters": {"pid.kp": [1.0, 2.0, 3.0]}}})
    assert scn.param("controller", "pid.kp") == [1.0, 2.0, 3.0]
    assert all(scn.param(node, "control_period") == 0.02 for node in GRAPH_NODES)


def test_scenario_loader_merges_two_keys_of_one_node_in_file_order():
    scn = scenario_from_dict({"controller": {"ros__parameters": {"pid.kp": [1.0, 1.0, 1.0], "pid.kd": [2.0] * 3}},
                              "/**/controller": {"ros__parameters": {"pid.kp": [5.0, 5.0, 5.0]}}})
    assert scn.param("controller", "pid.kp") == [5.0, 5.0, 5.0]
    assert scn.param("controller", "pid.kd") == [2.0, 2.0, 2.0]


@pytest.mark.parametrize("name", SCENARIOS)
def test_shipped_scenarios_key_every_node_for_any_namespace(name):
    data = yaml.safe_load((CONFIG / f"{name}.yaml").read_text())
    assert set(data) <= {"/**", "scenario", *(node_key(n) for n in GRAPH_NODES)}, sorted(data)
    assert any(k.startswith("/**/") for k in data)
    load_scenario(CONFIG / f"{name}.yaml")


def test_written_files_use_the_wildcard_key_and_load_back(tmp_path, monkeypatch):
    # the tuner's best.yaml
    spec = load_spec(CONFIG / "tune_hst_pid_ga.yaml")
    x = np.array([(g.low + g.high) / 2 for g in spec.genome for _ in range(g.width)])
    values = write_best_yaml(spec, x, tmp_path / "best.yaml")
    best = yaml.safe_load((tmp_path / "best.yaml").read_text())
    assert list(best) == ["/**/controller"]
    scn = scenario_from_dict(best, check=False)
    assert scn.param("controller", "pid.kp") == values["pid.kp"]
    # the bag's parameter snapshot
    snapshot = yaml.safe_load(load_scenario(CONFIG / "hst_roll_step.yaml").parameters_yaml())
    assert sorted(snapshot) == sorted(node_key(n) for n in GRAPH_NODES)
    # the files of a --processes run (one per node process)
    started = []
    monkeypatch.setattr(launcher.subprocess, "Popen", lambda cmd, **kw: started.append(cmd))
    launcher.start_processes(load_scenario(CONFIG / "hst_roll_step.yaml"), {}, tmp_path, namespace="sat1")
    for cmd in started:
        node = cmd[2].rsplit(".", 1)[1].removesuffix("_node")
        data = yaml.safe_load(open(cmd[cmd.index("--params-file") + 1]).read())
        assert list(data) == [node_key(node)] and data[node_key(node)]["ros__parameters"]["use_sim_time"] is True
    assert len(started) == len(GRAPH_NODES)


def test_a_node_whose_parameter_file_has_no_section_for_it_warns(tmp_path):
    files = {}
    for label, key in (("wild", "/**/controller"), ("all", "/**"), ("plain", "controller"), ("other", "/plant")):
        files[label] = tmp_path / f"{label}.yaml"
        files[label].write_text(yaml.safe_dump({key: {"ros__parameters": {"x": 1}}}))
    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    node = rclpy.create_node("controller", namespace="/sat1", context=context)
    try:
        def warning(*labels):
            return params_file_warning(node, ["controller_node", "--ros-args",
                                              *(a for lb in labels for a in ("--params-file", str(files[lb])))])
        assert warning() == ""
        assert warning("wild") == "" and warning("all") == "" and warning("plain", "wild") == ""
        text = warning("plain", "other")
        assert "/sat1/controller" in text and "'/**/controller:'" in text and "plain.yaml" in text
        assert warning("other").startswith("no section of the parameter file(s)")
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_param_dump_writes_ros2_form_that_param_load_and_the_loaders_read(tmp_path):
    text = format_dump("/sat1/controller", {"pid.kp": array("d", [1.0, 2.0, 3.0]), "controller_type": "pid",
                                            "use_sim_time": True, "ga_flc.rules": [1, 2]})
    data = yaml.safe_load(text)
    assert data == {"/sat1/controller": {"ros__parameters": {
        "pid": {"kp": [1.0, 2.0, 3.0]}, "controller_type": "pid", "use_sim_time": True,
        "ga_flc": {"rules": [1, 2]}}}}
    path = tmp_path / "dump.yaml"
    path.write_text(text)
    assert file_values(path, "/sat1/controller") == {"pid.kp": [1.0, 2.0, 3.0], "controller_type": "pid",
                                                     "use_sim_time": True, "ga_flc.rules": [1, 2]}
    with pytest.raises(ParamClientError, match="no section applies to /controller .keys: /sat1/controller"):
        file_values(path, "/controller")
    # every section that applies counts, later ones over earlier ones
    path.write_text("/**:\n  ros__parameters: {a: 1, b: 1}\n/**/controller:\n  ros__parameters: {b: 2}\n"
                    "/plant:\n  ros__parameters: {c: 3}\n")
    assert file_values(path, "/sat1/controller") == {"a": 1, "b": 2}
    path.write_text("/**/controller: 3\n")
    with pytest.raises(ParamClientError, match="ros__parameters"):
        file_values(path, "/controller")


def test_a_parameter_read_is_asked_again_until_answered_and_a_silent_node_is_one_error():
    # a get whose answer was lost (sent before DDS matched the client's reader) is sent again after 1 s and the
    # second answer taken; a node that never answers is one ParamClientError naming it and the timeout
    from concurrent.futures import Future
    from types import SimpleNamespace

    from attitude_sil.tools.paramclient import _Session

    def answered(value):
        f = Future()
        f.set_result(value)
        return f

    waited = []
    session = _Session.__new__(_Session)  # no rclpy context: the executor is a stand-in that only waits
    session.node_name, session.timeout = "/controller", 10.0
    session.executor = SimpleNamespace(spin_once=lambda timeout_sec: waited.append(timeout_sec)
                                       or time.sleep(timeout_sec))
    sent = []
    lost_then_answered = lambda: sent.append(1) or (Future() if len(sent) == 1 else answered("values"))  # noqa: E731
    assert session.ask(lost_then_answered) == "values" and len(sent) == 2
    assert 0.9 < sum(waited) < 5.0  # the first wait (1 s) ran out, the second answer came at once
    session.timeout, sent[:] = 1.5, []
    with pytest.raises(ParamClientError, match=r"node /controller did not answer within 1\.5 s"):
        session.ask(lambda: sent.append(1) or Future())
    assert len(sent) == 2  # asked at 0 s and again at 1 s, then the 1.5 s were up
