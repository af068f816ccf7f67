"""Tests of attitude_sil.bag: rosbag2/MCAP bags readable by independent readers.

Messages are serialized with rclpy, written with BagWriter, and read back with
mcap + mcap-ros2-support's decoder and with rosbags (which also checks the
recorded RIHS01 type hashes against the stored definitions and matches the
QoS of metadata.yaml against the channel metadata).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
from pathlib import Path
from typing import Any

import pytest
import yaml
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Vector3Stamped
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from rcl_interfaces.msg import Parameter, ParameterEvent, ParameterType, ParameterValue
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from attitude_sil.storage import (
    BagClosedError,
    BagWriter,
    message_definition,
    qos_profiles_yaml,
    type_description_hash,
)

REPO = Path(__file__).resolve().parents[2]
SHARE = Path(sys.prefix) / 'share'

TOPIC_TYPES = {
    '/attitude/omega': 'geometry_msgs/msg/Vector3Stamped',
    '/wheels/joint_states': 'sensor_msgs/msg/JointState',
    '/clock': 'rosgraph_msgs/msg/Clock',
    '/parameter_events': 'rcl_interfaces/msg/ParameterEvent',
}
T0 = 1_700_000_000_000_000_000


def _msg_text(pkg: str, name: str) -> str:
    return (SHARE / pkg / 'msg' / f'{name}.msg').read_text()


# ----------------------------------------------------------------- messages
def _vector(i: int) -> Vector3Stamped:
    m = Vector3Stamped()
    m.header.stamp = Time(sec=100 + i, nanosec=1000 * i + 7)
    m.header.frame_id = f'body_{i}'
    m.vector.x, m.vector.y, m.vector.z = 1.5 * i, -float(i), i * i + 0.25
    return m


def _joints(i: int) -> JointState:
    m = JointState()
    m.header.stamp = Time(sec=200 + i, nanosec=i)
    m.header.frame_id = 'wheels'
    m.name = ['wheel_x', 'wheel_y', f'wheel_z{i}']
    m.position = [0.1 * i, 0.2 * i, 0.3 * i]
    m.velocity = [10.0 + i, -20.0 - i, 30.5]
    # Not empty: for an empty float64[] rclpy's CDR buffer ends with padding
    # that rosbags' deserializer rejects (mcap-ros2-support accepts it).
    m.effort = [0.5 * i]
    return m


def _clock(i: int) -> Clock:
    return Clock(clock=Time(sec=i, nanosec=500_000_000 + i))


def _param_event(i: int) -> ParameterEvent:
    m = ParameterEvent()
    m.stamp = Time(sec=300 + i, nanosec=3)
    m.node = '/attitude_controller'
    m.changed_parameters = [Parameter(
        name='kp', value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                        double_value=0.75 + i))]
    m.new_parameters = [Parameter(
        name='axes', value=ParameterValue(type=ParameterType.PARAMETER_STRING_ARRAY,
                                          string_array_value=['x', 'y', f'z{i}'])),
        Parameter(name='gains', value=ParameterValue(
            type=ParameterType.PARAMETER_INTEGER_ARRAY, integer_array_value=[1, -2, 3 + i]))]
    return m


MAKERS = {
    '/attitude/omega': _vector,
    '/wheels/joint_states': _joints,
    '/clock': _clock,
    '/parameter_events': _param_event,
}
COUNTS = {'/attitude/omega': 7, '/wheels/joint_states': 5, '/clock': 11,
          '/parameter_events': 2}


def _log_time(topic: str, i: int) -> int:
    # Interleaved and not monotonic across topics; /clock has the earliest
    # and /parameter_events the latest stamp.
    offset = {'/attitude/omega': 3, '/wheels/joint_states': 5, '/clock': 0,
              '/parameter_events': 900}[topic]
    return T0 + (offset + 10 * i) * 1_000_000


def _fields(topic: str, m: Any) -> tuple:
    """Comparable field values of a message from any of the three libraries."""
    if topic == '/attitude/omega':
        return (m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id,
                m.vector.x, m.vector.y, m.vector.z)
    if topic == '/wheels/joint_states':
        return (m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id,
                list(m.name), [float(v) for v in m.position],
                [float(v) for v in m.velocity], [float(v) for v in m.effort])
    if topic == '/clock':
        return (m.clock.sec, m.clock.nanosec)

    def param(p: Any) -> tuple:
        v = p.value
        return (p.name, v.type, v.double_value, list(v.string_array_value),
                [int(x) for x in v.integer_array_value])
    return (m.stamp.sec, m.stamp.nanosec, m.node,
            [param(p) for p in m.new_parameters],
            [param(p) for p in m.changed_parameters],
            [param(p) for p in m.deleted_parameters])


def _expected() -> dict[str, list[tuple[int, tuple]]]:
    return {topic: [(_log_time(topic, i), _fields(topic, MAKERS[topic](i)))
                    for i in range(n)] for topic, n in COUNTS.items()}


WRITTEN: dict[tuple[str, int], bytes] = {}


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> BagWriter:
    run_dir = tmp_path_factory.mktemp('bags') / 'run_roundtrip'
    writer = BagWriter(run_dir, chunk_size=512, custom_data={'scenario': 'detumble'})
    channel_ids = {topic: writer.add_topic(topic, type_name)
                   for topic, type_name in TOPIC_TYPES.items()}
    assert len(set(channel_ids.values())) == len(channel_ids)
    # Interleave the topics while writing.
    for i in range(max(COUNTS.values())):
        for topic, n in COUNTS.items():
            if i < n:
                # Kept: alignment padding in rclpy's buffers is not initialised,
                # so serializing again need not give the same bytes.
                WRITTEN[topic, i] = serialize_message(MAKERS[topic](i))
                writer.write(topic, WRITTEN[topic, i],
                             _log_time(topic, i), publish_time_ns=_log_time(topic, i) - 1)
    assert writer.message_counts == COUNTS
    writer.close()
    writer.close()  # idempotent
    return writer


# ------------------------------------------------------------ message definitions
def test_message_definition_matches_rosbag2_layout() -> None:
    sep = '\n' + '=' * 80 + '\n'
    expected = (
        _msg_text('geometry_msgs', 'Vector3Stamped')
        + sep + 'MSG: geometry_msgs/Vector3\n' + _msg_text('geometry_msgs', 'Vector3')
        + sep + 'MSG: std_msgs/Header\n' + _msg_text('std_msgs', 'Header')
        + sep + 'MSG: builtin_interfaces/Time\n' + _msg_text('builtin_interfaces', 'Time')
    )
    text = message_definition('geometry_msgs/msg/Vector3Stamped')
    assert text == expected
    assert message_definition('geometry_msgs/Vector3Stamped') == expected
    for line in ('MSG: std_msgs/Header', 'MSG: geometry_msgs/Vector3',
                 'MSG: builtin_interfaces/Time'):
        assert text.count(line + '\n') == 1
    assert '/msg/' not in ''.join(x for x in text.splitlines() if x.startswith('MSG:'))


def test_message_definition_nested_and_package_relative_types() -> None:
    text = message_definition('rcl_interfaces/msg/ParameterEvent')
    msg_lines = [x for x in text.splitlines() if x.startswith('MSG: ')]
    # Parameter and ParameterValue are referenced without their package.
    assert msg_lines == ['MSG: builtin_interfaces/Time', 'MSG: rcl_interfaces/Parameter',
                         'MSG: rcl_interfaces/ParameterValue']
    assert 'string[] string_array_value' in text
    # Bounded arrays and constants are no dependencies; unbounded arrays of
    # messages are.
    solid = message_definition('shape_msgs/msg/SolidPrimitive')
    assert [x for x in solid.splitlines() if x.startswith('MSG: ')] == [
        'MSG: geometry_msgs/Polygon', 'MSG: geometry_msgs/Point32']
    assert 'float64[<=3] dimensions' in solid
    # A type reached along two paths (Marker -> Point, Marker -> Pose ->
    # Point) is written once, at its first place in the depth-first walk.
    marker = message_definition('visualization_msgs/msg/Marker')
    marker_lines = [x for x in marker.splitlines() if x.startswith('MSG: ')]
    assert len(marker_lines) == len(set(marker_lines))
    assert marker_lines.index('MSG: geometry_msgs/Point') < marker_lines.index(
        'MSG: geometry_msgs/Pose') < marker_lines.index('MSG: geometry_msgs/Quaternion')
    assert marker.count('=' * 80) == len(marker_lines)
    # Bounded strings are primitives.
    node_info = message_definition('rmw_dds_common/msg/NodeEntitiesInfo')
    assert 'MSG: rmw_dds_common/Gid' in node_info
    assert 'string<=256' in node_info and 'MSG: rmw_dds_common/string' not in node_info


@pytest.mark.parametrize('type_name', [*TOPIC_TYPES.values(), 'shape_msgs/msg/SolidPrimitive',
                                       'rcl_interfaces/msg/ParameterDescriptor',
                                       'visualization_msgs/msg/Marker'])
def test_message_definition_parsed_by_mcap_ros2(type_name: str) -> None:
    from mcap_ros2._dynamic import generate_dynamic

    decoders = generate_dynamic(type_name, message_definition(type_name))
    assert type_name in decoders


def test_message_definition_errors_name_the_type() -> None:
    with pytest.raises(ValueError, match="'nonexistent_msgs/msg/Thing'"):
        message_definition('nonexistent_msgs/msg/Thing')
    with pytest.raises(ValueError, match="'geometry_msgs/msg/NoSuchType'"):
        message_definition('geometry_msgs/msg/NoSuchType')
    with pytest.raises(ValueError, match='invalid message type name'):
        message_definition('not a type')


def test_type_description_hash_from_rosidl() -> None:
    digest = type_description_hash('geometry_msgs/msg/Vector3Stamped')
    assert digest.startswith('RIHS01_') and len(digest) == 7 + 64
    assert digest != type_description_hash('sensor_msgs/msg/JointState')
    assert type_description_hash('nonexistent_msgs/msg/Thing') == ''


# ------------------------------------------------------------------- readers
def test_read_back_with_mcap_ros2(bag: BagWriter) -> None:
    assert bag.path == bag.run_dir / 'run_roundtrip_0.mcap'
    got: dict[str, list[tuple[int, tuple]]] = {t: [] for t in COUNTS}
    with bag.path.open('rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == 'ros2'
        assert 'attitude_sil' in header.library
        summary = reader.get_summary()
        assert summary.statistics.message_count == sum(COUNTS.values())
        assert summary.statistics.chunk_count > 1  # chunk_size=512 forced several
        assert {summary.channels[c].topic: n for c, n in
                summary.statistics.channel_message_counts.items()} == COUNTS
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            assert channel.message_encoding == 'cdr'
            assert schema.encoding == 'ros2msg'
            assert schema.name == TOPIC_TYPES[channel.topic]
            assert schema.data.decode() == message_definition(schema.name)
            qos = yaml.safe_load(channel.metadata['offered_qos_profiles'])
            assert qos[0]['reliability'] == 'reliable'
            assert qos[0]['durability'] == 'volatile'
            assert (qos[0]['history'], qos[0]['depth']) == ('keep_last', 10)
            assert channel.metadata['topic_type_hash'] == type_description_hash(schema.name)
        raw_by_time = {}
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert schema.name == TOPIC_TYPES[channel.topic]
            assert message.publish_time == message.log_time - 1
            got[channel.topic].append((message.log_time, _fields(channel.topic, decoded)))
            raw_by_time[channel.topic, message.log_time] = (message.data, message.sequence)
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    assert got == _expected()
    # The CDR bytes are stored verbatim, sequence numbers count per channel.
    for topic, n in COUNTS.items():
        for i in range(n):
            assert raw_by_time[topic, _log_time(topic, i)] == (WRITTEN[topic, i], i + 1)
    # rosbag2 reads the bag's format version back from this record.
    serialized = yaml.safe_load(records['rosbag2']['serialized_metadata'])
    on_disk = yaml.safe_load(bag.metadata_path.read_text())['rosbag2_bagfile_information']
    assert serialized == on_disk


def test_read_back_with_rosbags(bag: BagWriter) -> None:
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import QosDurability, QosReliability

    got: dict[str, list[tuple[int, tuple]]] = {t: [] for t in COUNTS}
    # AnyReader builds its types from the bag's own definitions and refuses
    # the bag if a type_description_hash does not match them.
    with AnyReader([bag.run_dir]) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == TOPIC_TYPES
        assert {c.topic: c.msgcount for c in reader.connections} == COUNTS
        for connection in reader.connections:
            assert connection.digest == type_description_hash(connection.msgtype)
            (qos,) = connection.ext.offered_qos_profiles
            assert qos.reliability == QosReliability.RELIABLE
            assert qos.durability == QosDurability.VOLATILE
            assert qos.depth == 10
        assert reader.message_count == sum(COUNTS.values())
        for connection, timestamp, raw in reader.messages():
            decoded = _rosbags_decode(reader.typestore, raw, connection.msgtype)
            got[connection.topic].append((timestamp, _fields(connection.topic, decoded)))
    assert got == _expected()


def _rosbags_decode(typestore: Any, raw: bytes, msgtype: str) -> object:
    """rosbags' CDR decoding without its end-of-buffer check.

    For messages with empty int64/float64 sequences (every ParameterValue),
    rclpy's serialized buffer is a few bytes longer than the encoded data and
    ``AnyReader.deserialize`` refuses it ("CDR message size mismatch"); the
    bytes themselves are fine, as mcap-ros2-support and rclpy show.
    """
    assert raw[:4] == b'\x00\x01\x00\x00'  # CDR little endian
    msgdef = typestore.get_msgdef(msgtype)
    message, end = msgdef.deserialize_cdr_le(raw[4:], 0, msgdef.cls, typestore)
    assert end <= len(raw) - 4
    return message


def test_metadata_yaml(bag: BagWriter) -> None:
    info = yaml.safe_load(bag.metadata_path.read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9
    assert info['storage_identifier'] == 'mcap'
    assert info['ros_distro'] == 'jazzy'
    assert info['relative_file_paths'] == ['run_roundtrip_0.mcap']
    assert (info['compression_format'], info['compression_mode']) == ('', '')
    assert info['custom_data'] == {'scenario': 'detumble'}
    times = [t for entries in _expected().values() for t, _ in entries]
    start, duration = min(times), max(times) - min(times)
    assert start == _log_time('/clock', 0)
    assert info['starting_time'] == {'nanoseconds_since_epoch': start}
    assert info['duration'] == {'nanoseconds': duration}
    assert info['message_count'] == sum(COUNTS.values())
    assert info['files'] == [{
        'path': 'run_roundtrip_0.mcap',
        'starting_time': {'nanoseconds_since_epoch': start},
        'duration': {'nanoseconds': duration},
        'message_count': sum(COUNTS.values()),
    }]
    topics = info['topics_with_message_count']
    assert [t['topic_metadata']['name'] for t in topics] == list(TOPIC_TYPES)
    for entry in topics:
        meta = entry['topic_metadata']
        assert entry['message_count'] == COUNTS[meta['name']]
        assert meta['type'] == TOPIC_TYPES[meta['name']]
        assert meta['serialization_format'] == 'cdr'
        assert meta['type_description_hash'] == type_description_hash(meta['type'])
        (qos,) = meta['offered_qos_profiles']  # a YAML list in version 9
        assert (qos['reliability'], qos['durability']) == ('reliable', 'volatile')
        assert qos['deadline'] == {'sec': 9223372036, 'nsec': 854775807}
        assert qos['avoid_ros_namespace_conventions'] is False


@pytest.mark.parametrize('compression', ['lz4', 'none'])
def test_other_compressions_are_readable(tmp_path: Path, compression: str) -> None:
    from rosbags.highlevel import AnyReader

    with BagWriter(tmp_path / 'run', compression=compression) as writer:
        writer.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
        for i in range(3):
            writer.write('/clock', serialize_message(_clock(i)), T0 + i)
    with writer.path.open('rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert [d.clock.sec for *_, d in reader.iter_decoded_messages()] == [0, 1, 2]
    with AnyReader([writer.run_dir]) as reader:
        assert [reader.deserialize(raw, c.msgtype).clock.nanosec
                for c, _, raw in reader.messages()] == [500_000_000, 500_000_001, 500_000_002]


def test_custom_qos_profile_is_recorded(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import QosDurability, QosReliability

    qos = qos_profiles_yaml(reliability='best_effort', durability='transient_local', depth=1)
    with BagWriter(tmp_path / 'run') as writer:
        writer.add_topic('/tf_static', 'geometry_msgs/msg/Vector3Stamped', qos)
        writer.write('/tf_static', serialize_message(_vector(1)), T0)
    info = yaml.safe_load(writer.metadata_path.read_text())['rosbag2_bagfile_information']
    (profile,) = info['topics_with_message_count'][0]['topic_metadata']['offered_qos_profiles']
    assert (profile['reliability'], profile['durability'], profile['depth']) == (
        'best_effort', 'transient_local', 1)
    with AnyReader([writer.run_dir]) as reader:
        (connection,) = reader.connections
        (parsed,) = connection.ext.offered_qos_profiles
        assert parsed.reliability == QosReliability.BEST_EFFORT
        assert parsed.durability == QosDurability.TRANSIENT_LOCAL
        # Channel QoS and metadata.yaml QoS agree, or rosbags yields nothing.
        assert len(list(reader.messages())) == 1


# --------------------------------------------------------- threads and signals
def test_writes_from_two_threads_and_close_from_a_third(tmp_path: Path) -> None:
    writer = BagWriter(tmp_path / 'run', chunk_size=2048)
    writer.add_topic('/a', 'rosgraph_msgs/msg/Clock')
    writer.add_topic('/b', 'rosgraph_msgs/msg/Clock')
    n = 2000
    barrier = threading.Barrier(2)

    def produce(topic: str, base: int) -> None:
        barrier.wait()
        for i in range(n):
            writer.write(topic, serialize_message(Clock(clock=Time(sec=base + i))), T0 + i)

    threads = [threading.Thread(target=produce, args=('/a', 0)),
               threading.Thread(target=produce, args=('/b', 100_000))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    closer = threading.Thread(target=writer.close)
    closer.start()
    closer.join()
    assert writer.message_counts == {'/a': n, '/b': n}
    seen: dict[str, list[int]] = {'/a': [], '/b': []}
    with writer.path.open('rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, decoded in reader.iter_decoded_messages(log_time_order=False):
            seen[channel.topic].append(decoded.clock.sec)
    # Every message once, and each thread's messages in the order written.
    assert seen == {'/a': list(range(n)), '/b': list(range(100_000, 100_000 + n))}
    info = yaml.safe_load(writer.metadata_path.read_text())['rosbag2_bagfile_information']
    assert info['message_count'] == 2 * n


_CHILD = textwrap.dedent('''
    import faulthandler, signal, sys
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # a hung child shows where it hangs
    from builtin_interfaces.msg import Time
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    from attitude_sil.storage import BagWriter

    writer = BagWriter(sys.argv[1], chunk_size=4096)
    writer.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
    blobs = [serialize_message(Clock(clock=Time(sec=i))) for i in range(1000)]
    written = 0
    try:
        if sys.argv[2] == 'kill':
            for i in range(50):
                writer.write('/clock', blobs[i], 10**9 + i)
            writer.flush()
            for i in range(50, 53):  # still in the open chunk: lost
                writer.write('/clock', blobs[i], 10**9 + i)
            import os, signal
            os.kill(os.getpid(), signal.SIGKILL)
        for written in range(1000):  # something to keep before the signal can come
            writer.write('/clock', blobs[written], 10**9 + written)
        written += 1
        print('ready', flush=True)
        while True:  # as fast as possible, so the signal lands inside write()
            writer.write('/clock', blobs[written % 1000], 10**9 + written)
            written += 1
    except KeyboardInterrupt:
        pass
    finally:
        writer.close()
        print(writer.message_counts['/clock'], flush=True)
''')


def _default_sigint() -> None:
    # the child must not inherit an ignored or blocked SIGINT from whatever ran in this process
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _run_child(run_dir: Path, mode: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(REPO), *filter(None, [os.environ.get('PYTHONPATH')])]))
    return subprocess.Popen([sys.executable, '-c', _CHILD, str(run_dir), mode],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=_default_sigint)


def _communicate(child: subprocess.Popen, timeout: float = 60.0) -> tuple[str, str]:
    try:
        return child.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        child.send_signal(signal.SIGUSR1)  # faulthandler: every thread's stack on stderr
        child.kill()
        out, err = child.communicate()
        raise AssertionError(f'the writer child did not finish within {timeout:g} s; its stacks:\n{err}') from None


def test_ctrl_c_leaves_a_readable_bag(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader

    run_dir = tmp_path / 'interrupted'
    child = _run_child(run_dir, 'sigint')
    try:
        assert child.stdout.readline().strip() == 'ready', child.stderr.read()
        child.send_signal(signal.SIGINT)  # 1000 messages are in; the writing loop runs
        out, err = _communicate(child)
    finally:
        child.kill()
    assert child.returncode == 0, err
    recorded = int(out.strip())
    assert recorded >= 1000
    with (run_dir / 'interrupted_0.mcap').open('rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_summary().statistics.message_count == recorded
        secs = [d.clock.sec for *_, d in reader.iter_decoded_messages()]
    assert secs == [i % 1000 for i in range(recorded)]
    with AnyReader([run_dir]) as reader:
        assert sum(1 for _ in reader.messages()) == recorded
    info = yaml.safe_load((run_dir / 'metadata.yaml').read_text())
    assert info['rosbag2_bagfile_information']['message_count'] == recorded


def test_killed_writer_keeps_flushed_chunks(tmp_path: Path) -> None:
    run_dir = tmp_path / 'killed'
    child = _run_child(run_dir, 'kill')
    _, err = _communicate(child)
    assert child.returncode == -signal.SIGKILL, err
    # No summary or footer: scan the records as far as the file goes.
    schemas, channels, secs = {}, {}, []
    factory = DecoderFactory()
    with (run_dir / 'killed_0.mcap').open('rb') as f:
        records = StreamReader(f).records
        with pytest.raises(EndOfFile):
            for record in records:
                kind = type(record).__name__
                if kind == 'Schema':
                    schemas[record.id] = record
                elif kind == 'Channel':
                    channels[record.id] = record
                elif kind == 'Message':
                    schema = schemas[channels[record.channel_id].schema_id]
                    secs.append(factory.decoder_for('cdr', schema)(record.data).clock.sec)
    assert secs == list(range(50))
    info = yaml.safe_load((run_dir / 'metadata.yaml').read_text())  # provisional
    assert info['rosbag2_bagfile_information']['message_count'] == 50


# ------------------------------------------------------------------- errors
def test_errors(tmp_path: Path) -> None:
    run_dir = tmp_path / 'run'
    writer = BagWriter(run_dir)
    clock_id = writer.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
    assert writer.add_topic('/clock', 'rosgraph_msgs/Clock') == clock_id
    with pytest.raises(ValueError, match="already recorded with type 'rosgraph_msgs/msg/Clock'"):
        writer.add_topic('/clock', 'std_msgs/msg/String')
    with pytest.raises(ValueError, match="'nonexistent_msgs/msg/Thing'"):
        writer.add_topic('/x', 'nonexistent_msgs/msg/Thing')
    with pytest.raises(ValueError, match='invalid topic name'):
        writer.add_topic('clock', 'rosgraph_msgs/msg/Clock')
    with pytest.raises(ValueError, match='invalid QoS reliability'):
        writer.add_topic('/y', 'rosgraph_msgs/msg/Clock', '- reliability: sometimes')
    with pytest.raises(ValueError, match="'/unregistered' was not registered"):
        writer.write('/unregistered', b'\x00\x01\x00\x00', T0)
    with pytest.raises(ValueError, match='log time'):
        writer.write('/clock', serialize_message(_clock(0)), -1)
    with pytest.raises(TypeError, match='bytes'):
        writer.write('/clock', 'not bytes', T0)  # type: ignore[arg-type]
    writer.write('/clock', serialize_message(_clock(0)), T0)
    writer.close()
    with pytest.raises(BagClosedError):
        writer.write('/clock', serialize_message(_clock(1)), T0 + 1)
    assert writer.message_counts == {'/clock': 1}
    # The directory now holds a bag: a second writer must not touch it.
    with pytest.raises(FileExistsError, match='already contains a bag'):
        BagWriter(run_dir)
    with pytest.raises(ValueError, match="unknown compression 'gzip'"):
        BagWriter(tmp_path / 'other', compression='gzip')
    assert not (tmp_path / 'other').exists()


def test_a_failed_metadata_write_leaves_no_tmp_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # the disk fills while metadata.yaml is replaced: the close reports it, and no metadata.yaml.tmp is left
    from attitude_sil.storage import writer as writer_module

    run_dir = tmp_path / 'full'
    writer = BagWriter(run_dir)
    writer.add_topic('/clock', 'rosgraph_msgs/msg/Clock')

    def no_space(src, dst):
        raise OSError(28, 'No space left on device')

    monkeypatch.setattr(writer_module.os, 'replace', no_space)
    with pytest.raises(Exception, match='No space left on device'):
        writer.close()
    assert (run_dir / 'metadata.yaml.tmp').exists() is False
    assert (run_dir / 'full_0.mcap').is_file()
