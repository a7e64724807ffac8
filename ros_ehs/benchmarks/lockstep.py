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
``python -m ros_ehs.benchmarks lockstep``: the lock-step closed loop over DDS.

Plant (lock-step), controller (reference-synchronised) and reference (on ``/clock``) run as
separate processes for ``--seconds`` of sim time; the plant reports how many steps per
second of wall time the loop made. In the same run, two yardsticks: the in-process loop (no
DDS, :func:`ros_ehs.core.sim.closed_loop.run_closed_loop`), and a bare rclpy ping-pong sending each
message as soon as the last echo is back (the most round trips per second rclpy makes on this
machine over JointState objects), best effort and with the lock-step QoS; and the barest
lock-step of the bench's earlier topology (``--relay``: a third process turns
a clock every period into the reference the pong waits for, reliable; the bench now sends
``/clock`` every 10 periods and the references as one ``reference_trajectory`` per clock),
none of our code in any of them. And, for reference, the bare ping-pong over serialized
messages (``--raw``), the path our loop nodes take: the ceiling for them.

Placement: by default the loop runs as
:meth:`ros_ehs.nodes.processes.NodeProcesses.start_loop` places a
lock-step loop (plant and controller on one CPU, the reference on another), and every
yardstick is placed alike; one more bare ping-pong, unpinned, shows what the placement is
worth (``bare_unpinned_*``). ``--no-cpu-affinity`` leaves everything to the scheduler.
Last line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time

from domain_coordinator import domain_id
from ros_ehs.benchmarks import BOUND, count, positive, report
from ros_ehs.core.control.waveforms import Sine
from ros_ehs.core.params import Params
from ros_ehs.core.sim.closed_loop import run_closed_loop
from ros_ehs.nodes.processes import loop_placement, NodeProcesses
import ros_ehs_msgs_py as contract


def _volley(dom: int, seconds: float, extra: list[str], pin: bool = False) -> dict:
    """
    Return the ceiling: a bare rclpy ping-pong, back to back (``extra``: its options).

    ``pin``: volley and pong on one CPU, the relay on another, as ``--cpu-affinity`` places
    ours (:func:`ros_ehs.nodes.processes.loop_placement`).
    """
    cpus = loop_placement(True) if pin else None
    roles = ['pong', 'relay', 'volley'] if '--relay' in extra else ['pong', 'volley']
    with NodeProcesses(dom, bound=BOUND) as bare:
        for role in roles:
            cpu = ['--cpu', str(cpus[role == 'relay'])] if cpus else []
            bare.start(role, cmd=[sys.executable, '-m', 'ros_ehs.benchmarks.pingpong', role,
                                  *extra, *cpu, '--seconds', repr(seconds)])
        try:            # the volley ends by itself ``seconds`` after its first echo
            bare['volley'].popen.wait(BOUND)
        except subprocess.TimeoutExpired:
            raise RuntimeError(f'the bare ping-pong {extra} did not end within {BOUND:g} s:\n'
                               + bare['volley'].output()[-2000:]) from None
        bare.stop(roles[::-1])
        return json.loads(bare['volley'].output().strip().splitlines()[-1])


def _ours(dom: int, seconds: float, model: str, pin: bool) -> dict:
    """Run plant, controller and reference in lock-step for ``seconds``; the plant's figures."""
    with NodeProcesses(dom, bound=BOUND) as procs:
        procs.start_loop('lockstep', plant={'duration': seconds, 'model': model,
                                            'start_delay': 1.0}, pin=pin)
        if not procs.wait_status(contract.PLANT_STATUS,
                                 lambda st: st.message == 'lock-step run complete', 600):
            raise RuntimeError('lock-step did not finish:\n' + procs['plant'].output())
        procs.stop(['reference', 'controller', 'plant'])
        return procs['plant'].figures()


def main(argv=None) -> int:
    """
    Run the benchmark; print figures, the last line JSON.

    Ours and the bare best-effort ping-pong (the issue's ceiling) run in alternating rounds
    (``--rounds``), the ping-pong for as long as our run just took, so that the load of the
    machine, which moves both by tens of percent within a minute here, weighs on both alike;
    the figures are the medians over the rounds. Then, once each, the other yardsticks: the
    ping-pong with the lock-step loop's own QoS (reliable, depth 10000), the old topology's
    relay and the serialized ping-pong.
    """
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks lockstep')
    ap.add_argument('--seconds', type=positive, default=5.0, help='sim seconds per round')
    ap.add_argument('--rounds', type=count, default=3, help='alternating rounds (ours, bare)')
    ap.add_argument('--model', default='simplified', choices=('simplified', 'reduced', 'full'))
    ap.add_argument('--cpu-affinity', action=argparse.BooleanOptionalAction, default=True,
                    help='plant and controller on one CPU, the reference on another (as '
                    'NodeProcesses.start_loop places a lock-step loop by default), and the bare '
                    'yardsticks placed alike; --no-cpu-affinity: all unpinned')
    a = ap.parse_args(argv)
    pin = a.cpu_affinity
    ours, bare = [], []
    # each yardstick runs as long as our loop took, at least a second (of a run shorter than
    # a second of sim time, that long)
    least = min(1.0, a.seconds)
    with domain_id() as dom:
        for _ in range(a.rounds):
            f = _ours(dom, a.seconds, a.model, pin)
            ours.append(f)
            wall = max(least, f['steps'] / f['steps_per_s'])
            bare.append(_volley(dom, wall, [], pin)['volleys_per_s'])
        wall = max(least, a.seconds * 1000.0 / statistics.median(
            x['steps_per_s'] for x in ours))
        vr, v3, vw = (_volley(dom, wall, extra, pin)['volleys_per_s']
                      for extra in (['--reliable'], ['--reliable', '--relay'], ['--raw']))
        # pinned, the yardsticks are placed alike; the bare ping-pong as the scheduler
        # places it, once, shows what the placement itself is worth
        free = _volley(dom, wall, [])['volleys_per_s'] if pin else None
    run_closed_loop(Params(), Sine(), 0.01, model=a.model)   # load the compiled kernels first
    t0 = time.perf_counter()
    run_closed_loop(Params(), Sine(), a.seconds, model=a.model)
    inproc = a.seconds * 1000 / (time.perf_counter() - t0)
    rate = statistics.median(x['steps_per_s'] for x in ours)
    v = statistics.median(bare)
    f = sorted(ours, key=lambda x: x['steps_per_s'])[len(ours) // 2]     # the median run

    def r(x: float, n: int = 3) -> float:
        return round(x, n)
    per_round = [x['steps_per_s'] / b for x, b in zip(ours, bare)]
    return report({'model': a.model, 'sim_seconds': a.seconds, 'rounds': a.rounds,
                   'cpu_affinity': pin, 'steps': f['steps'],
                   'steps_per_s': r(rate, 1), 'realtime_factor': r(rate / 1000.0),
                   'resends': sum(x['resends'] for x in ours),
                   'step_p50_ms': r(f['period_p50_ms'], 4),
                   'step_p99_ms': r(f['period_p99_ms'], 4),
                   'in_process_steps_per_s': r(inproc, 1),
                   'dds_vs_in_process': r(rate / inproc, 4),
                   'bare_pingpong_round_trips_per_s': r(v, 1),
                   'lockstep_vs_bare_pingpong': r(rate / v),
                   'per_round': [[r(x['steps_per_s'], 1), r(b, 1), r(q)]
                                 for x, b, q in zip(ours, bare, per_round)],
                   'bare_reliable_round_trips_per_s': r(vr, 1),
                   'lockstep_vs_bare_reliable': r(rate / vr),
                   'bare_relay_round_trips_per_s': r(v3, 1),
                   'lockstep_vs_bare_relay': r(rate / v3),
                   'bare_relay_vs_bare_pingpong': r(v3 / v),
                   'bare_serialized_round_trips_per_s': r(vw, 1),
                   'lockstep_vs_bare_serialized': r(rate / vw),
                   **({'bare_unpinned_round_trips_per_s': r(free, 1),
                       'lockstep_vs_bare_unpinned': r(rate / free)} if pin else {}),
                   # the target: the median round at 0.8 of the bare ping-pong or more; and
                   # how many single rounds were (the machine moves a round by +-10 %)
                   'rounds_at_0.8_of_bare': sum(x >= 0.8 for x in per_round),
                   'targets_met': {'lockstep_0.8_of_bare': rate / v >= 0.8}})


if __name__ == '__main__':
    sys.exit(main())
