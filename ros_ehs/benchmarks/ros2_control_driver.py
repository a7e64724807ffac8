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
A rig driver written to ros2_control's conventions, for tests and benchmarks (not our plant).

One process: a hardware interface whose "hardware" is the model (``Plant``), a
joint_state_broadcaster and a forward command controller, in ros2_control's cycle at
``--rate`` Hz: read (sample the piston), update (publish ``/joint_states``: every joint, the
piston among others, position only, stamped with the cycle's time; take the newest
``/<controller>/commands`` Float64MultiArray), write (apply it over the coming period). Both
topics use ROS 2's system-default QoS (reliable, keep last 10), as ros2_control's do, and no
watchdog: the last command holds, as a forward command controller holds it. At SIGINT it
prints one JSON line: cycles, commands taken, cycles whose command was not new (the
controller's answer came after the cycle: the command is two periods late or more), and the
state it ended in.

``--lockstep``: the same cycle on a simulated clock, for tests that must not depend on the
machine's timing: each cycle's states are stamped on that clock, ``/clock`` goes out every 10
cycles (with the first), and the next cycle starts only once the controller has answered
(a command counted for every state; the answer to cycle k is written at cycle k + 1, as in
real time when the controller answers within the period). It starts once the state and
``/clock`` have their listeners, and a cycle unanswered for ``RESEND`` s sends its clock
again (one the reference missed: discovery had matched it on the driver's side only).
``--seconds`` is then simulated time; it exits when done (its JSON line first).
"""

import argparse
import json
import signal
import sys
import time

import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

#: lock-step: a cycle unanswered this long [s] sends its clock again
RESEND = 2.0


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument('--rate', type=float, default=500.0)
    ap.add_argument('--joint', default='actuator_z')
    ap.add_argument('--controller', default='servo_valve_controller')
    ap.add_argument('--model', default='simplified')
    ap.add_argument('--seconds', type=float, default=0.0)
    ap.add_argument('--effort', action='store_true', help="export the piston's effort state "
                    'interface: the hydraulic force from the chamber pressures [N]')
    ap.add_argument('--lockstep', action='store_true', help='cycle on a simulated clock, each '
                    "cycle once the controller's answer to the last has come (see above)")
    ap.add_argument('--wait-subscribers', type=int, default=1, help='lock-step: start once '
                    '/joint_states has this many subscribers')
    ap.add_argument('--rt-priority', type=int, default=0, help='SCHED_FIFO priority of the '
                    "driver's threads, as controller_manager's update loop takes (0: the "
                    'default scheduler)')
    a = ap.parse_args()
    from ros_ehs.core.model.plant import Plant
    from ros_ehs.core.params import Params
    rclpy.init()
    node = rclpy.create_node('rig_driver')
    if a.rt_priority > 0:       # after the node: the middleware's threads exist by now
        from ros_ehs.nodes.scheduling import set_realtime
        print(set_realtime(a.rt_priority), file=sys.stderr, flush=True)
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(JointState, '/joint_states', qos)
    latest = {'cmd': 0.0, 'n': 0, 'max': 0.0}

    def on_cmd(msg: Float64MultiArray) -> None:
        if len(msg.data) >= 1:
            latest['cmd'] = float(msg.data[0])
            latest['n'] += 1
            latest['max'] = max(latest['max'], abs(latest['cmd']))

    node.create_subscription(Float64MultiArray, f'/{a.controller}/commands', on_cmd, qos)
    plant = Plant(Params(), a.model)
    x = plant.equilibrium()
    iz = plant.state_names.index('z')
    ipa, ipb = plant.state_names.index('p_CP'), plant.state_names.index('p_CT')
    a_p = Params()['A_p']
    dt = 1.0 / a.rate
    names = ['table_pitch', a.joint, 'table_roll']
    u = np.zeros(2)
    cycles = [0]
    fresh = {'seen': 0, 'stale': 0}     # cycles whose command was not new since the last one
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))

    clock = {'t0': None, 'steps': 0, 'unread': 0}

    def cycle() -> None:
        # the axis does not wait for its driver: when a stall of this process let two periods
        # or more pass unread, the model runs through them with the command written last, so
        # it stays within two periods of the wall clock; otherwise one period a cycle
        nonlocal x
        now = time.monotonic()
        first = now - (clock['steps'] + 1) * dt  # the timer's phase: its least late cycle's
        clock['t0'] = first if clock['t0'] is None else min(clock['t0'], first)
        behind = int((now - clock['t0']) / dt) - clock['steps']
        n = behind - 1 if behind >= 3 else 1
        clock['unread'] += n - 1
        for _ in range(n):
            x = plant.step(x, u, dt)
        clock['steps'] += n
        msg = JointState()                       # read + joint_state_broadcaster
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.name = names
        msg.position = [0.0, float(x[iz]), 0.0]
        if a.effort:
            msg.effort = [0.0, float(a_p * (x[ipa] - x[ipb])), 0.0]
        pub.publish(msg)
        u[0] = latest['cmd']                     # forward command controller + write
        if latest['n'] == fresh['seen']:
            fresh['stale'] += 1
        fresh['seen'] = latest['n']
        cycles[0] += 1

    plant.step(x, u, dt)          # compile (or load) the model's kernels before the loop runs
    if a.lockstep:
        lockstep(node, a, plant, pub, latest, stop)
        x = plant.x_final
    else:
        node.create_timer(dt, cycle)
        t_end = time.monotonic() + a.seconds if a.seconds > 0 else float('inf')
        while not stop and time.monotonic() < t_end:
            rclpy.spin_once(node, timeout_sec=0.05)
    print(json.dumps({'cycles': cycles[0], 'commands': latest['n'], 'z': float(x[iz]),
                      'last_command_a': latest['cmd'], 'max_command_a': latest['max'],
                      'stale_cycles': fresh['stale'], 'unread_periods': clock['unread']}),
          flush=True)
    # a reliable writer that is destroyed drops what its readers have not acknowledged: the
    # last state (lock-step) would miss a recorder now and then
    pub.wait_for_all_acked(Duration(seconds=5.0))
    node.destroy_node()
    rclpy.shutdown()
    return 0


def lockstep(node, a, plant, pub, latest, stop) -> None:
    """Cycle on a simulated clock, one cycle per answer (see the module docstring)."""
    from rosgraph_msgs.msg import Clock
    from ros_ehs.core.params import Params
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    clock_pub = node.create_publisher(Clock, '/clock', qos)
    x = plant.equilibrium()
    iz = plant.state_names.index('z')
    ipa, ipb = plant.state_names.index('p_CP'), plant.state_names.index('p_CT')
    a_p = Params()['A_p']
    dt_ns = int(round(1e9 / a.rate))
    t0 = 10**9
    u = np.zeros(2)
    answer = 0.0                  # the answer to the last cycle: written at this one
    # the state's listeners, and the clock's (the reference under sim time)
    while not stop and (pub.get_subscription_count() < a.wait_subscribers or
                        clock_pub.get_subscription_count() < 1):
        rclpy.spin_once(node, timeout_sec=0.05)
    for _ in range(20):           # and let every endpoint match before the first cycle
        rclpy.spin_once(node, timeout_sec=0.05)
    steps = int(round(a.seconds * a.rate)) if a.seconds > 0 else 10**12
    c = None
    for k in range(steps + 1):
        if stop:
            break
        stamp = t0 + k * dt_ns
        if k % 10 == 0:
            c = Clock()
            c.clock.sec, c.clock.nanosec = divmod(stamp, 10**9)
            clock_pub.publish(c)
        msg = JointState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
        msg.name = ['table_pitch', a.joint, 'table_roll']
        msg.position = [0.0, float(x[iz]), 0.0]
        if a.effort:
            msg.effort = [0.0, float(a_p * (x[ipa] - x[ipb])), 0.0]
        pub.publish(msg)
        if k == steps:
            break
        want = k + 1                       # a command for every state so far
        asked = time.monotonic()
        while not stop and latest['n'] < want:
            rclpy.spin_once(node, timeout_sec=0.05)
            if time.monotonic() - asked > RESEND:
                # a clock the reference missed (matched on our side only, as discovery
                # goes): its window never came, the controller cannot answer; say it again
                clock_pub.publish(c)
                asked = time.monotonic()
        u[0] = answer                      # write: the answer to the last cycle's state
        answer = latest['cmd']
        x = plant.step(x, u, dt_ns * 1e-9)
    plant.x_final = x


if __name__ == '__main__':
    sys.exit(main())
