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
"""
Bags for long runs: split files, chunk compression, sqlite3 bags, time windows, write errors.

Every split or compressed bag is read by three readers we did not write (rosbags, mcap's own
reader, mcap-ros2-support) besides ours; write errors are real OS errors (a file-size limit
in a child process, a 2 MB tmpfs), never the machine's own disk filling up.
"""

import os
from pathlib import Path
import shutil
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest
from ros_ehs.core.errors import BagError, DataError
from ros_ehs.data.bag import BagWriter, open_bag
from ros_ehs.data.experiments import load_experiments
import ros_ehs_msgs_py as c
import yaml

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = Path(__file__).resolve().parent / 'fixtures' / 'rosbag2'
SAMPLE = ROOT / 'bags' / 'sample_sine_1hz'


def _meta(bag):
    return yaml.safe_load((Path(bag) / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']


def _state(k, ns):
    return c.fill_state(c.empty_msg(c.STATE.msg_type), c.AxisState(ns, float(k), 0.5))


def _write_seq(path, n, **kw):
    """Write states whose position is their sequence number, 1 kHz from t = 1 s."""
    with BagWriter(path, **kw) as w:
        w.add_topic('/state', c.STATE.msg_type, c.STATE.qos)
        w.add_topic('/servo_current', c.COMMAND.msg_type, c.COMMAND.qos)
        for k in range(n):
            ns = 1_000_000_000 + k * 1_000_000
            w.write_msg('/state', _state(k, ns), ns)
            if k % 10 == 0:
                w.write_msg('/servo_current', c.fill_command(
                    c.empty_msg(c.COMMAND.msg_type), c.Command(ns, 1e-3)), ns)
    return Path(path)


def _mcap_ros2(path):
    """Return (positions of /state, message count, log times) of one MCAP file (mcap-ros2)."""
    from mcap_ros2.reader import read_ros2_messages
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DeprecationWarning)
        ms = list(read_ros2_messages(str(path)))
    return ([m.ros_msg.position[0] for m in ms if m.channel.topic == '/state'], len(ms),
            [m.log_time_ns for m in ms])


# -- splitting ---------------------------------------------------------------------------------
def test_split_by_size_loses_and_duplicates_nothing_for_any_reader(tmp_path):
    n = 30000
    bag = _write_seq(tmp_path / 'big', n, max_bag_size=150_000, compression='none')
    info = _meta(bag)
    files = info['relative_file_paths']
    assert len(files) >= 5 and files == [f'big_{k}.mcap' for k in range(len(files))]
    assert sorted(os.listdir(bag)) == sorted(files + ['metadata.yaml'])
    # every file a complete MCAP file of its own, read alone by mcap-ros2-support, in order
    per_file = [_mcap_ros2(bag / f) for f in files]
    assert [x for p, _, _ in per_file for x in p] == list(range(n))
    for f, entry, (pos, count, times) in zip(files, info['files'], per_file):
        assert entry['path'] == f
        assert entry['message_count'] == count
        assert entry['starting_time']['nanoseconds_since_epoch'] == min(times)
        assert entry['duration']['nanoseconds'] == max(times) - min(times)
        # a file ends a little past the limit: by at most its last chunk and its summary
        assert (bag / f).stat().st_size < 150_000 * 1.5
    assert info['message_count'] == n + n // 10
    # ours, as one bag
    ours = open_bag(bag)
    assert [c.state_from_msg(m).z for _, m in ours.decoded(['/state'])] == list(range(n))
    assert ours.files == [bag / f for f in files] and not ours.truncated
    # rosbags, as one bag
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as r:
        assert r.message_count == n + n // 10
        conn = [x for x in r.connections if x.topic == '/state']
        zs = [ts.deserialize_cdr(raw, cn.msgtype).position[0]
              for cn, _, raw in r.messages(connections=conn)]
    assert zs == list(range(n))


def test_split_by_duration(tmp_path):
    bag = _write_seq(tmp_path / 'dur', 3500, max_bag_duration=1.0)
    info = _meta(bag)
    assert len(info['files']) == 4
    assert [f['message_count'] for f in info['files']] == [1100, 1100, 1100, 550]
    assert all(f['duration']['nanoseconds'] < 1_000_000_000 for f in info['files'])
    assert open_bag(bag).topics['/state'].count == 3500


def test_the_real_rosbag2_split_bag_reads_as_one_bag():
    bag = open_bag(FIXTURES / 'split_wbag')
    info = _meta(FIXTURES / 'split_wbag')
    assert len(bag.files) == 5 and not bag.truncated
    assert bag.message_count == info['message_count'] == 6074
    assert {t['topic_metadata']['name']: t['message_count']
            for t in info['topics_with_message_count']} == {
        k: v.count for k, v in bag.topics.items()}
    texts = [msg.data for (_, msg), _ in zip(bag.decoded(['AAA']), range(3))]
    assert len(texts) == 3 and all(isinstance(t, str) and t for t in texts)
    times = [m.log_time_ns for m in bag.messages()]
    assert times == sorted(times)


def test_a_split_bag_missing_a_file_or_its_metadata(tmp_path):
    bag = _write_seq(tmp_path / 'gap', 8000, max_bag_size=100_000, compression='none')
    files = _meta(bag)['relative_file_paths']
    (bag / files[1]).unlink()
    b = open_bag(bag)
    assert b.truncated and files[1] in b.problem and 'missing' in b.problem
    assert 0 < b.topics['/state'].count < 8000
    # a recorder killed before metadata.yaml: the files in the order of their number
    (bag / 'metadata.yaml').unlink()
    names = [p.name for p in open_bag(bag).files]
    assert names == [f for f in files if f != files[1]]
    for f in files:
        (bag / f).unlink(missing_ok=True)
    with pytest.raises(BagError, match='holds no bag file'):
        open_bag(bag)


_KILL_SPLIT = textwrap.dedent("""
    import sys, time
    from ros_ehs.data.bag import BagWriter
    import ros_ehs_msgs_py as c
    w = BagWriter(sys.argv[1], flush_period=0.05, max_bag_duration=0.25, compression='zstd')
    w.add_topic('/state', c.STATE.msg_type, c.STATE.qos)
    while True:
        ns = time.time_ns()
        w.write_msg('/state', c.fill_state(c.empty_msg(c.STATE.msg_type),
                    c.AxisState(ns, 0.0, 0.0)), ns)
        print(ns, flush=True)
        time.sleep(0.001)
""")


def test_sigkill_of_a_splitting_writer_loses_at_most_100_ms(tmp_path, sigkilled):
    bag = tmp_path / 'killed'
    written = sigkilled(_KILL_SPLIT, bag, 1200)
    b = open_bag(bag)
    assert len(b.files) >= 3
    # every file but the open one was finished; the open one is cut where the kill came
    assert b.truncated and str(b.files[-1]) in b.problem
    assert all(str(f) not in b.problem for f in b.files[:-1])
    kept = [m.log_time_ns for m in b.messages(['/state'])]
    assert len(kept) == len(set(kept))                        # nothing twice across files
    assert set(kept) <= set(written) | {max(kept)}
    lost = [ns for ns in written if ns not in set(kept)]
    span_s = (written[-1] - min(lost, default=written[-1])) * 1e-9
    assert span_s <= 0.1, f'lost {len(lost)} messages spanning the last {span_s * 1e3:.0f} ms'


# -- compression -------------------------------------------------------------------------------
def test_zstd_chunks_are_smaller_and_every_reader_undoes_them(tmp_path):
    n = 20000
    plain = _write_seq(tmp_path / 'plain', n, compression='none')
    packed = _write_seq(tmp_path / 'packed', n, compression='zstd')
    size = {b.name: (b / f'{b.name}_0.mcap').stat().st_size for b in (plain, packed)}
    assert size['packed'] * 3 < size['plain']
    from mcap.reader import make_reader
    with open(packed / 'packed_0.mcap', 'rb') as f:
        s = make_reader(f).get_summary()
    assert {ci.compression for ci in s.chunk_indexes} == {'zstd'}
    assert _meta(packed)['compression_format'] == ''    # chunk compression, not rosbag2's
    assert _mcap_ros2(packed / 'packed_0.mcap')[:2] == (list(range(n)), n + n // 10)
    assert [c.state_from_msg(m).z for _, m in open_bag(packed).decoded(['/state'])] == \
        list(range(n))
    from rosbags.rosbag2 import Reader
    with Reader(packed) as r:
        assert r.message_count == n + n // 10


def test_writer_rejects_bad_split_and_compression_settings(tmp_path):
    for kw, what in (({'compression': 'gzip'}, 'compression'),
                     ({'max_bag_size': -1}, 'max_bag_size'),
                     ({'max_bag_size': 1.5}, 'max_bag_size'),
                     ({'max_bag_duration': float('nan')}, 'max_bag_duration'),
                     ({'max_bag_duration': -2.0}, 'max_bag_duration')):
        with pytest.raises(BagError, match=what):
            BagWriter(tmp_path / what, **kw)


# -- sqlite3 bags ------------------------------------------------------------------------------
def _db3_twin(src_path, out, definitions=True):
    """Write the bag at ``src_path`` again as a sqlite3 bag with rosbags' own writer."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    src = open_bag(src_path)
    with Writer(out, version=8, storage_plugin=StoragePlugin.SQLITE3) as w:
        conns = {k: w.add_connection(k, t.msg_type, typestore=ts) for k, t in src.topics.items()}
        for m in src.messages():
            w.write(conns[m.topic], m.log_time_ns, m.data)
    if not definitions:        # a Humble-era bag: no message_definitions table
        import sqlite3
        db = next(Path(out).glob('*.db3'))
        with sqlite3.connect(db) as con:
            con.execute('DROP TABLE message_definitions')
    return Path(out)


@pytest.mark.parametrize('definitions', [True, False])
def test_a_sqlite3_bag_identifies_like_its_mcap_twin(tmp_path, definitions):
    db3 = _db3_twin(SAMPLE, tmp_path / 'twin', definitions)
    assert _meta(db3)['storage_identifier'] == 'sqlite3'
    a, = load_experiments(db3)
    b, = load_experiments(SAMPLE)
    for k in ('t', 'i', 'z', 'v', 'p_a', 'p_b'):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))
    bare = open_bag(next(db3.glob('*.db3')))                 # a bare .db3 file reads too
    assert bare.message_count == open_bag(SAMPLE).message_count


def test_foreign_sqlite3_and_unknown_storage_are_named(tmp_path):
    import sqlite3
    f = tmp_path / 'other.db3'
    with sqlite3.connect(f) as con:
        con.execute('CREATE TABLE cats(name TEXT)')
    with pytest.raises(BagError, match="not a rosbag2 bag.*'cats'"):
        open_bag(f)
    d = tmp_path / 'weird'
    d.mkdir()
    (d / 'metadata.yaml').write_text(yaml.safe_dump({'rosbag2_bagfile_information': {
        'storage_identifier': 'hdf5', 'relative_file_paths': ['x.h5']}}))
    with pytest.raises(BagError, match="storage 'hdf5'"):
        open_bag(d)


# -- time windows --------------------------------------------------------------------------------
def test_a_time_window_of_a_split_bag_reads_only_its_files(tmp_path):
    split = tmp_path / 'split'
    with BagWriter(split, max_bag_duration=2.0) as w:
        src = open_bag(SAMPLE)
        for k, t in src.topics.items():
            w.add_topic(k, t.msg_type, t.qos)
        for m in src.messages():
            w.write(m.topic, m.data, m.log_time_ns, m.publish_time_ns)
    assert len(_meta(split)['files']) == 5
    win = open_bag(split, start=4.5, end=5.5)
    assert [p.name for p in win.files] == ['split_2.mcap']
    t0 = src.start_ns
    times = [m.log_time_ns for m in win.messages()]
    assert t0 + 4_500_000_000 <= times[0] and times[-1] <= t0 + 5_500_000_000
    exp, = load_experiments(split, start=2.5, end=7.5)
    full, = load_experiments(SAMPLE)
    k = int(np.flatnonzero(full.z == exp.z[0])[0])
    np.testing.assert_array_equal(exp.z, full.z[k:k + exp.z.size])
    assert 2400 <= k <= 2600
    assert exp.duration == pytest.approx(5.0, abs=2e-3)
    with pytest.raises(DataError, match='holds no message'):
        load_experiments(split, start=100.0)
    with pytest.raises(BagError, match='`end`'):
        open_bag(split, start=3.0, end=2.0)
    with pytest.raises(BagError, match='`start`'):
        open_bag(split, start=float('nan'))


def test_identify_command_fits_a_window(tmp_path):
    res = subprocess.run([sys.executable, '-m', 'ros_ehs.tools.cli', 'identify', str(SAMPLE),
                          '--start', '1', '--end', '6', '--no-figures', '--quiet',
                          '--out', str(tmp_path / 'id')], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert 'sample_sine_1hz [1-6 s]' in res.stdout
    res = subprocess.run([sys.executable, '-m', 'ros_ehs.tools.cli', 'identify', str(SAMPLE),
                          '--start', '50', '--out', str(tmp_path / 'none')],
                         capture_output=True, text=True)
    assert res.returncode == 2 and 'holds no message' in res.stderr
    assert 'Traceback' not in res.stderr


# -- write errors ------------------------------------------------------------------------------
_LIMITED = textwrap.dedent("""
    import resource, sys
    resource.setrlimit(resource.RLIMIT_FSIZE, (300_000, 300_000))   # Python ignores SIGXFSZ
    from ros_ehs.data.bag import BagWriter
    from ros_ehs.core.errors import BagWriteError
    import ros_ehs_msgs_py as c
    w = BagWriter(sys.argv[1], compression='none', flush_period=1e-4)
    w.add_topic('/state', c.STATE.msg_type, c.STATE.qos)
    k = 0
    try:
        while True:
            ns = 1_000_000_000 + k * 1_000_000
            w.write_msg('/state', c.fill_state(c.empty_msg(c.STATE.msg_type),
                        c.AxisState(ns, float(k), 0.0)), ns)
            k += 1
    except BagWriteError as err:
        print('ERROR', err)
        try:
            w.write_msg('/state', c.fill_state(c.empty_msg(c.STATE.msg_type),
                        c.AxisState(0, 0.0, 0.0)), 0)
        except BagWriteError:
            print('STOPPED')
    w.close()
    print('WRITTEN', k, 'FLUSHED', w.metadata(flushed=True)['message_count'])
    print('METADATA_ERROR', repr(w.metadata_error))
""")


def test_a_write_error_stops_the_bag_and_keeps_what_was_flushed(tmp_path):
    bag = tmp_path / 'limited'
    res = subprocess.run([sys.executable, '-c', _LIMITED, str(bag)], capture_output=True,
                         text=True, timeout=120)
    out = res.stdout
    assert res.returncode == 0, res.stderr
    assert "ERROR write error writing '" + str(bag / 'limited_0.mcap') in out
    assert 'errno 27' in out and 'MB free on its filesystem' in out and 'STOPPED' in out
    assert "METADATA_ERROR ''" in out
    written = int(out.split('WRITTEN ')[1].split()[0])
    flushed = int(out.split('FLUSHED ')[1].split()[0])
    b = open_bag(bag)
    zs = [c.state_from_msg(m).z for _, m in b.decoded(['/state'])]
    assert zs == list(range(len(zs))) and len(zs) == flushed and 0.9 * written <= flushed
    assert _meta(bag)['message_count'] == flushed
    assert (bag / 'limited_0.mcap').stat().st_size <= 300_000
    assert sorted(os.listdir(bag)) == ['limited_0.mcap', 'metadata.yaml']


def _tmpfs_available():
    if shutil.which('unshare') is None:
        return False
    r = subprocess.run(['unshare', '-m', 'sh', '-c', 'mount -t tmpfs -o size=1m tmpfs /mnt'],
                       capture_output=True)
    return r.returncode == 0


def test_a_full_disk_during_a_bench_leaves_a_readable_bag_and_one_line(dom, tmp_path):
    """The bench on a 2 MB tmpfs (its own mount namespace): the recorder fills it."""
    assert _tmpfs_available(), 'this test needs unshare -m and tmpfs (root or user namespaces)'
    mnt = tmp_path / 'small'
    mnt.mkdir()
    env = dict(os.environ)
    script = (f'mount -t tmpfs -o size=2m tmpfs {mnt} && '
              f'{sys.executable} {ROOT / "launch_scripts" / "bench.py"} --duration 30 '
              f'--out {mnt}/run --compression none --min-free-space 0 --domain-id {dom}; rc=$?; '
              f'cp -r {mnt}/run {tmp_path}/copy; exit $rc')
    res = subprocess.run(['unshare', '-m', 'sh', '-c', script], capture_output=True,
                         text=True, env=env, cwd=tmp_path, timeout=180)
    assert res.returncode == 1, res.stdout + res.stderr
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith('bench: recorder error')]
    assert len(errors) == 1, res.stderr
    assert 'disk full' in errors[0] and str(mnt / 'run' / 'run_0.mcap') in errors[0]
    assert 'MB free' in errors[0] and 'metadata.yaml written' in errors[0]
    assert 'Traceback' not in res.stdout + res.stderr
    kept = int(errors[0].split('; ')[-2].split()[0])
    b = open_bag(tmp_path / 'copy')
    assert b.message_count == kept > 1000 and b.topics['/state'].count > 200
    assert _meta(tmp_path / 'copy')['message_count'] == kept
    # it warned as space ran low (2 MB is below the default 1 GB warning level)
    log = (tmp_path / 'out' / 'logs' / 'run' / 'recorder.log').read_text()
    assert log.count('disk space low') == 1 and 'recording stops at' in log


def test_below_min_free_space_the_recorder_stops_cleanly(dom, tmp_path):
    """
    On a 4 MB tmpfs with min_free_space 2 MB: a clean stop before the disk is full.

    Uncompressed, so the bench fills the 2 MB sooner (the test took 17 s with zstd, 14 s so).
    """
    assert _tmpfs_available(), 'this test needs unshare -m and tmpfs (root or user namespaces)'
    mnt = tmp_path / 'small'
    mnt.mkdir()
    script = (f'mount -t tmpfs -o size=4m tmpfs {mnt} && '
              f'{sys.executable} {ROOT / "launch_scripts" / "bench.py"} --duration 60 '
              f'--out {mnt}/run --min-free-space 2000000 --compression none '
              f'--domain-id {dom}; rc=$?; '
              f'cp -r {mnt}/run {tmp_path}/copy; exit $rc')
    res = subprocess.run(['unshare', '-m', 'sh', '-c', script], capture_output=True,
                         text=True, cwd=tmp_path, timeout=180)
    assert res.returncode == 1, res.stdout + res.stderr
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith('bench: recorder error')]
    assert len(errors) == 1 and 'stopped recording to' in errors[0], res.stderr
    assert 'below min_free_space = 2.0 MB' in errors[0]
    kept = int(errors[0].split('; ')[-2].split()[0])
    b = open_bag(tmp_path / 'copy')
    assert not b.truncated and b.message_count == kept > 1000      # closed properly
    assert _meta(tmp_path / 'copy')['message_count'] == kept
    from rosbags.rosbag2 import Reader
    with Reader(tmp_path / 'copy') as r:                          # a complete bag
        assert r.message_count == kept


def test_a_split_sqlite3_bag_reads_as_one_bag(tmp_path):
    """Two .db3 files written by rosbags, listed by one metadata.yaml, as rosbag2 splits."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    src = open_bag(SAMPLE)
    msgs = list(src.messages())
    half = len(msgs) // 2
    bag = tmp_path / 'split'
    bag.mkdir()
    infos = []
    for k, part in enumerate((msgs[:half], msgs[half:])):
        d = tmp_path / f'part{k}'
        with Writer(d, version=8, storage_plugin=StoragePlugin.SQLITE3) as w:
            conns = {t: w.add_connection(t, i.msg_type, typestore=ts)
                     for t, i in src.topics.items()}
            for m in part:
                w.write(conns[m.topic], m.log_time_ns, m.data)
        next(d.glob('*.db3')).rename(bag / f'split_{k}.db3')
        infos.append(_meta(d))
    info = infos[0]
    info['relative_file_paths'] = ['split_0.db3', 'split_1.db3']
    info['message_count'] = len(msgs)
    (bag / 'metadata.yaml').write_text(yaml.safe_dump({'rosbag2_bagfile_information': info}))
    b = open_bag(bag)
    assert [p.name for p in b.files] == ['split_0.db3', 'split_1.db3']
    assert b.message_count == len(msgs) and not b.truncated
    a, = load_experiments(bag)
    ref, = load_experiments(SAMPLE)
    np.testing.assert_array_equal(a.z, ref.z)
