"""CDR without rclpy: the stamp at the start of a message, and series of fixed-layout messages encoded at once.

The recorder reads stamps with :func:`stamp_from_cdr`; bags written from the
batch engine encode a whole episode's messages per topic with the
``encode_*`` functions (byte-identical to ``rclpy.serialization``, tested).
The nodes publish each step's stamped vectors, quaternions and clock as the
bytes of :func:`stamped_vector_cdr`, :func:`clock_cdr` and
:func:`joint_state_cdr`, which rclpy sends
as they are (``Publisher.publish(bytes)``): building a Python message and
having rclpy convert and serialise it cost 34 us a message here, these 8 us
with the send.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Sequence

import numpy as np

__all__ = ["stamp_from_cdr", "stamped_values", "encode_stamped_vectors", "encode_clocks", "encode_joint_states",
           "stamped_vector_cdr", "clock_cdr", "joint_state_cdr"]

_STAMP = struct.Struct("<iI")


def stamp_from_cdr(data: bytes) -> int | None:
    """Nanoseconds of the ``builtin_interfaces/Time`` that opens a message, or None.

    Every recorded type starts with a stamp (a ``Header``, ``Clock.clock`` or
    ``ParameterEvent.stamp``), right after the 4-byte CDR encapsulation header.
    """
    if len(data) < 12 or data[1] not in (0, 1):
        return None
    sec, nsec = _STAMP.unpack_from(data, 4) if data[1] == 1 else struct.unpack_from(">iI", data, 4)
    return sec * 1_000_000_000 + nsec


# -- encoding whole series of fixed-layout messages (little-endian CDR, XCDR1) ------------------------
# A series of messages that differ only in their stamp and float64 fields has one byte layout:
# it is built once and the varying fields are written for all messages at once with numpy.

_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little endian


class _Layout:
    """Byte layout of a message body: constant bytes plus the offsets of float64 runs."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.size = 0  # bytes after the encapsulation header
        self.stamp_at: int | None = None
        self.doubles: list[tuple[int, int]] = []  # (offset, count)

    def _align(self, n: int) -> None:
        pad = (-self.size) % n
        if pad:
            self._raw(b"\x00" * pad)

    def _raw(self, data: bytes) -> None:
        self.parts.append(data)
        self.size += len(data)

    def stamp(self) -> None:
        self._align(4)
        self.stamp_at = self.size
        self._raw(b"\x00" * 8)

    def string(self, text: str) -> None:
        data = text.encode("utf-8") + b"\x00"
        self._align(4)
        self._raw(struct.pack("<I", len(data)) + data)

    def strings(self, texts: list[str]) -> None:
        self._align(4)
        self._raw(struct.pack("<I", len(texts)))
        for text in texts:
            self.string(text)

    def float64s(self, count: int, sequence: bool = False) -> None:
        if sequence:
            self._align(4)
            self._raw(struct.pack("<I", count))
        self._align(8)  # Fast CDR aligns an empty run too
        if count:
            self.doubles.append((self.size, count))
            self._raw(b"\x00" * (8 * count))

    @functools.cached_property
    def _template(self) -> bytes:
        # the message's bytes with zeros where the stamp and the float64 runs go; a layout is complete before
        # it first encodes, and the nodes' cached layouts encode every step
        return _ENCAPSULATION + b"".join(self.parts)

    def encode(self, stamps_ns: np.ndarray, columns: list[np.ndarray]) -> list[bytes]:
        """Messages with these stamps (n,) ns and float64 runs, each (n, count)."""
        n = len(stamps_ns)
        buf = np.empty((n, 4 + self.size), dtype=np.uint8)
        buf[:] = np.frombuffer(self._template, dtype=np.uint8)
        if self.stamp_at is not None:
            t = np.asarray(stamps_ns, dtype=np.int64)
            stamp = np.empty((n, 2), dtype="<u4")
            stamp[:, 0] = (t // 1_000_000_000).astype("<i4").view("<u4")
            stamp[:, 1] = t % 1_000_000_000
            buf[:, 4 + self.stamp_at:12 + self.stamp_at] = stamp.view(np.uint8).reshape(n, 8)
        for (offset, count), values in zip(self.doubles, columns, strict=True):
            v = np.ascontiguousarray(np.asarray(values, dtype="<f8").reshape(n, count))
            buf[:, 4 + offset:4 + offset + 8 * count] = v.view(np.uint8).reshape(n, 8 * count)
        return [row.tobytes() for row in buf]

    def encode_one(self, t_ns: int, *runs: Sequence[float]) -> bytes:
        """One message: :meth:`encode` for a single stamp, written with ``struct`` (no arrays to build)."""
        buf = bytearray(self._template)
        if self.stamp_at is not None:
            sec, nsec = divmod(int(t_ns), 1_000_000_000)
            _STAMP.pack_into(buf, 4 + self.stamp_at, sec, nsec)
        for (offset, count), values in zip(self.doubles, runs, strict=True):
            struct.pack_into(f"<{count}d", buf, 4 + offset, *values)
        return bytes(buf)


def stamped_vector_cdr(values: Sequence[float], t_ns: int, frame_id: str) -> bytes:
    """One ``Vector3Stamped`` (values (3,), or (2,) with z = 0) or ``QuaternionStamped`` ((4,), x y z w) as CDR.

    The bytes ``rclpy.serialization.serialize_message`` gives for the same
    message (tested), for a publisher of that type to send as they are.
    """
    v = [float(x) for x in values]
    if len(v) < 3:
        v += [0.0] * (3 - len(v))
    return _stamped_layout(frame_id, len(v)).encode_one(t_ns, v)


def clock_cdr(t_ns: int) -> bytes:
    """One ``rosgraph_msgs/Clock`` as CDR (as :func:`stamped_vector_cdr`)."""
    return _CLOCK.encode_one(t_ns)


@functools.cache
def _stamped_layout(frame_id: str, count: int) -> _Layout:
    layout = _Layout()
    layout.stamp()
    layout.string(frame_id)
    layout.float64s(count)
    return layout


_CLOCK = _Layout()
_CLOCK.stamp()


def encode_stamped_vectors(stamps_ns: np.ndarray, frame_id: str, values: np.ndarray) -> list[bytes]:
    """``geometry_msgs/Vector3Stamped`` (values (n, 3)) or ``QuaternionStamped`` ((n, 4), x y z w) as CDR."""
    return _stamped_layout(frame_id, np.asarray(values).shape[1]).encode(stamps_ns, [values])


def encode_clocks(stamps_ns: np.ndarray) -> list[bytes]:
    """``rosgraph_msgs/Clock`` messages as CDR."""
    return _CLOCK.encode(stamps_ns, [])


@functools.cache
def _joint_layout(frame_id: str, names: tuple[str, ...]) -> _Layout:
    layout = _Layout()
    layout.stamp()
    layout.string(frame_id)
    layout.strings(list(names))
    for _ in range(3):
        layout.float64s(len(names), sequence=True)
    return layout


def encode_joint_states(stamps_ns: np.ndarray, frame_id: str, names: list[str], position: np.ndarray,
                        velocity: np.ndarray, effort: np.ndarray) -> list[bytes]:
    """``sensor_msgs/JointState`` messages (each array (n, joints)) as CDR."""
    joints = len(names)
    columns = [np.asarray(a, dtype=float).reshape(len(stamps_ns), joints) for a in (position, velocity, effort)]
    return _joint_layout(frame_id, tuple(names)).encode(stamps_ns, [c for c in columns if joints])


def joint_state_cdr(names: Sequence[str], position: Sequence[float], velocity: Sequence[float],
                    effort: Sequence[float], t_ns: int, frame_id: str = "") -> bytes:
    """One ``sensor_msgs/JointState`` (each array (joints,)) as CDR (as :func:`stamped_vector_cdr`)."""
    runs = [[float(x) for x in a] for a in (position, velocity, effort)]
    if any(len(r) != len(names) for r in runs):
        raise ValueError(f"joint_state_cdr: {len(names)} names, arrays of {[len(r) for r in runs]}")
    return _joint_layout(frame_id, tuple(names)).encode_one(t_ns, *(r for r in runs if names))


def stamped_values(data: bytes, count: int) -> np.ndarray | None:
    """The ``count`` float64 values that end a CDR ``Vector3Stamped`` (3) or ``QuaternionStamped`` (4), or None.

    Reads the header's frame id length to find them, without decoding the
    message: what the recorder needs to check a value before it records it.
    """
    if len(data) < 16 or data[1] != 1:  # little-endian CDR only (what rmw writes here)
        return None
    (length,) = struct.unpack_from("<I", data, 12)
    start = 8 + 4 + length  # relative to the data after the 4-byte encapsulation header
    start += (-start) % 8
    end = 4 + start + 8 * count
    if end > len(data):
        return None
    return np.frombuffer(data, dtype="<f8", count=count, offset=4 + start)
