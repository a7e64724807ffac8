# Copyright 2026 ros_ehs contributors
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""Bag writer and reader: rosbag2 conventions, external readers, fixtures, crashes."""

import os
from pathlib import Path
import sys
import textwrap
import threading

import numpy as np
import pytest
from ros_ehs.core.errors import BagError, DataError
from ros_ehs.data.bag import (bag_counts, BagWriter, full_definition, open_bag, type_hash,
                              wait_for_counts)
from ros_ehs.data.experiments import load_experiment
import ros_ehs_msgs_py as c
from waits import BOUND
import yaml

FIXTURES = Path(__file__).resolve().parent / 'fixtures' / 'rosbag2'
N = 300


def _write(path, n=N, pressures=True, dz=0.001):
    with BagWriter(path) as w:
        tops = [c.STATE, c.COMMAND] + ([c.PRESSURE_P] if pressures else [])
        for tp in tops:
            w.add_topic('/' + tp.name, tp.msg_type, tp.qos)
        for k in range(n):
            ns = 1_000_000_000 + k * 1_000_000
            w.write_msg('/state', c.fill_state(c.empty_msg(c.STATE.msg_type),
                                               c.AxisState(ns, dz * k, 0.5, 10.0, 1e-5)),
                        ns)
            w.write_msg('/servo_current', c.fill_command(c.empty_msg(c.COMMAND.msg_type),
                                                         c.Command(ns, 0.001 * (k % 7))), ns)
            if pressures:
                w.write_msg('/pressure/chamber_p', c.fill_pressure(
                    c.empty_msg(c.PRESSURE_P.msg_type), c.Pressure(ns, 1e7 + k)), ns)
    return path


def test_layout_and_rosbag2_conventions(tmp_path):
    bag = _write(tmp_path / 'run1')
    assert sorted(os.listdir(bag)) == ['metadata.yaml', 'run1_0.mcap']
    from mcap.reader import make_reader
    with open(bag / 'run1_0.mcap', 'rb') as f:
        r = make_reader(f)
        assert r.get_header().profile == 'ros2'
        s = r.get_summary()
        ch = {x.topic: x for x in s.channels.values()}
        st = ch['/state']
        assert st.message_encoding == 'cdr'
        schema = s.schemas[st.schema_id]
        assert schema.name == 'sensor_msgs/msg/JointState' and schema.encoding == 'ros2msg'
        text = schema.data.decode()
        assert text.startswith(full_definition('sensor_msgs/msg/JointState')[:40])
        assert '\nMSG: std_msgs/Header\n' in text and '\nMSG: builtin_interfaces/Time\n' in text
        assert st.metadata['topic_type_hash'] == type_hash('sensor_msgs/msg/JointState')
        assert st.metadata['topic_type_hash'].startswith('RIHS01_')
        qos = yaml.safe_load(st.metadata['offered_qos_profiles'])
        assert qos[0]['reliability'] == 'best_effort' and qos[0]['depth'] == 1
        meta = {m.name: m.metadata for m in r.iter_metadata()}
        assert yaml.safe_load(meta['rosbag2']['serialized_metadata'])['message_count'] == 3 * N
        assert s.statistics.message_count == 3 * N
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['run1_0.mcap']
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    assert counts == {'/state': N, '/servo_current': N, '/pressure/chamber_p': N}
    assert info['duration']['nanoseconds'] == (N - 1) * 1_000_000
    assert '&id' not in (bag / 'metadata.yaml').read_text()   # no YAML anchors


def test_full_definition_matches_a_real_rosbag2_schema():
    from mcap.reader import make_reader
    with open(FIXTURES / 'talker.mcap', 'rb') as f:
        s = make_reader(f).get_summary()
    real = {x.name: x.data.decode() for x in s.schemas.values()}
    ours = full_definition('rcl_interfaces/msg/Log')
    blocks = [ln for ln in real['rcl_interfaces/msg/Log'].splitlines() if ln.startswith('MSG:')]
    assert blocks == [ln for ln in ours.splitlines() if ln.startswith('MSG:')]


def test_external_readers_see_types_counts_times_and_qos(tmp_path):
    bag = _write(tmp_path / 'ext')
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as r:
        assert r.message_count == 3 * N
        conns = {x.topic: x for x in r.connections}
        assert conns['/state'].msgtype == 'sensor_msgs/msg/JointState'
        assert conns['/state'].ext.offered_qos_profiles[0].depth == 1
        times, zs = [], []
        for conn, t, raw in r.messages(connections=[conns['/state']]):
            times.append(t)
            zs.append(ts.deserialize_cdr(raw, conn.msgtype).position[0])
    assert len(times) == N and times[0] == 1_000_000_000
    np.testing.assert_allclose(zs, 0.001 * np.arange(N))
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DeprecationWarning)
        from mcap_ros2.reader import read_ros2_messages
        ms = list(read_ros2_messages(str(bag / 'ext_0.mcap'), topics=['/servo_current']))
    assert len(ms) == N
    assert ms[3].ros_msg.effort[0] == pytest.approx(0.003)
    assert ms[3].log_time_ns == 1_003_000_000


def test_round_trip_through_our_reader(tmp_path):
    bag = open_bag(_write(tmp_path / 'rt'))
    assert not bag.truncated
    assert {t: i.count for t, i in bag.topics.items()} == {
        '/state': N, '/servo_current': N, '/pressure/chamber_p': N}
    states = [c.state_from_msg(m) for _, m in bag.decoded(['/state'])]
    assert states[10] == c.AxisState(1_010_000_000, 0.01, 0.5, 10.0, 1e-5)


@pytest.mark.parametrize('name', ['talker.mcap', 'cdr_test_0.mcap', 'only_topics.mcap',
                                  'bag_with_topics_and_service_events.mcap'])
def test_reads_real_rosbag2_fixtures(name):
    bag = open_bag(FIXTURES / name)
    assert not bag.truncated and bag.topics
    for info in bag.topics.values():
        assert info.encoding == 'cdr' and '/msg/' in info.msg_type or '/srv/' in info.msg_type
    topics = [t for t, i in bag.topics.items() if i.count]      # service events too
    decoded = list(bag.decoded(topics))
    assert len(decoded) == sum(bag.topics[t].count for t in topics) > 0


def test_service_events_stored_with_their_services_definition_read_and_decode():
    # rosbag2 (Jazzy) stores a service's events under the service's text (request --- response)
    bag = open_bag(FIXTURES / 'bag_with_topics_and_service_events.mcap')
    ev = [t for t, i in bag.topics.items() if i.msg_type == 'test_msgs/srv/BasicTypes_Event']
    assert len(ev) == 2
    got = list(bag.decoded(ev))
    assert len(got) == 8
    for m, d in got:
        # ServiceEventInfo leads the CDR: event_type at byte 4, and one request (sent) or
        # one response (received) each, as the raw bytes say
        assert d.info.event_type == m.data[4] and d.info.event_type in (0, 3)
        assert (len(d.request), len(d.response)) == ((1, 0) if d.info.event_type == 0 else (0, 1))
    seqs = sorted(d.info.sequence_number for m, d in got if m.topic == ev[0])
    assert seqs == [1, 1, 2, 2]


def test_a_service_event_definition_is_built_from_the_services_text():
    from ros_ehs.data.bag.definitions import service_event_definition
    srv = ('=' * 80 + '\nSRV: my_pkg/srv/Move_Axis\ngeometry_msgs/Point target\n'
           'float64 speed\n---\nbool ok\n' + '=' * 80 +
           '\nMSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n')
    name, text = service_event_definition('my_pkg/srv/Move_Axis_Event', srv)
    assert name == 'my_pkg/srv/MoveAxisEvent'
    assert text.startswith('service_msgs/ServiceEventInfo info\nmy_pkg/MoveAxisRequest[<=1] '
                           'request\nmy_pkg/MoveAxisResponse[<=1] response\n')
    assert '\nMSG: my_pkg/srv/MoveAxisRequest\ngeometry_msgs/Point target\nfloat64 speed\n' in text
    assert '\nMSG: my_pkg/srv/MoveAxisResponse\nbool ok\n' in text
    assert text.endswith('MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n')
    from mcap_ros2._dynamic import generate_dynamic
    assert name in generate_dynamic(name, text)          # the parser takes it
    # no service event, or no service text: nothing to build
    assert service_event_definition('my_pkg/msg/Move', srv) is None
    assert service_event_definition('my_pkg/srv/Move_Event', 'float64 x\n') is None


def test_fixture_without_our_topics_says_which_it_has():
    with pytest.raises(BagError, match=r"no topic 'state'.*/topic \(std_msgs/msg/String"):
        load_experiment(FIXTURES / 'talker.mcap')


def test_foreign_and_missing_files(tmp_path):
    with pytest.raises(BagError, match='no bag at'):
        open_bag(tmp_path / 'nope')
    (tmp_path / 'x.mcap').write_bytes(b'not an mcap file at all')
    with pytest.raises(BagError, match='not an MCAP file'):
        open_bag(tmp_path / 'x.mcap')
    with pytest.raises(BagError, match='already exists'):
        _write(tmp_path)


def test_truncated_file_is_read_up_to_the_cut(tmp_path):
    bag = _write(tmp_path / 'cut', n=3000)
    f = bag / 'cut_0.mcap'
    data = f.read_bytes()
    f.write_bytes(data[:len(data) * 2 // 3])
    b = open_bag(bag)
    assert b.truncated and b.problem
    assert 0 < b.topics['/state'].count < 3000


def test_a_cut_anywhere_gives_a_truncated_bag_or_a_bag_error(tmp_path):
    bag = _write(tmp_path / 'cuts', n=200)
    f = bag / 'cuts_0.mcap'
    data = f.read_bytes()
    counts = []
    for cut in range(8, len(data), 211):       # every record kind gets cut somewhere
        f.write_bytes(data[:cut])
        try:
            b = open_bag(bag)
        except BagError:
            continue
        assert b.truncated and b.problem
        counts.append(b.message_count)
    assert counts and counts == sorted(counts) and counts[-1] > 0


_KILL_SCRIPT = textwrap.dedent("""
    import sys, time
    from ros_ehs.data.bag import BagWriter
    import ros_ehs_msgs_py as c
    w = BagWriter(sys.argv[1], flush_period=0.05)
    w.add_topic('/state', c.STATE.msg_type, c.STATE.qos)
    while True:
        ns = time.time_ns()
        w.write_msg('/state', c.fill_state(c.empty_msg(c.STATE.msg_type),
                    c.AxisState(ns, 0.0, 0.0)), ns)
        print(ns, flush=True)  # written: the parent knows what the bag should hold
        time.sleep(0.001)
""")


def test_sigkill_loses_at_most_100_ms(tmp_path, sigkilled):
    # Judged on what the writer had written, not on wall-clock sleeps: a loaded machine may
    # stall the writer, but whatever it wrote more than flush_period before its last write
    # must be in the bag after SIGKILL.
    bag = tmp_path / 'killed'
    written = sigkilled(_KILL_SCRIPT, bag, 600)
    b = open_bag(bag)
    assert b.truncated
    kept = {m.log_time_ns for m in b.messages(['/state'])}
    assert kept <= set(written) | {max(kept)}  # at most one written but not yet printed
    lost = [ns for ns in written if ns not in kept]
    assert len(kept) >= 500
    span_s = (written[-1] - min(lost, default=written[-1])) * 1e-9
    assert span_s <= 0.1, f'lost {len(lost)} messages spanning the last {span_s * 1e3:.0f} ms'


def test_experiment_needs_data_and_excitation(tmp_path):
    with pytest.raises(DataError, match='too little data'):
        load_experiment(_write(tmp_path / 'short', n=100))
    with pytest.raises(DataError, match='no excitation'):
        load_experiment(_write(tmp_path / 'still', n=N * 2, dz=0.0))


def test_wrong_message_type_is_named(tmp_path):
    with BagWriter(tmp_path / 'wrong') as w:
        w.add_topic('/state', 'sensor_msgs/msg/FluidPressure')
        w.add_topic('/servo_current', c.COMMAND.msg_type)
    with pytest.raises(BagError, match="'/state'.*FluidPressure, expected "
                                       'sensor_msgs/msg/JointState'):
        load_experiment(tmp_path / 'wrong')


def test_writer_rejects_bad_input_without_losing_what_is_written(tmp_path):
    w = BagWriter(tmp_path / 'bad')
    w.add_topic('/state', c.STATE.msg_type, c.STATE.qos)
    msg = c.fill_state(c.empty_msg(c.STATE.msg_type), c.AxisState(5, 0.0, 0.0))
    w.write_msg('/state', msg, 5)
    with pytest.raises(BagError, match='negative log time'):
        w.write_msg('/state', msg, -1)
    with pytest.raises(BagError, match="'/nope' is not registered"):
        w.write_msg('/nope', msg, 6)
    with pytest.raises(BagError, match='already registered as sensor_msgs/msg/JointState'):
        w.add_topic('/state', c.PRESSURE_P.msg_type)
    with pytest.raises(BagError, match='not a ROS message type'):
        w.add_topic('/x', 'JointState')
    with pytest.raises(BagError, match='flush_period'):
        BagWriter(tmp_path / 'other', flush_period=0.0)
    w.close()
    with pytest.raises(BagError, match='is closed'):
        w.add_topic('/later', c.STATE.msg_type)
    assert open_bag(tmp_path / 'bad').topics['/state'].count == 1
    with pytest.raises(BagError, match='is closed'):
        w.write_msg('/state', msg, 7)


def test_a_bag_closed_while_another_thread_writes_stays_whole(tmp_path):
    # A node whose executor does not return in time is closed on the main thread while its
    # callbacks may still write: each write lands before the summary or is refused, whole.
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)      # switch threads as often as CPython can
    try:
        for trial in range(12):
            w = BagWriter(tmp_path / f'b{trial}', flush_period=1e-3)
            w.add_topic('/state', c.STATE.msg_type, c.STATE.qos)
            written, refused, started = [], [], threading.Event()

            def pump():
                for k in range(10**6):
                    ns = 10**9 + k * 10**6
                    try:
                        w.write_msg('/state', c.fill_state(c.empty_msg(c.STATE.msg_type),
                                                           c.AxisState(ns, 1e-3 * k, 0.0)), ns)
                    except BagError as err:
                        refused.append(str(err))
                        return
                    written.append(ns)
                    if k == 100 + 7 * trial:
                        started.set()

            th = threading.Thread(target=pump, daemon=True)
            th.start()
            assert started.wait(BOUND)
            w.close()
            th.join(BOUND)
            assert not th.is_alive()
            assert refused and 'is closed' in refused[0]
            bag = open_bag(tmp_path / f'b{trial}')
            assert not bag.truncated, bag.problem
            stamps = [m.log_time_ns for m, _ in bag.decoded(['/state'])]
            assert stamps == written
    finally:
        sys.setswitchinterval(interval)


def test_a_wait_for_counts_returns_them_or_says_what_the_bag_held(tmp_path):
    with pytest.raises(BagError, match='after 0 s the bag holds nothing readable '
                                       r"\(.*not \{'/state': 1\}"):
        wait_for_counts(tmp_path / 'none', {'/state': 1}, 0.0)
    w = BagWriter(tmp_path / 'live')
    w.add_topic('/state', c.STATE.msg_type, c.STATE.qos)
    msg = c.fill_state(c.empty_msg(c.STATE.msg_type), c.AxisState(5, 0.0, 0.0))
    for k in range(10):
        w.write_msg('/state', msg, 10**9 + k)
    w.flush()                     # on disk, as a recorder's flush leaves it; not closed
    assert bag_counts(tmp_path / 'live') == {'/state': 10}
    assert wait_for_counts(tmp_path / 'live', {'/state': 10}, 0.0) == {'/state': 10}
    with pytest.raises(BagError, match=r"holds \{'/state': 10\}, not \{'/state': 11\}"):
        wait_for_counts(tmp_path / 'live', {'/state': 11}, 0.0)
    later = threading.Thread(target=lambda: (w.write_msg('/state', msg, 2 * 10**9), w.flush()))
    later.start()                 # the wait sees the message another thread writes
    assert wait_for_counts(tmp_path / 'live', {'/state': 11}, BOUND) == {'/state': 11}
    later.join()
    w.close()


def _without_states(bag, out, drop):
    """Copy ``bag`` (1 kHz from t = 1 s) to ``out`` without the states k where drop(k)."""
    with BagWriter(out) as w:
        for name, info in bag.topics.items():
            w.add_topic(name, info.msg_type, info.qos)
        for m in bag.messages():
            k = (m.log_time_ns - 1_000_000_000) // 1_000_000
            if not (m.topic == '/state' and drop(k)):
                w.write(m.topic, m.data, m.log_time_ns)
    return out


def test_missing_samples_split_the_record_into_runs(tmp_path):
    from ros_ehs.core.identify.experiment import BRIDGE, MIN_SAMPLES
    from ros_ehs.data.experiments import load_experiments
    bag = _write(tmp_path / 'gappy', n=2000)
    # rewrite without states 700..849 (a recorder that missed 150 ms)
    b = open_bag(bag)
    out = _without_states(b, tmp_path / 'holed', lambda k: 700 <= k < 850)
    with pytest.raises(DataError, match='not on a uniform grid'):
        load_experiment(out)
    runs = load_experiments(out)
    assert [r.name for r in runs] == ['holed [1/2]', 'holed [2/2]']
    assert [r.t.size for r in runs] == [700, 1150]
    assert runs[1].z[0] == pytest.approx(0.001 * 850)         # starts after the gap
    # a state or two missed in a row are bridged: one run on the whole grid, the missed
    # positions between their neighbours'
    assert BRIDGE == 2
    for name, drop in (('once', lambda k: k % 400 == 7), ('twice', lambda k: k % 400 in (7, 8))):
        bridged = _without_states(b, tmp_path / name, drop)
        for e in (load_experiment(bridged), *load_experiments(bridged)):
            assert e.name == name and e.t.size == 2000 and e.dt == pytest.approx(1e-3)
            np.testing.assert_allclose(e.z, 0.001 * np.arange(2000), rtol=0, atol=1e-12)
    # three missed in a row split it; runs shorter than MIN_SAMPLES are dropped; none left is
    # a clear error
    assert MIN_SAMPLES > 100
    short = _without_states(b, tmp_path / 'short', lambda k: k % 400 < 3)
    with pytest.raises(DataError, match='longest run without missing samples has 397'):
        load_experiments(short)


def test_stray_states_from_another_clock_are_dropped_not_fatal(tmp_path):
    """Stamp policy of the bag reader: strangers off the grid are dropped and named."""
    from ros_ehs.data.experiments import load_experiments
    clean = _write(tmp_path / 'clean', n=2000)
    bag = tmp_path / 'stray'
    src = open_bag(clean)
    with BagWriter(bag) as w:
        for k, t in src.topics.items():
            w.add_topic(k, t.msg_type, t.qos)
        for m in src.messages():
            w.write(m.topic, m.data, m.log_time_ns)
        for ns in (1_500_400_000, 1_500_400_001, 1_000_000_000 + 3600 * 10**9):
            # a stray publisher: between two grid points, and an hour ahead
            w.write_msg('/state', c.fill_state(c.empty_msg(c.STATE.msg_type),
                                               c.AxisState(ns, 9.0, 9.0)), 2_000_000_000)
    exp, = load_experiments(bag)
    ref, = load_experiments(clean)
    assert exp.name == 'stray (2 off-grid states dropped)'
    np.testing.assert_array_equal(exp.z, ref.z)
    np.testing.assert_array_equal(exp.i, ref.i)


def test_a_still_run_before_the_trajectory_is_dropped_when_another_moves(tmp_path):
    """A real-time bench bag: the hold before the reference started, a gap, the sine."""
    from ros_ehs.data.experiments import load_experiments

    def write(path, moving_after_gap):
        with BagWriter(path) as w:
            for tp in (c.STATE, c.COMMAND):
                w.add_topic('/' + tp.name, tp.msg_type, tp.qos)
            for k in list(range(600)) + list(range(700, 1500)):
                ns = 1_000_000_000 + k * 1_000_000
                move = moving_after_gap and k >= 700
                z = 0.01 * np.sin(k * 0.01) if move else 0.0
                w.write_msg('/state', c.fill_state(c.empty_msg(c.STATE.msg_type),
                                                   c.AxisState(ns, z, 0.0)), ns)
                w.write_msg('/servo_current', c.fill_command(
                    c.empty_msg(c.COMMAND.msg_type), c.Command(ns, 1e-3 * z)), ns)
        return path

    runs = load_experiments(write(tmp_path / 'bench', True))
    assert [r.name for r in runs] == ['bench [2/2]'] and runs[0].t.size == 800
    with pytest.raises(DataError, match=r'no run moves the piston: still \[1/2\]: no '
                                        r'excitation.*still \[2/2\]: no excitation'):
        load_experiments(write(tmp_path / 'still', False))
