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
``python -m ros_ehs.benchmarks record``: how many messages per second the recorder node keeps.

A publisher process sends numbered JointState messages (the size of a ``state`` message) on
a reliable topic at a set rate for ``--seconds``; the recorder node records them; the bench
then counts what the bag holds and which numbers are missing. Rates are tried from
``--rates`` in order, for each chunk compression of ``--compressions``; ``msgs_per_s`` is
the highest rate recorded without loss (per compression in ``by_compression``, with the
recorder's CPU share at that rate). In the same run, the raw write speed of
:class:`ros_ehs.data.bag.BagWriter` (no DDS) is the yardstick. Then ``--kills`` real-time
benches whose recorder is SIGKILLed mid-run: what each kill lost, ``sigkill_lost_ms`` (the
kill's time against the bag's last message; the recorder flushes every 50 ms). Last line:
one JSON object.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time

from domain_coordinator import domain_id
import numpy as np
import psutil
from ros_ehs.benchmarks import BOUND, positive, positives, report
from ros_ehs.core.errors import EhsError
from ros_ehs.data.bag import BagWriter, open_bag
from ros_ehs.nodes.processes import NodeProcesses, recording
import ros_ehs_msgs_py as contract

TOPIC = '/bench/blast'

_PUBLISHER = """
import sys, time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
import ros_ehs_msgs_py as c
rate, seconds, bound = float(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
rclpy.init()
node = rclpy.create_node('blaster')
pub = node.create_publisher(JointState, '{topic}', QoSProfile(
    depth=1000, reliability=ReliabilityPolicy.RELIABLE))
t_end = time.monotonic() + bound
while pub.get_subscription_count() < 1:
    if time.monotonic() >= t_end:
        print(f'no subscriber to {topic} within {{bound:g}} s: nothing sent', file=sys.stderr)
        sys.exit(3)
    time.sleep(0.05)
time.sleep(1.0)
m = JointState()
n = int(rate * seconds)
t0 = time.monotonic()
for k in range(1, n + 1):
    c.fill_state(m, c.AxisState(k, 0.01, 0.02, 3.0, 4e-5, 0.001))
    pub.publish(m)
    if k % 20 == 0:
        d = t0 + k / rate - time.monotonic()
        if d > 0:
            time.sleep(d)
print('sent', n, n / (time.monotonic() - t0), flush=True)
time.sleep(1.0)
""".format(topic=TOPIC)


def _one(dom: int, rate: float, seconds: float, out: str, compression: str) -> dict:
    with NodeProcesses(dom, bound=BOUND) as procs:
        rec = procs.start('recorder', {'out': out, 'topics': [TOPIC], 'depth': 10000,
                                       'compression': compression})
        if not procs.wait_status(contract.RECORDER_STATUS, lambda st: True):
            raise RuntimeError(f'the recorder did not start within {BOUND:g} s:\n'
                               + rec.output()[-2000:])
        pub = procs.start('pub', cmd=[sys.executable, '-c', _PUBLISHER, str(rate),
                                      str(seconds), str(BOUND)])
        if not procs.wait_status(contract.RECORDER_STATUS, recording(TOPIC)):
            raise RuntimeError(f'the recorder did not discover {TOPIC} within {BOUND:g} s:\n'
                               + rec.output()[-2000:])
        proc = psutil.Process(rec.pid)
        c0 = sum(proc.cpu_times()[:2])
        t0 = time.monotonic()
        code = pub.popen.wait(seconds * 10 + BOUND)
        cpu = (sum(proc.cpu_times()[:2]) - c0) / (time.monotonic() - t0)
        if code != 0:
            raise RuntimeError(f'the publisher exited with {code}:\n' + pub.output()[-2000:])
        procs.stop(['recorder'])
        sent_line = [x for x in pub.output().splitlines() if x.startswith('sent')][-1]
    n, achieved = int(sent_line.split()[1]), float(sent_line.split()[2])
    bag = open_bag(out)
    seqs = np.array([contract.state_from_msg(m).stamp_ns for _, m in bag.decoded([TOPIC])])
    lost = n - len(np.unique(seqs))
    return {'compression': compression, 'rate': rate, 'sent': n,
            'achieved_rate': round(achieved, 1),
            'recorded': int(seqs.size), 'lost': int(lost), 'recorder_cpu_frac': round(cpu, 3)}


def _raw_writer_rate(compression: str, n: int = 100000) -> float:
    m = contract.fill_state(contract.empty_msg(contract.STATE.msg_type),
                            contract.AxisState(1, 0.01, 0.02, 3.0, 4e-5, 0.001))
    with tempfile.TemporaryDirectory() as d:
        w = BagWriter(f'{d}/raw', compression=compression)
        w.add_topic(TOPIC, contract.STATE.msg_type, contract.RECORD_QOS)
        w.write_msg(TOPIC, m, 1)
        data = bytes(w._encoders[contract.STATE.msg_type](m))
        t0 = time.perf_counter()
        for k in range(n):
            w.write(TOPIC, data, k + 2)
        w.close()
        return n / (time.perf_counter() - t0)


def main(argv=None) -> int:
    """Run the benchmark; print figures, the last line JSON."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks record')
    ap.add_argument('--seconds', type=positive, default=5.0)
    ap.add_argument('--rates', type=positives, default=[20000.0, 25000.0, 30000.0],
                    help='message rates, comma-separated [1/s]')
    ap.add_argument('--compressions', default='none,zstd')
    ap.add_argument('--kills', type=int, default=3, help='benches whose recorder is SIGKILLed '
                    'mid-run, to measure what a kill loses (0: none)')
    a = ap.parse_args(argv)
    comps = a.compressions.split(',')
    if not set(comps) <= {'none', 'zstd', 'lz4'}:
        ap.error('--compressions takes none, zstd or lz4, comma-separated')
    runs = []
    with domain_id() as dom, tempfile.TemporaryDirectory() as tmp:
        for comp in comps:
            for k, r in enumerate(a.rates):
                res = _one(dom, r, a.seconds, f'{tmp}/bag_{comp}_{k}', comp)
                print(f'  {comp:>5} rate {r:>8.0f}/s: {res}', flush=True)
                runs.append(res)
    by = {}
    for comp in comps:
        ok = [x for x in runs if x['compression'] == comp and x['lost'] == 0]
        best = max(ok, key=lambda x: x['achieved_rate'], default=None)
        by[comp] = {'msgs_per_s': best['achieved_rate'] if best else 0.0,
                    'recorder_cpu_frac': best['recorder_cpu_frac'] if best else None,
                    'raw_writer_msgs_per_s': round(_raw_writer_rate(comp), 1)}
    fig = {'msgs_per_s': by[comps[0]]['msgs_per_s'], 'seconds_per_rate': a.seconds,
           'by_compression': by, 'runs': runs,
           'raw_writer_msgs_per_s': by[comps[0]]['raw_writer_msgs_per_s']}
    if a.kills > 0:
        lost = _kills(a.kills)
        fig.update(sigkill_lost_ms=lost, sigkill_lost_ms_max=max(lost))
    return report(fig)


def _kills(n: int) -> list[float]:
    """
    Measure what a SIGKILL of the recorder loses [ms]: the kill against the bag's last message.

    A real-time bench each time, the recorder killed 1.5 s into the recording; the recorder
    flushes every 50 ms (its ``flush_period``), the bound of what a crash can lose.
    """
    out = []
    with domain_id() as dom, tempfile.TemporaryDirectory() as tmp:
        for k in range(n):
            bag = f'{tmp}/killed_{k}'
            with NodeProcesses(dom, f'{tmp}/logs_{k}', bound=BOUND) as procs:
                procs.start_loop('realtime', bag=bag)
                end = time.monotonic() + 120.0
                while time.monotonic() < end:
                    try:
                        if open_bag(bag).topics['/state'].count >= 1500:
                            break
                    except (KeyError, EhsError):       # not written yet
                        pass
                    time.sleep(0.1)
                kill_ns = time.time_ns()
                procs.kill('recorder')
            out.append(round((kill_ns - open_bag(bag).end_ns) / 1e6, 1))
    return out


if __name__ == '__main__':
    sys.exit(main())
