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
A bare rclpy ping-pong, the yardstick of ``bench loop``: same executor, QoS and message.

``python -m ros_ehs.bench.pingpong ping|pong``. The ping node publishes a JointState of the
plant's size at ``rate_hz`` on a steady timer; the pong node echoes each one back with its
stamp. On SIGINT the ping node prints its figures (the LoopStats of the plant) as JSON.
"""

from __future__ import annotations

import json
import sys
import time

from rclpy.node import Node
from ros_ehs.nodes.loop_stats import LoopStats
from ros_ehs.nodes.ros_common import qos_profile, run, steady_clock
import ros_ehs_msgs_py as contract
from sensor_msgs.msg import JointState


class Ping(Node):
    """Publish at 1 kHz, measure the echo's round trip."""

    def __init__(self, timer: bool = True) -> None:
        super().__init__('ping')
        self.stats = LoopStats()
        self.k = 0
        self.fresh = False
        self.sent: dict[int, float] = {}
        self.msg = JointState()
        self.pub = self.create_publisher(JointState, 'ping', qos_profile(contract.LOOP_QOS))
        self.create_subscription(JointState, 'pong', self.on_pong,
                                 qos_profile(contract.LOOP_QOS))
        if timer:
            self.create_timer(1e-3, self.tick, clock=steady_clock())

    def tick(self) -> None:
        now = time.monotonic()
        if self.k:
            self.stats.tick(now, self.fresh)
        self.fresh = False
        self.k += 1
        contract.fill_state(self.msg, contract.AxisState(self.k, 0.01, 0.02, 3.0, 4e-5, 0.001))
        self.sent[self.k] = now
        self.sent.pop(self.k - 1000, None)
        self.pub.publish(self.msg)

    def on_pong(self, msg: JointState) -> None:
        t = self.sent.get(contract.stamp_ns(msg.header))
        if t is not None:
            self.stats.rtt.add(time.monotonic() - t)
            self.fresh = True

    def close(self) -> None:
        """Print the figures."""
        print(json.dumps(self.stats.as_dict()), flush=True)


class Volley(Ping):
    """Send the next ping as soon as the echo of the last one is back (a bare lock-step)."""

    def __init__(self) -> None:
        super().__init__(timer=False)
        self.t0 = None
        self.create_timer(0.05, self.kick, clock=steady_clock())

    def kick(self) -> None:
        if self.pub.get_subscription_count() and (self.k == 0 or
                                                  time.monotonic() - self.sent[self.k] > 0.05):
            self.tick()           # start, or restart after a lost message

    def on_pong(self, msg: JointState) -> None:
        super().on_pong(msg)
        if contract.stamp_ns(msg.header) == self.k:
            if self.t0 is None:
                self.t0 = time.monotonic()
            self.tick()

    def close(self) -> None:
        """Print the volleys per second."""
        n = self.stats.rtt.total
        dt = time.monotonic() - (self.t0 or time.monotonic())
        print(json.dumps({'volleys': n, 'volleys_per_s': n / dt if dt > 0 else 0.0}),
              flush=True)


class Pong(Node):
    """Echo every ping as a command."""

    def __init__(self) -> None:
        super().__init__('pong')
        self.msg = JointState()
        self.pub = self.create_publisher(JointState, 'pong', qos_profile(contract.LOOP_QOS))
        self.create_subscription(JointState, 'ping', self.on_ping,
                                 qos_profile(contract.LOOP_QOS))

    def on_ping(self, msg: JointState) -> None:
        s = contract.state_from_msg(msg)
        contract.fill_command(self.msg, contract.Command(s.stamp_ns, s.z))
        self.pub.publish(self.msg)


def main(argv=None) -> int:
    """Run ``ping`` or ``pong``."""
    argv = sys.argv[1:] if argv is None else argv
    return run({'ping': Ping, 'pong': Pong, 'volley': Volley}[argv[0]],
               [sys.argv[0]] + argv[1:])


if __name__ == '__main__':
    raise SystemExit(main())
