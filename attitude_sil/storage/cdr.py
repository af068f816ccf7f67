"""Reading the few bytes of a CDR message the storage needs without decoding it (no rclpy)."""

from __future__ import annotations

import struct

__all__ = ["stamp_from_cdr"]

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
