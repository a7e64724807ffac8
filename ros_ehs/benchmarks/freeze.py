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
``python -m ros_ehs.benchmarks freeze``: a node frozen as a whole during a lock-step run.

What a process the OS stops (SIGSTOP; a swapping host, Ctrl-Z) costs the loop and the bag
(docs/recording.md, "A recorder that stalls"). Each run is the bench's lock-step loop with
its recorder, paced at the rig's speed (the plant's ``real_time_factor`` 1, so the loop runs
on while the node is frozen), for ``--seconds`` of sim time. One second in, ``--node`` is
stopped for a pause of ``--pauses`` and continued; the loop runs to its end and the bench
stops, the recorder first, as ``NodeProcesses.stop`` does. The yardstick, in the same run:
the same loop with no pause (pause 0), run first in each round.

Per run: the messages each loop topic lost against the yardstick's median (``lost``: the bag
holds fewer; a writer whose path to the recorder was dropped loses the rest of the run, and
its topics name it: ``/state`` and ``/clock`` are the plant's), and how far the plant stepped
while the node was frozen (``held``: the loop's steps in the pause over the pause at 1000
steps/s; 1.0 the loop ran on, below it the frozen node held the others). Last line: one JSON
object.
"""

from __future__ import annotations

import argparse
import signal
import statistics
import sys
import tempfile
import time

from domain_coordinator import domain_id
from ros_ehs.benchmarks import BOUND, count, positive, report
import ros_ehs_msgs_py as contract

#: the loop topics whose messages are counted in the bag
TOPICS = ('/state', '/servo_current', '/reference_trajectory', '/clock')
#: the nodes of the loop, and the order the bench stops them in
NODES = ('recorder', 'reference', 'controller', 'plant')
#: the loop's rate [Hz] (the plant's default)
RATE = 1000.0


def pause_or_zero(text: str) -> float:
    """Parse a pause [s]: 0 or a finite number > 0 (an argparse ``type``)."""
    return 0.0 if text.strip() in ('0', '0.0') else positive(text)


def _run(dom: int, seconds: float, pause: float, node: str, tmp: str, k: int) -> dict:
    """Run the loop once, ``node`` stopped ``pause`` s one second in; the bag's counts."""
    from ros_ehs.data.bag import open_bag
    from ros_ehs.nodes.processes import NodeProcesses
    bag = f'{tmp}/bag{k}'
    with NodeProcesses(dom, f'{tmp}/logs{k}', bound=BOUND) as procs:
        procs.start_loop('lockstep', bag=bag, recorder={'compression': 'none'},
                         plant={'duration': seconds, 'real_time_factor': 1.0,
                                'diagnostics_period': 0.05})
        held = None
        if pause > 0:
            one = int(RATE)
            if not procs.wait_status(contract.PLANT_STATUS,
                                     lambda st: float(st.values['steps']) >= one):
                raise RuntimeError('the loop did not step a second:\n' +
                                   procs['plant'].output()[-2000:])
            p = procs[node].popen
            before, t0 = procs.status_value(contract.PLANT_STATUS, 'steps'), time.monotonic()
            p.send_signal(signal.SIGSTOP)
            try:
                time.sleep(pause)
                after, t1 = procs.status_value(contract.PLANT_STATUS, 'steps'), time.monotonic()
            finally:
                p.send_signal(signal.SIGCONT)
            held = (after - before) / ((t1 - t0) * RATE)
        if not procs.wait_status(contract.PLANT_STATUS,
                                 lambda st: st.message == 'lock-step run complete'):
            raise RuntimeError('the lock-step run did not complete:\n' +
                               procs['plant'].output()[-2000:])
        codes = procs.stop(list(NODES))
        resends = procs['plant'].figures().get('resends', 0)
    counts = dict.fromkeys(TOPICS, 0)
    for m in open_bag(bag).messages(list(TOPICS)):
        counts[m.topic] += 1
    return {'pause_s': pause, 'counts': counts,
            'held': None if held is None else round(held, 3), 'resends': resends,
            'exit_codes': codes}


def main(argv=None) -> int:
    """Run the benchmark; print each run and the figures, the last line JSON."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks freeze')
    ap.add_argument('--pauses', type=lambda s: [pause_or_zero(x) for x in s.split(',')],
                    default=[0.5, 1.2, 2.5], help='how long the node is frozen [s], each run')
    ap.add_argument('--runs', type=count, default=3, help='rounds (each pause once a round)')
    ap.add_argument('--seconds', type=positive, default=4.0,
                    help='sim time of a run [s], paced at 1x (at least the pause plus 1.5 s)')
    ap.add_argument('--node', default='recorder', choices=NODES, help='the node frozen')
    a = ap.parse_args(argv)
    pauses = [p for p in a.pauses if p > 0]
    if a.seconds < max(pauses, default=0.0) + 1.5:
        ap.error(f'argument --seconds: {a.seconds:g} s must be at least the longest pause '
                 'plus 1.5 s (the pause starts one second in)')
    runs = []
    with domain_id() as dom, tempfile.TemporaryDirectory() as tmp:
        k = 0
        for _ in range(a.runs):
            for p in [0.0, *pauses]:
                r = _run(dom, a.seconds, p, a.node, tmp, k)
                k += 1
                runs.append(r)
                print(f'pause {p:4.2f} s: {r["counts"]} held {r["held"]} '
                      f'resends {r["resends"]}', flush=True)
    base = {t: statistics.median(r['counts'][t] for r in runs if r['pause_s'] == 0)
            for t in TOPICS}
    for r in runs:
        r['lost'] = {t: int(base[t] - n) for t, n in r['counts'].items() if base[t] - n > 0}
    per_pause = {}
    for p in pauses:
        rs = [r for r in runs if r['pause_s'] == p]
        per_pause[f'{p:g}'] = {
            'runs': len(rs),
            'runs_losing': sum(bool(r['lost']) for r in rs),
            'lost_most': max((max(r['lost'].values(), default=0) for r in rs), default=0),
            'held_least': min(r['held'] for r in rs)}
    return report({'node': a.node, 'seconds': a.seconds, 'baseline_counts': base,
                   'per_pause': per_pause,
                   'runs': [{k: r[k] for k in ('pause_s', 'lost', 'held', 'resends',
                                               'exit_codes')} for r in runs]})


if __name__ == '__main__':
    sys.exit(main())
