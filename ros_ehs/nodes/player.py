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
The player node: replays a bag with its recorded timing.

``bag`` is a bag directory or ``.mcap`` file (ours or rosbag2's). ``rate`` scales time (2.0
plays twice as fast); ``topics`` selects topics (default all); ``loop`` starts over at the
end; ``clock`` publishes ``/clock`` with the bag's time (every ``1 / clock_hz`` of bag time and
before each message) so ``use_sim_time`` nodes follow the replay. Discovery between
processes takes up to seconds: ``wait_subscribers`` holds the first message until every
replayed topic has that many subscribers, then ``start_delay`` passes. Each topic is re-offered
with the QoS it was recorded with. Topics whose message type is not installed are skipped
with a warning naming them. The node exits when the bag is done (unless ``loop``).

With ``topic_map`` (a rig's map, docs/identification.md) it replays a rig driver's bag as
this package's contract instead: ``state`` (joint ``piston``: the position, the velocity as
recorded or derived, and joint ``servo_valve``: the current of each period, built from the
commands with the map's ``input_delay``, 0 when it says auto), ``servo_current`` and the
chamber pressures, on a uniform grid, stamped on the driver's clock: what identification reads
from that bag, so any node of ours can follow a rig's recording.

A split bag (rosbag2's or ours) plays as one bag, in file order; sqlite3 bags play too. The
bag is read into memory first: for a long recording, replay a window (``start``/``end``,
seconds from its first message), which reads only the files it overlaps.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
from rclpy.node import Node
from rclpy.task import Future
from ros_ehs.core.errors import BagError
from ros_ehs.core.options import PLAYER
from ros_ehs.data.bag.reader import BagMessage, open_bag
from ros_ehs.data.experiments import load_experiments
from ros_ehs.data.mapping import load_topic_map
from ros_ehs.nodes.parameters import declare_settings
from ros_ehs.nodes.ros_common import msg_class, qos_profile, run
import ros_ehs_msgs_py as contract
from rosgraph_msgs.msg import Clock

__all__ = ['OPTIONS', 'PlayerNode', 'main']

#: the node's options (declared in :mod:`ros_ehs.core.options`)
OPTIONS = PLAYER


def contract_messages(experiments) -> list[BagMessage]:
    """Return a rig's runs as the contract's messages, in time order (the player's map)."""
    out = []
    for e in experiments:
        stamps = e.t0_ns + np.round(e.t * 1e9).astype(np.int64)
        held = np.concatenate([[e.i[0]], e.i[:-1]])   # state k: the period that ended there
        for k, st in enumerate(stamps.tolist()):
            out.append(BagMessage('/' + contract.STATE.name, st, st, contract.state_to_cdr(
                contract.AxisState(st, float(e.z[k]), float(e.v[k]), math.nan, math.nan,
                                   float(held[k]))), contract.STATE.msg_type))
            out.append(BagMessage('/' + contract.COMMAND.name, st, st, contract.command_to_cdr(
                contract.Command(st, float(e.i[k]))), contract.COMMAND.msg_type))
            if e.p_a is not None:
                for tp, p in ((contract.PRESSURE_P, e.p_a[k]), (contract.PRESSURE_T, e.p_b[k])):
                    out.append(BagMessage('/' + tp.name, st, st, contract.pressure_to_cdr(
                        contract.Pressure(st, float(p))), tp.msg_type))
    out.sort(key=lambda m: m.log_time_ns)
    return out


class PlayerNode(Node):
    """Replay a bag (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('player', **kwargs)
        self.opt = declare_settings(self, OPTIONS)
        if not self.opt['bag']:
            raise BagError('parameter `bag` is empty: give the bag to replay '
                           '(-p bag:=bags/sample_sine_1hz)')
        self.bag = open_bag(self.opt['bag'], start=float(self.opt['start']) or None,
                            end=float(self.opt['end']) or None)
        if self.bag.truncated:
            self.get_logger().warning(f'bag is truncated ({self.bag.problem}); replaying what '
                                      'it holds')
        self._mapped: list[BagMessage] | None = None
        available = {n: (i.msg_type, i.qos[0] if i.qos else None)
                     for n, i in self.bag.topics.items()}
        if self.opt['topic_map']:
            tmap = load_topic_map(self.opt['topic_map'])
            if tmap.input_delay is None:
                self.get_logger().warning('the map says input_delay: auto; the player replays '
                                          'the commands undelayed (give it in the map)')
            exps = load_experiments(self.opt['bag'], topics=tmap, bag=self.bag)
            self._mapped = contract_messages(exps)
            available = {m.topic: (m.msg_type, None) for m in self._mapped[:8]}
        wanted = list(self.opt['topics']) or list(available)
        missing = [t for t in wanted if t not in available]
        if missing:
            raise BagError(f'bag {self.opt["bag"]!r} has no topic {missing}; it has: '
                           + (', '.join(sorted(available)) if self._mapped is not None
                              else self.bag.describe()))
        self.pubs = {}
        for name in wanted:
            msg_type, qos = available[name]
            try:
                cls = msg_class(msg_type)
            except KeyError as err:
                self.get_logger().warning(f'skipping {name}: {err}')
                continue
            offered = contract.QosSpec.from_rosbag2(qos)
            self.pubs[name] = self.create_publisher(cls, name, qos_profile(offered))
        if not self.pubs:
            raise BagError(f'nothing to replay: no topic of {wanted} has an installed type')
        self.pub_clock = None
        if self.opt['clock'] and contract.CLOCK.name not in self.pubs:
            self.pub_clock = self.create_publisher(Clock, contract.CLOCK.name,
                                                   qos_profile(contract.CLOCK.qos))
        self.published = dict.fromkeys(self.pubs, 0)
        self.done = Future()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._play, daemon=True)
        self._thread.start()
        self.get_logger().info(f'replaying {sorted(self.pubs)} from {self.opt["bag"]} at '
                               f'rate {self.opt["rate"]:g}')

    def _tick_clock(self, t_ns: int) -> None:
        if self.pub_clock is not None:
            m = Clock()
            m.clock.sec, m.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
            self.pub_clock.publish(m)

    def _play(self) -> None:
        try:
            self._replay()
        except Exception as err:  # noqa: B902 - a thread must report, not vanish
            self.get_logger().error(f'replay failed: {err}')
            self.done.set_result(1)

    def _replay(self) -> None:
        if self._mapped is not None:
            msgs = [m for m in self._mapped if m.topic in self.pubs]
        else:
            msgs = list(self.bag.messages(list(self.pubs)))
        rate = float(self.opt['rate'])
        clock_step = int(1e9 / float(self.opt['clock_hz']))
        need = int(self.opt['wait_subscribers'])
        if need:
            self.get_logger().info(f'waiting for {need} subscriber(s) on each of '
                                   f'{sorted(self.pubs)}')
            while min(p.get_subscription_count() for p in self.pubs.values()) < need:
                if self._stop.wait(0.01):
                    return
        if self._stop.wait(float(self.opt['start_delay'])):
            return
        while msgs and not self._stop.is_set():
            t0_bag = msgs[0].log_time_ns
            t0 = time.monotonic()
            next_clock = t0_bag
            for m in msgs:
                # /clock ticks up to this message, then the message itself, on time
                while self.pub_clock is not None and next_clock < m.log_time_ns:
                    if self._wait(t0 + (next_clock - t0_bag) * 1e-9 / rate):
                        return
                    self._tick_clock(next_clock)
                    next_clock += clock_step
                if self._wait(t0 + (m.log_time_ns - t0_bag) * 1e-9 / rate):
                    return
                self._tick_clock(m.log_time_ns)
                self.pubs[m.topic].publish(m.data)
                self.published[m.topic] += 1
            if not self.opt['loop']:
                break
        self.get_logger().info('replay done: ' + ', '.join(
            f'{k} {v}' for k, v in self.published.items()))
        self.done.set_result(0)

    def _wait(self, due: float) -> bool:
        """Sleep until ``due`` (monotonic); True if asked to stop."""
        dt = due - time.monotonic()
        return self._stop.wait(dt) if dt > 0 else self._stop.is_set()

    def close(self) -> None:
        """Stop the replay thread."""
        self._stop.set()
        self._thread.join(timeout=2.0)


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs player``."""
    return run(PlayerNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
