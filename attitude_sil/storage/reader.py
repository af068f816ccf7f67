"""Read rosbag2 bags with MCAP storage, including runs killed before closing.

:func:`open_bag` takes a rosbag2 directory (``<run>/<run>_0.mcap`` plus
``metadata.yaml``, as :mod:`attitude_sil.storage.writer` or ``ros2 bag record -s
mcap`` lays it out) or a single ``.mcap`` file and returns a
:class:`BagReader`, which lists the topics and time range and iterates over
the messages in log-time order, raw (CDR bytes) or decoded from the schemas
stored in the bag with mcap-ros2-support (no rclpy needed).

A file whose footer and summary are missing (a run killed without closing
its bag, or a copy cut short) is indexed by a forward scan of its records:
every complete chunk is read, chunk CRCs are checked and a torn trailing
record is skipped; :attr:`BagReader.recovered` then says so.  Anything else
that is wrong with a file (missing, empty, not MCAP, a corrupt chunk) raises
:class:`BagError` with a one-line message naming the file.

Log times are what the recorder stored: here the header stamps, i.e. sim
time in nanoseconds.
"""

from __future__ import annotations

import contextlib
import heapq
import io
import re
import struct
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

import yaml
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    Footer,
    Message,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)
from mcap.stream_reader import breakup_chunk
from mcap_ros2.decoder import DecoderFactory

from attitude_sil.errors import BagError

__all__ = ['BagError', 'BagReader', 'RawMessage', 'TopicInfo', 'open_bag']

MAGIC = b'\x89MCAP0\r\n'
_RECORD_HEADER = struct.Struct('<BQ')
_FOOTER_LENGTH = 8 + 8 + 4  # summary start, summary offset start, summary CRC
_FOOTER_RECORD_SIZE = _RECORD_HEADER.size + _FOOTER_LENGTH
_KNOWN_OPCODES = frozenset(int(op) for op in Opcode)
_METADATA_FILE = 'metadata.yaml'


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag.

    Attributes
    ----------
    name : str
        Full topic name, e.g. ``/sat1/attitude``.
    type : str
        Message type, e.g. ``geometry_msgs/msg/QuaternionStamped``.
    count : int
        Messages on the topic in the bag (may be 0).
    message_encoding : str
        Serialization format, ``cdr`` for ROS 2.
    schema_encoding : str
        Encoding of the stored type definition, ``ros2msg`` for ROS 2.
    offered_qos_profiles : str
        The QoS the recording saw offered, as rosbag2 stores it (YAML, see
        :func:`~attitude_sil.storage.writer.parse_qos_profiles`): from the
        channel's metadata, else from ``metadata.yaml``; empty if neither has it.
    """

    name: str
    type: str
    count: int
    message_encoding: str
    schema_encoding: str
    offered_qos_profiles: str = ''


class RawMessage(NamedTuple):
    """One recorded message, still serialized.

    Attributes
    ----------
    topic : str
        Full topic name.
    type : str
        Message type (``pkg/msg/Name``).
    log_time_ns : int
        Log time in nanoseconds (here: the header stamp, sim time).
    publish_time_ns : int
        Publish time in nanoseconds.
    data : bytes
        The serialized message (CDR for ROS 2 bags).
    """

    topic: str
    type: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


@dataclass
class _ChunkRef:
    """Where a chunk is and what it may hold."""

    offset: int  # of the chunk record (its opcode byte)
    start_ns: int
    end_ns: int
    channel_ids: frozenset[int] | None  # None: unknown, must be read to know


@dataclass
class _McapFile:
    """What :func:`_index_file` learns about one MCAP file."""

    path: Path
    size: int
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)
    chunks: list[_ChunkRef] = field(default_factory=list)
    # Messages outside chunks (unchunked files), with their record offsets.
    loose: list[tuple[int, Message]] = field(default_factory=list)
    start_ns: int | None = None
    end_ns: int | None = None
    recovered: bool = False
    note: str = ''
    rosbag2_metadata: dict[str, str] | None = None

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    def add_time(self, t: int) -> None:
        self.start_ns = t if self.start_ns is None else min(self.start_ns, t)
        self.end_ns = t if self.end_ns is None else max(self.end_ns, t)


# ------------------------------------------------------------------ file indexing
def _read_exact(f: BinaryIO, offset: int, length: int) -> bytes:
    f.seek(offset)
    data = f.read(length)
    if len(data) != length:
        raise EOFError(f'{length} bytes wanted at byte offset {offset}, file ends first')
    return data


def _read_summary(f: BinaryIO, info: _McapFile) -> bool:
    """Fill ``info`` from the footer and summary section; False if they are unusable."""
    if info.size < 2 * len(MAGIC) + _FOOTER_RECORD_SIZE:
        return False
    try:
        tail = _read_exact(f, info.size - len(MAGIC) - _FOOTER_RECORD_SIZE,
                           _FOOTER_RECORD_SIZE + len(MAGIC))
    except EOFError:
        return False
    if tail[-len(MAGIC):] != MAGIC:
        return False
    opcode, length = _RECORD_HEADER.unpack_from(tail)
    if opcode != Opcode.FOOTER or length != _FOOTER_LENGTH:
        return False
    footer = Footer.read(ReadDataStream(io.BytesIO(tail[_RECORD_HEADER.size:])))
    summary_end = info.size - len(MAGIC) - _FOOTER_RECORD_SIZE
    if footer.summary_start == 0 or not len(MAGIC) <= footer.summary_start <= summary_end:
        return False
    try:
        section = _read_exact(f, footer.summary_start, summary_end - footer.summary_start)
        if footer.summary_crc:
            # The CRC covers the summary section and the footer up to the CRC field.
            crc = zlib.crc32(section + tail[:_FOOTER_RECORD_SIZE - 4])
            if crc != footer.summary_crc:
                return False
        stats: Statistics | None = None
        chunk_indexes: list[ChunkIndex] = []
        metadata_indexes: list[MetadataIndex] = []
        for opcode, body in _iter_records(section):
            stream = ReadDataStream(io.BytesIO(body))
            if opcode == Opcode.SCHEMA:
                schema = Schema.read(stream)
                info.schemas[schema.id] = schema
            elif opcode == Opcode.CHANNEL:
                channel = Channel.read(stream)
                info.channels[channel.id] = channel
            elif opcode == Opcode.STATISTICS:
                stats = Statistics.read(stream)
            elif opcode == Opcode.CHUNK_INDEX:
                chunk_indexes.append(ChunkIndex.read(stream))
            elif opcode == Opcode.METADATA_INDEX:
                metadata_indexes.append(MetadataIndex.read(stream))
    except (EOFError, McapError, struct.error, UnicodeDecodeError, ValueError):
        return False
    if (stats is None or (stats.message_count and not chunk_indexes)
            or not set(stats.channel_message_counts) <= set(info.channels)):
        # Counts or channels unknown, or messages outside chunks: a scan is needed.
        info.schemas.clear()
        info.channels.clear()
        return False
    for channel_id, count in stats.channel_message_counts.items():
        info.counts[channel_id] = count
    for channel_id in info.channels:
        info.counts.setdefault(channel_id, 0)
    if stats.message_count:
        info.start_ns, info.end_ns = stats.message_start_time, stats.message_end_time
    for index in chunk_indexes:
        ids = frozenset(index.message_index_offsets) if index.message_index_offsets else None
        info.chunks.append(_ChunkRef(index.chunk_start_offset, index.message_start_time,
                                     index.message_end_time, ids))
    for index in metadata_indexes:
        if index.name != 'rosbag2':
            continue
        with contextlib.suppress(EOFError, McapError, struct.error, UnicodeDecodeError):
            opcode, body = _read_record_at(f, index.offset, info.size)
            if opcode == Opcode.METADATA:
                info.rosbag2_metadata = Metadata.read(ReadDataStream(io.BytesIO(body))).metadata
    return True


def _iter_records(section: bytes) -> Iterator[tuple[int, bytes]]:
    pos = 0
    while pos < len(section):
        if len(section) - pos < _RECORD_HEADER.size:
            raise EOFError('torn record header')
        opcode, length = _RECORD_HEADER.unpack_from(section, pos)
        pos += _RECORD_HEADER.size
        if pos + length > len(section):
            raise EOFError('torn record')
        yield opcode, section[pos:pos + length]
        pos += length


def _read_record_at(f: BinaryIO, offset: int, size: int) -> tuple[int, bytes]:
    header = _read_exact(f, offset, _RECORD_HEADER.size)
    opcode, length = _RECORD_HEADER.unpack(header)
    if offset + _RECORD_HEADER.size + length > size:
        raise EOFError(f'record at byte offset {offset} runs past the end of the file')
    return opcode, _read_exact(f, offset + _RECORD_HEADER.size, length)


def _chunk_records(chunk_body: bytes, where: str) -> list[Any]:
    """Decompress a chunk record's body, check its CRC and split it into records."""
    try:
        chunk = Chunk.read(ReadDataStream(io.BytesIO(chunk_body)))
        return breakup_chunk(chunk, validate_crc=True)
    except Exception as exc:  # noqa: BLE001 - zstd/lz4/CRC/struct errors alike
        raise BagError(f'{where}: {_first_line(exc)}') from None


def _scan_chunk(info: _McapFile, body: bytes, pos: int, where: str) -> None:
    """Add the schemas, channels and messages of the chunk record at byte offset ``pos`` to ``info``."""
    ids: set[int] = set()
    start = end = None
    for record in _chunk_records(body, where):
        if isinstance(record, Schema):
            info.schemas[record.id] = record
        elif isinstance(record, Channel):
            info.channels[record.id] = record
            info.counts.setdefault(record.id, 0)
        elif isinstance(record, Message):
            _check_channel(info, record, where)
            ids.add(record.channel_id)
            info.counts[record.channel_id] += 1
            info.add_time(record.log_time)
            start = record.log_time if start is None else min(start, record.log_time)
            end = record.log_time if end is None else max(end, record.log_time)
    if start is not None and end is not None:
        info.chunks.append(_ChunkRef(pos, start, end, frozenset(ids)))


def _scan_file(f: BinaryIO, info: _McapFile, closed: bool) -> None:
    """Index ``info`` by reading every record from the start.

    ``closed`` says the file ends with the MCAP magic: then a record that runs
    past the end is corruption, not a file cut short.
    """
    path = info.path
    pos = len(MAGIC)
    torn = False
    data_end = False
    f.seek(pos)
    while pos < info.size:
        if info.size - pos < _RECORD_HEADER.size:
            torn = True
            break
        opcode, length = _RECORD_HEADER.unpack(f.read(_RECORD_HEADER.size))
        if opcode not in _KNOWN_OPCODES and opcode < 0x80:
            raise BagError(f'{path}: corrupt record at byte offset {pos} (opcode 0x{opcode:02x})')
        if pos + _RECORD_HEADER.size + length > info.size:
            if closed:
                raise BagError(f'{path}: corrupt record at byte offset {pos}: '
                               f'its length {length} runs past the end of the file')
            torn = True
            break
        body = f.read(length)
        where = f'{path}: corrupt {_opcode_name(opcode)} record at byte offset {pos}'
        try:
            if opcode == Opcode.CHUNK:
                _scan_chunk(info, body, pos, where)
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.METADATA):
                stream = ReadDataStream(io.BytesIO(body))
                if opcode == Opcode.SCHEMA:
                    schema = Schema.read(stream)
                    info.schemas[schema.id] = schema
                elif opcode == Opcode.CHANNEL:
                    channel = Channel.read(stream)
                    info.channels[channel.id] = channel
                    info.counts.setdefault(channel.id, 0)
                elif opcode == Opcode.MESSAGE:
                    message = Message.read(stream, length)
                    _check_channel(info, message, where)
                    info.loose.append((pos, message))
                    info.counts[message.channel_id] += 1
                    info.add_time(message.log_time)
                else:
                    metadata = Metadata.read(stream)
                    if metadata.name == 'rosbag2':
                        info.rosbag2_metadata = metadata.metadata
            elif opcode == Opcode.DATA_END:
                data_end = True
                break
            elif opcode == Opcode.FOOTER:
                break
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001 - struct/unicode/mcap errors alike
            raise BagError(f'{where}: {_first_line(exc)}') from None
        pos += _RECORD_HEADER.size + length
    if not closed:
        info.recovered = True
        count = info.message_count
        problem = 'truncated: summary incomplete' if data_end else 'truncated: summary missing'
        torn_note = f' (torn record at byte offset {pos} skipped)' if torn else ''
        if count == 0:
            raise BagError(f'{path}: {problem}; no complete message found by scanning{torn_note}')
        info.note = f'{path}: {problem}; recovered {count} messages by scanning{torn_note}'


def _check_channel(info: _McapFile, message: Message, where: str) -> None:
    if message.channel_id not in info.channels:
        raise BagError(f'{where}: message on unknown channel id {message.channel_id}')


def _opcode_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower().replace('_', ' ')
    except ValueError:
        return f'0x{opcode:02x}'


def _index_file(path: Path) -> _McapFile:
    try:
        size = path.stat().st_size
        f = path.open('rb')
    except OSError as exc:
        raise BagError(f'{path}: cannot open: {exc.strerror or _first_line(exc)}') from None
    with f:
        if size == 0:
            raise BagError(f'{path}: empty file (0 bytes), not an MCAP file')
        head = f.read(len(MAGIC))
        if head != MAGIC:
            if MAGIC.startswith(head):
                raise BagError(f'{path}: truncated: only {size} bytes, no MCAP records')
            raise BagError(f'{path}: not an MCAP file')
        info = _McapFile(path, size)
        if _read_summary(f, info):
            return info
        f.seek(max(size - len(MAGIC), len(MAGIC)))
        closed = size >= 2 * len(MAGIC) and f.read(len(MAGIC)) == MAGIC
        _scan_file(f, info, closed)
        return info


# ------------------------------------------------------------------ bag layout
def _natural_key(path: Path) -> list[Any]:
    return [int(part) if part.isdigit() else part for part in re.split(r'(\d+)', path.name)]


def _load_metadata_yaml(directory: Path) -> dict[str, Any] | None:
    meta_path = directory / _METADATA_FILE
    if not meta_path.is_file():
        return None
    try:
        loaded = yaml.safe_load(meta_path.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return None
    if not isinstance(loaded, dict):
        return None
    info = loaded.get('rosbag2_bagfile_information')
    return info if isinstance(info, dict) else None


def _metadata_qos(metadata: dict[str, Any]) -> dict[str, str]:
    """Topic -> ``offered_qos_profiles`` as a YAML string, from ``metadata.yaml`` (a list in version 9)."""
    out = {}
    for entry in metadata.get('topics_with_message_count') or []:
        topic = entry.get('topic_metadata') if isinstance(entry, dict) else None
        if not isinstance(topic, dict) or not isinstance(topic.get('name'), str):
            continue
        qos = topic.get('offered_qos_profiles')
        if isinstance(qos, list):
            qos = yaml.safe_dump(qos, sort_keys=False)
        if isinstance(qos, str):
            out[topic['name']] = qos
    return out


def _bag_files(path: Path) -> tuple[list[Path], dict[str, Any] | None]:
    if not path.exists():
        raise BagError(f'{path}: no such file or directory')
    if path.is_file():
        if path.name == _METADATA_FILE:
            path = path.parent
        else:
            return [path], None
    if not path.is_dir():
        raise BagError(f'{path}: not a file or directory')
    metadata = _load_metadata_yaml(path)
    listed = metadata.get('relative_file_paths') if metadata else None
    if isinstance(listed, list) and listed and all(isinstance(p, str) for p in listed):
        files = [path / p for p in listed]
        for file in files:
            if not file.is_file():
                raise BagError(f'{path / _METADATA_FILE}: lists {file.name}, which does not exist')
            if file.suffix != '.mcap':
                raise BagError(f'{file}: not an .mcap file (compressed or other storage?)')
        return files, metadata
    files = sorted((p for p in path.glob('*.mcap') if p.is_file()), key=_natural_key)
    if not files:
        raise BagError(f'{path}: no .mcap file in this directory')
    return files, metadata


def open_bag(path: str | Path) -> BagReader:
    """Open a rosbag2 directory with MCAP storage, or a single ``.mcap`` file.

    Parameters
    ----------
    path : str or Path
        A bag directory (its ``*.mcap`` files are read in the order of
        ``relative_file_paths`` in ``metadata.yaml``, else by name), its
        ``metadata.yaml``, or one MCAP file.

    Returns
    -------
    BagReader
        Indexed bag; files are only opened while reading.

    Raises
    ------
    BagError
        If the path is missing, a directory holds no ``.mcap`` file, or a
        file is empty, not MCAP, or corrupt (a file cut short is not an
        error if complete messages can be recovered from it).
    """
    files, metadata = _bag_files(Path(path))
    return BagReader([_index_file(p) for p in files], metadata)


class BagReader:
    """An indexed bag of one or more MCAP files; use :func:`open_bag`.

    Parameters
    ----------
    files : list of _McapFile
        The indexed files, in order.
    metadata : dict, optional
        ``rosbag2_bagfile_information`` of ``metadata.yaml``.
    """

    def __init__(self, files: list[_McapFile], metadata: dict[str, Any] | None = None) -> None:
        self._files = files
        self._metadata = metadata or {}
        listed_qos = _metadata_qos(self._metadata)
        topics: dict[str, TopicInfo] = {}
        for info in files:
            for channel_id, channel in info.channels.items():
                schema = info.schemas.get(channel.schema_id)
                type_name = schema.name if schema is not None else ''
                old = topics.get(channel.topic)
                if old is not None and old.type != type_name:
                    raise BagError(f'{info.path}: topic {channel.topic} has type {type_name}, '
                                   f'but {old.type} in another channel')
                topics[channel.topic] = TopicInfo(
                    name=channel.topic,
                    type=type_name,
                    count=(old.count if old else 0) + info.counts.get(channel_id, 0),
                    message_encoding=channel.message_encoding,
                    schema_encoding=schema.encoding if schema is not None else '',
                    offered_qos_profiles=(channel.metadata or {}).get('offered_qos_profiles')
                    or (old.offered_qos_profiles if old else '') or listed_qos.get(channel.topic, ''),
                )
        self._topics = dict(sorted(topics.items()))

    # ----------------------------------------------------------- properties
    @property
    def paths(self) -> list[Path]:
        """The MCAP files of the bag, in reading order."""
        return [f.path for f in self._files]

    @property
    def topics(self) -> dict[str, TopicInfo]:
        """Topic name -> :class:`TopicInfo`, sorted by name (including topics with 0 messages)."""
        return dict(self._topics)

    @property
    def start_ns(self) -> int:
        """Log time of the earliest message (ns); 0 for a bag without messages."""
        starts = [f.start_ns for f in self._files if f.start_ns is not None]
        return min(starts) if starts else 0

    @property
    def end_ns(self) -> int:
        """Log time of the latest message (ns); 0 for a bag without messages."""
        ends = [f.end_ns for f in self._files if f.end_ns is not None]
        return max(ends) if ends else 0

    @property
    def duration_ns(self) -> int:
        """``end_ns - start_ns`` (ns)."""
        return self.end_ns - self.start_ns

    @property
    def message_count(self) -> int:
        """Messages on all topics."""
        return sum(f.message_count for f in self._files)

    @property
    def size_bytes(self) -> int:
        """Total size of the MCAP files (bytes)."""
        return sum(f.size for f in self._files)

    @property
    def recovered(self) -> bool:
        """True if a file had no usable footer/summary and was indexed by scanning it."""
        return any(f.recovered for f in self._files)

    @property
    def notes(self) -> list[str]:
        """One line per recovered file, e.g. ``'<file>: truncated: summary missing; recovered N messages ...'``."""
        return [f.note for f in self._files if f.note]

    @property
    def custom_data(self) -> dict[str, str]:
        """``custom_data`` of ``metadata.yaml`` (empty without one)."""
        custom = self._metadata.get('custom_data')
        return {str(k): str(v) for k, v in custom.items()} if isinstance(custom, dict) else {}

    @property
    def storage(self) -> str:
        """Storage identifier: always ``'mcap'``."""
        return 'mcap'

    @property
    def ros_distro(self) -> str | None:
        """ROS distribution that recorded the bag (``metadata.yaml`` or the ``rosbag2`` record), if known."""
        distro = self._metadata.get('ros_distro')
        if isinstance(distro, str) and distro:
            return distro
        for info in self._files:
            meta = info.rosbag2_metadata or {}
            if meta.get('ros_distro'):
                return meta['ros_distro']
            with contextlib.suppress(yaml.YAMLError):
                loaded = yaml.safe_load(meta.get('serialized_metadata', '') or '{}')
                if isinstance(loaded, dict):
                    loaded = loaded.get('rosbag2_bagfile_information', loaded)
                    if isinstance(loaded, dict) and isinstance(loaded.get('ros_distro'), str):
                        return loaded['ros_distro']
        return None

    def find_topic(self, suffix: str) -> str | None:
        """Full name of the topic whose last path component is ``suffix``.

        Parameters
        ----------
        suffix : str
            E.g. ``'attitude'`` (a leading ``/`` is ignored).

        Returns
        -------
        str or None
            ``/suffix`` if the bag has it, else the first (by name) topic
            ending in ``/suffix``, e.g. ``/sat1/attitude``; None if none does.
        """
        suffix = suffix.strip('/')
        if f'/{suffix}' in self._topics:
            return f'/{suffix}'
        for name in self._topics:
            if name.rsplit('/', 1)[-1] == suffix:
                return name
        return None

    def __repr__(self) -> str:
        return (f'<BagReader {", ".join(p.name for p in self.paths)}: {len(self._topics)} topics, '
                f'{self.message_count} messages{", recovered" if self.recovered else ""}>')

    # ------------------------------------------------------------ iteration
    def _topic_set(self, topics: Iterable[str] | str | None) -> set[str] | None:
        if topics is None:
            return None
        wanted = {topics} if isinstance(topics, str) else set(topics)
        unknown = sorted(wanted - set(self._topics))
        if unknown:
            where = self.paths[0].parent if len(self.paths) > 1 else self.paths[0]
            raise BagError(f'{where}: no topic {", ".join(unknown)} in this bag')
        return wanted

    def _iter(self, topics: Iterable[str] | str | None, start_ns: int | None,
              end_ns: int | None) -> Iterator[tuple[RawMessage, int, int]]:
        """Yield ``(message, file index, channel id)`` in log-time order."""
        wanted = self._topic_set(topics)
        lo = -1 if start_ns is None else start_ns
        hi = 1 << 64 if end_ns is None else end_ns
        # Heap of (log time, file, record offset, index in chunk, payload): a chunk
        # (index -1) is opened when the merge reaches its first log time, so at
        # most the chunks overlapping in time are in memory; ties keep file order.
        heap: list[tuple[int, int, int, int, Any]] = []

        def selected(info: _McapFile, message: Message) -> bool:
            channel = info.channels.get(message.channel_id)
            return (channel is not None and lo <= message.log_time <= hi
                    and (wanted is None or channel.topic in wanted))

        for file_index, info in enumerate(self._files):
            ids = None if wanted is None else {
                cid for cid, ch in info.channels.items() if ch.topic in wanted}
            for chunk in info.chunks:
                if chunk.end_ns < lo or chunk.start_ns > hi:
                    continue
                if ids is not None and chunk.channel_ids is not None and not ids & chunk.channel_ids:
                    continue
                heap.append((chunk.start_ns, file_index, chunk.offset, -1, chunk))
            for offset, message in info.loose:
                if selected(info, message):
                    heap.append((message.log_time, file_index, offset, 0, message))
        heapq.heapify(heap)
        with contextlib.ExitStack() as stack:
            handles: dict[int, BinaryIO] = {}
            while heap:
                _, file_index, offset, index, payload = heapq.heappop(heap)
                info = self._files[file_index]
                if index >= 0:
                    message = payload
                    channel = info.channels[message.channel_id]
                    schema = info.schemas.get(channel.schema_id)
                    yield (RawMessage(channel.topic, schema.name if schema else '', message.log_time,
                                      message.publish_time, message.data),
                           file_index, message.channel_id)
                    continue
                f = handles.get(file_index)
                if f is None:
                    try:
                        f = stack.enter_context(info.path.open('rb'))
                    except OSError as exc:
                        raise BagError(f'{info.path}: cannot open: {exc.strerror}') from None
                    handles[file_index] = f
                where = f'{info.path}: corrupt chunk at byte offset {offset}'
                try:
                    opcode, body = _read_record_at(f, offset, info.size)
                except (EOFError, struct.error) as exc:
                    raise BagError(f'{where}: {_first_line(exc)}') from None
                if opcode != Opcode.CHUNK:
                    raise BagError(f'{where}: expected a chunk record, found {_opcode_name(opcode)}')
                position = 0
                for record in _chunk_records(body, where):
                    if isinstance(record, Message):
                        if record.channel_id not in info.channels:
                            raise BagError(f'{where}: message on unknown channel id {record.channel_id}')
                        if selected(info, record):
                            heapq.heappush(heap, (record.log_time, file_index, offset, position, record))
                        position += 1

    def iter_raw(self, topics: Iterable[str] | str | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[RawMessage]:
        """Iterate over serialized messages in log-time order.

        Parameters
        ----------
        topics : str or iterable of str, optional
            Full topic names to read; default all.
        start_ns, end_ns : int, optional
            Inclusive log-time bounds (ns).

        Yields
        ------
        RawMessage
            Messages with equal log times come in file order.

        Raises
        ------
        BagError
            If a topic is not in the bag, or a chunk turns out corrupt (the
            error names the file and the chunk's byte offset).
        """
        for raw, _, _ in self._iter(topics, start_ns, end_ns):
            yield raw

    def iter_decoded(self, topics: Iterable[str] | str | None = None, start_ns: int | None = None,
                     end_ns: int | None = None) -> Iterator[tuple[RawMessage, Any]]:
        """Iterate over messages in log-time order, decoded from the schemas stored in the bag.

        Parameters
        ----------
        topics, start_ns, end_ns
            As for :meth:`iter_raw`.

        Yields
        ------
        (RawMessage, object)
            The raw message and the decoded one (a mcap-ros2-support dynamic
            message with the ROS field names, e.g. ``m.header.stamp.sec``).

        Raises
        ------
        BagError
            As for :meth:`iter_raw`, and if a message cannot be decoded.
        """
        factories = [DecoderFactory() for _ in self._files]  # schema ids are per file
        decoders: dict[tuple[int, int], Callable[[bytes], Any]] = {}
        for raw, file_index, channel_id in self._iter(topics, start_ns, end_ns):
            key = (file_index, channel_id)
            decoder = decoders.get(key)
            info = self._files[file_index]
            if decoder is None:
                channel = info.channels[channel_id]
                schema = info.schemas.get(channel.schema_id)
                try:
                    decoder = factories[file_index].decoder_for(channel.message_encoding, schema)
                except Exception as exc:  # noqa: BLE001 - schema parse errors of any kind
                    raise BagError(f'{info.path}: cannot parse the schema of {raw.topic} '
                                   f'({raw.type}): {_first_line(exc)}') from None
                if decoder is None:
                    raise BagError(f'{info.path}: cannot decode {raw.topic}: encoding '
                                   f'{channel.message_encoding!r} with schema '
                                   f'{schema.encoding if schema else "none"!r} is not supported')
                decoders[key] = decoder
            try:
                decoded = decoder(raw.data)
            except Exception as exc:  # noqa: BLE001 - CDR errors of any kind
                raise BagError(f'{info.path}: cannot decode a {raw.type} on {raw.topic} at log time '
                               f'{raw.log_time_ns} ns: {_first_line(exc)}') from None
            yield raw, decoded
