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
Find and remove the shared-memory files Fast DDS left behind (no ROS import).

Fast DDS's shared-memory transport keeps, in ``/dev/shm``, each listening port as
``fastrtps_port<N>`` with a lock file ``fastrtps_port<N>_el`` (or ``_sl``) and a mutex
``sem.fastrtps_port<N>_mutex``, and each participant's data segment as
``fastrtps_<16 characters>`` with a lock file ``_el``. A live process holds a lock on the
lock file of every port it listens on and of its segment (tested). A process that does not
exit cleanly (killed, crashed) leaves its files behind. Ports without any lock file were
found too, left by earlier runs (how they lost it was not traced).

Why it matters to a real-time bench: a participant that later takes the same port number
reuses such a port, with the timeouts its first creator stored in it. Fast DDS waits on a
port for a third of its ``healthy_check_timeout_ms`` (1000 ms by default): 333 ms. With
stale ports from earlier runs in ``/dev/shm``, a node joining a running loop (all nodes with
``launch_scripts/fastdds_rt.xml``, whose 30 ms applies only to ports created under it) can
reuse a port created without that profile, and block the plant's publish for 333 ms: a
watchdog trip. Removing those files first avoids it (docs/nodes.md).

:func:`clean_zombies` removes every port and segment that no live process holds, as
``fastdds shm clean`` does, and also the ports left without a lock file, which that tool
does not list. A lock is tested with ``flock`` (what Fast DDS takes); a file that cannot be
tested is left alone. Files changed in the last ``min_age`` seconds (10 s) are not even
tested: a port another participant is just setting up may not be locked yet, and the brief
``flock`` that tests it could make its creator's own lock fail; so it may run while
participants start, as the test suite's workers start theirs (running participants are safe
whatever their age). ``python -m ros_ehs.nodes.fastdds_shm`` runs it and prints what it
removed; :class:`ros_ehs.nodes.processes.NodeProcesses` and ``launch_scripts/bench.py`` run it
before starting nodes.
"""

from __future__ import annotations

from dataclasses import dataclass
import fcntl
import os
from pathlib import Path
import re
import sys
import time

__all__ = ['SHM_DIR', 'ShmCleanup', 'clean_zombies', 'main']

#: Where Fast DDS keeps its shared memory on Linux.
SHM_DIR = Path('/dev/shm')

_PORT = re.compile(r'^fastrtps_port(\d{1,5})$')
_SEGMENT = re.compile(r'^fastrtps_[0-9a-z]{16}$')
_LOCKS = ('_el', '_sl')
#: Files changed more recently than this [s] are left untested (see the module docstring).
MIN_AGE = 10.0


@dataclass(frozen=True)
class ShmCleanup:
    """What :func:`clean_zombies` did: file names removed, ports and segments kept in use."""

    removed: tuple[str, ...]
    ports_removed: int
    segments_removed: int
    in_use: int

    def summary(self) -> str:
        """Return one line for a log."""
        return (f'{self.ports_removed} stale Fast DDS shared-memory port(s) and '
                f'{self.segments_removed} segment(s) removed, {self.in_use} in use kept')


def _locked(path: Path) -> bool | None:
    """Return whether a live process holds a lock on ``path`` (None: it does not exist)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return None
    except OSError:
        return True             # cannot test it: leave it alone
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return False
    finally:
        os.close(fd)


def _remove(path: Path, removed: list[str]) -> None:
    try:
        path.unlink()
    except FileNotFoundError:
        return
    except OSError:
        return                  # not ours to remove (permissions): Fast DDS copes as before
    removed.append(path.name)


def clean_zombies(shm_dir: str | os.PathLike = SHM_DIR, min_age: float = MIN_AGE) -> ShmCleanup:
    """
    Remove Fast DDS's ports and segments in ``shm_dir`` that no live process holds.

    A port or segment is in use when any of its lock files is locked; one whose lock files
    are all unlocked or missing is stale, and its files (segment, lock files, a port's
    mutex) are removed. One with a file changed less than ``min_age`` s ago is counted in
    use, untested. Nothing else in ``shm_dir`` is touched. Raises ValueError when
    ``shm_dir`` is not a directory or ``min_age`` is not a finite number >= 0.
    """
    d = Path(shm_dir)
    if not d.is_dir():
        raise ValueError(f'shm_dir: {str(d)!r} is not a directory')
    if not (isinstance(min_age, (int, float)) and 0.0 <= min_age < float('inf')):
        raise ValueError(f'min_age: {min_age!r} is not a finite number of seconds >= 0')
    since = time.time() - float(min_age)

    def young(*paths: Path) -> bool:
        for path in paths:
            try:
                if path.stat().st_mtime > since:
                    return True
            except OSError:
                pass
        return False
    removed: list[str] = []
    ports = segments = in_use = 0
    for name in sorted(os.listdir(d)):
        port = _PORT.match(name)
        if not (port or _SEGMENT.match(name)):
            continue
        if young(d / name, *(d / (name + s) for s in _LOCKS), d / f'sem.{name}_mutex'):
            in_use += 1
            continue
        held = [_locked(d / (name + s)) for s in _LOCKS]
        if any(held):
            in_use += 1
            continue
        before = len(removed)
        _remove(d / name, removed)
        for s in _LOCKS:
            _remove(d / (name + s), removed)
        if port:
            _remove(d / f'sem.{name}_mutex', removed)
        if len(removed) > before:
            ports += bool(port)
            segments += not port
    # lock files whose port or segment is already gone, unlocked: left by a crash
    for name in sorted(os.listdir(d)):
        base = name[:-3]
        if name.endswith(_LOCKS) and (_PORT.match(base) or _SEGMENT.match(base)) and \
                not (d / base).exists() and not young(d / name) and \
                _locked(d / name) is False:
            _remove(d / name, removed)
    return ShmCleanup(tuple(removed), ports, segments, in_use)


def main(argv=None) -> int:
    """``python -m ros_ehs.nodes.fastdds_shm [DIR]``: remove stale files; print what went."""
    args = sys.argv[1:] if argv is None else list(argv)
    if len(args) > 1 or (args and args[0] in ('-h', '--help')):
        print('usage: python -m ros_ehs.nodes.fastdds_shm [SHM_DIR]  (default /dev/shm)')
        return 0 if args and args[0] in ('-h', '--help') else 2
    try:
        res = clean_zombies(args[0] if args else SHM_DIR)
    except ValueError as err:
        print(f'fastdds_shm: {err}', file=sys.stderr)
        return 2
    for name in res.removed:
        print(f'removed {name}')
    print(res.summary())
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
