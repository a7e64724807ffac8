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
``python -m ros_ehs.benchmarks live``: whether the live identify node disturbs the real-time loop.

The bench's loop (plant, controller and the reference's 1 Hz sine, placed as
``NodeProcesses.start_loop`` places them: plant and controller on one CPU, the reference on the
other; at the bench's priorities, ``--rt-priority``) runs in real time for ``--seconds`` per
round, in ``--rounds`` rounds without and with the identify node in the order without, with,
with, without (so a drift of the machine's load over the run weighs on both alike) in live
mode (window 10 s, period 5 s, pushing to the controller), placed on the reference's CPU, its
refits at idle priority. Every round is
recorded and its piston judged from the bag (:func:`ros_ehs.benchmarks.load.figures`: the
tracking error's RMS and worst, the periods beyond 1 mm, the hydraulic force's and the
current's peaks, after the ramp-on). Prints each round's fresh-cycle fraction, late commands
(over 3 periods old), the live node's CPU share, refits and the piston; the last line is one
JSON object with the figures pooled per kind, the spread of the rounds without it
(``fresh_spread_without``), ``fresh_ratio_with_vs_without`` and
``piston_ratio_with_vs_without``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
import tempfile
import time

from domain_coordinator import domain_id
import psutil
from ros_ehs.benchmarks import BOUND, count, positive, report, setting
from ros_ehs.benchmarks.load import bench_priority, piston, piston_ratios, pooled
from ros_ehs.core.options import RT_PRIORITY
from ros_ehs.nodes.processes import loop_placement, NodeProcesses
from ros_ehs.nodes.scheduling import BENCH_PRIORITY
import ros_ehs_msgs_py as contract

LIVE = {'live': True, 'push': True, 'window': 10.0, 'period': 5.0}


def _cpu(pid: int) -> float:
    t = psutil.Process(pid).cpu_times()
    return t.user + t.system


def _round(dom: int, seconds: float, with_live: bool, bag: Path, rt: int) -> dict:
    env, loop, ref = bench_priority(rt)
    with NodeProcesses(dom, bag.parent / f'logs_{bag.name}', env=env, bound=BOUND) as procs:
        procs.start_loop('realtime', bag=bag, plant=loop, controller=loop, reference=ref)
        live_cpu = 0.0
        if with_live:
            ref_cpu = (loop_placement(True) or (-1, -1))[1]
            procs.start('identify', {**LIVE, 'cpu_affinity': ref_cpu})
            state = '/' + contract.STATE.name
            if not procs.wait_status(contract.IDENTIFY_STATUS,
                                     lambda st: state in st.listed('subscribed')):
                raise RuntimeError('the identify node did not subscribe to the state:\n'
                                   + procs['identify'].output()[-3000:])
            c0 = _cpu(procs['identify'].pid)
        t0 = time.monotonic()
        time.sleep(seconds)
        if with_live:
            live_cpu = (_cpu(procs['identify'].pid) - c0) / (time.monotonic() - t0)
        st = procs.status(contract.IDENTIFY_STATUS) if with_live else None
        procs.stop(['identify'] if with_live else [])
        # the plant first (no stale tail), the recorder after it (every state it sent)
        procs.stop(['plant', 'controller', 'reference', 'recorder'])
        f = procs['plant'].figures()
    return {'with_live': with_live, 'cycles': f['cycles'],
            'fresh_cycle_fraction': f['fresh_cycle_fraction'],
            'late_commands': f['late_commands'], 'watchdog_trips': f['watchdog_trips'],
            'live_cpu_frac': round(live_cpu, 3),
            'refits': int(st.values['refits']) if st else 0,
            'pushes': int(st.values['pushes']) if st else 0, 'piston': piston(bag)}


def main(argv=None) -> int:
    """Run the benchmark; print figures, the last line JSON."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks live')
    ap.add_argument('--seconds', type=positive, default=40.0, help='seconds per round')
    ap.add_argument('--rounds', type=count, default=4,
                    help='rounds: without, with, with, without the live node, ...')
    ap.add_argument('--rt-priority', type=setting(RT_PRIORITY), default=BENCH_PRIORITY,
                    help="SCHED_FIFO priority of plant and controller (the bench's default; the "
                         'reference 10 under it; 0: the default scheduler)')
    a = ap.parse_args(argv)
    rounds = []
    with domain_id() as dom, tempfile.TemporaryDirectory() as tmp:
        for r in range(a.rounds):
            res = _round(dom, a.seconds, r % 4 in (1, 2), Path(tmp) / f'r{r}',  # ABBA
                         a.rt_priority)
            rounds.append(res)
            p = res['piston']
            print(f'round {r + 1}: live node {"on " if res["with_live"] else "off"}  fresh '
                  f'{res["fresh_cycle_fraction"]:.5f}  late commands {res["late_commands"]}'
                  f'  live CPU {res["live_cpu_frac"]:.3f}  refits {res["refits"]}  pushes '
                  f'{res["pushes"]}  piston {p["rms_mm"]} mm RMS, {p["max_mm"]} mm worst, '
                  f'{p["force_peak_kn"]} kN', flush=True)
    figures = {'seconds': a.seconds, 'rounds': a.rounds, 'rt_priority': a.rt_priority,
               'per_round': rounds}
    for kind, on in (('with', True), ('without', False)):
        rs = [r for r in rounds if r['with_live'] == on]
        n = sum(r['cycles'] for r in rs)
        figures[f'fresh_{kind}'] = round(sum(r['fresh_cycle_fraction'] * r['cycles']
                                             for r in rs) / max(n, 1), 5)
        figures[f'late_commands_{kind}'] = sum(r['late_commands'] for r in rs)
        figures[f'watchdog_trips_{kind}'] = sum(r['watchdog_trips'] for r in rs)
        figures[f'piston_{kind}'] = pooled([r['piston'] for r in rs])
        fr = [r['fresh_cycle_fraction'] for r in rs]
        figures[f'fresh_spread_{kind}'] = round(max(fr) - min(fr), 5) if fr else None
    figures['fresh_ratio_with_vs_without'] = round(figures['fresh_with'] /
                                                   figures['fresh_without'], 5)
    figures['piston_ratio_with_vs_without'] = piston_ratios(figures['piston_with'],
                                                            figures['piston_without'])
    figures['refits'] = sum(r['refits'] for r in rounds)
    figures['live_cpu_frac'] = max(r['live_cpu_frac'] for r in rounds)
    return report(figures)


if __name__ == '__main__':
    sys.exit(main())
