"""Tests of attitude_sil.storage.reader, attitude_sil.storage.info and attitude_sil.tools.plot.

Bags are built here with BagWriter from messages serialized by rclpy (no ROS
graph): a 2 s run at 100 Hz with every topic of a voltage-commanded run and
a controller swap from pid to fuzzy_pid at 1.2 s, written in small chunks so
that truncated copies still hold complete ones.
"""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from mcap.reader import make_reader
from rcl_interfaces.msg import Parameter, ParameterEvent, ParameterType, ParameterValue
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from attitude_sil.storage import BagWriter
from attitude_sil.storage.info import format_info, format_size
from attitude_sil.storage.reader import BagError, RawMessage, open_bag
from attitude_sil.tools.plot import controller_swaps, initial_controller, plot_bag

STEPS = 200
DT_NS = 10_000_000  # 100 Hz
T_START_NS = 1_000_000_000  # sim time of the first step: 1 s
SWAP_STEP = 120  # at sim time 2.2 s
VECTOR_TOPICS = ('body_rate', 'attitude_error', 'voltage_cmd', 'disturbance_torque')
TYPES = {
    'clock': 'rosgraph_msgs/msg/Clock',
    'attitude': 'geometry_msgs/msg/QuaternionStamped',
    'attitude_setpoint': 'geometry_msgs/msg/QuaternionStamped',
    'body_rate': 'geometry_msgs/msg/Vector3Stamped',
    'attitude_error': 'geometry_msgs/msg/Vector3Stamped',
    'voltage_cmd': 'geometry_msgs/msg/Vector3Stamped',
    'disturbance_torque': 'geometry_msgs/msg/Vector3Stamped',
    'wheel_state': 'sensor_msgs/msg/JointState',
    'flexible_mode': 'geometry_msgs/msg/Vector3Stamped',
    'parameter_events': 'rcl_interfaces/msg/ParameterEvent',
}
FULL = ('clock', 'attitude', 'attitude_setpoint', *VECTOR_TOPICS, 'wheel_state', 'parameter_events')
FULL_PANELS = 6  # attitude, error, rates, command, wheels, disturbance


def _time(t_ns: int) -> Time:
    return Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9)


def _roll(i: int) -> float:
    return 0.002 * i  # rad


def _vector_values(name: str, i: int) -> tuple[float, float, float]:
    k = VECTOR_TOPICS.index(name) if name in VECTOR_TOPICS else 9
    return (0.5 * k + 0.01 * i, -0.25 * i, k * 1e-3)


def _string_param(name: str, value: str) -> Parameter:
    return Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_STRING,
                                                     string_value=value))


def _event(t_ns: int, node: str, *, new: list | None = None, changed: list | None = None) -> ParameterEvent:
    return ParameterEvent(stamp=_time(t_ns), node=node, new_parameters=new or [],
                          changed_parameters=changed or [])


def _messages(i: int, topics: tuple[str, ...], ns: str) -> list[tuple[str, object]]:
    """(short topic, message) of step i, all stamped with the step's sim time."""
    t = T_START_NS + i * DT_NS
    out: list[tuple[str, object]] = []
    for name in topics:
        if name == 'clock':
            out.append((name, Clock(clock=_time(t))))
        elif name in ('attitude', 'attitude_setpoint'):
            m = QuaternionStamped()
            m.header.stamp = _time(t)
            angle = _roll(i) if name == 'attitude' else 0.3
            m.quaternion.x, m.quaternion.w = math.sin(angle / 2), math.cos(angle / 2)
            out.append((name, m))
        elif name in VECTOR_TOPICS or name == 'flexible_mode':
            m = Vector3Stamped()
            m.header.stamp = _time(t)
            m.vector.x, m.vector.y, m.vector.z = _vector_values(name, i)
            out.append((name, m))
        elif name == 'wheel_state':
            m = JointState()
            m.header.stamp = _time(t)
            m.name = ['wheel_1', 'wheel_2', 'wheel_3']
            m.position = [0.0, 0.0, 0.0]
            m.velocity = [0.1 * i, -0.05 * i, 1.0]
            m.effort = [0.0, 0.0, 0.0]
            out.append((name, m))
        elif name == 'parameter_events':
            controller = f'{ns}/controller'
            if i == 0:
                out.append((name, _event(t, controller, new=[_string_param('controller_type', 'pid')])))
            if i == SWAP_STEP:
                # Neither a plant parameter nor another controller parameter is a swap.
                out.append((name, _event(t, f'{ns}/plant', changed=[_string_param('controller_type', 'x')])))
                out.append((name, _event(t, controller, changed=[_string_param('error_mode', 'angle')])))
                out.append((name, _event(t, controller,
                                         changed=[_string_param('controller_type', 'fuzzy_pid')])))
    return out


def _topic(name: str, ns: str) -> str:
    return '/parameter_events' if name == 'parameter_events' else f'{ns}/{name}'


def build_bag(run_dir: Path, topics: tuple[str, ...] = FULL, *, ns: str = '', steps: int = STEPS,
              first_step: int = 0, chunk_size: int = 4096) -> list[tuple[str, int, bytes]]:
    """Write a bag; returns the (topic, log time ns, CDR bytes) written, in order."""
    written = []
    with BagWriter(run_dir, chunk_size=chunk_size) as writer:
        for name in topics:
            writer.add_topic(_topic(name, ns), TYPES[name])
        for i in range(first_step, first_step + steps):
            for name, msg in _messages(i, topics, ns):
                data = serialize_message(msg)
                t = T_START_NS + i * DT_NS
                writer.write(_topic(name, ns), data, t)
                written.append((_topic(name, ns), t, data))
    return written


@pytest.fixture(scope='module')
def full_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[tuple[str, int, bytes]]]:
    run_dir = tmp_path_factory.mktemp('bags') / 'run'
    return run_dir, build_bag(run_dir)


def _triples(messages) -> list[tuple[str, int, bytes]]:
    return [(m.topic, m.log_time_ns, m.data) for m in messages]


# ------------------------------------------------------------------ opening and info
def test_open_directory_and_single_file(full_bag) -> None:
    run_dir, written = full_bag
    for path in (run_dir, run_dir / 'run_0.mcap', str(run_dir / 'metadata.yaml')):
        reader = open_bag(path)
        assert reader.paths == [run_dir / 'run_0.mcap']
        assert not reader.recovered and reader.notes == []
        assert reader.storage == 'mcap'
        assert reader.ros_distro == 'jazzy'
        assert reader.message_count == len(written) == STEPS * 8 + 4
        assert reader.size_bytes == (run_dir / 'run_0.mcap').stat().st_size
        assert reader.start_ns == T_START_NS
        assert reader.end_ns == T_START_NS + (STEPS - 1) * DT_NS
        assert reader.duration_ns == (STEPS - 1) * DT_NS
        assert list(reader.topics) == sorted(f'/{t}' for t in FULL)
        attitude = reader.topics['/attitude']
        assert (attitude.type, attitude.count, attitude.message_encoding, attitude.schema_encoding) == (
            'geometry_msgs/msg/QuaternionStamped', STEPS, 'cdr', 'ros2msg')
        assert reader.topics['/parameter_events'].count == 4
        assert reader.topics['/wheel_state'].type == 'sensor_msgs/msg/JointState'


def test_info_text(full_bag) -> None:
    run_dir, written = full_bag
    text = format_info(open_bag(run_dir))
    lines = text.splitlines()
    fields = {line.split(':', 1)[0]: line.split(':', 1)[1].strip() for line in lines if not line.startswith(' ')}
    assert fields['Files'] == 'run_0.mcap'
    assert fields['Storage id'] == 'mcap'
    assert fields['Messages'] == str(len(written))
    assert fields['Duration'] == '1.990000000s'
    assert fields['Start'] == '1.000000000 s (sim time)'
    assert fields['End'] == '2.990000000 s (sim time)'
    assert fields['Bag size'].endswith('KiB')
    assert fields['Service'] == '0' and lines[-1] == 'Service information:'  # as Jazzy's ros2 bag info
    assert 'Recovered' not in fields
    topic_lines = [line.split('Topic: ', 1)[1] for line in lines if 'Topic: ' in line]
    assert topic_lines == [
        f'{name} | Type: {TYPES[name[1:]]} | Count: {4 if name == "/parameter_events" else STEPS} '
        '| Serialization Format: cdr'
        for name in sorted(f'/{t}' for t in FULL)
    ]
    assert lines[lines.index(next(x for x in lines if x.startswith('Topic information:')))].startswith(
        'Topic information: Topic: /attitude | Type: geometry_msgs/msg/QuaternionStamped | Count: 200 |')


def test_format_size() -> None:
    assert format_size(512) == '512 B'
    assert format_size(1536) == '1.5 KiB'
    assert format_size(3 * 1024**3) == '3.0 GiB'


# ------------------------------------------------------------------ iteration
def test_iter_raw_order_and_filters(full_bag) -> None:
    run_dir, written = full_bag
    reader = open_bag(run_dir)
    everything = list(reader.iter_raw())
    assert all(isinstance(m, RawMessage) for m in everything)
    # Written in time order, so log-time order (ties in file order) is the written order.
    assert _triples(everything) == written
    assert everything[0].publish_time_ns == everything[0].log_time_ns
    assert {m.type for m in everything if m.topic == '/clock'} == {'rosgraph_msgs/msg/Clock'}

    picked = list(reader.iter_raw(['/attitude', '/clock'], start_ns=T_START_NS + 10 * DT_NS,
                                  end_ns=T_START_NS + 19 * DT_NS))
    assert _triples(picked) == [w for w in written if w[0] in ('/attitude', '/clock')
                                and T_START_NS + 10 * DT_NS <= w[1] <= T_START_NS + 19 * DT_NS]
    assert len(picked) == 20
    assert [m.topic for m in reader.iter_raw('/parameter_events')] == ['/parameter_events'] * 4
    assert list(reader.iter_raw(start_ns=reader.end_ns + 1)) == []
    with pytest.raises(BagError, match='no topic /nope'):
        list(reader.iter_raw(['/attitude', '/nope']))


def test_decoded_values_equal_written(full_bag) -> None:
    run_dir, _ = full_bag
    reader = open_bag(run_dir)
    quats = [(raw.log_time_ns, m.quaternion.x, m.quaternion.w, m.header.stamp.sec, m.header.stamp.nanosec)
             for raw, m in reader.iter_decoded('/attitude')]
    assert len(quats) == STEPS
    for i, (t, x, w, sec, nsec) in enumerate(quats):
        assert t == T_START_NS + i * DT_NS == sec * 10**9 + nsec
        assert (x, w) == (math.sin(_roll(i) / 2), math.cos(_roll(i) / 2))
    rates = [(m.vector.x, m.vector.y, m.vector.z) for _, m in reader.iter_decoded(['/body_rate'])]
    assert rates == [_vector_values('body_rate', i) for i in range(STEPS)]
    _, joints = next(iter(reader.iter_decoded('/wheel_state', start_ns=T_START_NS + 7 * DT_NS)))
    assert list(joints.name) == ['wheel_1', 'wheel_2', 'wheel_3']
    assert list(joints.velocity) == [0.1 * 7, -0.05 * 7, 1.0]
    events = [m for _, m in reader.iter_decoded('/parameter_events')]
    assert [e.node for e in events] == ['/controller', '/plant', '/controller', '/controller']
    assert events[-1].changed_parameters[0].value.string_value == 'fuzzy_pid'


def test_find_topic_in_a_namespace(tmp_path: Path) -> None:
    build_bag(tmp_path / 'ns', ('attitude', 'attitude_setpoint', 'parameter_events'), ns='/sat1', steps=5)
    reader = open_bag(tmp_path / 'ns')
    assert reader.find_topic('attitude') == '/sat1/attitude'
    assert reader.find_topic('/attitude_setpoint') == '/sat1/attitude_setpoint'
    assert reader.find_topic('parameter_events') == '/parameter_events'
    assert reader.find_topic('setpoint') is None
    assert reader.find_topic('body_rate') is None


def test_several_files_are_merged_in_time_order(tmp_path: Path) -> None:
    # Overlapping in time: steps 0-29 and 15-44.
    first = build_bag(tmp_path / 'a', ('clock', 'attitude'), steps=30, chunk_size=512)
    second = build_bag(tmp_path / 'b', ('clock', 'attitude'), steps=30, first_step=15, chunk_size=512)
    merged = tmp_path / 'merged'
    merged.mkdir()
    # Named so that a plain string sort would put part 10 first.
    shutil.copy(tmp_path / 'b' / 'b_0.mcap', merged / 'merged_10.mcap')
    shutil.copy(tmp_path / 'a' / 'a_0.mcap', merged / 'merged_9.mcap')
    reader = open_bag(merged)
    assert [p.name for p in reader.paths] == ['merged_9.mcap', 'merged_10.mcap']
    assert reader.message_count == 120 and reader.topics['/attitude'].count == 60
    # Log-time order; equal times in file order (stable sort of the files' messages).
    assert _triples(reader.iter_raw()) == sorted(first + second, key=lambda w: w[1])
    assert reader.start_ns == T_START_NS and reader.end_ns == T_START_NS + 44 * DT_NS
    xs = [m.quaternion.x for _, m in reader.iter_decoded('/attitude')]
    assert xs == sorted(xs) and len(xs) == 60


# ------------------------------------------------------------------ broken files
def test_truncated_bag_is_recovered_as_a_prefix(full_bag, tmp_path: Path) -> None:
    run_dir, written = full_bag
    data = (run_dir / 'run_0.mcap').read_bytes()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:int(len(data) * 0.6)])
    reader = open_bag(cut)
    assert reader.recovered
    assert len(reader.notes) == 1 and 'cut.mcap: truncated: summary missing; recovered' in reader.notes[0]
    got = _triples(reader.iter_raw())
    assert 0 < len(got) < len(written)
    assert got == written[:len(got)]  # intact, in order, nothing after a gap
    assert reader.message_count == len(got)
    assert reader.end_ns == got[-1][1]
    assert sum(t.count for t in reader.topics.values()) == len(got)
    decoded = [m.quaternion.x for _, m in reader.iter_decoded('/attitude')]
    assert decoded == [math.sin(_roll(i) / 2) for i in range(len(decoded))]
    assert 'Recovered:         yes (summary missing, read by scanning)' in format_info(reader)


def test_bag_of_a_process_that_never_closed_it(tmp_path: Path) -> None:
    writer = BagWriter(tmp_path / 'live', chunk_size=1 << 20)
    writer.add_topic('/clock', TYPES['clock'])
    for i in range(40):
        writer.write('/clock', serialize_message(Clock(clock=_time(i * DT_NS))), i * DT_NS)
    writer.flush()  # the chunk reaches the file, no summary yet
    snapshot = tmp_path / 'snapshot.mcap'
    shutil.copy(tmp_path / 'live' / 'live_0.mcap', snapshot)
    writer.close()
    reader = open_bag(snapshot)
    assert reader.recovered and reader.message_count == 40
    assert [raw.log_time_ns for raw in reader.iter_raw()] == [i * DT_NS for i in range(40)]


def test_corrupt_chunk_names_file_and_offset(full_bag, tmp_path: Path) -> None:
    run_dir, _ = full_bag
    with (run_dir / 'run_0.mcap').open('rb') as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) > 5
    middle = chunks[len(chunks) // 2]
    data = bytearray((run_dir / 'run_0.mcap').read_bytes())
    data[middle.chunk_start_offset + middle.chunk_length - 20] ^= 0xFF  # in its compressed data
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(bytes(data))
    with pytest.raises(BagError, match=rf'bad\.mcap: corrupt chunk at byte offset {middle.chunk_start_offset}:') as err:
        list(open_bag(bad).iter_raw())
    assert '\n' not in str(err.value)
    # The same damage in a file without summary is found while scanning it.
    bad.write_bytes(bytes(data[:int(len(data) * 0.8)]))
    with pytest.raises(BagError, match=rf'bad\.mcap: corrupt chunk record at byte offset {middle.chunk_start_offset}:'):
        open_bag(bad)


def test_uncompressed_chunk_with_a_wrong_byte_fails_its_crc(tmp_path: Path) -> None:
    with BagWriter(tmp_path / 'plain', chunk_size=512, compression='none') as writer:
        writer.add_topic('/clock', TYPES['clock'])
        for i in range(100):
            writer.write('/clock', serialize_message(Clock(clock=_time(i))), i)
    path = tmp_path / 'plain' / 'plain_0.mcap'
    data = bytearray(path.read_bytes())
    with path.open('rb') as f:
        chunk = make_reader(f).get_summary().chunk_indexes[2]
    data[chunk.chunk_start_offset + chunk.chunk_length - 3] ^= 0x01  # a clock nanosec byte
    path.write_bytes(bytes(data))
    reader = open_bag(path)
    with pytest.raises(BagError, match=rf'corrupt chunk at byte offset {chunk.chunk_start_offset}: crc'):
        list(reader.iter_raw())


def test_unreadable_inputs_raise_bag_error(tmp_path: Path) -> None:
    junk = tmp_path / 'junk.mcap'
    junk.write_bytes(os.urandom(4000))
    with pytest.raises(BagError, match=r'junk\.mcap: not an MCAP file$'):
        open_bag(junk)
    empty = tmp_path / 'empty.mcap'
    empty.touch()
    with pytest.raises(BagError, match=r'empty\.mcap: empty file'):
        open_bag(empty)
    with pytest.raises(BagError, match=r'missing: no such file or directory'):
        open_bag(tmp_path / 'missing')
    (tmp_path / 'no_files').mkdir()
    with pytest.raises(BagError, match=r'no_files: no \.mcap file'):
        open_bag(tmp_path / 'no_files')
    header_only = tmp_path / 'header_only.mcap'
    header_only.write_bytes(b'\x89MCAP0\r\n\x01\x20\x00')
    with pytest.raises(BagError, match=r'header_only\.mcap: truncated.*no complete message'):
        open_bag(header_only)


# ------------------------------------------------------------------ swaps and plots
def test_controller_swaps(full_bag, tmp_path: Path) -> None:
    run_dir, _ = full_bag
    reader = open_bag(run_dir)
    swap_time = (T_START_NS + SWAP_STEP * DT_NS) / 1e9
    assert controller_swaps(reader) == [(swap_time, 'fuzzy_pid')]
    assert initial_controller(reader) == 'pid'
    build_bag(tmp_path / 'ns', ('attitude', 'parameter_events'), ns='/sat1', steps=SWAP_STEP + 1)
    assert controller_swaps(open_bag(tmp_path / 'ns')) == [(swap_time, 'fuzzy_pid')]
    build_bag(tmp_path / 'none', ('attitude',), steps=3)
    assert controller_swaps(open_bag(tmp_path / 'none')) == []


def _png(path: Path) -> np.ndarray:
    import matplotlib.image

    return np.asarray(matplotlib.image.imread(path))


def _png_size(path: Path) -> tuple[int, int]:
    height, width = _png(path).shape[:2]
    return width, height


def test_plot_bag_panels(full_bag, tmp_path: Path) -> None:
    run_dir, _ = full_bag
    out = plot_bag(run_dir, tmp_path / 'plots' / 'run.png')
    assert out == tmp_path / 'plots' / 'run.png' and out.stat().st_size > 10_000
    assert _png_size(out) == (1210, round(FULL_PANELS * 2.2 * 110))
    # Attitude and flexible mode only: two panels.
    build_bag(tmp_path / 'flex', ('attitude', 'flexible_mode'), steps=20)
    out = plot_bag(tmp_path / 'flex' / 'flex_0.mcap', tmp_path / 'flex.png', title='flexible')
    assert _png_size(out) == (1210, round(2 * 2.2 * 110))
    assert _png(out)[..., :3].std() > 0.05  # something was drawn


def test_plot_bag_without_attitude(tmp_path: Path) -> None:
    build_bag(tmp_path / 'noatt', ('clock', 'body_rate'), steps=5)
    with pytest.raises(BagError, match=r'noatt: no attitude messages'):
        plot_bag(tmp_path / 'noatt', tmp_path / 'x.png')
    assert not (tmp_path / 'x.png').exists()
