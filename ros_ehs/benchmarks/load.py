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
``python -m ros_ehs.benchmarks load``: the piston on the real-time bench, quiet and loaded.

Each case runs the README's real-time bench as ``launch_scripts/bench.py`` starts it (plant,
controller, the reference's paper sine of 40 mm at 1 Hz and the recorder, placed as
:meth:`~ros_ehs.nodes.processes.NodeProcesses.start_loop` places them, with the command's
defaults: plant and controller on SCHED_FIFO 50, ``--rt-priority 0`` for the default
scheduler; the Fast DDS profile ``fastdds_rt.xml`` with it, as the bench) for ``--seconds``,
beside one load a user brings:

* ``quiet``: nothing else (run first and last: the yardstick, and the machine's drift);
* ``busy``: two processes spinning at normal priority;
* ``browser``: the station beside the bench (on the reference's CPU, as the bench puts it)
  and its page open in headless Chromium (Debian's, driven by Playwright);
* ``live``: the identify node's live refits beside the bench (as ``--live-identify``);
* ``stall``: the controller stopped as a whole (SIGSTOP) for ``STALL`` s every ``STALL_EVERY``
  s from ``SKIP`` s on, then continued: past ``loop_timing_late`` and short of the lost
  states' 50 ms, a stall the newest state hides (the loop's topics keep one): met only by
  its ``loop_timing`` trip.

Per case, read from the bag after the ramp-on (``SKIP`` s), every state counted (nothing left
out for a late period: the piston is judged, not the loop): the tracking error ``z_ref - z``
against the reference as the controller holds it (RMS, max, and the periods beyond 1 mm),
the hydraulic force's peak, the valve current's peak and its largest step from one period to
the next (and the steps over 2 mA; the current the plant reports it applied over each
period, whatever the controller sent), and the safety events with their detectors (a
``loop_timing`` trip holds the axis, and the rest of the run is then a hold, not tracking:
the case says when). A reference the reference node did not send for longer than the
controller's ``reference_timeout`` is held and ramped back onto by design: those periods are
left out and reported (``reference_gap_s``). Each figure also as a ratio to the mean of the
two quiet runs. The last line is one JSON object; ``met`` holds the targets: each loaded
case within 1.5x the quiet RMS, 2x its worst and 1.2x its force peak, or its
``loop_timing`` trip (the stalled case by the trip alone).
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import threading
import time

from domain_coordinator import domain_id
import numpy as np
from ros_ehs.benchmarks import BOUND, CHROMIUM, CHROMIUM_ARGS, positive, report, setting
from ros_ehs.core.options import CONTROLLER, RT_PRIORITY
from ros_ehs.core.params import spec
from ros_ehs.data.bag import open_bag, wait_for_counts
from ros_ehs.nodes.fastdds_profile import ENV
from ros_ehs.nodes.processes import launch_script, NodeProcesses
from ros_ehs.nodes.scheduling import BENCH_PRIORITY, setpoint_priority
import ros_ehs_msgs_py as contract

#: the start left out: the ramp-on (1 s) and the reference's first second [s]
SKIP = 2.0
#: the cases, in the order they run (the quiet one twice: first and last)
CASES = ('quiet', 'busy', 'browser', 'live', 'stall', 'quiet')
#: the stalled case: the controller stopped this long [s] ...
STALL = 0.03
#: ... every this many seconds [s]
STALL_EVERY = 2.0
#: the controller's reference_timeout and ramp_time (their defaults) [s]
REF_TIMEOUT = next(o.default for o in CONTROLLER if o.name == 'reference_timeout')
RAMP = spec('ramp_time').default
#: a command step counted as a jump [A]
JUMP = 2.0e-3
#: the longest wait for a run's states to reach its bag [s]: this, plus this many times the
#: run's own length (a recorder behind on a loaded machine)
BAG_WAIT = (60.0, 10.0)
SPIN = 'import time\nwhile True:\n    pass\n'


def safety_events(b) -> list:
    """Return the controller's safety events an open bag ``b`` recorded (none: no topic)."""
    topic = '/' + contract.EVENTS.name
    return [contract.event_from_msg(m) for _, m in b.decoded([topic])] \
        if topic in b.topics else []


def figures(bag: Path, skip: float = SKIP) -> dict:
    """Return the piston's, the force's and the command's figures of a bench's bag."""
    b = open_bag(bag)
    ref = sorted(contract.reference_from_cdr(m.data) for m in b.messages(['/reference']))
    st = sorted((contract.state_from_cdr(m.data, contract.JOINT_PISTON)
                 for m in b.messages(['/state'])), key=lambda s: s.stamp_ns)
    events = safety_events(b)
    if not ref or not st:
        raise RuntimeError(f'{bag}: no reference or no state recorded')
    tr = np.array([r.stamp_ns for r in ref])
    zr = np.array([r.z_ref for r in ref])
    vr = np.array([r.v_ref for r in ref])
    ts = np.array([s.stamp_ns for s in st])
    k = np.clip(np.searchsorted(tr, ts, side='right') - 1, 0, tr.size - 1)
    e = zr[k] + vr[k] * (ts - tr[k]) * 1e-9 - np.array([s.z for s in st])
    t0 = tr[0] + skip * 1e9
    trips = [ev for ev in events if ev.kind == 'trip']
    end = min([ev.stamp_ns for ev in trips if ev.action in ('hold', 'stop', 'power_off')],
              default=ts[-1] + 1)
    m = (ts > t0) & (ts < end)
    # a reference silent for longer than the controller's reference_timeout (0.1 s) is held
    # where it was, then ramped back onto over ramp_time (1 s), by design (the reference node
    # starved, not the loop): not tracking, left out and reported
    gap = np.zeros(ts.size, dtype=bool)
    for g in np.flatnonzero(np.diff(tr) > REF_TIMEOUT * 1e9):
        gap |= (ts > tr[g]) & (ts < tr[g + 1] + RAMP * 1e9)
    gaps = int(np.sum(gap & m))
    m &= ~gap
    f = np.abs(np.array([s.force for s in st]))[ts > t0]
    # the current the valve had over each period, as the plant reports it (commands sorted by
    # stamp interleave the controller's 0 A for lost states with answers to late ones)
    i = np.array([s.i for s in st])
    mc = m & np.isfinite(i)
    di = np.abs(np.diff(i[mc])) if mc.sum() > 1 else np.zeros(1)
    em = e[m]
    return {'states': int(m.sum()), 'reference_gap_s': round(gaps * 1e-3, 3),
            'rms_mm': round(float(np.sqrt(np.mean(em ** 2))) * 1e3, 4) if em.size else None,
            'max_mm': round(float(np.max(np.abs(em))) * 1e3, 3) if em.size else None,
            'periods_over_1mm': int(np.sum(np.abs(em) > 1e-3)),
            'force_peak_kn': round(float(np.nanmax(f)) * 1e-3, 3) if f.size else None,
            'current_peak_ma': round(float(np.max(np.abs(i[mc]))) * 1e3, 3) if mc.any()
            else None,
            'current_step_ma': round(float(np.max(di)) * 1e3, 3),
            'current_jumps': int(np.sum(di > JUMP)),
            'trips': sorted({ev.detector for ev in trips}),
            'held_after_s': round((end - tr[0]) * 1e-9, 3) if end <= ts[-1] else None}


#: the piston's figures a loop benchmark reports per kind of round (:func:`pooled`)
PISTON = ('rms_mm', 'max_mm', 'periods_over_1mm', 'force_peak_kn', 'current_peak_ma',
          'current_step_ma')


def bench_priority(rt: int) -> tuple[dict, dict, dict]:
    """
    Return what bench.py gives its nodes at SCHED_FIFO ``rt`` (0: none).

    The environment (the Fast DDS profile ``fastdds_rt.xml``), the loop's parameters (plant
    and controller) and the setpoint source's (the reference, under the loop).
    """
    profile = launch_script('fastdds_rt.xml')
    env = {ENV: str(profile)} if rt and profile.is_file() else {}
    loop = {'rt_priority': rt} if rt else {}
    ref = {'rt_priority': setpoint_priority(rt)} if rt else {}
    return env, loop, ref


def piston(bag: Path) -> dict:
    """Return a bench bag's piston figures (:data:`PISTON`), its states and its trips."""
    f = figures(bag)
    return {'states': f['states'], **{k: f[k] for k in PISTON}, 'trips': f['trips']}


def pooled(rows: list[dict]) -> dict:
    """
    Return the piston's figures of several rounds (:func:`figures` each) as one.

    The RMS over every state counted, the periods beyond 1 mm summed, the rest the worst.
    """
    rows = [r for r in rows if r.get('states')]
    n = sum(r['states'] for r in rows)
    if not n:
        return dict.fromkeys(PISTON)
    return {'rms_mm': round(math.sqrt(sum(r['rms_mm'] ** 2 * r['states'] for r in rows) / n),
                            4),
            'max_mm': max(r['max_mm'] for r in rows),
            'periods_over_1mm': sum(r['periods_over_1mm'] for r in rows),
            'force_peak_kn': max(r['force_peak_kn'] for r in rows),
            'current_peak_ma': max(r['current_peak_ma'] for r in rows),
            'current_step_ma': max(r['current_step_ma'] for r in rows)}


def piston_ratios(with_: dict, without: dict) -> dict:
    """Return each piston figure with the load over the same without it (None: no figure)."""
    return {k: _ratio(with_[k], without[k]) for k in PISTON if k != 'periods_over_1mm'}


def _stall(pid: int, done: threading.Event) -> None:
    """Stop process ``pid`` for ``STALL`` s every ``STALL_EVERY`` s from ``SKIP`` s on."""
    wait = SKIP
    while not done.wait(wait):
        try:
            os.kill(pid, signal.SIGSTOP)
            try:
                time.sleep(STALL)
            finally:
                os.kill(pid, signal.SIGCONT)
        except ProcessLookupError:
            return
        wait = STALL_EVERY


def _run(dom: int, tmp: Path, case: str, n: int, seconds: float, rt: int, pw) -> dict:
    bag = tmp / f'{n}_{case}'
    spinners: list[subprocess.Popen] = []
    browser = stall = None
    done = threading.Event()
    env, loop, ref = bench_priority(rt)
    with NodeProcesses(dom, tmp / f'logs_{n}_{case}', env=env, bound=BOUND) as procs:
        procs.start_loop('realtime', bag=bag, plant=loop, controller=loop,
                         reference={'rate_hz': 250.0, **ref})
        ref_cpu = -1 if procs.placement is None else procs.placement[1]
        try:
            if case == 'busy':
                spinners = [subprocess.Popen([sys.executable, '-c', SPIN]) for _ in range(2)]
            elif case == 'stall':
                stall = threading.Thread(target=_stall, args=(procs['controller'].pid, done),
                                         daemon=True)
                stall.start()
            elif case == 'live':
                procs.start('identify', {'live': True, 'push': True, 'cpu_affinity': ref_cpu})
            elif case == 'browser':
                procs.start('station', {'port': 0, 'cpu_affinity': ref_cpu})
                if not procs.wait_status(contract.STATION_STATUS,
                                         lambda st: 'url' in st.values):
                    raise RuntimeError('the station did not start:\n'
                                       + procs['station'].output()[-3000:])
                browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS,
                                             headless=True)
                page = browser.new_page()
                page.set_default_timeout(BOUND * 1000)
                page.goto(procs.status(contract.STATION_STATUS).values['url'])
                page.wait_for_function('window.station.frames > 0')
            wait_for_counts(bag, {'/state': int((seconds + SKIP) * 1000)},
                            BAG_WAIT[0] + BAG_WAIT[1] * (seconds + SKIP))
        finally:
            done.set()
            if stall is not None:
                stall.join()
            for p in spinners:
                p.kill()
                p.wait()
            if browser is not None:
                browser.close()
        procs.stop([n for n in ('recorder', 'identify', 'station', 'reference', 'plant',
                                'controller') if n in procs.procs])
    return {'case': case, **figures(bag)}


def _ratio(x, y):
    return round(x / y, 3) if x is not None and y else None


def main(argv=None) -> int:
    """Run the benchmark; print each case, the last line JSON."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks load',
                                 description=__doc__.split('\n\n')[0])
    ap.add_argument('--seconds', type=positive, default=30.0,
                    help='seconds of each case after the ramp-on')
    ap.add_argument('--cases', nargs='*', choices=sorted(set(CASES)), default=None,
                    help='the loads to run (default all; quiet always runs first and last)')
    ap.add_argument('--rt-priority', type=setting(RT_PRIORITY), default=BENCH_PRIORITY,
                    help="SCHED_FIFO priority of plant and controller (the bench's default; "
                         '0: the default scheduler)')
    a = ap.parse_args(argv)
    cases = ['quiet', *[c for c in CASES[1:-1] if a.cases is None or c in a.cases], 'quiet']
    rows = []
    with domain_id() as dom, tempfile.TemporaryDirectory() as tmp:
        pw_cm = None
        if 'browser' in cases:
            from playwright.sync_api import sync_playwright
            pw_cm = sync_playwright()
        pw = pw_cm.__enter__() if pw_cm is not None else None
        try:
            for n, case in enumerate(cases):
                row = _run(dom, Path(tmp), case, n, a.seconds, a.rt_priority, pw)
                rows.append(row)
                print(row, flush=True)
        finally:
            if pw_cm is not None:
                pw_cm.__exit__(None, None, None)
    quiet = [r for r in rows if r['case'] == 'quiet']

    def qmean(key):
        v = [r[key] for r in quiet if r[key] is not None]
        return sum(v) / len(v) if v else None
    yard = {k: qmean(k) for k in ('rms_mm', 'max_mm', 'force_peak_kn', 'current_peak_ma',
                                  'current_step_ma')}
    met = {}
    for r in rows:
        if r['case'] == 'quiet':
            continue
        r['ratios'] = {k: _ratio(r[k], yard[k]) for k in yard}
        rr = r['ratios']
        within = rr['rms_mm'] is not None and rr['rms_mm'] <= 1.5 and rr['max_mm'] <= 2.0 \
            and rr['force_peak_kn'] <= 1.2
        tripped = 'loop_timing' in r['trips']
        met[r['case']] = tripped if r['case'] == 'stall' else bool(within or tripped)
    return report({'seconds': a.seconds, 'rt_priority': a.rt_priority, 'cases': rows,
                   'quiet': {k: (round(v, 4) if v is not None else None)
                             for k, v in yard.items()}, 'met': met})


if __name__ == '__main__':
    sys.exit(main())
