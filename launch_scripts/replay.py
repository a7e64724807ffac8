#!/usr/bin/env python3
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
Replay a bag on the bench network (the player node in the foreground).

    python launch_scripts/replay.py bags/sample_sine_1hz --rate 2 --topics /state,/servo_current

Options map onto the player's parameters: ``--rate``, ``--topics``, ``--loop``,
``--no-clock``, ``--wait-subscribers N`` (hold the first message until every replayed topic
has N subscribers). Ctrl-C stops it; it exits by itself at the end of the bag (unless ``--loop``).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import subprocess
import sys

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # a source checkout works too

from ros_ehs.nodes.processes import node_command  # noqa: E402


def main(argv=None) -> int:
    """Run the player; see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument('bag')
    ap.add_argument('--rate', type=float, default=1.0)
    ap.add_argument('--topics', default='', help='comma-separated (default: all)')
    ap.add_argument('--loop', action='store_true')
    ap.add_argument('--no-clock', action='store_true')
    ap.add_argument('--wait-subscribers', type=int, default=0)
    ap.add_argument('--start', type=float, default=0.0,
                    help='from this time on [s from the first message of the bag]')
    ap.add_argument('--end', type=float, default=0.0, help='up to this time (0: the end) [s]')
    a = ap.parse_args(argv)
    params = {'bag': a.bag, 'rate': float(a.rate), 'loop': a.loop, 'clock': not a.no_clock,
              'wait_subscribers': a.wait_subscribers, 'start': float(a.start),
              'end': float(a.end)}
    topics = [t for t in a.topics.split(',') if t]
    if topics:
        params['topics'] = topics
    try:
        return subprocess.call(node_command('player', params))
    except KeyboardInterrupt:      # the child got the same SIGINT and closes by itself
        return 130


if __name__ == '__main__':
    sys.exit(main())
