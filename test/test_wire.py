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
"""The wire fast path (``ros_ehs_msgs_py.wire``) against rclpy's own serializer."""

import math
import struct

import pytest
import ros_ehs_msgs_py as c

pytestmark = pytest.mark.ros


def test_state_carries_the_applied_current_and_old_states_still_read():
    m = c.fill_state(c.empty_msg(c.STATE.msg_type), c.AxisState(5, 0.1, 0.2, 3.0, 1e-5, 0.004))
    assert m['name'] == ['piston', 'spool', 'servo_valve']
    s = c.state_from_msg(m)
    assert s.i == 0.004 and s.z == 0.1 and s.x_spool == 1e-5
    old = c.fill_state(c.empty_msg(c.STATE.msg_type), c.AxisState(5, 0.1, 0.2, 3.0, 1e-5))
    assert old['name'] == ['piston', 'spool'] and math.isnan(c.state_from_msg(old).i)


def test_wire_reads_any_joint_state_rclpy_serializes_and_writes_what_rclpy_reads():
    import random
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState
    rng = random.Random(8)
    for n in range(1500):      # foreign layouts: names, lengths, frame ids, extreme values
        j = JointState()
        j.header.stamp.sec = rng.randint(-2**31, 2**31 - 1)
        j.header.stamp.nanosec = rng.randint(0, 999_999_999)
        j.header.frame_id = 'f' * rng.randint(0, 6)
        j.name = ['j' * rng.randint(0, 9) for _ in range(rng.randint(0, 4))]
        for f in ('position', 'velocity', 'effort'):
            setattr(j, f, [rng.choice([rng.uniform(-1e308, 1e308), math.inf, -0.0])
                           for _ in range(rng.randint(0, 4))])
        data = serialize_message(j)
        for _ in range(2):     # the second read goes through the cached layout
            d = c.decode_joint_state(data)
            assert d.stamp_ns == j.header.stamp.sec * 10**9 + j.header.stamp.nanosec, n
            assert list(d.name) == list(j.name), n
            for f in ('position', 'velocity', 'effort'):
                assert list(getattr(d, f)) == list(getattr(j, f)), (n, f)
    s = c.AxisState(1_234_567_890_123, 0.01, 0.02, 3.0, 1e-5, 0.004)
    m = deserialize_message(c.state_to_cdr(s), JointState)
    assert list(m.name) == ['piston', 'spool', 'servo_valve'] and c.state_from_msg(m) == s
    m = deserialize_message(c.command_to_cdr(c.Command(-5, 0.001)), JointState)
    assert c.command_from_msg(m) == c.Command(-5, 0.001) and list(m.name) == ['servo_valve']
    r = c.Reference(7, 0.02, -0.3)
    m = deserialize_message(c.reference_to_cdr(r), JointState)
    assert c.reference_from_msg(m) == r == c.reference_from_cdr(serialize_message(m))
    # the records by the same rules as from message objects, foreign joint order included
    other = c.fill_state(JointState(), s)
    other.name, other.position = ['spool', 'piston', 'servo_valve'], [1e-5, 0.01, math.nan]
    other.velocity, other.effort = [0.0, 0.02, 0.0], [0.0, 3.0, 0.004]
    assert c.state_from_cdr(serialize_message(other)) == c.state_from_msg(other) == s
    with pytest.raises(ValueError, match="no joint 'servo_valve'"):
        c.command_from_cdr(serialize_message(c.fill_reference(JointState(),
                                                              c.Reference(0, 0.1, 0.0))))
    for bad, why in ((b'\x00\x01\x00', 'no CDR header'),
                     (b'\x00\x03\x00\x00' + bytes(40), 'encapsulation'),
                     (c.state_to_cdr(s)[:60], 'truncated|bad string')):
        with pytest.raises(ValueError, match=why):
            c.decode_joint_state(bad)


def test_wire_reads_any_joint_trajectory_as_the_message_objects_are_read():
    import random
    from rclpy.serialization import deserialize_message, serialize_message
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
    refs = [c.Reference(5 * 10**9 + k * 10**6, 0.01 * k, -0.5 * k) for k in range(21)]
    data = c.reference_trajectory_to_cdr(refs)
    obj = deserialize_message(data, JointTrajectory)       # rclpy reads what we write
    assert c.reference_trajectory_from_msg(obj) == refs
    assert c.reference_trajectory_from_cdr(data) == refs == c.reference_trajectory_from_cdr(data)
    # the dict form (bag writer) and the rclpy form of the same records agree
    point = 'trajectory_msgs/msg/JointTrajectoryPoint'
    d = c.fill_reference_trajectory(c.empty_msg(c.REFERENCE_TRAJECTORY.msg_type), refs,
                                    lambda: c.empty_msg(point))
    assert c.reference_trajectory_from_msg(d) == refs
    rng = random.Random(3)
    for n in range(400):      # foreign trajectories: more joints, any order, other fields
        m = JointTrajectory()
        m.header.stamp.sec, m.header.stamp.nanosec = rng.randint(0, 2**31 - 1), rng.randint(
            0, 999_999_999)
        m.header.frame_id = 'x' * rng.randint(0, 5)
        names = ['a' * rng.randint(1, 5) for _ in range(rng.randint(0, 3))]
        names.insert(rng.randint(0, len(names)), 'piston')
        m.joint_names = names
        for _ in range(rng.randint(0, 6)):
            p = JointTrajectoryPoint()
            p.positions = [rng.uniform(-1, 1) for _ in range(len(names) + rng.randint(0, 1))]
            p.velocities = [rng.uniform(-1, 1) for _ in range(rng.choice([0, len(names)]))]
            p.accelerations = [rng.uniform(-1, 1) for _ in range(rng.randint(0, 3))]
            p.effort = [rng.uniform(-1, 1) for _ in range(rng.randint(0, 2))]
            p.time_from_start.sec = rng.randint(0, 100)
            p.time_from_start.nanosec = rng.randint(0, 999_999_999)
            m.points.append(p)
        raw = serialize_message(m)
        for _ in range(2):    # the second read goes through the cached layout
            assert c.reference_trajectory_from_cdr(raw) == c.reference_trajectory_from_msg(m), n
    m = JointTrajectory(joint_names=['other'], points=[JointTrajectoryPoint(positions=[1.0])])
    with pytest.raises(ValueError, match="no joint 'piston'"):
        c.reference_trajectory_from_cdr(serialize_message(m))
    with pytest.raises(ValueError, match='truncated|bad string|claims'):
        c.reference_trajectory_from_cdr(data[:200])


def test_wire_clock_is_rclpys_both_ways_and_rejects_what_is_not_a_clock():
    from rclpy.serialization import deserialize_message, serialize_message
    from rosgraph_msgs.msg import Clock
    for ns in (0, 1, 999_999_999, 1_000_000_000, 10_010_000_000, 10**9 * (2**31 - 1) + 5):
        m = deserialize_message(c.clock_to_cdr(ns), Clock)     # rclpy reads what we write
        assert m.clock.sec * 10**9 + m.clock.nanosec == ns
        assert c.clock_from_cdr(serialize_message(m)) == ns     # we read what rclpy writes
        big = b'\x00\x00\x00\x00' + struct.pack('>iI', *divmod(ns, 10**9))
        assert c.clock_from_cdr(big) == ns                      # the other byte order
    with pytest.raises(ValueError, match='truncated in the Clock'):
        c.clock_from_cdr(c.clock_to_cdr(5)[:10])
    with pytest.raises(ValueError, match='unsupported CDR encapsulation'):
        c.clock_from_cdr(b'\x07\x07' + c.clock_to_cdr(5)[2:])


def test_wire_pressure_is_read_by_rclpy_as_written():
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import FluidPressure
    for ns, p in ((0, 0.0), (1, -1.5e5), (10_010_000_007, 2.1e7), (10**9 * (2**31 - 1), 1e308)):
        data = c.pressure_to_cdr(c.Pressure(ns, p))
        # the same length as rclpy's (whose padding bytes are not zeroed, so not compared)
        assert len(data) == len(serialize_message(
            c.fill_pressure(FluidPressure(), c.Pressure(ns, p))))
        m = deserialize_message(data, FluidPressure)
        assert (c.stamp_ns(m.header), m.fluid_pressure, m.variance, m.header.frame_id) == \
            (ns, p, 0.0, '')


def test_the_state_carries_the_load_cell_and_references_a_force_both_ways():
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState
    from trajectory_msgs.msg import JointTrajectory
    s = c.AxisState(1_234_567_890_123, 0.01, 0.02, 3.0, 1e-5, 0.004, -9876.5)
    m = deserialize_message(c.state_to_cdr(s), JointState)
    assert list(m.name) == ['piston', 'spool', 'servo_valve', 'load_cell']
    assert c.state_from_msg(m) == s == c.state_from_cdr(serialize_message(m))
    d = c.fill_state(c.empty_msg(c.STATE.msg_type), s)
    assert d['name'] == list(m.name) and c.state_from_msg(d) == s
    r = c.Reference(7, 0.02, -0.3, 1.0e4)
    m = deserialize_message(c.reference_to_cdr(r), JointState)
    assert list(m.effort) == [1.0e4]
    assert c.reference_from_msg(m) == r == c.reference_from_cdr(serialize_message(m))
    assert math.isnan(c.reference_from_cdr(c.reference_to_cdr(c.Reference(7, 0.0, 0.0))).f_ref)
    refs = [c.Reference(5 * 10**9 + k * 10**6, 0.01 * k, -0.5 * k, 100.0 * k) for k in range(21)]
    data = c.reference_trajectory_to_cdr(refs)
    obj = deserialize_message(data, JointTrajectory)
    assert list(obj.points[3].effort) == [300.0]
    assert c.reference_trajectory_from_msg(obj) == refs
    for _ in range(2):       # the second read through the cached layout
        assert c.reference_trajectory_from_cdr(data) == refs
    # a displacement trajectory after a force one: NaN F_ref again, not a stale cache
    plain = [c.Reference(k, 0.0, 0.0) for k in range(3)]
    got = c.reference_trajectory_from_cdr(c.reference_trajectory_to_cdr(plain))
    assert [x[:3] for x in got] == [x[:3] for x in plain]
    assert all(math.isnan(x.f_ref) for x in got)
    # a window that turns to force at a mode switch: its force points keep F_ref
    mixed = plain + [c.Reference(k, math.nan, math.nan, 50.0 * k) for k in range(3, 6)]
    data = c.reference_trajectory_to_cdr(mixed)
    got = c.reference_trajectory_from_cdr(data)
    assert [x.f_ref for x in got[3:]] == [150.0, 200.0, 250.0]
    assert all(math.isnan(x.f_ref) for x in got[:3]) and [x.z_ref for x in got[:3]] == [0.0] * 3
    assert [x.f_ref for x in c.reference_trajectory_from_msg(
        deserialize_message(data, JointTrajectory))[3:]] == [150.0, 200.0, 250.0]


def test_the_load_cell_wrench_is_rclpys_both_ways_on_any_axis():
    from geometry_msgs.msg import WrenchStamped
    from rclpy.serialization import deserialize_message, serialize_message
    for ns, f in ((0, 0.0), (1, -1.5e4), (10**9 * (2**31 - 1), 1e308)):
        data = c.load_to_cdr(c.Load(ns, f))
        m = deserialize_message(data, WrenchStamped)
        assert (c.stamp_ns(m.header), m.header.frame_id, m.wrench.force.z) == (ns, 'load_cell', f)
        assert (m.wrench.force.x, m.wrench.torque.z) == (0.0, 0.0)
        assert c.load_from_msg(m) == c.Load(ns, f) == c.load_from_cdr(data)
    # a force/torque sensor broadcaster's wrench, its frame and axis its own
    w = WrenchStamped()
    w.header.frame_id = 'ft_sensor_frame'
    w.header.stamp.sec = 3
    w.wrench.force.x, w.wrench.force.y, w.wrench.torque.y = 1.0, -250.5, 7.0
    raw = serialize_message(w)
    assert c.load_from_cdr(raw, 'force.y') == c.Load(3 * 10**9, -250.5) == \
        c.load_from_msg(w, 'force.y')
    assert c.load_from_cdr(raw, 'torque.y').force == 7.0
    d = c.fill_load(c.empty_msg(c.LOAD_CELL.msg_type), c.Load(5, 12.0), 'force.x')
    assert d['wrench']['force'] == {'x': 12.0, 'y': 0.0, 'z': 0.0}
    with pytest.raises(ValueError, match="axis 'force.w' is not one of"):
        c.load_from_cdr(raw, 'force.w')
    with pytest.raises(ValueError, match='truncated in wrench'):
        c.load_from_cdr(raw[:40])
