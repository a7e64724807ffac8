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
``python -m ros_ehs.benchmarks soak``: the recorded bench, long enough to see what grows.

Runs the bench (plant, controller, reference and recorder, each its own process) for
``--seconds`` (default 600) in real time (``--mode lockstep`` runs as fast as DDS goes and
stands in for more hours of bench time), with the recorder splitting every
``--max-bag-duration`` seconds (default 60) and compressing with ``--compression``.

Every ``--sample`` seconds it reads each node's resident memory (RSS); after the warm-up (the
first third of the run, and at least one split) it fits a line to each node's RSS against
the recorded time and prints the slope in MB per hour of recorded time. It also prints the
bag's bytes per hour as recorded and as the same messages take uncompressed, each node's CPU
share, the files written, and the plant's late commands (over 3 periods old) per hour. Last
line: one JSON
object. The target of a long run: every node's slope <= 5 MB/hour with splitting on.

``--rt-priority`` (default 50, as the demo run's bench runs; 0: the default scheduler) puts
plant and controller on SCHED_FIFO, with ``launch_scripts/fastdds_rt.xml`` for every node
when the source checkout has it, as ``launch_scripts/bench.py`` does.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
import tempfile
import time

from domain_coordinator import domain_id
import numpy as np
import psutil
from ros_ehs.benchmarks import BOUND, positive, report
from ros_ehs.data.bag import BagWriter, open_bag
from ros_ehs.nodes.fastdds_profile import ENV
from ros_ehs.nodes.processes import launch_script, NodeProcesses
import ros_ehs_msgs_py as contract
import yaml

NODES = ('plant', 'controller', 'reference', 'recorder')
RT_PROFILE = launch_script('fastdds_rt.xml')


def _uncompressed_bytes(bag: Path) -> int:
    """Bytes the bag's messages take written again without compression (one file)."""
    src = open_bag(bag)
    with tempfile.TemporaryDirectory() as d:
        with BagWriter(Path(d) / 'plain', compression='none') as w:
            for k, t in src.topics.items():
                w.add_topic(k, t.msg_type, t.qos)
            for m in src.messages():
                w.write(m.topic, m.data, m.log_time_ns, m.publish_time_ns)
        return sum(p.stat().st_size for p in (Path(d) / 'plain').glob('*.mcap'))


def _slope_mb_per_h(t_s: np.ndarray, rss: np.ndarray) -> float:
    return float(np.polyfit(t_s, rss / 1e6, 1)[0] * 3600.0) if t_s.size > 2 else float('nan')


def main(argv=None) -> int:
    """Run the benchmark; print figures, the last line JSON."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks soak')
    ap.add_argument('--seconds', type=positive, default=600.0,
                    help='run length (real time: wall seconds; lock-step: sim seconds)')
    ap.add_argument('--mode', choices=('realtime', 'lockstep'), default='realtime')
    ap.add_argument('--max-bag-duration', type=positive, default=60.0)
    ap.add_argument('--compression', choices=('zstd', 'lz4', 'none'), default='zstd')
    ap.add_argument('--sample', type=positive, default=2.0, help='RSS sampling period [s]')
    ap.add_argument('--keep', default=None, help='keep the bag in this directory')
    ap.add_argument('--rt-priority', type=int, default=50,
                    help="SCHED_FIFO priority of plant and controller (the demo run's 50; 0: "
                    'the default scheduler)')
    a = ap.parse_args(argv)
    lock = a.mode == 'lockstep'
    rt = {'rt_priority': a.rt_priority} if a.rt_priority else {}
    env = {ENV: str(RT_PROFILE)} if rt and RT_PROFILE.is_file() else {}
    with domain_id() as dom, tempfile.TemporaryDirectory() as tmp:
        bag = Path(a.keep) if a.keep else Path(tmp) / 'soak'
        with NodeProcesses(dom, Path(tmp) / 'logs', env=env, bound=BOUND) as procs:
            procs.start_loop(a.mode, bag=bag, controller=rt,
                             plant={**rt, 'duration': a.seconds} if lock else rt,
                             reference={'kind': 'sine', 'rate_hz': 1000.0 if lock else 250.0},
                             recorder={'max_bag_duration': a.max_bag_duration,
                                       'compression': a.compression})
            ps = {n: psutil.Process(procs[n].pid) for n in NODES}
            cpu0 = {n: sum(p.cpu_times()[:2]) for n, p in ps.items()}
            t0 = time.monotonic()
            samples = []                              # (wall s, {node: rss})
            while True:
                samples.append((time.monotonic() - t0,
                                {n: p.memory_info().rss for n, p in ps.items()}))
                done = procs.status(contract.PLANT_STATUS)
                if lock and done is not None and done.message == 'lock-step run complete':
                    break
                if not lock and time.monotonic() - t0 >= a.seconds:
                    break
                if not all(procs[n].alive() for n in NODES):
                    raise RuntimeError('a node stopped: ' + ', '.join(
                        f'{n}: {procs[n].output()[-1500:]}' for n in NODES
                        if not procs[n].alive()))
                time.sleep(a.sample)
            wall = time.monotonic() - t0
            cpu = {n: (sum(p.cpu_times()[:2]) - cpu0[n]) / wall for n, p in ps.items()}
            # the plant before its controller, as bench.py stops them: a plant outliving its
            # controller counts every period until its exit as stale (and a late command)
            codes = procs.stop(['recorder', 'reference', 'plant', 'controller'])
            fig_plant = procs['plant'].figures()
        info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
        rec_h = info['duration']['nanoseconds'] * 1e-9 / 3600.0
        # lock-step: RSS against recorded (sim) time, which runs faster than the wall
        scale = rec_h * 3600.0 / wall if lock else 1.0
        t = np.array([s[0] for s in samples]) * scale
        warm = max(t[-1] / 3.0, a.max_bag_duration * 1.05)
        keep = t >= warm
        slopes = {n: round(_slope_mb_per_h(t[keep], np.array([s[1][n] for s in samples])[keep]),
                           2) for n in NODES}
        size = sum((bag / f).stat().st_size for f in info['relative_file_paths'])
        plain = _uncompressed_bytes(bag)
    late = int(fig_plant.get('late_commands', 0))
    fig = {
        'mode': a.mode, 'rt_priority': a.rt_priority, 'recorded_s': round(rec_h * 3600.0, 1),
        'wall_s': round(wall, 1),
        'compression': a.compression, 'max_bag_duration_s': a.max_bag_duration,
        'files': len(info['relative_file_paths']), 'messages': info['message_count'],
        'rss_slope_mb_per_h': slopes,
        'rss_end_mb': {n: round(samples[-1][1][n] / 1e6, 1) for n in NODES},
        'fit_from_s': round(float(warm), 1),
        'bag_bytes_per_h': int(size / rec_h), 'uncompressed_bytes_per_h': int(plain / rec_h),
        'compression_ratio': round(plain / size, 2),
        'cpu_frac': {n: round(v, 3) for n, v in cpu.items()},
        'late_commands': late,
        'late_commands_per_h': round(late / rec_h, 1) if not lock else None,
        'watchdog_trips': int(fig_plant.get('watchdog_trips', 0)),
        'fresh_cycle_fraction': fig_plant.get('fresh_cycle_fraction'),
        'exit_codes': codes,
        'max_slope_mb_per_h': max(slopes.values()),
    }
    return report(fig)


if __name__ == '__main__':
    sys.exit(main())
