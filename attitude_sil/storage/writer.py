"""Record already-serialized ROS 2 messages into a rosbag2 bag with MCAP storage.

A run is written as a rosbag2 directory::

    <run_dir>/<run_dir.name>_0.mcap
    <run_dir>/metadata.yaml

laid out as ``ros2 bag record -s mcap`` on Jazzy lays it out, so ``ros2 bag
info`` and ``ros2 bag play``, Foxglove, PlotJuggler, mcap-ros2-support and
rosbags can all read it:

* the MCAP file has profile ``ros2``; each topic is a channel of message
  encoding ``cdr`` whose channel metadata holds ``offered_qos_profiles`` (a
  YAML string in the rosbag2 version-9 form) and ``topic_type_hash``; each
  type is a schema of encoding ``ros2msg`` named ``pkg/msg/Name`` whose data
  is the concatenated definition from :mod:`attitude_sil.storage.msgdefs`;
* messages go into chunks (zstd-compressed by default) that reach the file as
  soon as they are complete;
* :meth:`BagWriter.close` writes the summary and indexes, a ``rosbag2``
  metadata record (rosbag2 reads the QoS format version from it) and
  ``metadata.yaml`` (rosbag2 format version 9).

The writer does not import rclpy: it is fed CDR bytes, e.g. from
``rclpy.serialization.serialize_message``.

Threads and Ctrl-C: only one background thread per bag touches the MCAP
writer; :meth:`BagWriter.write` just queues the message.  So a
``KeyboardInterrupt`` (or any signal handler) that strikes in the middle of a
``write()`` can never leave a half-written record, and :meth:`BagWriter.close`
may be called from any thread, from a signal handler or at exit.  Bags still
open when the interpreter exits are closed by an ``atexit`` hook.
"""

from __future__ import annotations

import atexit
import collections
import copy
import functools
import importlib.metadata
import importlib.util
import io
import json
import operator
import os
import sys
import threading
import time
import weakref
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import yaml
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from attitude_sil.errors import BagWriteError

from .msgdefs import message_definition, normalize_type_name, type_description_hash

__all__ = [
    'check_bag_dir',
    'DEFAULT_QOS_PROFILES_YAML',
    'ROSBAG2_FORMAT_VERSION',
    'BagClosedError',
    'BagWriteError',
    'BagWriter',
    'PARAMETERS_KEY',
    'SCENARIO_KEY',
    'parse_qos_profiles',
    'qos_profiles_yaml',
]

#: metadata.yaml ``custom_data`` key holding every node's parameters at the start of a run
#: (a ROS 2 parameter YAML string; docs/architecture.md, "Bags")
PARAMETERS_KEY = 'attitude_sil.parameters'
#: metadata.yaml ``custom_data`` key holding the scenario section (name and metrics settings) of the run
SCENARIO_KEY = 'attitude_sil.scenario'

#: metadata.yaml format version written (rosbag2 in ROS 2 Jazzy).
ROSBAG2_FORMAT_VERSION = 9
ROS_DISTRO = 'jazzy'
STORAGE_IDENTIFIER = 'mcap'
SERIALIZATION_FORMAT = 'cdr'
SCHEMA_ENCODING = 'ros2msg'

_MAX_UINT64 = (1 << 64) - 1
# How long the writer thread sleeps when it has nothing to do.
_IDLE_SLEEP_S = 0.005
# write() waits while this many items are queued (the disk cannot keep up).
_MAX_PENDING = 100_000
# RMW_DURATION_INFINITE as the ROS graph reports it for default QoS policies.
_INFINITE = {'sec': 9223372036, 'nsec': 854775807}
_QOS_KEYS = (
    'history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan',
    'liveliness', 'liveliness_lease_duration', 'avoid_ros_namespace_conventions',
)
# Policy names (version 9) indexed by their rmw enum value (version <= 8).
_QOS_POLICIES: dict[str, tuple[str, ...]] = {
    'history': ('system_default', 'keep_last', 'keep_all', 'unknown'),
    'reliability': ('system_default', 'reliable', 'best_effort', 'unknown', 'best_available'),
    'durability': ('system_default', 'transient_local', 'volatile', 'unknown',
                   'best_available'),
    'liveliness': ('system_default', 'automatic', 'manual_by_node', 'manual_by_topic',
                   'unknown', 'best_available'),
}
_COMPRESSIONS = {
    'zstd': (CompressionType.ZSTD, 'zstandard'),
    'lz4': (CompressionType.LZ4, 'lz4'),
    'none': (CompressionType.NONE, None),
}


class BagClosedError(RuntimeError):
    """Raised when using a :class:`BagWriter` that is closed or closing."""


@functools.lru_cache(maxsize=64)
def qos_profiles_yaml(*, reliability: str = 'reliable', durability: str = 'volatile',
                      history: str = 'keep_last', depth: int = 10) -> str:
    """Return an ``offered_qos_profiles`` YAML string holding one profile.

    Parameters
    ----------
    reliability : str
        ``reliable``, ``best_effort``, ``system_default`` or ``best_available``.
    durability : str
        ``volatile``, ``transient_local``, ``system_default`` or ``best_available``.
    history : str
        ``keep_last``, ``keep_all`` or ``system_default``.
    depth : int
        History depth.

    Returns
    -------
    str
        YAML list of one profile in the rosbag2 version-9 form, with
        deadline, lifespan and liveliness lease left infinite and liveliness
        automatic, as the ROS graph reports a default publisher.

    Raises
    ------
    ValueError
        If a policy name or the depth is invalid.
    """
    profile = {'history': history, 'depth': depth, 'reliability': reliability,
               'durability': durability}
    return _dump_qos(_parse_qos(yaml.safe_dump([profile])))


def _default_qos_profile() -> dict[str, Any]:
    return {
        'history': 'keep_last',
        'depth': 10,
        'reliability': 'reliable',
        'durability': 'volatile',
        'deadline': dict(_INFINITE),
        'lifespan': dict(_INFINITE),
        'liveliness': 'automatic',
        'liveliness_lease_duration': dict(_INFINITE),
        'avoid_ros_namespace_conventions': False,
    }


def _dump_qos(profiles: list[dict[str, Any]]) -> str:
    # a bag writes the same few profiles for every topic, and tuning writes many bags: dump each once
    return _dump_qos_cached(json.dumps(profiles))


@functools.lru_cache(maxsize=64)
def _dump_qos_cached(profiles_json: str) -> str:
    return yaml.safe_dump(json.loads(profiles_json), sort_keys=False, default_flow_style=False).rstrip('\n')


def _parse_qos(text: str) -> list[dict[str, Any]]:
    """:func:`_parse_qos_uncached`, remembered per text (a fresh copy each call)."""
    return copy.deepcopy(_parse_qos_cached(text))


def parse_qos_profiles(text: str) -> list[dict[str, Any]]:
    """Read an ``offered_qos_profiles`` YAML string (any rosbag2 format version).

    Parameters
    ----------
    text : str
        The string a bag records per topic; empty means the default profile.

    Returns
    -------
    list of dict
        One complete profile per offer (``history``, ``depth``,
        ``reliability``, ``durability``, ... as version-9 names).

    Raises
    ------
    ValueError
        Not valid YAML, an unknown key or an invalid policy.
    """
    return _parse_qos(text)


@functools.lru_cache(maxsize=64)
def _parse_qos_cached(text: str) -> list[dict[str, Any]]:
    return _parse_qos_uncached(text)


def _parse_qos_uncached(text: str) -> list[dict[str, Any]]:
    """Parse and complete an ``offered_qos_profiles`` YAML string.

    Keys missing from a profile take the default profile's values; policies
    given as rmw enum numbers (rosbag2 format <= 8) become names.
    """
    if not text.strip():
        return [_default_qos_profile()]
    try:
        loaded = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0] if str(exc) else 'syntax error'
        raise ValueError(f'offered QoS profiles are not valid YAML: {first}') from None
    if isinstance(loaded, dict):
        loaded = [loaded]
    if not isinstance(loaded, list) or not all(isinstance(p, dict) for p in loaded):
        raise ValueError('offered QoS profiles must be a YAML list of mappings')
    profiles = []
    for given in loaded:
        unknown = sorted(set(given) - set(_QOS_KEYS))
        if unknown:
            raise ValueError(f'unknown QoS profile key(s): {", ".join(map(str, unknown))}')
        profile = _default_qos_profile()
        profile.update(given)
        for policy, names in _QOS_POLICIES.items():
            value = profile[policy]
            if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < len(names):
                value = names[value]
            if not isinstance(value, str) or value.lower() not in names:
                raise ValueError(
                    f'invalid QoS {policy} {value!r}: expected one of {", ".join(names)}'
                )
            profile[policy] = value.lower()
        depth = profile['depth']
        if isinstance(depth, bool) or not isinstance(depth, int) or depth < 0:
            raise ValueError(f'invalid QoS depth {depth!r}: expected an integer >= 0')
        for key in ('deadline', 'lifespan', 'liveliness_lease_duration'):
            value = profile[key]
            if (not isinstance(value, dict) or set(value) != {'sec', 'nsec'}
                    or not all(isinstance(v, int) and v >= 0 for v in value.values())):
                raise ValueError(
                    f'invalid QoS {key} {value!r}: expected {{sec: int, nsec: int}}'
                )
            profile[key] = {'sec': value['sec'], 'nsec': value['nsec']}
        avoid = profile['avoid_ros_namespace_conventions']
        if avoid is not True and avoid is not False:
            raise ValueError('invalid QoS avoid_ros_namespace_conventions: expected true/false')
        profiles.append(profile)
    return profiles


#: The ``offered_qos_profiles`` used when :meth:`BagWriter.add_topic` gets none:
#: reliable, volatile, keep-last depth 10.
DEFAULT_QOS_PROFILES_YAML = _dump_qos([_default_qos_profile()])


def _library_string() -> str:
    try:
        own = importlib.metadata.version('attitude_sil')
    except importlib.metadata.PackageNotFoundError:
        own = 'dev'
    try:
        mcap_version = importlib.metadata.version('mcap')
    except importlib.metadata.PackageNotFoundError:
        mcap_version = 'unknown'
    return f'attitude_sil/{own} (attitude_sil.storage.writer; mcap-python/{mcap_version})'


def _timestamp(value: Any, what: str) -> int:
    try:
        stamp = operator.index(value)
    except TypeError:
        raise ValueError(f'{what} must be an integer number of nanoseconds, '
                         f'got {type(value).__name__}') from None
    if not 0 <= stamp <= _MAX_UINT64:
        raise ValueError(f'{what} {stamp} is outside 0..2**64-1 nanoseconds')
    return stamp


class _FileSink:
    """Unbuffered output file for the MCAP writer.

    mcap's writer keeps messages in memory until a chunk is complete and then
    writes it in a few calls; handing those straight to the OS means a
    process killed without closing the bag still leaves every completed chunk
    in the file.  (mcap would wrap a raw file object in a buffer, hence this
    small class.)
    """

    def __init__(self, path: Path) -> None:
        self._raw = io.FileIO(path, 'x')

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        total = len(view)
        while view:
            written = self._raw.write(view)
            view = view[written:]
        return total

    def tell(self) -> int:
        return self._raw.tell()

    def flush(self) -> None:
        """Nothing is buffered here."""

    def close(self) -> None:
        self._raw.close()


class _Command:
    """A request to the writer thread; the caller polls ``done``."""

    __slots__ = ('done', 'error', 'kind', 'topic')

    def __init__(self, kind: str, topic: _Topic | None = None) -> None:
        self.kind = kind
        self.topic = topic
        self.done = False
        self.error: BaseException | None = None


@dataclass(eq=False)
class _Topic:
    name: str
    type_name: str
    qos_profiles: list[dict[str, Any]]
    type_hash: str
    definition: str
    registration: _Command | None = None
    channel_id: int = 0  # set by the writer thread
    accepted: int = 0  # messages passed to write()
    written: int = 0  # messages written to the file


_OPEN_WRITERS: weakref.WeakSet[BagWriter] = weakref.WeakSet()


@atexit.register
def _close_open_writers() -> None:
    """Finish bags still open when the interpreter exits."""
    for writer in list(_OPEN_WRITERS):
        try:
            writer.close()
        except BagWriteError as exc:
            print(f'attitude_sil.bag: {exc}', file=sys.stderr)


def check_bag_dir(run_dir: str | os.PathLike[str]) -> None:
    """Refuse a bag directory :class:`BagWriter` could not create, without creating anything.

    Raises
    ------
    ValueError
        No usable name (``.``, ``..``, empty).
    FileExistsError
        It is a file, or it already holds a bag.
    NotADirectoryError
        A parent of it is a file.
    """
    run_dir = Path(run_dir)
    if not run_dir.name or run_dir.name in ('.', '..'):
        raise ValueError(f'invalid bag directory {str(run_dir)!r}')
    if run_dir.exists():
        if not run_dir.is_dir():
            raise FileExistsError(f"bag path '{run_dir}' exists and is not a directory")
        if ((run_dir / 'metadata.yaml').exists() or any(run_dir.glob('*.mcap'))
                or any(run_dir.glob('*.db3'))):
            raise FileExistsError(
                f"bag directory '{run_dir}' already contains a bag; "
                'choose another run name or remove it'
            )
        return
    parent = next((p for p in run_dir.parents if p.exists()), None)
    if parent is not None and not parent.is_dir():
        raise NotADirectoryError(f"bag directory '{run_dir}': '{parent}' is a file, not a directory")


class BagWriter:
    """Write CDR-serialized messages to a rosbag2 directory with MCAP storage.

    Parameters
    ----------
    run_dir : str or os.PathLike
        Bag directory to create, e.g. ``bags/<run>``; parents are created.
        It may already exist if it does not hold a bag.
    chunk_size : int
        Uncompressed size in bytes at which a chunk is closed and written.
    compression : str
        Chunk compression: ``'zstd'`` (default), ``'lz4'`` or ``'none'``.
        All three are read by rosbag2, Foxglove, mcap and rosbags.
    custom_data : Mapping[str, str], optional
        Written to ``custom_data`` of ``metadata.yaml``.

    Raises
    ------
    FileExistsError
        If ``run_dir`` already holds a bag or is not a directory.
    ValueError
        If ``chunk_size``, ``compression`` or ``custom_data`` is invalid.

    Notes
    -----
    All methods are thread-safe.  :meth:`write` only queues the message; a
    background thread writes it to the file within milliseconds, so errors
    of the file itself (disk full) surface as :class:`BagWriteError` from a
    later call or from :meth:`close`.  :meth:`close` is idempotent and may be
    called from any thread, from a signal handler or at exit; a message
    whose :meth:`write` is interrupted by the signal handler that closes the
    bag is not recorded.
    """

    def __init__(self, run_dir: str | os.PathLike[str], *, chunk_size: int = 1 << 20,
                 compression: str = 'zstd',
                 custom_data: Mapping[str, str] | None = None) -> None:
        run_dir = Path(run_dir)
        if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size <= 0:
            raise ValueError(f'chunk_size must be a positive integer, got {chunk_size!r}')
        if compression not in _COMPRESSIONS:
            raise ValueError(
                f"unknown compression {compression!r}: expected 'zstd', 'lz4' or 'none'"
            )
        compression_type, module = _COMPRESSIONS[compression]
        if module is not None and importlib.util.find_spec(module) is None:
            raise ValueError(
                f"compression {compression!r} needs the Python package '{module}', "
                'which is not installed'
            )
        custom = dict(custom_data or {})
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in custom.items()):
            raise ValueError('custom_data keys and values must be strings')
        check_bag_dir(run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)

        self._run_dir = run_dir
        self._path = run_dir / f'{run_dir.name}_0.mcap'
        self._custom_data = custom
        # Guards _closing, _topics and the queue against other threads; it is
        # re-entrant so that close() from a signal handler cannot deadlock.
        self._accept_lock = threading.RLock()
        self._pending: collections.deque[Any] = collections.deque()
        self._topics: dict[str, _Topic] = {}
        self._closing = False  # no more writes accepted
        self._stop = False  # tells the writer thread to finish the file
        self._finished = False  # the writer thread is done
        self._error: BaseException | None = None
        self._error_reported = False
        # Owned by the writer thread:
        self._schema_ids: dict[str, int] = {}
        self._written = 0
        self._start_ns = 0
        self._end_ns = 0

        try:
            self._sink = _FileSink(self._path)
        except FileExistsError:
            raise FileExistsError(
                f"bag file '{self._path}' already exists; choose another run name"
            ) from None
        try:
            self._mcap = McapWriter(self._sink, chunk_size=chunk_size,
                                    compression=compression_type)
            self._mcap.start(profile='ros2', library=_library_string())
        except BaseException:
            self._sink.close()
            self._path.unlink(missing_ok=True)
            raise
        self._thread = threading.Thread(
            target=self._run, name=f'BagWriter[{run_dir.name}]', daemon=True)
        self._thread.start()
        _OPEN_WRITERS.add(self)

    # ------------------------------------------------------------------ properties
    @property
    def run_dir(self) -> Path:
        """The bag directory."""
        return self._run_dir

    @property
    def path(self) -> Path:
        """The ``.mcap`` file being written."""
        return self._path

    @property
    def metadata_path(self) -> Path:
        """The ``metadata.yaml`` written by :meth:`close`."""
        return self._run_dir / 'metadata.yaml'

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` has been called."""
        return self._closing

    @property
    def message_counts(self) -> dict[str, int]:
        """Messages per registered topic: accepted so far, or written once closed."""
        with self._accept_lock:
            topics = list(self._topics.values())
        if self._finished:
            return {t.name: t.written for t in topics}
        return {t.name: t.accepted for t in topics}

    @property
    def message_count(self) -> int:
        """Messages on all topics: accepted so far, or written once closed."""
        return sum(self.message_counts.values())

    # --------------------------------------------------------------------- writing
    def add_topic(self, topic: str, type_name: str, qos_profiles_yaml: str = '', wait: bool = True) -> int | None:
        """Register a topic (its schema and channel); idempotent.

        Parameters
        ----------
        topic : str
            Topic name, e.g. ``/attitude``.
        type_name : str
            Message type, e.g. ``geometry_msgs/msg/Vector3Stamped``.
        qos_profiles_yaml : str
            ``offered_qos_profiles`` as YAML (a list of profiles, see
            :func:`qos_profiles_yaml`); missing keys are filled in. Empty
            means :data:`DEFAULT_QOS_PROFILES_YAML`.  Ignored when the topic
            is already registered.
        wait : bool
            Wait until the writer thread has registered the channel (False:
            return at once; messages written next still follow it).

        Returns
        -------
        int or None
            The MCAP channel id of the topic (None with ``wait=False``).

        Raises
        ------
        ValueError
            If the topic name or QoS is invalid, the type's definition cannot
            be found, or the topic was registered with another type.
        BagClosedError
            If the bag is closed.
        BagWriteError
            If writing the bag failed.
        """
        if not isinstance(topic, str) or not topic.startswith('/') or topic.strip() != topic:
            raise ValueError(f'invalid topic name {topic!r}: expected an absolute name like /foo')
        full_type = normalize_type_name(type_name)
        with self._accept_lock:
            self._check_open()
            entry = self._topics.get(topic)
            if entry is None:
                # Definitions are cached: holding the lock here is brief.
                entry = _Topic(topic, full_type, _parse_qos(qos_profiles_yaml),
                               type_description_hash(full_type),
                               message_definition(full_type))
                entry.registration = _Command('topic', entry)
                self._topics[topic] = entry
                self._pending.append(entry.registration)
            elif entry.type_name != full_type:
                raise ValueError(
                    f'topic {topic!r} is already recorded with type '
                    f'{entry.type_name!r}, not {full_type!r}'
                )
        assert entry.registration is not None
        if not wait:
            return None
        self._wait(entry.registration)
        return entry.channel_id

    def set_custom_data(self, key: str, value: str) -> None:
        """Set one ``custom_data`` entry of ``metadata.yaml`` (written at :meth:`close`).

        Raises
        ------
        ValueError
            If ``key`` or ``value`` is not a string.
        BagClosedError
            If the bag is closed.
        """
        if not isinstance(key, str) or not isinstance(value, str):
            raise ValueError('custom_data keys and values must be strings')
        with self._accept_lock:
            self._check_open()
            self._custom_data[key] = value

    def write(self, topic: str, data: bytes, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Queue one CDR-serialized message for writing.

        Parameters
        ----------
        topic : str
            A topic registered with :meth:`add_topic`.
        data : bytes
            The serialized message (bytes, bytearray or memoryview).
        log_time_ns : int
            Receive/log time in nanoseconds; rosbag2 plays back by this time.
        publish_time_ns : int, optional
            Publish time in nanoseconds; defaults to ``log_time_ns``.

        Raises
        ------
        ValueError
            If the topic is not registered or a time is invalid.
        TypeError
            If ``data`` is not bytes-like.
        BagClosedError
            If the bag is closed.
        BagWriteError
            If writing the bag failed.
        """
        log_time = _timestamp(log_time_ns, 'log time')
        publish_time = log_time if publish_time_ns is None else _timestamp(
            publish_time_ns, 'publish time')
        if not isinstance(data, bytes):
            if not isinstance(data, (bytearray, memoryview)):
                raise TypeError(f'message data must be bytes, got {type(data).__name__}')
            data = bytes(data)
        with self._accept_lock:
            self._check_open()
            entry = self._topics.get(topic)
            if entry is None:
                raise ValueError(f'topic {topic!r} was not registered with add_topic()')
            self._pending.append((entry, data, log_time, publish_time))
            entry.accepted += 1
        while len(self._pending) > _MAX_PENDING and not self._finished:
            time.sleep(0.001)

    def write_many(self, messages: list[tuple[str, bytes, int]]) -> None:
        """Queue many ``(topic, CDR bytes, log time ns)`` at once, in order (publish time = log time).

        The checks of :meth:`write`, under one lock: what a bag written from a
        computed episode (hundreds of thousands of messages) needs.

        Raises
        ------
        ValueError, TypeError, BagClosedError, BagWriteError
            As :meth:`write`; nothing of the batch is queued then.
        """
        items = []
        for topic, data, log_time_ns in messages:
            t = _timestamp(log_time_ns, 'log time')
            if not isinstance(data, bytes):
                raise TypeError(f'message data must be bytes, got {type(data).__name__}')
            items.append((topic, data, t))
        with self._accept_lock:
            self._check_open()
            topics = self._topics
            queued = []
            for topic, data, t in items:
                entry = topics.get(topic)
                if entry is None:
                    raise ValueError(f'topic {topic!r} was not registered with add_topic()')
                queued.append((entry, data, t, t))
            for entry, *_ in queued:
                entry.accepted += 1
            self._pending.extend(queued)
        while len(self._pending) > _MAX_PENDING and not self._finished:
            time.sleep(0.001)

    def flush(self) -> None:
        """Write everything queued, the open chunk and a provisional ``metadata.yaml``.

        Useful now and then in long runs: a process killed without
        :meth:`close` then leaves all messages up to the flush in complete
        chunks, which readers that scan an MCAP file without its summary
        (``mcap.stream_reader.StreamReader``, ``mcap recover``) can read.

        Raises
        ------
        BagClosedError
            If the bag is closed.
        BagWriteError
            If writing the bag failed.
        """
        command = _Command('flush')
        with self._accept_lock:
            self._check_open()
            self._pending.append(command)
        self._wait(command)

    def close(self) -> None:
        """Write what is queued, finish the MCAP file and write ``metadata.yaml``.

        Idempotent; safe from any thread, a signal handler or an ``atexit``
        handler.

        Raises
        ------
        BagWriteError
            If writing the bag failed (reported once).
        """
        with self._accept_lock:
            self._closing = True
        self._stop = True
        if threading.current_thread() is not self._thread:
            self._thread.join()
        _OPEN_WRITERS.discard(self)
        if self._error is not None and not self._error_reported:
            self._error_reported = True
            raise self._write_error()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def __repr__(self) -> str:
        state = 'closed' if self._closing else 'open'
        return f'<BagWriter {str(self._path)!r} {state}, {self.message_count} messages>'

    # ------------------------------------------------------------ caller helpers
    def _check_open(self) -> None:
        if self._closing:
            raise BagClosedError(f"bag '{self._path}' is closed")
        if self._error is not None:
            raise self._write_error()

    def _write_error(self) -> BagWriteError:
        return BagWriteError(f"writing bag '{self._path}' failed: {self._error}")

    def _wait(self, command: _Command) -> None:
        # Polling a flag (rather than waiting on an Event) keeps the caller
        # free of locks the writer thread needs, even if a signal handler
        # that closes the bag interrupts this wait.
        while not command.done:
            if self._finished and not command.done:
                raise BagClosedError(f"bag '{self._path}' is closed")
            time.sleep(0.001)
        if command.error is not None:
            raise BagWriteError(f"writing bag '{self._path}' failed: {command.error}")

    # ------------------------------------------------------------- writer thread
    def _run(self) -> None:
        try:
            while True:
                stopping = self._stop
                busy = self._drain()
                if stopping:
                    break
                if not busy:
                    time.sleep(_IDLE_SLEEP_S)
        except Exception as exc:  # noqa: BLE001 - reported by the caller's next call
            self._error = exc
        finally:
            self._finish()

    def _drain(self) -> bool:
        pending = self._pending
        busy = False
        while pending:
            item = pending.popleft()
            busy = True
            if isinstance(item, _Command):
                try:
                    self._execute(item)
                except Exception as exc:
                    item.error = exc
                    raise
                finally:
                    item.done = True
                continue
            entry, data, log_time, publish_time = item
            entry.written += 1
            self._mcap.add_message(
                channel_id=entry.channel_id,
                log_time=log_time,
                data=data,
                publish_time=publish_time,
                sequence=entry.written & 0xFFFFFFFF,
            )
            if self._written == 0:
                self._start_ns = self._end_ns = log_time
            elif log_time < self._start_ns:
                self._start_ns = log_time
            elif log_time > self._end_ns:
                self._end_ns = log_time
            self._written += 1
        return busy

    def _execute(self, command: _Command) -> None:
        if command.kind == 'topic':
            entry = command.topic
            assert entry is not None
            schema_id = self._schema_ids.get(entry.type_name)
            if schema_id is None:
                schema_id = self._mcap.register_schema(
                    name=entry.type_name, encoding=SCHEMA_ENCODING,
                    data=entry.definition.encode('utf-8'))
                self._schema_ids[entry.type_name] = schema_id
            entry.channel_id = self._mcap.register_channel(
                topic=entry.name,
                message_encoding=SERIALIZATION_FORMAT,
                schema_id=schema_id,
                metadata={'offered_qos_profiles': _dump_qos(entry.qos_profiles),
                          'topic_type_hash': entry.type_hash},
            )
        elif command.kind == 'flush':
            self._mcap.flush()
            self._write_metadata_file()
        else:  # pragma: no cover - internal misuse
            raise AssertionError(f'unknown command {command.kind!r}')

    def _finish(self) -> None:
        """Finish the file, even after an error, so the chunks written stay readable."""
        try:
            try:
                self._mcap.add_metadata(
                    'rosbag2', {'serialized_metadata': self._dump_yaml(self._bag_info())})
                self._mcap.finish()
            finally:
                self._sink.close()
        except Exception as exc:  # noqa: BLE001 - reported by close()
            self._error = self._error or exc
        try:
            self._write_metadata_file()
        except Exception as exc:  # noqa: BLE001 - reported by close()
            self._error = self._error or exc
        self._closing = True
        for item in list(self._pending):
            if isinstance(item, _Command):
                item.error = item.error or BagClosedError(f"bag '{self._path}' is closed")
                item.done = True
        self._finished = True

    def _bag_info(self) -> dict[str, Any]:
        """The ``rosbag2_bagfile_information`` mapping (format version 9)."""
        count = self._written
        start = self._start_ns if count else 0
        duration = self._end_ns - self._start_ns if count else 0
        file_name = self._path.name
        topics = [t for t in list(self._topics.values()) if t.channel_id]
        return {
            'version': ROSBAG2_FORMAT_VERSION,
            'storage_identifier': STORAGE_IDENTIFIER,
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': count,
            'topics_with_message_count': [
                {
                    'topic_metadata': {
                        'name': t.name,
                        'type': t.type_name,
                        'serialization_format': SERIALIZATION_FORMAT,
                        'offered_qos_profiles': t.qos_profiles,
                        'type_description_hash': t.type_hash,
                    },
                    'message_count': t.written,
                }
                for t in topics
            ],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [file_name],
            'files': [{
                'path': file_name,
                'starting_time': {'nanoseconds_since_epoch': start},
                'duration': {'nanoseconds': duration},
                'message_count': count,
            }],
            'custom_data': dict(self._custom_data),
            'ros_distro': ROS_DISTRO,
        }

    @staticmethod
    def _dump_yaml(data: Any) -> str:
        return yaml.safe_dump(data, sort_keys=False, default_flow_style=False)

    def _write_metadata_file(self) -> None:
        text = self._dump_yaml({'rosbag2_bagfile_information': self._bag_info()})
        tmp = self.metadata_path.with_name('metadata.yaml.tmp')
        try:
            tmp.write_text(text, encoding='utf-8')
            os.replace(tmp, self.metadata_path)
        except OSError:
            tmp.unlink(missing_ok=True)  # a full disk: no half-written .tmp left beside the bag
            raise
