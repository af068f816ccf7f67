"""Summary text of a bag in the style of ``ros2 bag info``.

Start and end are shown as seconds with 9 decimals rather than dates: the
simulator stamps messages (and so logs them) with sim time, which starts at 0.
"""

from __future__ import annotations

from .reader import BagReader

__all__ = ['format_info', 'format_size']

_LABEL_WIDTH = 19  # 'Topic information: ' as ros2 bag info aligns it
# No recording spans more than this: a wider range mixes sim and wall-clock stamps.
_MAX_PLAUSIBLE_SPAN_NS = 10 * 365 * 86_400 * 10**9


def format_size(size_bytes: int) -> str:
    """Human-readable size as ``ros2 bag info`` prints it.

    Parameters
    ----------
    size_bytes : int
        Size in bytes.

    Returns
    -------
    str
        E.g. ``'512 B'``, ``'637.3 KiB'``, ``'1.2 GiB'``.
    """
    value = float(size_bytes)
    for unit in ('B', 'KiB', 'MiB', 'GiB', 'TiB'):
        if value < 1024 or unit == 'TiB':
            return f'{size_bytes} B' if unit == 'B' else f'{value:.1f} {unit}'
        value /= 1024
    raise AssertionError('unreachable')  # pragma: no cover


def _seconds(ns: int) -> str:
    sign = '-' if ns < 0 else ''
    sec, nsec = divmod(abs(ns), 10**9)
    return f'{sign}{sec}.{nsec:09d}'


def format_info(reader: BagReader) -> str:
    """Describe a bag: files, size, time range, message counts and topics.

    Parameters
    ----------
    reader : BagReader
        An opened bag.

    Returns
    -------
    str
        Lines (no trailing newline) like ``ros2 bag info``: ``Files``,
        ``Bag size``, ``Storage id``, ``ROS Distro`` (if known), ``Duration``
        (s), ``Start`` and ``End`` (sim-time stamps in s, 9 decimals),
        ``Messages``, then ``Topic information:`` with one line per topic
        sorted by name::

            Topic: /attitude | Type: geometry_msgs/msg/QuaternionStamped | Count: 2001 | Serialization Format: cdr

        then ``Service: 0`` and ``Service information:`` (Jazzy's service
        lines; the simulator records no services), plus ``Recovered: yes (summary missing, read by scanning)`` when the
        bag was recovered from files without a summary, and a ``Note`` when
        the log times span more than ten years (sim and wall-clock stamps
        mixed).
    """
    lines: list[str] = []

    def add(label: str, value: str) -> None:
        head = f'{label}:' if label else ''
        lines.append(f'{head:<{_LABEL_WIDTH}}{value}'.rstrip())

    for i, path in enumerate(reader.paths):
        add('Files' if i == 0 else '', path.name)
    add('Bag size', format_size(reader.size_bytes))
    add('Storage id', reader.storage)
    if reader.ros_distro:
        add('ROS Distro', reader.ros_distro)
    add('Duration', f'{_seconds(reader.duration_ns)}s')
    add('Start', f'{_seconds(reader.start_ns)} s (sim time)')
    add('End', f'{_seconds(reader.end_ns)} s (sim time)')
    add('Messages', str(reader.message_count))
    topics = list(reader.topics.values())
    if not topics:
        add('Topic information', '')
    for i, topic in enumerate(topics):
        add('Topic information' if i == 0 else '',
            f'Topic: {topic.name} | Type: {topic.type} | Count: {topic.count} | '
            f'Serialization Format: {topic.message_encoding}')
    # ros2 bag info of Jazzy goes on with the recorded services: a run records none
    add('Service', '0')
    add('Service information', '')
    if reader.recovered:
        add('Recovered', 'yes (summary missing, read by scanning)')
    if reader.duration_ns > _MAX_PLAUSIBLE_SPAN_NS:
        years = reader.duration_ns / (365.25 * 86_400 * 10**9)
        add('Note', f'log times span {years:.0f} years: some messages carry wall-clock '
                    'stamps, the others sim time')
    return '\n'.join(lines)
