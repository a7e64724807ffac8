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
The recorder node: topics into a rosbag2-style MCAP bag (:class:`ros_ehs.bag.BagWriter`).

Subscriptions are raw (the CDR bytes go to the file without a decode). ``topics`` defaults
to every contract topic of this namespace; other topics named there are subscribed when
they appear on the graph (their type is discovered). As in rosbag2, a topic is subscribed
when its first publisher is discovered, with QoS adapted to the publishers: reliable if every
one offers reliable (the loop topics in lock-step), else best effort; depth ``depth``. The
log line ``recording <topic> (<type>, <reliability>)`` says when. The
``offered_qos_profiles`` stored are the publishers'.

Crash safety is the writer's: the open chunk is closed and flushed every ``flush_period``
(default 50 ms, also on a timer when traffic stops), so SIGKILL loses at most that much.
SIGINT/SIGTERM close the bag properly (summary, metadata.yaml).
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
import time

from rclpy.node import Node
from ros_ehs.bag.writer import BagWriter
from ros_ehs.nodes.ros_common import (declare_options, msg_class, Option, qos_profile,
                                      qos_spec, run, steady_clock)
import ros_ehs_msgs_py as contract

__all__ = ['OPTIONS', 'RecorderNode', 'main', 'default_bag_path']

OPTIONS = (
    Option('out', '', 'bag directory to create (default bags/ehs_<UTC time>)'),
    Option('topics', [], 'topics to record (default: every contract topic)'),
    Option('flush_period', 0.05, 'close the open chunk and flush at least this often [s]: '
           'the most a crash can lose', 0.005, 10.0),
    Option('fsync', False, 'also fsync on every flush (survives power loss)'),
    Option('depth', 1000, 'subscription queue depth', 1, 100000),
    Option('discovery_period', 0.2, 'how often to look for listed topics not yet seen [s]',
           0.05, 60.0),
)


def default_bag_path() -> Path:
    """Return ``bags/ehs_<UTC time>`` (rosbag2's ``rosbag2_<time>`` convention)."""
    return Path('bags') / datetime.now(timezone.utc).strftime('ehs_%Y_%m_%d-%H_%M_%S')


class RecorderNode(Node):
    """Record topics to a bag (see the module docstring)."""

    #: after SIGINT, keep taking in the messages DDS has already queued for this long [s]
    drain_period = 0.3

    def __init__(self, **kwargs) -> None:
        super().__init__('recorder', **kwargs)
        self.opt = declare_options(self, OPTIONS)
        out = Path(self.opt['out'] or default_bag_path())
        self.writer = BagWriter(out, flush_period=float(self.opt['flush_period']),
                                fsync=bool(self.opt['fsync']))
        self.path = out
        self._subs = {}
        self._dirty = False
        wanted = list(self.opt['topics']) or [t.name for t in contract.TOPICS]
        self._wanted = {self.resolve_topic_name(n): n for n in wanted}
        self._discover()
        self.create_timer(float(self.opt['discovery_period']), self._discover,
                          clock=steady_clock())
        self.create_timer(float(self.opt['flush_period']), self._flush, clock=steady_clock())
        self.get_logger().info(f'recording {sorted(self._wanted)} to {out}')

    def _subscribe(self, full: str, msg_type: str, offered: list, reliability: str) -> None:
        """Subscribe raw to ``full`` and add it to the bag (a type not installed: warn)."""
        try:
            cls = msg_class(msg_type)
        except KeyError as err:
            self.get_logger().warning(f'not recording {full}: {err}')
            self._subs[full] = None
            return
        self.writer.add_topic(full, msg_type, offered)
        qos = qos_profile(contract.QosSpec(reliability, int(self.opt['depth'])))
        write = self.writer.write
        if self.get_parameter('use_sim_time').value:
            clock = self.get_clock()

            def now() -> int:
                return clock.now().nanoseconds
        else:
            now = time.time_ns      # the same system time, without a Time object

        def on_msg(data: bytes, topic=full) -> None:
            write(topic, data, now())
            self._dirty = True

        self._subs[full] = self.create_subscription(cls, full, on_msg, qos, raw=True)
        self.get_logger().info(f'recording {full} ({msg_type}, {reliability})')

    def _discover(self) -> None:
        missing = [t for t in self._wanted if t not in self._subs]
        if not missing:
            return
        types = None
        for full in missing:
            pubs = self.get_publishers_info_by_topic(full)
            if not pubs:
                continue
            if types is None:
                types = dict(self.get_topic_names_and_types())
            try:
                msg_type = contract.by_name(self._wanted[full]).msg_type
            except KeyError:
                if full not in types:
                    continue
                msg_type = types[full][0]
            specs = [qos_spec(p.qos_profile) for p in pubs]
            rel = ('reliable' if all(q.reliability == 'reliable' for q in specs)
                   else 'best_effort')
            self._subscribe(full, msg_type, [q.as_rosbag2() for q in specs], rel)

    def _flush(self) -> None:
        if self._dirty:
            self._dirty = False
            self.writer.flush()

    def close(self) -> None:
        """Close the bag (summary and metadata.yaml) and log what it holds."""
        if self.writer.closed:
            return
        self.writer.close()
        counts = ', '.join(f'{k} {n}' for k, n in self.writer.counts.items())
        print(f'[recorder] closed {self.path}: {self.writer.count} messages ({counts})',
              flush=True)


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs recorder``."""
    return run(RecorderNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
