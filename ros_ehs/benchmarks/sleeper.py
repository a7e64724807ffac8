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
The machine alone: a 1 kHz sleep loop with no ROS at all, the floor under ``bench loop``.

``python -m ros_ehs.benchmarks.sleeper --seconds S [--rt-priority N] [--cpu C] [--gaps-over MS]``.
One Python thread sleeps to each millisecond of a steady grid, as the plant's timer does, and
counts the periods it was not given the CPU for: ``stalls_2ms`` counts the gaps between ticks
longer than 2 ms (consecutive long gaps once), which is what the plant's watchdog rule (3
periods, the last one ending at the next tick) trips on with a round trip of zero. rclpy is
not imported: whatever stalls here stalls every process, ours and the bare ping-pong alike.
Prints one JSON line.

``--seconds 0`` runs until SIGINT or SIGTERM (a probe beside a bench: ``launch_scripts/
bench.py`` runs one on each CPU); ``--gaps-over MS`` also lists the gaps longer than MS as
``[end, length, waited]`` (``time.monotonic()`` seconds, ms, ms), the newest ``MAX_GAPS``, so
that :func:`coincident` can tell whether a watchdog trip of the plant fell in a stall of the
machine. ``waited`` is the part of the gap the probe spent ready to run but queued behind
other threads on its CPU (the kernel's ``/proc/thread-self/schedstat``; null where the kernel
does not keep it). The rest of a gap is the machine's own: the probe's timer fired late, or
the vCPU was not running. :func:`hiccups` picks the gaps whose own part is over
``HICCUP_MS``: a probe the machine woke 0.3 ms late or more, which a scheduler trace of two
of the plant's trips showed to be enough (the vCPU idle with timers due for 0.3-0.6 ms, then
running ~20x slower).
"""

import argparse
from collections import deque
import json
import os
import signal
import sys
import time

__all__ = ['coincident', 'command', 'hiccups', 'HICCUP_MS', 'main', 'MAX_GAPS', 'STALL_MS']

#: Gaps kept by ``--gaps-over`` (the newest): bounded however long the probe runs.
MAX_GAPS = 1000
#: A gap this long [ms] is a stall of the machine (``stalls_2ms``): a loop held this long
#: trips the plant's 3-period watchdog at 1 kHz with a round trip of zero.
STALL_MS = 2.0
#: A gap whose own part (not queued behind other threads) is this long [ms] is a hiccup of
#: the machine: the probe's 1 ms timer fired 0.3 ms late or more.
HICCUP_MS = 1.3


def hiccups(gaps: list, over: float = HICCUP_MS) -> list[tuple[float, float]]:
    """
    Return ``(end, ms)`` of the probe gaps ``[end, ms, waited]`` that the machine made.

    A gap counts when its length less the time the probe waited behind other threads on its
    CPU is over ``over`` [ms]: a probe held by busy threads (ours) is not the machine's.
    Gaps without ``waited`` (a kernel without schedstat) count whole. That holds for a probe
    on SCHED_FIFO, as ``launch_scripts/bench.py`` runs them with ``--rt-priority``: only
    threads at its priority or above can keep it waiting. On the default scheduler the
    machine's own tasks can too (a guest's init, the kernel's ``kdamond``), and their
    part of the wait is left out here.
    """
    return [(g[0], g[1]) for g in gaps
            if g[1] - (g[2] if len(g) > 2 and g[2] is not None else 0.0) > over]


def _rq_wait(fd: int | None) -> int:
    """Return this thread's run-queue wait so far [ns] (0 without schedstat)."""
    return int(os.pread(fd, 64, 0).split()[1]) if fd is not None else 0


def command(cpu: int, gaps_over: float, rt_priority: int = 0) -> list[str]:
    """Return the command line of a probe on ``cpu`` that runs until SIGINT or SIGTERM."""
    rt = ['--rt-priority', str(rt_priority)] if rt_priority else []
    return [sys.executable, '-m', 'ros_ehs.benchmarks.sleeper', '--seconds', '0', '--cpu',
            str(cpu), '--gaps-over', str(gaps_over), *rt]


def coincident(spans: list[tuple[float, float]],
               gaps: list[tuple[float, float]]) -> list[bool]:
    """
    Say, for each span, whether a probe's gap overlaps it.

    ``spans``: ``(t, ms)``, the span ``[t - ms, t]`` (``time.monotonic()`` seconds; a tick
    that ran ``ms`` late at ``t``, or a watchdog trip at ``t`` after ``ms`` without a fresh
    command); ``gaps``: ``(end, ms)`` from the probes, each a span ``[end - ms, end]`` in which
    a probe was not run. They must overlap by at least a quarter of the shorter one (clock
    reads and wake-ups take some microseconds).
    """
    held = [(end - g * 1e-3, end, g) for end, g in gaps]
    return [any(min(t, hi) - max(t - ms * 1e-3, lo) >= 0.25e-3 * min(ms, g)
                for lo, hi, g in held) for t, ms in spans]


def main(argv=None) -> int:
    """Run the loop for ``--seconds`` (0: until a signal); print its figures as one JSON line."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks.sleeper')
    ap.add_argument('--seconds', type=float, default=20.0, help='0: until SIGINT or SIGTERM')
    ap.add_argument('--rt-priority', type=int, default=0,
                    help='SCHED_FIFO priority, as the loop nodes and the bare ping-pong get')
    ap.add_argument('--cpu', type=int, default=-1, help='run on this CPU only')
    ap.add_argument('--gaps-over', type=float, default=0.0,
                    help='list the gaps longer than this [ms] (0: none)')
    ap.add_argument('--progress', type=int, default=0, help='every this many ticks, print a '
                    'line `progress TICKS GAPS` (0: none), for whoever waits on it')
    a = ap.parse_args(argv)
    if a.seconds < 0 or a.gaps_over < 0 or a.progress < 0:
        ap.error('--seconds, --gaps-over and --progress must be >= 0')
    said = []      # unprivileged, or no such CPU: run on, and say so
    if a.rt_priority:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(a.rt_priority))
        except OSError as err:
            said.append(f'rt_priority not applied: {err.strerror}')
    if a.cpu >= 0:
        try:
            os.sched_setaffinity(0, {a.cpu})
        except OSError as err:
            said.append(f'cpu not applied: {err.strerror}')
    stop = []
    if a.seconds == 0:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.append(1))
    period = 1_000_000
    stall = int(STALL_MS * 1e6)
    n = int(a.seconds * 1000) if a.seconds else -1
    over = int(a.gaps_over * 1e6) if a.gaps_over else None
    gaps = deque(maxlen=MAX_GAPS)
    stalls, stalled, top, ticks = 0, False, 0, 0
    try:
        fd = os.open('/proc/thread-self/schedstat', os.O_RDONLY) if over is not None else None
    except OSError:
        fd = None
    waited = _rq_wait(fd)
    last = nxt = time.monotonic_ns()
    while ticks != n and not stop:
        nxt += period
        d = nxt - time.monotonic_ns()
        if d > 0:
            time.sleep(d * 1e-9)
        now = time.monotonic_ns()
        gap = now - last
        last = now
        ticks += 1
        top = max(top, gap)
        long = gap > stall
        stalls += long and not stalled
        stalled = long
        if over is not None:
            w, waited = waited, _rq_wait(fd)
            if gap > over:
                gaps.append((now * 1e-9, gap * 1e-6, (waited - w) * 1e-6))
        if a.progress and ticks % a.progress == 0:
            print(f'progress {ticks} {len(gaps)}', flush=True)
    f = {'ticks': ticks, 'stalls_2ms': stalls, 'max_gap_ms': top * 1e-6}
    if over is not None:
        f['gaps'] = [[round(e, 6), round(g, 4), round(w, 4) if fd is not None else None]
                     for e, g, w in gaps]
    if said:
        f['not_applied'] = said
    print(json.dumps(f), flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
