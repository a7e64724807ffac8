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
``python -m ros_ehs.bench lockstep``: the lock-step closed loop over DDS.

Plant (lock-step), controller (reference-synchronised) and reference (on ``/clock``) run as
separate processes for ``--seconds`` of sim time; the plant reports how many steps per
second of wall time the loop made. In the same run, two yardsticks: the in-process loop (no
DDS, :func:`ros_ehs.closed_loop.run_closed_loop`), and a bare rclpy ping-pong sending each
message as soon as the last echo is back (the most round trips per second rclpy makes on this
machine over JointState objects), best effort and with the lock-step QoS; and the barest
lock-step of the topology the bench had until session 8 (``--relay``: a third process turns
a clock every period into the reference the pong waits for, reliable; the bench now sends
``/clock`` every 10 periods and the references as one ``reference_trajectory`` per clock),
none of our code in any of them. And, for reference, the bare ping-pong over serialized
messages (``--raw``), the path our loop nodes take: the ceiling for them.
Last line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from domain_coordinator import domain_id
from ros_ehs.bench import report
from ros_ehs.closed_loop import run_closed_loop
from ros_ehs.launch import Launch
from ros_ehs.params import Params
from ros_ehs.reference import Sine


def _volley(dom: int, seconds: float, extra: list[str], pin: bool = False) -> dict:
    """
    Return the ceiling: a bare rclpy ping-pong, back to back (``extra``: its options).

    ``pin``: volley and pong on CPU 0, the relay on CPU 1, as ``--cpu-affinity`` places ours.
    """
    roles = ['pong', 'relay', 'volley'] if '--relay' in extra else ['pong', 'volley']
    with Launch(dom) as bare:
        for role in roles:
            cpu = ['--cpu', '1' if role == 'relay' else '0'] if pin else []
            bare.start(role, cmd=[sys.executable, '-m', 'ros_ehs.bench.pingpong', role, *extra,
                                  *cpu])
        time.sleep(2.0 + seconds)
        bare.stop(roles[::-1])
        return json.loads(bare['volley'].output().strip().splitlines()[-1])


def main(argv=None) -> int:
    """
    Run the benchmark; print figures, the last line JSON.

    Two yardsticks from the same run: the bare ping-pong best effort (the issue's ceiling)
    and with the lock-step loop's own QoS (reliable, depth 10000, so a recorder gets every
    sample), which costs the bare loop itself about a quarter of its rate.
    """
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.bench lockstep')
    ap.add_argument('--seconds', type=float, default=5.0, help='sim seconds')
    ap.add_argument('--model', default='simplified', choices=('simplified', 'reduced', 'full'))
    ap.add_argument('--cpu-affinity', action='store_true',
                    help='plant and controller on CPU 0, the reference on CPU 1 (the '
                    'cpu_affinity option of the nodes), and the bare yardsticks placed alike')
    a = ap.parse_args(argv)
    pin = a.cpu_affinity
    with domain_id() as dom:
        with Launch(dom) as launch:
            launch.start_loop('lockstep', plant={'duration': a.seconds, 'model': a.model,
                                                 'start_delay': 1.0,
                                                 **({'cpu_affinity': 0} if pin else {})},
                              controller={'cpu_affinity': 0} if pin else None,
                              reference={'cpu_affinity': 1} if pin else True)
            if not launch.wait_for_log('plant', 'lock-step run complete', 600):
                raise RuntimeError('lock-step did not finish:\n' + launch['plant'].output())
            launch.stop(['reference', 'controller', 'plant'])
            f = launch['plant'].figures()
        v, vr, v3, vw = (_volley(dom, a.seconds, extra, pin)
                         for extra in ([], ['--reliable'], ['--reliable', '--relay'], ['--raw']))
    run_closed_loop(Params(), Sine(), 0.01, model=a.model)   # load the compiled kernels first
    t0 = time.perf_counter()
    run_closed_loop(Params(), Sine(), a.seconds, model=a.model)
    inproc = a.seconds * 1000 / (time.perf_counter() - t0)
    return report({'model': a.model, 'sim_seconds': a.seconds, 'cpu_affinity': pin,
                   'steps': f['steps'],
                   'steps_per_s': round(f['steps_per_s'], 1),
                   'realtime_factor': round(f['steps_per_s'] / 1000.0, 3),
                   'resends': f['resends'], 'step_p50_ms': round(f['period_p50_ms'], 4),
                   'step_p99_ms': round(f['period_p99_ms'], 4),
                   'in_process_steps_per_s': round(inproc, 1),
                   'dds_vs_in_process': round(f['steps_per_s'] / inproc, 4),
                   'bare_pingpong_round_trips_per_s': round(v['volleys_per_s'], 1),
                   'lockstep_vs_bare_pingpong': round(f['steps_per_s'] / v['volleys_per_s'], 3),
                   'bare_reliable_round_trips_per_s': round(vr['volleys_per_s'], 1),
                   'lockstep_vs_bare_reliable': round(f['steps_per_s'] / vr['volleys_per_s'],
                                                      3),
                   'bare_relay_round_trips_per_s': round(v3['volleys_per_s'], 1),
                   'lockstep_vs_bare_relay': round(f['steps_per_s'] / v3['volleys_per_s'], 3),
                   'bare_relay_vs_bare_pingpong': round(v3['volleys_per_s']
                                                        / v['volleys_per_s'], 3),
                   'bare_serialized_round_trips_per_s': round(vw['volleys_per_s'], 1),
                   'lockstep_vs_bare_serialized': round(f['steps_per_s'] / vw['volleys_per_s'],
                                                        3)})


if __name__ == '__main__':
    sys.exit(main())
