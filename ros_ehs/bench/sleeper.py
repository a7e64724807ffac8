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

``python -m ros_ehs.bench.sleeper --seconds S [--rt-priority N]``. One Python thread sleeps
to each millisecond of a steady grid, as the plant's timer does, and counts the periods it
was not given the CPU for: ``stalls_2ms`` counts the gaps between ticks longer than 2 ms
(consecutive long gaps once), which is what the plant's watchdog rule (3 periods, the last
one ending at the next tick) trips on with a round trip of zero. rclpy is not imported:
whatever stalls here stalls every process, ours and the bare ping-pong alike. Prints one
JSON line.
"""

import argparse
import json
import os
import time


def main(argv=None) -> int:
    """Run the loop for ``--seconds``; print its figures as one JSON line."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.bench.sleeper')
    ap.add_argument('--seconds', type=float, default=20.0)
    ap.add_argument('--rt-priority', type=int, default=0,
                    help='SCHED_FIFO priority, as the loop nodes and the bare ping-pong get')
    a = ap.parse_args(argv)
    if a.rt_priority:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(a.rt_priority))
    period = 1_000_000
    n = int(a.seconds * 1000)
    stalls, stalled, top = 0, False, 0
    last = nxt = time.monotonic_ns()
    for _ in range(n):
        nxt += period
        d = nxt - time.monotonic_ns()
        if d > 0:
            time.sleep(d * 1e-9)
        now = time.monotonic_ns()
        gap = now - last
        last = now
        top = max(top, gap)
        long = gap > 2 * period
        stalls += long and not stalled
        stalled = long
    print(json.dumps({'ticks': n, 'stalls_2ms': stalls, 'max_gap_ms': top * 1e-6}), flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
