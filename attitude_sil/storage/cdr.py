"""CDR without rclpy: the stamp at the start of a message, and series of fixed-layout messages encoded at once.

The recorder reads stamps with :func:`stamp_from_cdr`; bags written from the
batch engine encode a whole episode's messages per topic with the
``encode_*`` functions (byte-identical to ``rclpy.serialization``, tested).
The 3D view's messages are written here too: ``tf2_msgs/msg/TFMessage``
(:class:`TfLayout`; tf2_msgs has no wheel on PyPI, so no rclpy class exists
to serialise it) and ``visualization_msgs/msg/MarkerArray``
(:func:`marker_array_cdr`).
The nodes publish each step's stamped vectors, quaternions and clock as the
bytes of :func:`stamped_vector_cdr`, :func:`clock_cdr` and
:func:`joint_state_cdr`, which rclpy sends
as they are (``Publisher.publish(bytes)``): building a Python message and
having rclpy convert and serialise it costs several times as much
(bench/README.md).
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Sequence

import numpy as np

__all__ = ["stamp_from_cdr", "stamped_values", "encode_stamped_vectors", "encode_clocks", "encode_joint_states",
           "stamped_vector_cdr", "clock_cdr", "joint_state_cdr", "TfLayout", "marker_array_cdr", "MARKER_FIELDS"]

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
        self.stamps_at: list[int] = []  # every stamp of the message takes the same time
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
        self.stamps_at.append(self.size)
        self._raw(b"\x00" * 8)

    def count(self, n: int) -> None:
        """A sequence's length (its elements follow)."""
        self._align(4)
        self._raw(struct.pack("<I", n))

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
        if self.stamps_at:
            t = np.asarray(stamps_ns, dtype=np.int64)
            stamp = np.empty((n, 2), dtype="<u4")
            stamp[:, 0] = (t // 1_000_000_000).astype("<i4").view("<u4")
            stamp[:, 1] = t % 1_000_000_000
            for at in self.stamps_at:
                buf[:, 4 + at:12 + at] = stamp.view(np.uint8).reshape(n, 8)
        for (offset, count), values in zip(self.doubles, columns, strict=True):
            v = np.ascontiguousarray(np.asarray(values, dtype="<f8").reshape(n, count))
            buf[:, 4 + offset:4 + offset + 8 * count] = v.view(np.uint8).reshape(n, 8 * count)
        return [row.tobytes() for row in buf]

    def encode_one(self, t_ns: int, *runs: Sequence[float]) -> bytes:
        """One message: :meth:`encode` for a single stamp, written with ``struct`` (no arrays to build)."""
        buf = bytearray(self._template)
        if self.stamps_at:
            sec, nsec = divmod(int(t_ns), 1_000_000_000)
            for at in self.stamps_at:
                _STAMP.pack_into(buf, 4 + at, sec, nsec)
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


class TfLayout:
    """``tf2_msgs/msg/TFMessage`` of fixed frames: one ``TransformStamped`` per (parent, child) pair, all stamped
    alike, translation zero (the frames share an origin), rotation the child's orientation in the parent.

    Parameters
    ----------
    pairs : sequence of (str, str)
        ``(header.frame_id, child_frame_id)`` of each transform, in order.
    """

    def __init__(self, pairs: Sequence[tuple[str, str]]) -> None:
        self.pairs = tuple((str(a), str(b)) for a, b in pairs)
        self._layout = _Layout()
        self._layout.count(len(self.pairs))
        for parent, child in self.pairs:
            self._layout.stamp()
            self._layout.string(parent)
            self._layout.string(child)
            self._layout.float64s(7)  # translation x y z, rotation x y z w: one run
        self._zeros = (0.0, 0.0, 0.0)

    def encode_one(self, t_ns: int, rotations: Sequence[Sequence[float]]) -> bytes:
        """One message stamped ``t_ns``: ``rotations`` one (4,) quaternion (x, y, z, w) per pair."""
        if len(rotations) != len(self.pairs):
            raise ValueError(f"TfLayout: {len(self.pairs)} frames, {len(rotations)} rotations")
        return self._layout.encode_one(t_ns, *((*self._zeros, *(float(v) for v in q)) for q in rotations))

    def encode(self, stamps_ns: np.ndarray, rotations: Sequence[np.ndarray]) -> list[bytes]:
        """A series: stamps (n,) ns, ``rotations`` one (n, 4) array per pair."""
        n = len(stamps_ns)
        if len(rotations) != len(self.pairs):
            raise ValueError(f"TfLayout: {len(self.pairs)} frames, {len(rotations)} rotations")
        runs = []
        for q in rotations:
            run = np.zeros((n, 7))
            run[:, 3:] = np.asarray(q, dtype=float).reshape(n, 4)
            runs.append(run)
        return self._layout.encode(stamps_ns, runs)


#: what :func:`marker_array_cdr` reads of each marker (attributes or keys): ``ns`` str, ``id`` int, ``type`` int
#: (``visualization_msgs/Marker`` codes), ``position`` (3,), ``orientation`` (4,) x y z w, ``scale`` (3,),
#: ``color`` (4,) r g b a in 0..1, ``points`` (m, 3), ``text`` str
MARKER_FIELDS = ("ns", "id", "type", "position", "orientation", "scale", "color", "points", "text")


class _Writer:
    """Little-endian CDR (XCDR1) of a message of any layout, field by field."""

    def __init__(self) -> None:
        self.buf = bytearray()

    def _align(self, n: int) -> None:
        self.buf += b"\x00" * ((-len(self.buf)) % n)

    def put(self, fmt: str, *values) -> None:
        """Values of one struct format, aligned to the size of its first type (``"3d"``: 8)."""
        self._align(struct.calcsize("<" + fmt.lstrip("0123456789")[0]))
        self.buf += struct.pack("<" + fmt, *values)

    def string(self, text: str) -> None:
        data = text.encode("utf-8") + b"\x00"
        self.put("I", len(data))
        self.buf += data

    def header(self, t_ns: int, frame_id: str) -> None:
        sec, nsec = divmod(int(t_ns), 1_000_000_000)
        self.put("iI", sec, nsec)
        self.string(frame_id)

    def bytes(self) -> bytes:
        return _ENCAPSULATION + bytes(self.buf)


def _field(marker, name: str):
    return marker[name] if isinstance(marker, dict) else getattr(marker, name)


def marker_array_cdr(t_ns: int, frame_id: str, markers: Sequence, frame_locked: bool = True) -> bytes:
    """One ``visualization_msgs/msg/MarkerArray`` (ROS 2 Jazzy's ``Marker``) as CDR, action ADD, no lifetime.

    Parameters
    ----------
    t_ns : int
        Header stamp of every marker, ns.
    frame_id : str
        The frame every marker is drawn in.
    markers : sequence
        Objects or dicts with the fields of :data:`MARKER_FIELDS`.
    frame_locked : bool
        Redraw each marker in its frame as the frame moves (what a body model needs).

    Returns
    -------
    bytes
        The bytes ``rclpy.serialization.serialize_message`` gives for the same
        message, padding aside (tested).
    """
    w = _Writer()
    w.put("I", len(markers))
    for m in markers:
        w.header(t_ns, frame_id)
        w.string(str(_field(m, "ns")))
        w.put("iii", int(_field(m, "id")), int(_field(m, "type")), 0)  # id, type, action ADD
        w.put("7d", *(float(v) for v in _field(m, "position")), *(float(v) for v in _field(m, "orientation")))
        w.put("3d", *(float(v) for v in _field(m, "scale")))
        w.put("4f", *(float(v) for v in _field(m, "color")))
        w.put("iI", 0, 0)  # lifetime 0: forever
        w.put("?", bool(frame_locked))
        points = np.asarray(_field(m, "points"), dtype=float).reshape(-1, 3)
        w.put("I", len(points))
        for p in points:
            w.put("3d", *(float(v) for v in p))
        w.put("I", 0)  # colors
        w.string("")  # texture_resource
        w.header(0, "")  # texture (sensor_msgs/CompressedImage): header, format, data
        w.string("")
        w.put("I", 0)
        w.put("I", 0)  # uv_coordinates
        w.string(str(_field(m, "text")))
        w.string("")  # mesh_resource
        w.string("")  # mesh_file: filename, data
        w.put("I", 0)
        w.put("?", False)  # mesh_use_embedded_materials
    return w.bytes()
