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
The ros_ehs topic contract (DESIGN.md section 3): names, message types, units, QoS, conversions.

Pure Python, no ROS import, so the numerical core and the bag reader use it as freely as the
nodes. Names are relative, so a namespace (``__ns:=/axis1``) runs several axes.

Conversions go through plain records (:class:`AxisState`, :class:`Reference`,
:class:`Command`, :class:`Pressure`). ``*_from_msg`` read any object with the message's
attributes (an rclpy message or a decoded bag message); ``fill_*`` write into one (an rclpy
message instance, or the nested dicts of :func:`empty_msg` for the bag writer).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

__all__ = [
    'AxisState', 'CLOCK', 'CLOCK_QOS', 'COMMAND', 'Command', 'DIAGNOSTICS', 'JOINT_PISTON',
    'JOINT_SPOOL', 'JOINT_VALVE', 'LOCKSTEP_QOS', 'LOOP_QOS', 'NODE_TOPICS', 'NodeTopics',
    'PRESSURE_P', 'PRESSURE_T', 'Pressure', 'QosSpec', 'RECORD_QOS', 'REFERENCE', 'Reference',
    'STATE', 'TOPICS', 'Topic', 'by_name',
    'command_from_msg', 'empty_msg', 'fill_command', 'fill_pressure', 'fill_reference',
    'fill_state', 'pressure_from_msg', 'reference_from_msg', 'stamp_ns', 'state_from_msg',
]

JOINT_PISTON = 'piston'
JOINT_SPOOL = 'spool'
JOINT_VALVE = 'servo_valve'


class QosSpec(NamedTuple):
    """A QoS profile as a plain record (rclpy conversion lives in the nodes)."""

    reliability: str = 'reliable'       # 'reliable' | 'best_effort'
    depth: int = 10
    durability: str = 'volatile'        # 'volatile' | 'transient_local'
    history: str = 'keep_last'

    def as_rosbag2(self) -> dict[str, Any]:
        """Return the rosbag2 v9 ``offered_qos_profiles`` entry for this profile."""
        inf = {'sec': 9223372036, 'nsec': 854775807}
        return {'history': self.history, 'depth': int(self.depth),
                'reliability': self.reliability, 'durability': self.durability,
                'deadline': dict(inf), 'lifespan': dict(inf), 'liveliness': 'automatic',
                'liveliness_lease_duration': dict(inf),
                'avoid_ros_namespace_conventions': False}

    @classmethod
    def from_rosbag2(cls, entry: dict[str, Any] | None) -> 'QosSpec':
        """
        Return the profile of an ``offered_qos_profiles`` entry (the inverse of the above).

        Reads names and rosbag2's older enum numbers (reliability 1 reliable, 2 best effort;
        durability 1 transient local, 2 volatile); anything else (0, system default) gives
        the default. ``None`` gives the default profile.
        """
        q, d = entry or {}, cls._field_defaults
        rel, dur = q.get('reliability'), q.get('durability')
        rel = {1: 'reliable', 2: 'best_effort'}.get(rel, rel)
        dur = {1: 'transient_local', 2: 'volatile'}.get(dur, dur)
        return cls(rel if rel in ('reliable', 'best_effort') else d['reliability'],
                   int(q.get('depth') or d['depth']),
                   dur if dur in ('volatile', 'transient_local') else d['durability'])


#: Loop topics: best effort, keep last 1 (what ros2_control uses for commands).
LOOP_QOS = QosSpec('best_effort', 1)
#: Everything else (diagnostics, recorder taps of slow topics): reliable, depth 10.
RECORD_QOS = QosSpec('reliable', 10)
#: ``/clock``, as rclcpp's ClockQoS.
CLOCK_QOS = QosSpec('best_effort', 1)
#: Loop topics and ``/clock`` in lock-step: reliable, keep last 1000. Nothing waits for the
#: recorder in lock-step, and a best-effort recorder that the OS pauses for 0.3 s loses
#: ~100 states; a reliable writer holds up to 1000 samples (1 s at 1 kHz) until each
#: reliable reader has them. Best-effort readers (rclpy's /clock) still match.
LOCKSTEP_QOS = QosSpec('reliable', 1000)


class Topic(NamedTuple):
    """One topic of the contract."""

    name: str
    msg_type: str
    content: str
    qos: QosSpec = LOOP_QOS

    def qos_in(self, lockstep: bool) -> QosSpec:
        """Return this topic's QoS in real time or lock-step (best-effort topics turn reliable)."""
        if lockstep and self.qos.reliability == 'best_effort':
            return LOCKSTEP_QOS
        return self.qos


REFERENCE = Topic('reference', 'sensor_msgs/msg/JointState',
                  'joint `piston`: position z_ref [m], velocity [m/s]')
STATE = Topic('state', 'sensor_msgs/msg/JointState',
              '`piston`: z [m], z_dot [m/s], effort = hydraulic force [N]; `spool`: x [m]; '
              '`servo_valve` (plant node): effort = current applied over the period [A]')
PRESSURE_P = Topic('pressure/chamber_p', 'sensor_msgs/msg/FluidPressure',
                   'chamber P pressure [Pa]')
PRESSURE_T = Topic('pressure/chamber_t', 'sensor_msgs/msg/FluidPressure',
                   'chamber T pressure [Pa]')
COMMAND = Topic('servo_current', 'sensor_msgs/msg/JointState',
                'joint `servo_valve`: effort = i [A]')
DIAGNOSTICS = Topic('diagnostics', 'diagnostic_msgs/msg/DiagnosticArray',
                    'loop timing, tracking error, watchdog', RECORD_QOS)
CLOCK = Topic('/clock', 'rosgraph_msgs/msg/Clock',
              'published by the plant in lock-step mode', CLOCK_QOS)

TOPICS = (REFERENCE, STATE, PRESSURE_P, PRESSURE_T, COMMAND, DIAGNOSTICS, CLOCK)


class NodeTopics(NamedTuple):
    """The contract topics a node publishes and subscribes (its part of the contract)."""

    publishes: tuple[Topic, ...]
    subscribes: tuple[Topic, ...]


#: What each loop node creates in its default (real-time) mode. In lock-step the plant also
#: publishes CLOCK, and under ``use_sim_time`` the reference subscribes to it.
NODE_TOPICS = {
    'plant': NodeTopics((STATE, PRESSURE_P, PRESSURE_T, DIAGNOSTICS), (COMMAND,)),
    'controller': NodeTopics((COMMAND, DIAGNOSTICS), (STATE, REFERENCE)),
    'reference': NodeTopics((REFERENCE, DIAGNOSTICS), ()),
}


def by_name(name: str) -> Topic:
    """Return the contract topic called ``name`` (leading ``/`` ignored except ``/clock``)."""
    for t in TOPICS:
        if name in (t.name, '/' + t.name):
            return t
    raise KeyError(f'{name!r} is not a contract topic; known: {[t.name for t in TOPICS]}')


# -- plain records ---------------------------------------------------------------------------
class AxisState(NamedTuple):
    """Measured piston state: position [m], velocity [m/s], hydraulic force [N], spool [m]."""

    stamp_ns: int
    z: float
    z_dot: float
    force: float = math.nan
    x_spool: float = math.nan
    i: float = math.nan     #: current [A] applied over the period that ended here (if known)


class Reference(NamedTuple):
    """Position reference [m] and its velocity [m/s]."""

    stamp_ns: int
    z_ref: float
    v_ref: float


class Command(NamedTuple):
    """Servo-valve current [A]."""

    stamp_ns: int
    i: float


class Pressure(NamedTuple):
    """A chamber pressure [Pa]."""

    stamp_ns: int
    p: float


# -- conversions ---------------------------------------------------------------------------
def stamp_ns(header: Any) -> int:
    """Return a ``std_msgs/Header`` stamp in nanoseconds."""
    s = _get(header, 'stamp')
    return int(_get(s, 'sec')) * 1_000_000_000 + int(_get(s, 'nanosec'))


def _get(obj: Any, name: str) -> Any:
    return obj[name] if isinstance(obj, dict) else getattr(obj, name)


def _set(obj: Any, name: str, value: Any) -> None:
    if isinstance(obj, dict):
        obj[name] = value
    else:
        setattr(obj, name, value)


def _set_header(msg: Any, t_ns: int, frame: str = '') -> None:
    h = _get(msg, 'header')
    s = _get(h, 'stamp')
    _set(s, 'sec', int(t_ns // 1_000_000_000))
    _set(s, 'nanosec', int(t_ns % 1_000_000_000))
    _set(h, 'frame_id', frame)


def empty_msg(msg_type: str) -> dict[str, Any]:
    """Return a nested-dict message of ``msg_type`` for the bag writer (contract types)."""
    header = {'stamp': {'sec': 0, 'nanosec': 0}, 'frame_id': ''}
    if msg_type == 'sensor_msgs/msg/JointState':
        return {'header': header, 'name': [], 'position': [], 'velocity': [], 'effort': []}
    if msg_type == 'sensor_msgs/msg/FluidPressure':
        return {'header': header, 'fluid_pressure': 0.0, 'variance': 0.0}
    if msg_type == 'rosgraph_msgs/msg/Clock':
        return {'clock': {'sec': 0, 'nanosec': 0}}
    raise KeyError(f'no empty message for {msg_type!r}')


def _joint(msg: Any, name: str, topic: str) -> int:
    names = list(_get(msg, 'name'))
    try:
        return names.index(name)
    except ValueError:
        raise ValueError(f'`{topic}` message has no joint {name!r} (joints: {names})') from None


def _field(msg: Any, field: str, k: int, topic: str) -> float:
    arr = _get(msg, field)
    if len(arr) <= k:
        raise ValueError(f'`{topic}` message has no {field}[{k}] (length {len(arr)})')
    return float(arr[k])


def fill_state(msg: Any, s: AxisState) -> Any:
    """Write ``s`` into a JointState (``piston``, ``spool``, and ``servo_valve`` if ``s.i``)."""
    _set_header(msg, s.stamp_ns)
    if math.isnan(s.i):
        _set(msg, 'name', [JOINT_PISTON, JOINT_SPOOL])
        _set(msg, 'position', [float(s.z), float(s.x_spool)])
        _set(msg, 'velocity', [float(s.z_dot), math.nan])
        _set(msg, 'effort', [float(s.force), math.nan])
        return msg
    _set(msg, 'name', [JOINT_PISTON, JOINT_SPOOL, JOINT_VALVE])
    _set(msg, 'position', [float(s.z), float(s.x_spool), math.nan])
    _set(msg, 'velocity', [float(s.z_dot), math.nan, math.nan])
    _set(msg, 'effort', [float(s.force), math.nan, float(s.i)])
    return msg


def state_from_msg(msg: Any) -> AxisState:
    """Read an :class:`AxisState` from a ``state`` JointState (ValueError if malformed)."""
    k = _joint(msg, JOINT_PISTON, 'state')
    eff = _get(msg, 'effort')
    force = float(eff[k]) if len(eff) > k else math.nan
    x = i = math.nan
    names = list(_get(msg, 'name'))
    if JOINT_SPOOL in names:
        j = names.index(JOINT_SPOOL)
        pos = _get(msg, 'position')
        x = float(pos[j]) if len(pos) > j else math.nan
    if JOINT_VALVE in names:
        j = names.index(JOINT_VALVE)
        i = float(eff[j]) if len(eff) > j else math.nan
    return AxisState(stamp_ns(_get(msg, 'header')), _field(msg, 'position', k, 'state'),
                     _field(msg, 'velocity', k, 'state'), force, x, i)


def fill_reference(msg: Any, r: Reference) -> Any:
    """Write ``r`` into a JointState (joint ``piston``)."""
    _set_header(msg, r.stamp_ns)
    _set(msg, 'name', [JOINT_PISTON])
    _set(msg, 'position', [float(r.z_ref)])
    _set(msg, 'velocity', [float(r.v_ref)])
    _set(msg, 'effort', [])
    return msg


def reference_from_msg(msg: Any) -> Reference:
    """Read a :class:`Reference` from a ``reference`` JointState."""
    k = _joint(msg, JOINT_PISTON, 'reference')
    vel = _get(msg, 'velocity')
    v = float(vel[k]) if len(vel) > k else 0.0
    return Reference(stamp_ns(_get(msg, 'header')), _field(msg, 'position', k, 'reference'), v)


def fill_command(msg: Any, c: Command) -> Any:
    """Write ``c`` into a JointState (joint ``servo_valve``, effort = current [A])."""
    _set_header(msg, c.stamp_ns)
    _set(msg, 'name', [JOINT_VALVE])
    _set(msg, 'position', [])
    _set(msg, 'velocity', [])
    _set(msg, 'effort', [float(c.i)])
    return msg


def command_from_msg(msg: Any) -> Command:
    """Read a :class:`Command` from a ``servo_current`` JointState."""
    k = _joint(msg, JOINT_VALVE, 'servo_current')
    return Command(stamp_ns(_get(msg, 'header')), _field(msg, 'effort', k, 'servo_current'))


def fill_pressure(msg: Any, p: Pressure) -> Any:
    """Write ``p`` into a FluidPressure."""
    _set_header(msg, p.stamp_ns)
    _set(msg, 'fluid_pressure', float(p.p))
    _set(msg, 'variance', 0.0)
    return msg


def pressure_from_msg(msg: Any) -> Pressure:
    """Read a :class:`Pressure` from a FluidPressure."""
    return Pressure(stamp_ns(_get(msg, 'header')), float(_get(msg, 'fluid_pressure')))
