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
Force control over real DDS, with the real nodes in lock-step, and on a rig driver of our own.

A mode switch on a running loop (a refusal first), a specimen that breaks under force control
and ends held in displacement, each checked in the bag as rosbags reads it (a reader we did
not write): the load cell's WrenchStamped, the states, the commands and the events. Then the
controller on a rig driver written here, to ros2_control's conventions: its own joint name
(position only), a force/torque broadcaster's WrenchStamped on its own topic and axis, a
forward command controller's commands written a cycle late.
"""

import math
import sys

import numpy as np
import pytest
from ros_ehs.core.control.safety import break_travel
from ros_ehs.core.params import preset
from ros_ehs.nodes.processes import NodeProcesses, recording
import ros_ehs_msgs_py as c
from waits import (BOUND, lockstep_complete, Paused, set_parameter, wait_for_bag,
                   wait_value)

pytestmark = pytest.mark.ros
#: the fatigue rig with a compliant specimen (the force benchmark's), its force gains tuned
SPECIMEN = {'k_L': 5.0e6, 'F_cc': 50.0, 'F_sc': 100.0}
GAINS = {'force_kp': 1.675e-7, 'force_ki': 5.0e-7, 'k_L': 5.0e6}
FAST = {'diagnostics_period': 0.05}


def _bag(bag, load_topic='/load_cell', axis='force.z'):
    """Return states, loads, commands ({stamp: value}) and events, decoded by rosbags."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    states, loads, cmds, events = {}, {}, {}, []
    comp, ax = axis.split('.')
    with Reader(bag) as r:
        for conn, _, raw in r.messages():
            m = ts.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == '/state':
                s = c.state_from_msg(m)
                states[s.stamp_ns] = s
            elif conn.topic == load_topic:
                st = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                loads[st] = getattr(getattr(m.wrench, comp), ax)
            elif conn.topic == '/servo_current':
                k = c.command_from_msg(m)
                cmds[k.stamp_ns] = k.i
            elif conn.topic == '/events':
                events.append(c.event_from_msg(m))
    return states, loads, cmds, events


def _set(ros, name, value, node='/controller'):
    """Set a parameter through the node's parameter service: (successful, reason)."""
    res = set_parameter(ros, node, name, value)
    return res.successful, res.reason


def test_a_mode_switch_on_a_running_loop_is_bumpless_and_a_refused_one_says_why(
        dom, tmp_path, ros):
    bag = tmp_path / 'bag'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start_loop('lockstep', bag=bag,
                         plant={'duration': 3.0, **SPECIMEN, **FAST},
                         controller={**GAINS, 'protect_force': 100.0, **FAST},
                         reference={'kind': 'step', 'amplitude': 0.0006, 'step_time': 0.1,
                                    'rise': 0.5})
        wait_value(procs, c.PLANT_STATUS, 'steps', 1500)        # held still at 3 kN
        with Paused(ros):
            ok, why = _set(ros, 'control_mode', 'displacement_force_limited')
            assert not ok and 'beyond protect_force 100 N' in why, why
            ok, why = _set(ros, 'control_mode', 'force')
            assert ok, why
        assert procs.wait_status(c.CONTROLLER_STATUS,
                                 lambda st: st.values.get('driving') == 'force', BOUND)
        lockstep_complete(procs)
        wait_for_bag(bag, {'/state': 3001, '/load_cell': 3001, '/events': 2})
        procs.stop(['recorder', 'reference', 'controller', 'plant'])
    states, loads, cmds, events = _bag(bag)
    assert [(e.kind, e.detector) for e in events] == [
        ('mode_refused', 'displacement_force_limited'), ('mode', 'force')]
    assert 'beyond protect_force' in events[0].message
    switch = events[1].stamp_ns
    stamps = np.array(sorted(loads))
    f = np.array([loads[s] for s in stamps])
    # the load cell in the state and on its own topic are the same reading
    assert all(states[s].load == loads[s] for s in stamps[::97])
    k = int(np.searchsorted(stamps, switch))
    f0 = f[k]
    assert 2.5e3 < f0 < 3.5e3                      # loaded: 0.6 mm into 5e6 N/m
    # bumpless: the force holds where it was (the reference carries no force) and the valve
    # command has no step
    assert np.max(np.abs(f[k:k + 500] - f0)) < 0.01 * 1e4
    i = np.array([cmds[s] for s in stamps[k - 20:k + 20]])
    assert np.max(np.abs(np.diff(i))) < 0.01 * preset('table1_estimated')['i_rated']
    # and it holds it to the end
    assert np.max(np.abs(f[k:] - f0)) < 0.01 * 1e4


def test_a_break_under_force_control_ends_held_in_displacement(dom, tmp_path):
    bag = tmp_path / 'bag'
    life = {'specimen_life': 8.0, 'specimen_life_range': 9e3, 'specimen_compliance': 0.0}
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start_loop('lockstep', bag=bag,
                         plant={'duration': 4.0, **SPECIMEN, **life, **FAST},
                         controller={**GAINS, 'control_mode': 'force', **FAST},
                         reference={'control_mode': 'force', 'amplitude': 4.5e3,
                                    'offset': 5.5e3, 'frequency': 5.0})
        assert procs.wait_status(
            c.CONTROLLER_STATUS,
            lambda st: 'specimen_break' in st.values.get('tripped', '').split(','), BOUND), \
            procs['controller'].output()[-3000:]
        lockstep_complete(procs)
        wait_for_bag(bag, {'/state': 4001, '/events': 2})
        procs.stop(['recorder', 'reference', 'controller', 'plant'])
    states, loads, cmds, events = _bag(bag)
    assert [(e.kind, e.detector, e.action) for e in events] == [
        ('trip', 'specimen_break', 'hold'), ('mode', 'displacement', 'hold')]
    stamps = np.array(sorted(states))
    f = np.array([loads[s] for s in stamps])
    z = np.array([states[s].z for s in stamps])
    kb = int(np.argmax((f == 0.0) & (stamps > stamps[0] + 10**9)))
    assert f[kb] == 0.0 and np.all(f[kb:] == 0.0)            # the force path is lost
    peak = f[kb - 60:kb].max()
    assert peak > 8e3
    trip = events[0].stamp_ns
    assert 0 <= trip - stamps[kb] <= 20 * 1_000_000          # detected within 20 periods
    p = preset('table1_estimated', **SPECIMEN)
    travel = np.max(np.abs(z[kb:] - z[kb]))
    assert travel <= break_travel(p, peak, 1e-3)
    assert np.max(np.abs(z)) < p['stroke'] - 0.09              # nowhere near the end stop


#: a rig driver to ros2_control's conventions, written here: the model (our simulated axis as
#: its hardware) behind its own joint name, a force/torque broadcaster's wrench on force.x,
#: and a forward command controller whose command is written at the next cycle; lock-step on
#: its own /clock, so the run does not depend on the machine's timing
DRIVER = r"""
import json, sys
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from geometry_msgs.msg import WrenchStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from ros_ehs.core.params import preset
from ros_ehs.core.sim.axis import SimulatedAxis

seconds, k_l = float(sys.argv[1]), float(sys.argv[2])
rclpy.init()
node = rclpy.create_node('rig')
qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
js = node.create_publisher(JointState, '/joint_states', qos)
ws = node.create_publisher(WrenchStamped, '/fts_broadcaster/wrench', qos)
ck = node.create_publisher(Clock, '/clock', qos)
axis = SimulatedAxis(preset('table1_estimated', k_L=k_l, F_cc=50.0, F_sc=100.0), 'full',
                     lockstep=True)
state = {'answers': 0, 'written': 0.0, 'k': 0}

def publish():
    s = axis.sample()
    sec, nsec = divmod(s.state.stamp_ns, 10**9)
    m = JointState(name=['actuator'], position=[s.state.z])
    m.header.stamp.sec, m.header.stamp.nanosec = sec, nsec
    w = WrenchStamped()
    w.header.stamp.sec, w.header.stamp.nanosec = sec, nsec
    w.header.frame_id = 'load_cell_link'
    w.wrench.force.x = s.load
    if state['k'] % 10 == 0:
        cm = Clock()
        cm.clock.sec, cm.clock.nanosec = sec, nsec
        ck.publish(cm)
        state['clock'] = cm
    ws.publish(w)
    js.publish(m)

def on_cmd(msg):
    # write the previous cycle's answer over this period, then the next cycle
    i, state['written'] = state['written'], float(msg.data[0])
    axis.step(i)
    axis.k += 1
    state['k'] += 1
    state['answers'] += 1
    publish()

node.create_subscription(Float64MultiArray, '/servo_valve_controller/commands', on_cmd, qos)
while js.get_subscription_count() < 2 or ws.get_subscription_count() < 2 or \
        ck.get_subscription_count() < 1:
    rclpy.spin_once(node, timeout_sec=0.05)
for _ in range(20):
    rclpy.spin_once(node, timeout_sec=0.05)
publish()
while state['k'] < seconds * 1000:
    k = state['k']
    rclpy.spin_once(node, timeout_sec=2.0)
    if state['k'] == k and 'clock' in state:   # unanswered: a clock the reference missed
        ck.publish(state['clock'])
print(json.dumps({'cycles': state['k'], 'load': axis.sample().load}), flush=True)
"""


def test_force_control_on_a_rig_driver_that_publishes_its_own_wrench(dom, tmp_path):
    bag = tmp_path / 'bag'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start('recorder', {'out': str(bag), 'use_sim_time': True,
                                 'topics': ['/joint_states', '/fts_broadcaster/wrench',
                                            '/servo_valve_controller/commands', '/events']})
        assert procs.wait_status(c.RECORDER_STATUS, lambda st: True, BOUND)
        procs.start('controller', {
            'state_topic': '/joint_states', 'joint': 'actuator', 'lockstep': True,
            'command_interface': 'forward_command', 'load_topic': '/fts_broadcaster/wrench',
            'load_axis': 'force.x', 'control_mode': 'force', 'ramp_time': 0.2, **GAINS,
            **FAST})
        procs.start('reference', {'use_sim_time': True, 'control_mode': 'force',
                                  'kind': 'step', 'amplitude': 3.0e3, 'step_time': 0.3,
                                  'rise': 0.2})
        assert procs.wait_status(c.RECORDER_STATUS,
                                 recording('/servo_valve_controller/commands'), BOUND)
        drv = procs.start('driver', cmd=[sys.executable, '-c', DRIVER, '2.0', '5e6'])
        assert drv.popen.wait(BOUND) == 0, drv.output()[-3000:]
        wait_for_bag(bag, {'/fts_broadcaster/wrench': 2001})
        procs.stop(['recorder', 'reference', 'controller'])
        status = procs.status(c.CONTROLLER_STATUS)
    _, loads, _, events = _bag(bag, '/fts_broadcaster/wrench', 'force.x')
    assert events == []
    stamps = sorted(loads)
    f = np.array([loads[s] for s in stamps])
    t = (np.array(stamps) - stamps[0]) * 1e-9
    # the force follows the reference's step to 3 kN and holds it, within 1 %
    assert np.max(np.abs(f[t > 1.5] - 3e3)) < 30.0, f[t > 1.5][:10]
    assert status.values['control_mode'] == 'force' and status.values['driving'] == 'force'
    assert math.isfinite(float(status.values['load_n']))
