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
"""Stale Fast DDS shared-memory files: found, removed; what a live process holds, kept."""

import fcntl
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import pytest
from ros_ehs.nodes.fastdds_shm import _locked, clean_zombies, main, SHM_DIR
from waits import BOUND


def _old(path: Path, data: bytes = b'x', age: float = 60.0) -> None:
    """Write ``path`` as a file last changed ``age`` s ago (left by an earlier run)."""
    path.write_bytes(data)
    t = time.time() - age
    os.utime(path, (t, t))


def _port(d: Path, n: int, locks=('_el',), age: float = 60.0) -> None:
    for name in (f'fastrtps_port{n}', f'sem.fastrtps_port{n}_mutex',
                 *(f'fastrtps_port{n}{s}' for s in locks)):
        _old(d / name, age=age)


def test_stale_ports_and_segments_go_and_held_ones_stay(tmp_path):
    d = tmp_path
    _port(d, 7000)                       # lock file, nobody holds it: a killed owner
    _port(d, 7001, locks=())             # no lock file at all: not seen by fastdds shm clean
    _port(d, 7002)                       # held below: a live listener
    _port(d, 7003, locks=('_sl',))       # shared lock held below: a live multicast listener
    for seg in ('0123456789abcdef', 'fedcba9876543210'):
        _old(d / f'fastrtps_{seg}')
        _old(d / f'fastrtps_{seg}_el', b'')
    _old(d / 'fastrtps_0000000000000000_el', b'')          # a lock without its segment
    for other in ('lttng-ust-wait-6', 'sem.other_mutex', 'fastrtps_portx', 'fastrtps_port123456',
                  'fastrtps_short_el'):
        (d / other).write_bytes(b'keep')
    names = ('fastrtps_port7002_el', 'fastrtps_port7003_sl', 'fastrtps_fedcba9876543210_el')
    held = [os.open(d / n, os.O_RDONLY) for n in names]
    fcntl.flock(held[0], fcntl.LOCK_EX)
    fcntl.flock(held[1], fcntl.LOCK_SH)
    fcntl.flock(held[2], fcntl.LOCK_EX)
    try:
        res = clean_zombies(d)
        left = sorted(p.name for p in d.iterdir())
        again = clean_zombies(d)         # nothing left to do while they are held
    finally:
        for fd in held:
            os.close(fd)
    assert res.ports_removed == 2 and res.segments_removed == 1 and res.in_use == 3, res
    assert set(res.removed) == {
        'fastrtps_port7000', 'fastrtps_port7000_el', 'sem.fastrtps_port7000_mutex',
        'fastrtps_port7001', 'sem.fastrtps_port7001_mutex',
        'fastrtps_0123456789abcdef', 'fastrtps_0123456789abcdef_el',
        'fastrtps_0000000000000000_el'}
    assert left == sorted([
        'fastrtps_fedcba9876543210', 'fastrtps_fedcba9876543210_el', 'fastrtps_port7002',
        'fastrtps_port7002_el', 'fastrtps_port7003', 'fastrtps_port7003_sl', 'fastrtps_portx',
        'fastrtps_port123456', 'fastrtps_short_el', 'lttng-ust-wait-6',
        'sem.fastrtps_port7002_mutex', 'sem.fastrtps_port7003_mutex', 'sem.other_mutex'])
    assert '2 stale Fast DDS shared-memory port(s) and 1 segment(s)' in res.summary()
    assert again.removed == () and again.in_use == 3
    released = clean_zombies(d)          # their holders gone: stale in turn
    assert released.ports_removed == 2 and released.segments_removed == 1
    assert sorted(p.name for p in d.iterdir()) == sorted([
        'fastrtps_portx', 'fastrtps_port123456', 'fastrtps_short_el', 'lttng-ust-wait-6',
        'sem.other_mutex'])


def test_files_changed_in_the_last_ten_seconds_are_left_untested(tmp_path):
    """A port a participant is just setting up may not be locked yet: it stays."""
    _port(tmp_path, 7200, age=1.0)                    # unlocked, but just made
    _port(tmp_path, 7201, locks=(), age=1.0)
    _old(tmp_path / 'fastrtps_0123456789abcdef_el', b'', age=1.0)   # a lock without segment
    _port(tmp_path, 7202)                             # the same, a minute old: stale
    before = sorted(p.name for p in tmp_path.iterdir())
    res = clean_zombies(tmp_path)
    assert res.ports_removed == 1 and res.in_use == 2, res
    assert set(res.removed) == {'fastrtps_port7202', 'fastrtps_port7202_el',
                                'sem.fastrtps_port7202_mutex'}
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        n for n in before if '7202' not in n]
    # one file of a port changed lately (its mutex) keeps the whole port
    _port(tmp_path, 7203)
    _old(tmp_path / 'sem.fastrtps_port7203_mutex', age=1.0)
    assert 'fastrtps_port7203' not in clean_zombies(tmp_path).removed
    everything = clean_zombies(tmp_path, min_age=0.0)  # what a caller who knows may ask
    assert everything.ports_removed == 3 and 'fastrtps_0123456789abcdef_el' in everything.removed
    for bad in (-1.0, float('nan'), float('inf'), '10'):
        with pytest.raises(ValueError, match='min_age: .* is not a finite number of seconds'):
            clean_zombies(tmp_path, min_age=bad)


def test_a_bad_directory_is_named(tmp_path, capsys):
    with pytest.raises(ValueError, match=r"shm_dir: '.*nowhere' is not a directory"):
        clean_zombies(tmp_path / 'nowhere')
    assert main([str(tmp_path / 'nowhere')]) == 2
    assert 'is not a directory' in capsys.readouterr().err
    _port(tmp_path, 7100)
    assert main([str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert 'removed fastrtps_port7100\n' in out and '1 stale Fast DDS' in out


def _files_of(pid: int) -> set:
    """Return the names of the /dev/shm files process ``pid`` has open or mapped."""
    names = set()
    for line in Path(f'/proc/{pid}/maps').read_text().splitlines():
        if '/dev/shm/fastrtps_' in line:
            names.add(line.split('/dev/shm/')[1].split()[0])
    for fd in Path(f'/proc/{pid}/fd').iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith('/dev/shm/fastrtps_'):
            names.add(target[len('/dev/shm/'):].split()[0])
    return names


@pytest.mark.ros
@pytest.mark.skipif(not SHM_DIR.is_dir(), reason='no /dev/shm on this machine')
def test_real_fast_dds_files_are_kept_while_alive_and_removed_once_killed(dom):
    """A bare rclpy participant's own files: kept while it runs; stale after SIGKILL."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(dom), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    code = ('import rclpy, time; rclpy.init(); n = rclpy.create_node("shm_probe"); '
            'print("up", flush=True); time.sleep(3600)')     # killed below
    p = subprocess.Popen([sys.executable, '-c', code], env=env, stdout=subprocess.PIPE,
                         text=True)
    try:
        assert p.stdout.readline().strip() == 'up'
        deadline = time.monotonic() + BOUND
        while time.monotonic() < deadline:
            own = {n for n in _files_of(p.pid) if n.startswith('fastrtps_port')}
            if own:
                break
            time.sleep(0.1)
        assert own, 'the participant opened no shared-memory port'
        res = clean_zombies()
        present = {f.name for f in SHM_DIR.iterdir()}
        assert own <= present, f'removed a live port: {own - present}'
        assert not own & set(res.removed)
        held = {n + s for n in own for s in ('_el', '_sl') if _locked(SHM_DIR / (n + s))}
        assert held, f'no lock held on {own}'
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait(BOUND)
    # the ports only this participant listened on: their locks died with it
    mine = {n for n in held if _locked(SHM_DIR / n) is False}
    assert mine, 'SIGKILL left no stale port'
    res = clean_zombies(min_age=0.0)           # they were made seconds ago
    stale = mine | {n[:-3] for n in mine}
    assert stale <= set(res.removed), res
    assert not stale & {f.name for f in SHM_DIR.iterdir()}
