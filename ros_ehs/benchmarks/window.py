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
``python -m ros_ehs.benchmarks window``: the demo run's bench, window by window, beside bare rclpy.

The demo run's target is that a 10 s bench has no late command (a command over 3 periods old
at a period's end: the plant's ``late_commands``; a *trip* here) *on a quiet machine*. This
benchmark says which windows were quiet. It runs ``--windows`` pairs of ``--seconds`` long
windows, alternating (ours first, then the bare loop first, ...):

* **ours**: ``launch_scripts/bench.py`` as the demo run runs it (plant, controller,
  reference and recorder, real time, ``--rt-priority``), from its ``loop running`` to its
  ``stopping``; the trips of the start-up before that are counted apart
  (``ours_trips_in_start_up``, and of those the ones in a machine stall or hiccup that the
  probes, started before the bench, saw);
* **bare**: the barest rclpy ping-pong (``ros_ehs.benchmarks.pingpong``, no code of ours) at the
  same priority, with the plant's late-command rule.

In every window a machine probe runs on each CPU (``ros_ehs.benchmarks.sleeper``: a 1 kHz sleep
loop without ROS, same priority). A window is *quiet* when no probe was held over 2 ms in it:
a stall that long makes any 1 kHz loop's command late. Per window it prints the
trips, the stalls and how many trips fell in one; the last line is one JSON object with the
trip-free share of all windows and of the quiet ones, ours and bare.

Shorter hiccups do not make a window loud, but a trip in a quiet window is checked against
them: a probe gap whose own part (not queued behind other threads on its CPU) is over
``HICCUP_MS`` (:func:`~ros_ehs.benchmarks.sleeper.hiccups`) on the loop's CPU (any, unplaced),
counted as ``*_quiet_trips_in_hiccups``. A 1 kHz probe sees only the hiccups that overlap
its own wake-ups, so a trip outside one is not proven ours.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time
from typing import Iterator

from domain_coordinator import domain_id
from ros_ehs.benchmarks import BOUND, count, positive, report, wait_first_echo
from ros_ehs.benchmarks.sleeper import coincident, command, HICCUP_MS, hiccups, STALL_MS
from ros_ehs.nodes.fastdds_profile import ENV
from ros_ehs.nodes.processes import launch_script, loop_placement, NodeProcesses

BENCH = launch_script('bench.py')
RT_PROFILE = BENCH.with_name('fastdds_rt.xml')


@contextlib.contextmanager
def _probes(rt_priority: int) -> Iterator[dict[int, subprocess.Popen]]:
    """
    Run a machine probe on each CPU this process may use: ``{cpu: process}``.

    :func:`_stalls` stops them; whatever is still running when the block ends (a window
    that failed) is killed, so no probe outlives the benchmark.
    """
    probes: dict[int, subprocess.Popen] = {}
    try:
        for c in sorted(os.sched_getaffinity(0)):
            probes[c] = subprocess.Popen(command(c, HICCUP_MS, rt_priority),
                                         stdout=subprocess.PIPE, text=True)
        yield probes
    finally:
        for p in probes.values():
            if p.poll() is None:
                p.kill()
            p.communicate()


def _stalls(probes: dict[int, subprocess.Popen]) -> tuple[list[tuple], list[tuple]]:
    """
    Stop the probes; return what they saw.

    The stalls, gaps over STALL_MS, and the hiccups (see
    :func:`~ros_ehs.benchmarks.sleeper.hiccups`), each as ``(end, ms, cpu)``.
    """
    stalls, hics = [], []
    for cpu, p in probes.items():
        p.send_signal(signal.SIGINT)
        out, _ = p.communicate(timeout=10)
        gaps = json.loads(out.strip().splitlines()[-1])['gaps']
        stalls += [(g[0], g[1], cpu) for g in gaps if g[1] > STALL_MS]
        hics += [(e, g, cpu) for e, g in hiccups(gaps)]
    return sorted(stalls), sorted(hics)


def _within(gaps: list[tuple], t0: float, t1: float) -> list[tuple]:
    """Return the gaps ``(end, ms, cpu)`` that overlap ``[t0, t1]``."""
    return [g for g in gaps if g[0] >= t0 and g[0] - g[1] * 1e-3 <= t1]


def _explained(trips: list[tuple], stalls: list[tuple], hics: list[tuple],
               loop_cpu: int | None) -> tuple[list[bool], list[bool]]:
    """Say, per trip, whether it fell in a stall and, if not, whether in a hiccup."""
    in_stall = coincident(trips, [(e, g) for e, g, _ in stalls])
    # a hiccup counts on the loop's CPU (anywhere, unplaced)
    near = coincident(trips, [(e, g) for e, g, cpu in hics if loop_cpu in (None, cpu)])
    return in_stall, [h and not s for h, s in zip(near, in_stall)]


def _ours(dom: int, seconds: float, prio: int, pin: bool, tmp: Path,
          i: int) -> tuple[list, float, float]:
    """
    Run the demo run's bench; return its trips ``(t, ms)`` and the window's span.

    The window runs from the bench's ``loop running`` (the loop closed, the reference and the
    recorder in) to its ``stopping``; the plant's trip log also holds the trips of the
    start-up before it, which the caller counts apart.
    """
    env = dict(os.environ, ROS_DOMAIN_ID=str(dom))
    logs = tmp / f'w{i}_logs'
    cmd = [sys.executable, str(BENCH), '--duration', str(seconds), '--out',
           str(tmp / f'w{i}'), '--log-dir', str(logs), '--no-machine-probe']
    cmd += ['--rt-priority', str(prio)] if prio else []
    cmd.append('--cpu-affinity' if pin else '--no-cpu-affinity')
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                         env=env)
    t0 = t1 = None
    lines = []
    for line in p.stdout:
        lines.append(line)
        if t0 is None and 'loop running' in line:
            t0 = time.monotonic()
        elif t1 is None and line.startswith('bench: stopping'):
            t1 = time.monotonic()      # the window ends here: what follows is shutting down
    if p.wait() != 0 or t0 is None or t1 is None:
        raise RuntimeError(f'the bench failed (exit {p.returncode}):\n' + ''.join(lines[-30:]))
    f = json.loads((logs / 'plant.figures.json').read_text())
    return [(t, age) for t, _, age, _ in f['late_log']], t0, t1


def _bare(dom: int, seconds: float, prio: int, pin: bool) -> tuple[list, float, float]:
    """Run the bare ping-pong; return its trips ``(t, ms)`` and the measured span."""
    rt = ['--rt-priority', str(prio)] if prio else []
    cpus = loop_placement(True) if pin else None
    if cpus:      # ping and pong on one CPU, as bench.py --cpu-affinity places ours
        rt += ['--cpu', str(cpus[0])]
    env = {ENV: str(RT_PROFILE)} if prio else {}
    with NodeProcesses(dom, env=env, bound=BOUND) as bare:
        for role in ('pong', 'ping'):
            bare.start(role, cmd=[sys.executable, '-m', 'ros_ehs.benchmarks.pingpong', role, *rt])
        wait_first_echo(bare['ping'])       # as ours counts from the loop's start
        t0 = time.monotonic()
        time.sleep(seconds)
        t1 = time.monotonic()
        codes = bare.stop(['ping', 'pong'])
        said = bare['ping'].output().strip()
        try:
            f = json.loads(said.splitlines()[-1])
        except (IndexError, ValueError):
            raise RuntimeError(f'the bare ping-pong left no figures (ping exit {codes["ping"]}, '
                               f'pong exit {codes["pong"]}); ping said:\n{said[-2000:]}'
                               ) from None
    # trips in the warm-up are not in the window (ours count from the loop's start)
    return [(t, ms) for t, ms in f['late_log'] if t >= t0], t0, t1


def main(argv=None) -> int:
    """Run the benchmark; print one line per window, then the figures, the last line JSON."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks window')
    ap.add_argument('--windows', type=count, default=8,
                    help='windows of ours and of the bare loop each')
    ap.add_argument('--seconds', type=positive, default=10.0, help='length of each window')
    ap.add_argument('--rt-priority', type=int, default=50,
                    help='SCHED_FIFO priority of the loop nodes, the bare ping-pong and the '
                    "probes (the demo run's 50; 0: the default scheduler)")
    ap.add_argument('--cpu-affinity', action=argparse.BooleanOptionalAction, default=True,
                    help='plant and controller on one CPU, the reference on another, as the '
                    "demo run places them, and the bare ping and pong on the plant's CPU; "
                    '--no-cpu-affinity: all left to the scheduler')
    a = ap.parse_args(argv)
    if not BENCH.is_file():
        print(f'window: needs a source checkout ({BENCH} not found)', file=sys.stderr)
        return 2
    rows = {'ours': [], 'bare': []}
    loop_cpu = loop_placement(True)[0] if a.cpu_affinity else None
    # our trips before a window (between the loop's closing and its start), and of those,
    # how many fell in a machine stall or, if not, a hiccup that the probes saw
    start_up = [0, 0, 0]
    with domain_id() as dom, tempfile.TemporaryDirectory(prefix='ehs_window_') as tmp:
        for i in range(a.windows):
            for kind in (('ours', 'bare') if i % 2 == 0 else ('bare', 'ours')):
                with _probes(a.rt_priority) as probes:
                    trips, t0, t1 = (
                        _ours(dom, a.seconds, a.rt_priority, a.cpu_affinity, Path(tmp), i)
                        if kind == 'ours' else
                        _bare(dom, a.seconds, a.rt_priority, a.cpu_affinity))
                    all_stalls, all_hics = _stalls(probes)
                early = [(t, ms) for t, ms in trips if t < t0]
                if early:
                    s_, h_ = _explained(early, all_stalls, all_hics, loop_cpu)
                    start_up = [start_up[0] + len(early), start_up[1] + sum(s_),
                                start_up[2] + sum(h_)]
                    print(f'window {i + 1} {kind}: {len(early)} late commands in the '
                          f'start-up ({sum(s_)} in a machine stall, {sum(h_)} more in a '
                          'hiccup)', flush=True)
                trips = [(t, ms) for t, ms in trips if t0 <= t <= t1]
                stalls, hics = _within(all_stalls, t0, t1), _within(all_hics, t0, t1)
                in_stall, in_hic = _explained(trips, stalls, hics, loop_cpu)
                hic = sum(in_hic)
                rows[kind].append((len(trips), len(stalls), sum(in_stall), hic))
                at = ', '.join(f'{g:.1f} ms on CPU {cpu} at {e - t0:.2f} s'
                               for e, g, cpu in stalls)
                print(f'window {i + 1} {kind}: {len(trips)} late commands in {t1 - t0:.1f} s '
                      f'({sum(in_stall)} in a machine stall, {hic} more in a hiccup); machine '
                      f'stalls over {STALL_MS:g} ms: {len(stalls)}{" (" + at + ")" if at else ""}'
                      f'; hiccups: {len(hics)}', flush=True)
    figures = {'windows': a.windows, 'seconds': a.seconds, 'rt_priority': a.rt_priority,
               'cpu_affinity': a.cpu_affinity}
    for kind, r in rows.items():
        quiet = [(t, h) for t, s, _, h in r if s == 0]
        figures.update({
            f'{kind}_trip_free_windows': sum(t == 0 for t, *_ in r),
            f'{kind}_quiet_windows': len(quiet),
            f'{kind}_quiet_trip_free_windows': sum(t == 0 for t, _ in quiet),
            f'{kind}_late_commands': sum(t for t, *_ in r),
            f'{kind}_trips_in_machine_stalls': sum(x[2] for x in r),
            f'{kind}_quiet_trips': sum(t for t, _ in quiet),
            f'{kind}_quiet_trips_in_hiccups': sum(h for _, h in quiet),
        })
    figures['ours_trips_in_start_up'] = start_up[0]
    figures['ours_start_up_trips_in_machine_stalls'] = start_up[1]
    figures['ours_start_up_trips_in_hiccups'] = start_up[2]
    figures['machine_stalled_windows'] = sum(x[1] > 0 for r in rows.values() for x in r)
    figures['targets_met'] = {
        # the demo run's target: on a quiet machine a 10 s run has no trip
        'quiet_windows_trip_free': figures['ours_quiet_trip_free_windows']
        == figures['ours_quiet_windows'],
    }
    return report(figures)


if __name__ == '__main__':
    sys.exit(main())
