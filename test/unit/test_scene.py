"""The 3D view's data: frames and body model from a scenario (core/plant/scene.py), and their messages.

``tf2_msgs/msg/TFMessage`` has no wheel on PyPI, so its definition (bundled in
storage/msgdefs.py) and its CDR (storage/cdr.py) are the project's own: both
are held to rosbags, an independent implementation that knows the type (its
CDR serializer and its RIHS01 type hash), and to mcap-ros2-support's decoder
reading the bundled definition. ``visualization_msgs/msg/MarkerArray`` is
installed, so its CDR is held to rclpy's (and to rosbags', byte for byte).
"""

import numpy as np
import pytest
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_typestore
from visualization_msgs.msg import MarkerArray

from attitude_sil.core.plant.disturbance import lvlh_attitude, orbit_rate
from attitude_sil.core.plant.quaternion import quat_conjugate, quat_from_euler, quat_multiply
from attitude_sil.core.plant.scene import ARROW, CUBE, body_scene, box_from_inertia, rotation_z_to
from attitude_sil.core.plant.wheels import hst_pyramid
from attitude_sil.core.sim.scenario import load_scenario
from attitude_sil.storage.cdr import TfLayout, marker_array_cdr
from attitude_sil.storage.msgdefs import message_definition, type_description_hash
from conftest import CONFIG

JAZZY = get_typestore(Stores.ROS2_JAZZY)
RNG = np.random.default_rng(39)


def _rotate(q, v):
    """v (3,) turned by q (4,): q ⊗ (v, 0) ⊗ q*."""
    return quat_multiply(quat_multiply(q, np.array([*v, 0.0])), quat_conjugate(q))[:3]


def test_the_box_has_the_inertia_of_its_proportions():
    for edges in ([3.0, 1.0, 0.5], [1.0, 1.0, 1.0], [0.2, 2.0, 1.1]):
        a, b, c = edges
        mass = 7.0
        inertia = mass / 12 * np.array([b * b + c * c, c * c + a * a, a * a + b * b])
        got = box_from_inertia(inertia, longest=2.0)
        assert np.allclose(got, 2.0 * np.array(edges) / max(edges), rtol=1e-12)
        assert np.allclose(box_from_inertia(np.diag(inertia)), got / 2.0, rtol=1e-12)  # a 3 x 3: its diagonal
    # a flat body still shows as a slab; a degenerate one as a cube
    assert box_from_inertia([1.0, 1.0, 2.0]).min() == pytest.approx(0.1)
    assert np.array_equal(box_from_inertia([0.0, 0.0, 0.0]), np.ones(3))


def test_a_disc_turns_its_z_axis_onto_the_wheel_axis():
    for axis in [*RNG.normal(size=(20, 3)), [0.0, 0.0, 1.0], [0.0, 0.0, -2.0], [1e-9, 0.0, -1.0]]:
        q = rotation_z_to(axis)
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)
        assert np.allclose(_rotate(q, [0.0, 0.0, 1.0]), np.asarray(axis) / np.linalg.norm(axis), atol=1e-9)


def test_the_presets_scenes():
    hst = body_scene(load_scenario(CONFIG / "hst_roll_step.yaml").values)
    assert hst.frames == (("inertial", "body"),) and hst.q_LN0 is None  # no orbit: no LVLH
    (box,) = [m for m in hst.markers if m.type == CUBE]
    assert max(box.scale) == pytest.approx(1.0) and box.scale[0] == max(box.scale)  # HST: long about x
    arrows = [m for m in hst.markers if m.type == ARROW]
    tips = np.array([m.points[1] for m in arrows])
    directions = tips / np.linalg.norm(tips, axis=1)[:, None]
    assert np.allclose(directions, hst_pyramid().T / np.linalg.norm(hst_pyramid().T, axis=1)[:, None], atol=1e-12)
    assert [m.text for m in hst.markers if m.text] == ["wheel_1", "wheel_2", "wheel_3", "wheel_4"]  # joint names
    cube = body_scene(load_scenario(CONFIG / "cubesat_1u.yaml").values)
    cube_axes = [m.points[1] / np.linalg.norm(m.points[1]) for m in cube.markers if m.type == ARROW]
    assert np.allclose(cube_axes, np.eye(3))  # the speed-loop wheels: one per body axis
    # Hawai'iSat tracks LVLH with torque rods: the orbit frame, no wheels
    scn = load_scenario(CONFIG / "hawaiisat_lvlh.yaml")
    sat = body_scene(scn.values)
    assert sat.frames == (("inertial", "body"), ("inertial", "lvlh"))
    assert [m.type for m in sat.markers] == [CUBE]
    rate = orbit_rate(scn.param("guidance", "orbit.mu"), scn.param("guidance", "orbit.radius"))
    assert sat.orbit_rate == rate
    q_LN0 = quat_from_euler(np.radians(scn.param("guidance", "orbit.lvlh_initial_rpy_deg")))
    q = np.array([0.1, -0.2, 0.3, 0.9273618495495703])
    body, lvlh = sat.rotations(123.4, q)
    assert body is q and np.array_equal(lvlh, lvlh_attitude(123.4, q_LN0, rate))
    t = np.array([0.0, 10.0, 123.4])
    series = sat.rotation_series(t, np.tile(q, (3, 1)))
    assert np.array_equal(series[1][2], lvlh)
    # a disturbance that flies the orbit gives the frame too; a scenario without one does not
    values = {"plant": {"inertia": [1.0, 2.0, 3.0]}, "disturbance": {"models": ["aerodynamic"], "orbit.mu": 4e14,
              "orbit.radius": 7e6, "orbit.lvlh_initial_rpy_deg": [0.0, 90.0, 0.0]}}
    assert body_scene(values).frames[1] == ("inertial", "lvlh")
    assert body_scene({**values, "disturbance": {"models": ["noise"]}}).q_LN0 is None


def test_the_frames_are_the_tf2_message_rosbags_writes():
    layout = TfLayout((("inertial", "body"), ("inertial", "lvlh")))
    q = RNG.normal(size=(5, 2, 4))
    q /= np.linalg.norm(q, axis=2, keepdims=True)
    stamps = np.array([0, 10_000_000, 1_999_999_999, 7 * 10**9 + 5, 2**31 * 10**9 - 1], dtype=np.int64)
    series = layout.encode(stamps, [q[:, 0], q[:, 1]])
    schema = Schema(id=1, name="tf2_msgs/msg/TFMessage", encoding="ros2msg",
                    data=message_definition("tf2_msgs/msg/TFMessage").encode())
    decode = DecoderFactory().decoder_for("cdr", schema)
    for k, t in enumerate(stamps):
        one = layout.encode_one(int(t), q[k])
        assert one == series[k]
        msg = JAZZY.deserialize_cdr(one, "tf2_msgs/msg/TFMessage")
        assert JAZZY.serialize_cdr(msg, "tf2_msgs/msg/TFMessage") == one  # rosbags writes these very bytes
        decoded = decode(one)  # and mcap-ros2-support reads them from the bundled definition
        for i, (tf, child) in enumerate(zip(decoded.transforms, ("body", "lvlh"), strict=True)):
            assert (tf.header.frame_id, tf.child_frame_id) == ("inertial", child)
            assert tf.header.stamp.sec * 10**9 + tf.header.stamp.nanosec == t
            r, p = tf.transform.rotation, tf.transform.translation
            assert [r.x, r.y, r.z, r.w] == list(q[k, i]) and [p.x, p.y, p.z] == [0.0, 0.0, 0.0]
    # the bundled definition: the standard text, its dependencies as rosbag2 writes them, rosidl's hash
    definition = message_definition("tf2_msgs/msg/TFMessage")
    assert definition.startswith("geometry_msgs/TransformStamped[] transforms\n")
    for dependency in ("geometry_msgs/TransformStamped", "geometry_msgs/Transform", "geometry_msgs/Quaternion",
                       "geometry_msgs/Vector3", "std_msgs/Header", "builtin_interfaces/Time"):
        assert f"\nMSG: {dependency}\n" in definition
    assert type_description_hash("tf2_msgs/msg/TFMessage") == JAZZY.hash_rihs01("tf2_msgs/msg/TFMessage")
    with pytest.raises(ValueError, match="rotations"):
        layout.encode_one(0, q[0, :1])


def test_the_body_model_is_the_marker_array_rclpy_writes():
    scene = body_scene(load_scenario(CONFIG / "hst_roll_step.yaml").values)
    ours = marker_array_cdr(1_500_000_007, "body", scene.markers)
    msg = deserialize_message(ours, MarkerArray)
    # rclpy leaves its alignment padding uninitialised: its bytes are compared by length and by what they decode
    # to; rosbags, which zeroes the padding as we do, gives these very bytes
    assert len(ours) == len(serialize_message(msg)) and deserialize_message(serialize_message(msg), MarkerArray) == msg
    assert JAZZY.serialize_cdr(JAZZY.deserialize_cdr(ours, "visualization_msgs/msg/MarkerArray"),
                               "visualization_msgs/msg/MarkerArray") == ours
    assert len(msg.markers) == len(scene.markers)
    for m, ref in zip(msg.markers, scene.markers, strict=True):
        assert (m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec) == ("body", 1, 500_000_007)
        assert m.frame_locked and m.action == 0 and (m.ns, m.id, m.type, m.text) == (ref.ns, ref.id, ref.type,
                                                                                      ref.text)
        assert [m.pose.position.x, m.pose.position.y, m.pose.position.z] == list(ref.position)
        assert [m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z,
                m.pose.orientation.w] == list(ref.orientation)
        assert [m.scale.x, m.scale.y, m.scale.z] == list(ref.scale)
        assert np.allclose([m.color.r, m.color.g, m.color.b, m.color.a], ref.color, atol=1e-7)  # float32
        assert [(p.x, p.y, p.z) for p in m.points] == [tuple(p) for p in ref.points]
