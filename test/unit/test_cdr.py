"""The CDR encoders of storage/cdr.py give rclpy's messages exactly: the numpy ones (a bag's series) and the
one-message ones the nodes publish, which must also be the series' bytes.

rclpy leaves its alignment padding uninitialised (stray bytes of other data show
up there), so the bytes are compared where they carry data: the same length,
the same bytes outside the padding, and rclpy decoding ours to the same message.
"""

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from attitude_sil.storage.cdr import (
    clock_cdr,
    encode_clocks,
    encode_joint_states,
    encode_stamped_vectors,
    joint_state_cdr,
    stamp_from_cdr,
    stamped_vector_cdr,
)

RNG = np.random.default_rng(3)
STAMPS = np.array([0, 10_000_000, 1_999_999_999, 7 * 10**9 + 5, 2**31 * 10**9 - 1], dtype=np.int64)


def _same(ours: bytes, msg) -> None:
    theirs = serialize_message(msg)
    assert len(ours) == len(theirs)
    back = deserialize_message(ours, type(msg))
    assert back == msg
    assert serialize_message(back)[:12] == theirs[:12]  # encapsulation and stamp, byte for byte


def _time(t):
    return Time(sec=int(t // 10**9), nanosec=int(t % 10**9))


@pytest.mark.parametrize("frame", ["", "body", "inertial", "reference", "abcdefg"])
def test_stamped_vectors_and_quaternions(frame):
    v3 = RNG.normal(size=(len(STAMPS), 3)) * 1e3
    q4 = RNG.normal(size=(len(STAMPS), 4))
    for t, data, vec in zip(STAMPS, encode_stamped_vectors(STAMPS, frame, v3), v3, strict=True):
        m = Vector3Stamped()
        m.header.stamp, m.header.frame_id = _time(t), frame
        m.vector.x, m.vector.y, m.vector.z = (float(x) for x in vec)
        _same(data, m)
        assert stamp_from_cdr(data) == t
        assert stamped_vector_cdr(vec, int(t), frame) == data
    for t, data, q in zip(STAMPS, encode_stamped_vectors(STAMPS, frame, q4), q4, strict=True):
        m = QuaternionStamped()
        m.header.stamp, m.header.frame_id = _time(t), frame
        m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w = (float(x) for x in q)
        _same(data, m)
        assert stamped_vector_cdr(q, int(t), frame) == data
    # a planar value (2,) goes out with z = 0, as vector_msg sends it
    assert stamped_vector_cdr(v3[0, :2], 5, frame) == stamped_vector_cdr([v3[0, 0], v3[0, 1], 0.0], 5, frame)


def test_clocks():
    for t, data in zip(STAMPS, encode_clocks(STAMPS), strict=True):
        assert data == serialize_message(Clock(clock=_time(t)))
        assert clock_cdr(int(t)) == data


@pytest.mark.parametrize("names", [[], ["wheel_1"], ["wheel_1", "wheel_2", "wheel_3", "wheel_4"], ["a", "bb", "ccc"]])
def test_joint_states(names):
    n = len(names)
    pos, vel, eff = (RNG.normal(size=(len(STAMPS), n)) for _ in range(3))
    for k, data in enumerate(encode_joint_states(STAMPS, "", names, pos, vel, eff)):
        m = JointState()
        m.header.stamp = _time(STAMPS[k])
        m.name = list(names)
        m.position, m.velocity, m.effort = pos[k].tolist(), vel[k].tolist(), eff[k].tolist()
        _same(data, m)
        assert joint_state_cdr(names, pos[k], vel[k], eff[k], int(STAMPS[k])) == data
    if names:
        with pytest.raises(ValueError, match="names"):
            joint_state_cdr(names, pos[0], vel[0, :-1], eff[0], 0)


@pytest.mark.parametrize("frame", ["", "body", "inertial", "reference"])
def test_stamped_values_reads_the_vector_without_decoding(frame):
    from attitude_sil.storage.cdr import stamped_values

    v3 = RNG.normal(size=(len(STAMPS), 3))
    q4 = RNG.normal(size=(len(STAMPS), 4))
    for values, width in ((v3, 3), (q4, 4)):
        for data, row in zip(encode_stamped_vectors(STAMPS, frame, values), values, strict=True):
            assert np.array_equal(stamped_values(data, width), row)
    m = Vector3Stamped()
    m.header.frame_id = frame
    m.vector.x = float("nan")
    assert np.isnan(stamped_values(serialize_message(m), 3)[0])  # rclpy's own bytes read the same way
    assert stamped_values(b"\x00\x01\x00\x00", 3) is None
