"""An engine-written bag equals the graph-recorded bag of the same design, message for message.

Tuning runs write each generation's best straight from the batch engine
(graph/engine_bag.py) instead of re-running it through the node graph; this
holds those bags to the graph's: same topics, types and QoS, same stamps and
frames, values within 1e-9, the same parameter snapshot.
"""

import math

import numpy as np
import yaml

from attitude_sil.core.sim.engine import simulate
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.graph.engine_bag import record_episode
from attitude_sil.graph.session import GraphSession
from attitude_sil.storage.reader import open_bag
from attitude_sil.storage.writer import PARAMETERS_KEY
from conftest import CONFIG

DESIGN = {"pid.kp": [40.0, 45.0, 50.0], "pid.kd": [90.0, 100.0, 110.0]}


def _flat(msg, prefix=""):
    """A decoded message as {field path: value}, numbers as floats."""
    if isinstance(msg, (int, float)):
        return {prefix: float(msg)}
    if isinstance(msg, str):
        return {prefix: msg}
    if isinstance(msg, (bytes, bytearray)):  # a uint8[] (the body model's empty mesh data)
        return {prefix: msg.hex()}
    if isinstance(msg, (list, tuple)):
        out = {}
        for i, v in enumerate(msg):
            out.update(_flat(v, f"{prefix}[{i}]"))
        return out
    slots = getattr(msg, "__slots__", None) or list(vars(msg))
    out = {}
    for name in slots:
        out.update(_flat(getattr(msg, name), f"{prefix}.{name.lstrip('_')}"))
    return out


def _messages(bag):
    reader = open_bag(bag)
    out = {}
    for raw, msg in reader.iter_decoded([t for t in reader.topics if t != "/parameter_events"]):
        out.setdefault(raw.topic, []).append((raw.log_time_ns, _flat(msg)))
    return reader, out


def _same_messages(graph_bag, engine_bag, steps: int, counts: dict | None = None):
    """The two bags hold the same topics, types, log times and fields, numbers within 1e-9: a message a step
    on each topic (``counts`` where another number) and the body model once. Returns the engine bag's reader."""
    g_reader, graph_msgs = _messages(graph_bag)
    e_reader, engine_msgs = _messages(engine_bag)
    assert set(e_reader.topics) == set(g_reader.topics)
    for topic, info in g_reader.topics.items():
        assert e_reader.topics[topic].type == info.type, topic
    assert set(graph_msgs) == set(engine_msgs) and {"/attitude", "/body_model"} <= set(graph_msgs)
    worst = 0.0
    for topic, g in graph_msgs.items():
        e = engine_msgs[topic]
        expected = (counts or {}).get(topic, 1 if topic == "/body_model" else steps)  # the model with step 0
        assert len(e) == len(g) == expected, (topic, len(e), len(g))
        for (tg, mg), (te, me) in zip(g, e, strict=True):
            assert tg == te, topic
            assert mg.keys() == me.keys(), topic
            for key, vg in mg.items():
                ve = me[key]
                if isinstance(vg, str):
                    assert vg == ve, (topic, key)
                else:
                    assert math.isfinite(ve), (topic, key)
                    worst = max(worst, abs(vg - ve))
    assert worst <= 1e-9
    return e_reader


def test_engine_bag_equals_the_graph_recorded_bag(tmp_path):
    scn = load_scenario(CONFIG / "hst_roll_step.yaml")
    with GraphSession(scn, duration=3.0, controller="pid") as graph:
        graph.run_episode(controller_params=DESIGN, record_dir=tmp_path / "graph")
    tr = simulate(scn, 1, duration=3.0, controller="pid",
                  controller_params={k: np.array([v]) for k, v in DESIGN.items()})
    record_episode(scn, tr, tmp_path / "engine", controller_params=DESIGN, controller="pid", duration=3.0)

    e_reader = _same_messages(tmp_path / "graph", tmp_path / "engine", 301)
    snapshots = [yaml.safe_load(yaml.safe_load((d / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
                                ["custom_data"][PARAMETERS_KEY]) for d in (tmp_path / "graph", tmp_path / "engine")]
    assert snapshots[0] == snapshots[1]
    assert snapshots[1]["/**/controller"]["ros__parameters"]["pid.kp"] == DESIGN["pid.kp"]
    # the design's parameter change is in /parameter_events, as the graph's parameter service logged it
    changes = {}
    for _, event in e_reader.iter_decoded(["/parameter_events"]):
        changes.update({p.name: list(p.value.double_array_value) for p in event.changed_parameters})
    assert changes == DESIGN


def test_an_engine_bag_of_a_sensing_run_carries_the_sensors_and_the_estimate_as_the_graph_records_them(tmp_path):
    # the gyro, the tachometers, the star tracker's reports (stamped with their exposures, one in an outage
    # without its attitude) and the filter's estimate, flown on the estimate, the tracker blind from 1 to 1.2 s
    scn = load_scenario(CONFIG / "hst_roll_step_sensors.yaml").with_values(
        "sensors", **{"star_tracker.outages_s": [1.0, 1.2]})
    with GraphSession(scn, duration=2.0) as graph:
        graph.run_episode(record_dir=tmp_path / "graph")
    record_episode(scn, simulate(scn, 1, duration=2.0), tmp_path / "engine", duration=2.0)
    reader = _same_messages(tmp_path / "graph", tmp_path / "engine", 201, {"/star_tracker": 20})
    assert {"/imu", "/wheel_speed", "/estimate/attitude", "/estimate/attitude_sigma"} <= set(reader.topics)
    blind = [m.header.stamp.nanosec for _, m in reader.iter_decoded(["/star_tracker"])
             if m.orientation_covariance[0] == -1.0]
    assert blind == [0, 100_000_000]  # the exposures at 1.0 and 1.1 s (seconds apart: in .sec)
