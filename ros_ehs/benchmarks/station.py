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
``python -m ros_ehs.benchmarks station``: whether the operator's station disturbs the loop.

The bench's real-time loop (plant, controller and the reference's 1 Hz sine, placed as
``NodeProcesses.start_loop`` places them) runs for ``--seconds`` per round, in ``--rounds``
rounds without and with the station in the order without, with, with, without (so a drift
of the machine's load weighs on both alike). With it: the station node on the reference's
CPU and one page open in headless Chromium (Debian's, driven by Playwright) at the default
5 s time base. Every round is recorded and its piston judged from the bag
(:func:`ros_ehs.benchmarks.load.figures`). Prints each round's fresh-cycle fraction, late
commands (over 3 periods old), the station's CPU share, the browser's (every Chromium
process), the frames the page received a second and the piston;
``--rt-priority`` runs plant and controller under SCHED_FIFO; ``--no-page`` runs the station
without a page on this machine (as when it is open on another); ``--browser-cpu N`` starts
Chromium pinned to CPU N (taskset), away from the loop's CPU. The last line is one JSON
object with ``fresh_with``, ``fresh_without``, ``late_commands_with``,
``late_commands_without``, ``piston_with``, ``piston_without`` and their ratio,
``station_cpu`` (fraction of a core, the worst round), ``browser_cpu`` and ``updates_per_s``
(what the page received, the slowest round), and the spread of the rounds without it.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import sys
import tempfile
import time

from domain_coordinator import domain_id
import psutil
from ros_ehs.benchmarks import (BOUND, CHROMIUM, CHROMIUM_ARGS, count, cpu, positive, report,
                                setting)
from ros_ehs.benchmarks.load import bench_priority, piston, piston_ratios, pooled
from ros_ehs.core.options import RT_PRIORITY
from ros_ehs.nodes.processes import loop_placement, NodeProcesses
import ros_ehs_msgs_py as contract


def _cpu(pid: int) -> float:
    t = psutil.Process(pid).cpu_times()
    return t.user + t.system


def _browser_cpu() -> float:
    """Return the CPU seconds of every Chromium process (browser, renderer, GPU, ...)."""
    total = 0.0
    for p in psutil.process_iter(['exe']):
        try:
            if (p.info['exe'] or '').startswith('/usr/lib/chromium/'):
                t = p.cpu_times()
                total += t.user + t.system
        except psutil.Error:
            pass
    return total


def _frames(page) -> int:
    """Return the frames the page has received (0 without a page)."""
    return page.evaluate('window.station.frames') if page is not None else 0


def _round(dom: int, seconds: float, browser, with_station: bool, rt_priority: int,
           page_open: bool, bag: Path) -> dict:
    env, loop, ref = bench_priority(rt_priority)
    with NodeProcesses(dom, bag.parent / f'logs_{bag.name}', env=env, bound=BOUND) as procs:
        procs.start_loop('realtime', bag=bag, plant=loop, controller=loop, reference=ref)
        station_cpu = updates = browser_cpu = 0.0
        if with_station:
            ref_cpu = (loop_placement(True) or (-1, -1))[1]
            procs.start('station', {'port': 0, 'cpu_affinity': ref_cpu})
            if not procs.wait_status(contract.STATION_STATUS, lambda st: 'url' in st.values):
                raise RuntimeError('the station did not start:\n'
                                   + procs['station'].output()[-3000:])
            page = browser.new_page() if page_open else None
            if page is not None:
                page.set_default_timeout(BOUND * 1000)
                page.goto(procs.status(contract.STATION_STATUS).values['url'])
                page.wait_for_function('window.station.frames > 0')
            c0, f0 = _cpu(procs['station'].pid), _frames(page)
            b0 = _browser_cpu()
        t0 = time.monotonic()
        time.sleep(seconds)
        if with_station:
            dt = time.monotonic() - t0
            station_cpu = (_cpu(procs['station'].pid) - c0) / dt
            updates = (_frames(page) - f0) / dt
            browser_cpu = (_browser_cpu() - b0) / dt
            if page is not None:
                page.close()
            procs.stop(['station'])
        # the plant first (no stale tail), the recorder after it (every state it sent)
        procs.stop(['plant', 'controller', 'reference', 'recorder'])
        f = procs['plant'].figures()
    return {'with_station': with_station, 'cycles': f['cycles'],
            'fresh_cycle_fraction': f['fresh_cycle_fraction'],
            'late_commands': f['late_commands'], 'watchdog_trips': f['watchdog_trips'],
            'station_cpu': round(station_cpu, 3), 'browser_cpu': round(browser_cpu, 3),
            'updates_per_s': round(updates, 1), 'piston': piston(bag)}


def main(argv=None) -> int:
    """Run the benchmark; print figures, the last line JSON."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks station')
    ap.add_argument('--seconds', type=positive, default=30.0, help='seconds per round')
    ap.add_argument('--rounds', type=count, default=4,
                    help='rounds: without, with, with, without the station, ...')
    ap.add_argument('--rt-priority', type=setting(RT_PRIORITY), default=0,
                    help='SCHED_FIFO priority of plant and controller, the reference 10 under '
                         'it, with the Fast DDS profile fastdds_rt.xml, as bench.py (0: none)')
    ap.add_argument('--browser-cpu', type=cpu, default=None, metavar='CPU',
                    help='start Chromium pinned to this CPU (taskset), away from the loop')
    ap.add_argument('--page', action=argparse.BooleanOptionalAction, default=True,
                    help='open the page in headless Chromium (--no-page: the station alone, '
                         'as when the page is open on another machine)')
    a = ap.parse_args(argv)
    from playwright.sync_api import sync_playwright
    rounds = []
    with domain_id() as dom, sync_playwright() as pw, tempfile.TemporaryDirectory() as tmp:
        exe = CHROMIUM
        if a.browser_cpu is not None:           # as an operator pins it: taskset -c N chromium
            exe = os.path.join(tmp, 'chromium')
            with open(exe, 'w') as f:
                f.write(f'#!/bin/sh\nexec taskset -c {a.browser_cpu} {CHROMIUM} "$@"\n')
            os.chmod(exe, 0o755)
        browser = pw.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS, headless=True)
        try:
            for r in range(a.rounds):
                res = _round(dom, a.seconds, browser, r % 4 in (1, 2), a.rt_priority,  # ABBA
                             a.page, Path(tmp) / f'r{r}')
                rounds.append(res)
                p = res['piston']
                print(f'round {r + 1}: station {"on " if res["with_station"] else "off"}  '
                      f'fresh {res["fresh_cycle_fraction"]:.5f}  late commands '
                      f'{res["late_commands"]}  station CPU {res["station_cpu"]:.3f}  browser '
                      f'CPU {res["browser_cpu"]:.3f}  page updates {res["updates_per_s"]:.1f}/s'
                      f'  piston {p["rms_mm"]} mm RMS, {p["max_mm"]} mm worst, '
                      f'{p["force_peak_kn"]} kN', flush=True)
        finally:
            browser.close()
    figures = {'seconds': a.seconds, 'rounds': a.rounds, 'rt_priority': a.rt_priority,
               'page': a.page, 'browser_cpu_pinned': a.browser_cpu,
               'per_round': rounds}
    for kind, on in (('with', True), ('without', False)):
        rs = [r for r in rounds if r['with_station'] == on]
        n = sum(r['cycles'] for r in rs)
        figures[f'fresh_{kind}'] = round(sum(r['fresh_cycle_fraction'] * r['cycles']
                                             for r in rs) / n, 5) if n else None
        figures[f'late_commands_{kind}'] = sum(r['late_commands'] for r in rs) if rs else None
        figures[f'watchdog_trips_{kind}'] = sum(r['watchdog_trips'] for r in rs) if rs else None
        figures[f'piston_{kind}'] = pooled([r['piston'] for r in rs])
        fr = [r['fresh_cycle_fraction'] for r in rs]
        figures[f'fresh_spread_{kind}'] = round(max(fr) - min(fr), 5) if fr else None
    figures['piston_ratio_with_vs_without'] = piston_ratios(figures['piston_with'],
                                                            figures['piston_without'])
    with_ = [r for r in rounds if r['with_station']]
    figures['station_cpu'] = max((r['station_cpu'] for r in with_), default=None)
    figures['updates_per_s'] = min((r['updates_per_s'] for r in with_), default=None)
    figures['browser_cpu'] = max((r['browser_cpu'] for r in with_), default=None)
    return report(figures)


if __name__ == '__main__':
    sys.exit(main())
