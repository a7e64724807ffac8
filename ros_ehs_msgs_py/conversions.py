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
Conversions between the plain values and messages.

``*_from_msg`` read any object with the message's attributes (an rclpy message or a decoded
bag message) and raise ValueError naming what is missing; ``fill_*`` write into one (an rclpy
message instance, or the nested dicts of :func:`empty_msg` for the bag writer).
"""

from __future__ import annotations

import math
import struct
from typing import Any, Callable, Sequence

from ros_ehs_msgs_py.topics import JOINT_LOAD, JOINT_PISTON, JOINT_SPOOL, JOINT_VALVE
from ros_ehs_msgs_py.values import (AxisState, Command, Load, NodeStatus, ParameterEstimate,
                                    Pressure, Reference, SafetyEvent)

__all__ = ['WRENCH_AXES', 'command_from_arrays', 'command_from_msg', 'empty_msg',
           'estimate_from_msg', 'event_from_msg', 'fill_estimate', 'event_level',
           'fill_command', 'fill_event', 'fill_load', 'joint_index', 'load_from_msg',
           'fill_pressure', 'fill_reference',
           'fill_reference_trajectory', 'fill_state', 'pressure_from_msg',
           'reference_from_arrays', 'reference_from_msg',
           'reference_trajectory_from_msg', 'stamp_ns', 'state_from_arrays',
           'state_from_msg', 'statuses_from_msg']


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
    if msg_type == 'trajectory_msgs/msg/JointTrajectory':
        return {'header': header, 'joint_names': [], 'points': []}
    if msg_type == 'trajectory_msgs/msg/JointTrajectoryPoint':
        return {'positions': [], 'velocities': [], 'accelerations': [], 'effort': [],
                'time_from_start': {'sec': 0, 'nanosec': 0}}
    if msg_type == 'diagnostic_msgs/msg/DiagnosticArray':
        return {'header': header, 'status': []}
    if msg_type == 'geometry_msgs/msg/WrenchStamped':
        vec = {'x': 0.0, 'y': 0.0, 'z': 0.0}
        return {'header': header, 'wrench': {'force': dict(vec), 'torque': dict(vec)}}
    raise KeyError(f'no empty message for {msg_type!r}')


def joint_index(names: Sequence[str], name: str, topic: str) -> int:
    """Return the index of joint ``name`` in ``names`` (ValueError naming ``topic`` if none)."""
    names = list(names)
    try:
        return names.index(name)
    except ValueError:
        raise ValueError(f'`{topic}` message has no joint {name!r} (joints: {names})') from None


def _joint(msg: Any, name: str, topic: str) -> int:
    return joint_index(_get(msg, 'name'), name, topic)


def _field(msg: Any, field: str, k: int, topic: str) -> float:
    arr = _get(msg, field)
    if len(arr) <= k:
        raise ValueError(f'`{topic}` message has no {field}[{k}] (length {len(arr)})')
    return float(arr[k])


def fill_state(msg: Any, s: AxisState) -> Any:
    """
    Write ``s`` into a JointState.

    Joints ``piston`` and ``spool``; ``servo_valve`` (effort: the applied current) if ``s.i``
    is known, and ``load_cell`` (effort: the specimen force) if ``s.load`` is.
    """
    _set_header(msg, s.stamp_ns)
    names, pos, vel, eff = [JOINT_PISTON, JOINT_SPOOL], [float(s.z), float(s.x_spool)], \
        [float(s.z_dot), math.nan], [float(s.force), math.nan]
    for joint, value in ((JOINT_VALVE, s.i), (JOINT_LOAD, s.load)):
        if not math.isnan(value):
            names.append(joint)
            pos.append(math.nan)
            vel.append(math.nan)
            eff.append(float(value))
    _set(msg, 'name', names)
    _set(msg, 'position', pos)
    _set(msg, 'velocity', vel)
    _set(msg, 'effort', eff)
    return msg


def state_from_arrays(stamp: int, names: Sequence[str], position: Sequence[float],
                      velocity: Sequence[float], effort: Sequence[float],
                      joint: str = JOINT_PISTON, load_joint: str = JOINT_LOAD) -> AxisState:
    """
    Read an :class:`AxisState` from a ``state`` JointState's fields (ValueError if bad).

    ``joint``: the axis's joint (a rig driver's ``/joint_states`` names its own); its position
    is required, and its velocity too for the contract's ``piston``; a rig's joint without
    a velocity gives NaN (the controller then differences the position). ``load_joint``: the
    joint whose effort is the load cell (NaN without one).
    """
    names = list(names)
    k = joint_index(names, joint, 'state')
    force = float(effort[k]) if len(effort) > k else math.nan
    x = i = load = math.nan
    if JOINT_SPOOL in names:
        j = names.index(JOINT_SPOOL)
        x = float(position[j]) if len(position) > j else math.nan
    if JOINT_VALVE in names:
        j = names.index(JOINT_VALVE)
        i = float(effort[j]) if len(effort) > j else math.nan
    if load_joint in names:
        j = names.index(load_joint)
        load = float(effort[j]) if len(effort) > j else math.nan
    required = (('position', position), ('velocity', velocity)) if joint == JOINT_PISTON \
        else (('position', position),)
    for field, arr in required:
        if len(arr) <= k:
            raise ValueError(f'`state` message has no {field}[{k}] (length {len(arr)})')
    v = float(velocity[k]) if len(velocity) > k else math.nan
    return AxisState(stamp, float(position[k]), v, force, x, i, load)


def state_from_msg(msg: Any) -> AxisState:
    """Read an :class:`AxisState` from a ``state`` JointState (ValueError if malformed)."""
    return state_from_arrays(stamp_ns(_get(msg, 'header')), _get(msg, 'name'),
                             _get(msg, 'position'), _get(msg, 'velocity'),
                             _get(msg, 'effort'))


def fill_reference(msg: Any, r: Reference) -> Any:
    """Write ``r`` into a JointState (joint ``piston``; effort F_ref when there is one)."""
    _set_header(msg, r.stamp_ns)
    _set(msg, 'name', [JOINT_PISTON])
    _set(msg, 'position', [float(r.z_ref)])
    _set(msg, 'velocity', [float(r.v_ref)])
    _set(msg, 'effort', [] if math.isnan(r.f_ref) else [float(r.f_ref)])
    return msg


def reference_from_arrays(stamp: int, names: Sequence[str], position: Sequence[float],
                          velocity: Sequence[float], effort: Sequence[float] = ()) -> Reference:
    """Read a :class:`Reference` from a ``reference`` JointState's fields."""
    k = joint_index(names, JOINT_PISTON, 'reference')
    if len(position) <= k:
        raise ValueError(f'`reference` message has no position[{k}] (length {len(position)})')
    return Reference(stamp, float(position[k]), float(velocity[k]) if len(velocity) > k else 0.0,
                     float(effort[k]) if len(effort) > k else math.nan)


def reference_from_msg(msg: Any) -> Reference:
    """Read a :class:`Reference` from a ``reference`` JointState."""
    return reference_from_arrays(stamp_ns(_get(msg, 'header')), _get(msg, 'name'),
                                 _get(msg, 'position'), _get(msg, 'velocity'),
                                 _get(msg, 'effort'))


def fill_reference_trajectory(msg: Any, refs: Sequence[Reference],
                              new_point: Callable[[], Any]) -> Any:
    """
    Write ``refs`` (in time order) into a JointTrajectory (joint ``piston``).

    ``header.stamp`` is the first reference's stamp and each point's ``time_from_start`` its
    offset from it. ``new_point`` makes an empty point: ``JointTrajectoryPoint`` for an rclpy
    message, ``lambda: empty_msg('trajectory_msgs/msg/JointTrajectoryPoint')`` for a dict.
    """
    if not refs:
        raise ValueError('a reference trajectory needs at least one point')
    t0 = refs[0].stamp_ns
    _set_header(msg, t0)
    _set(msg, 'joint_names', [JOINT_PISTON])
    points = []
    for r in refs:
        p = new_point()
        _set(p, 'positions', [float(r.z_ref)])
        _set(p, 'velocities', [float(r.v_ref)])
        if not math.isnan(r.f_ref):
            _set(p, 'effort', [float(r.f_ref)])
        d = _get(p, 'time_from_start')
        _set(d, 'sec', int((r.stamp_ns - t0) // 1_000_000_000))
        _set(d, 'nanosec', int((r.stamp_ns - t0) % 1_000_000_000))
        points.append(p)
    _set(msg, 'points', points)
    return msg


def reference_trajectory_from_msg(msg: Any) -> list[Reference]:
    """
    Read the :class:`Reference` of each point of a ``reference_trajectory`` JointTrajectory.

    Each stamp is ``header.stamp + time_from_start``; a point without a velocity for
    ``piston`` has v_ref 0, as in :func:`reference_from_msg`. ValueError names the joint or the
    point that is missing.
    """
    k = joint_index(_get(msg, 'joint_names'), JOINT_PISTON, 'reference_trajectory')
    t0 = stamp_ns(_get(msg, 'header'))
    out = []
    for n, p in enumerate(_get(msg, 'points')):
        pos, vel, eff = _get(p, 'positions'), _get(p, 'velocities'), _get(p, 'effort')
        if len(pos) <= k:
            raise ValueError(f'`reference_trajectory` point {n} has no positions[{k}] '
                             f'(length {len(pos)})')
        d = _get(p, 'time_from_start')
        out.append(Reference(t0 + int(_get(d, 'sec')) * 1_000_000_000 + int(_get(d, 'nanosec')),
                             float(pos[k]), float(vel[k]) if len(vel) > k else 0.0,
                             float(eff[k]) if len(eff) > k else math.nan))
    return out


def fill_command(msg: Any, c: Command) -> Any:
    """Write ``c`` into a JointState (joint ``servo_valve``, effort = current [A])."""
    _set_header(msg, c.stamp_ns)
    _set(msg, 'name', [JOINT_VALVE])
    _set(msg, 'position', [])
    _set(msg, 'velocity', [])
    _set(msg, 'effort', [float(c.i)])
    return msg


def command_from_arrays(stamp: int, names: Sequence[str], effort: Sequence[float]) -> Command:
    """Read a :class:`Command` from a ``servo_current`` JointState's fields."""
    k = joint_index(names, JOINT_VALVE, 'servo_current')
    if len(effort) <= k:
        raise ValueError(f'`servo_current` message has no effort[{k}] (length {len(effort)})')
    return Command(stamp, float(effort[k]))


def command_from_msg(msg: Any) -> Command:
    """Read a :class:`Command` from a ``servo_current`` JointState."""
    return command_from_arrays(stamp_ns(_get(msg, 'header')), _get(msg, 'name'),
                               _get(msg, 'effort'))


def fill_pressure(msg: Any, p: Pressure) -> Any:
    """Write ``p`` into a FluidPressure."""
    _set_header(msg, p.stamp_ns)
    _set(msg, 'fluid_pressure', float(p.p))
    _set(msg, 'variance', 0.0)
    return msg


def pressure_from_msg(msg: Any) -> Pressure:
    """Read a :class:`Pressure` from a FluidPressure."""
    return Pressure(stamp_ns(_get(msg, 'header')), float(_get(msg, 'fluid_pressure')))


#: the axes of a WrenchStamped a load cell's force can be on
WRENCH_AXES = ('force.x', 'force.y', 'force.z', 'torque.x', 'torque.y', 'torque.z')


def _axis(axis: str) -> tuple[str, str]:
    if axis not in WRENCH_AXES:
        raise ValueError(f'load cell axis {axis!r} is not one of {list(WRENCH_AXES)}')
    part, _, comp = axis.partition('.')
    return part, comp


def fill_load(msg: Any, ld: Load, axis: str = 'force.z', frame: str = JOINT_LOAD) -> Any:
    """Write ``ld`` into a WrenchStamped: its force on ``axis``, every other component 0."""
    part, comp = _axis(axis)
    _set_header(msg, ld.stamp_ns, frame)
    w = _get(msg, 'wrench')
    for p in ('force', 'torque'):
        v = _get(w, p)
        for c in 'xyz':
            _set(v, c, float(ld.force) if (p, c) == (part, comp) else 0.0)
    return msg


def load_from_msg(msg: Any, axis: str = 'force.z') -> Load:
    """Read a :class:`Load` from a WrenchStamped: the component on ``axis`` [N]."""
    part, comp = _axis(axis)
    return Load(stamp_ns(_get(msg, 'header')), float(_get(_get(_get(msg, 'wrench'), part), comp)))


#: DiagnosticStatus levels (OK, WARN, ERROR) of the events, by kind and action.
_OK, _WARN, _ERROR = 0, 1, 2
_EVENT_KEYS = ('kind', 'detector', 'value', 'limit', 'unit', 'action', 'stamp_ns')


def event_level(e: SafetyEvent) -> int:
    """Return the DiagnosticStatus level of an event: ERROR for a trip that acts, else WARN/OK."""
    if e.kind == 'trip':
        return _WARN if e.action == 'indicate' else _ERROR
    return _WARN if e.kind.endswith('refused') or e.kind in ('disabled', 'clipped') else _OK


def fill_event(msg: Any, e: SafetyEvent, node: str = 'controller', hardware_id: str = 'axis',
               status: Any = None, key_value: Callable[[], Any] | None = None) -> Any:
    """
    Write ``e`` into a ``diagnostic_msgs/DiagnosticArray`` (one status).

    ``status`` is an empty DiagnosticStatus and ``key_value`` makes an empty KeyValue (the
    message classes, or dicts for the bag writer).
    """
    pairs = [(k, f'{getattr(e, k):.9g}' if isinstance(getattr(e, k), float) else
              str(getattr(e, k))) for k in _EVENT_KEYS]
    return _fill_status(msg, e.stamp_ns, event_level(e), f'ros_ehs/{node}/{e.detector or e.kind}',
                        e.message, hardware_id, pairs, status, key_value)


def _status_values(msg: Any, topic: str, keys: Sequence[str]) -> tuple[Any, dict[str, str]]:
    """Return a DiagnosticArray's first status and its values; ValueError naming what lacks."""
    status = list(_get(msg, 'status'))
    if not status:
        raise ValueError(f'{topic}: a DiagnosticArray without a status')
    st = status[0]
    vals = {_get(kv, 'key'): _get(kv, 'value') for kv in _get(st, 'values')}
    missing = [k for k in keys if k not in vals]
    if missing:
        raise ValueError(f'{topic}: status {_get(st, "name")!r} lacks the values {missing}')
    return st, vals


def _fill_status(msg: Any, stamp: int, level: int, name: str, message: str, hardware_id: str,
                 pairs: Sequence[tuple[str, str]], status: Any, key_value) -> Any:
    """Write one DiagnosticStatus with ``pairs`` as its values into a DiagnosticArray."""
    _set_header(msg, stamp)
    st = status if status is not None else {}
    _set(st, 'level', bytes([level]))
    _set(st, 'name', name)
    _set(st, 'message', message)
    _set(st, 'hardware_id', hardware_id)
    values = []
    for k, v in pairs:
        kv = key_value() if key_value is not None else {}
        _set(kv, 'key', k)
        _set(kv, 'value', v)
        values.append(kv)
    _set(st, 'values', values)
    _set(msg, 'status', [st])
    return msg


def event_from_msg(msg: Any) -> SafetyEvent:
    """Read the event of an ``events`` DiagnosticArray (the first status); ValueError if none."""
    st, vals = _status_values(msg, 'events', _EVENT_KEYS)
    return SafetyEvent(int(vals['stamp_ns']), vals['kind'], vals['detector'],
                       float(vals['value']), float(vals['limit']), vals['unit'],
                       vals['action'], _get(st, 'message'))


_ESTIMATE_KEYS = ('adequate', 'pushed', 'reason', 'window_s', 'wall_s', 'iterations')
#: values an estimate may lack (a writer before them): the verdict's failed rules
_ESTIMATE_OPTIONAL = ('failed_rules',)
_STDERR = '.stderr'


def fill_estimate(msg: Any, e: ParameterEstimate, status: Any = None,
                  key_value: Callable[[], Any] | None = None) -> Any:
    """
    Write ``e`` into a ``diagnostic_msgs/DiagnosticArray`` (one status; see ``ESTIMATES``).

    ``status`` and ``key_value`` as in :func:`fill_event`.
    """
    pairs = []
    for n, v in e.values.items():
        pairs += [(n, f'{v:.9g}'), (n + _STDERR, f'{e.stderr.get(n, math.nan):.9g}')]
    pairs += [('adequate', str(bool(e.adequate)).lower()), ('pushed', str(bool(e.pushed)).lower()),
              ('reason', e.reason), ('window_s', f'{e.window_s:.9g}'),
              ('wall_s', f'{e.wall_s:.9g}'), ('iterations', str(int(e.iterations))),
              ('failed_rules', ','.join(e.failed))]
    return _fill_status(msg, e.stamp_ns, _OK if e.adequate else _WARN,
                        'ros_ehs/identify/estimate', e.verdict, 'axis', pairs, status, key_value)


def estimate_from_msg(msg: Any) -> ParameterEstimate:
    """Read the estimate of a ``parameter_estimates`` DiagnosticArray; ValueError if malformed."""
    st, vals = _status_values(msg, 'parameter_estimates', _ESTIMATE_KEYS)
    names = [k for k in vals if k not in _ESTIMATE_KEYS + _ESTIMATE_OPTIONAL
             and not k.endswith(_STDERR)]
    try:
        return ParameterEstimate(
            stamp_ns(_get(msg, 'header')), {n: float(vals[n]) for n in names},
            {n: float(vals.get(n + _STDERR, 'nan')) for n in names},
            vals['adequate'] == 'true', _get(st, 'message'), vals['pushed'] == 'true',
            vals['reason'], float(vals['window_s']), float(vals['wall_s']),
            int(vals['iterations']),
            tuple(x for x in vals.get('failed_rules', '').split(',') if x))
    except ValueError as err:
        raise ValueError(f'parameter_estimates: a value is not a number: {err}') from None


def _level_of(status: Any) -> int:
    """Return a DiagnosticStatus's level as an int (rclpy gives a byte, dicts an int)."""
    level = _get(status, 'level')
    return level[0] if isinstance(level, (bytes, bytearray)) else int(level)


def statuses_from_msg(msg: Any) -> list[NodeStatus]:
    """Return every status of a ``diagnostics`` DiagnosticArray as :class:`NodeStatus`."""
    t = stamp_ns(_get(msg, 'header'))
    out = []
    for st in _get(msg, 'status'):
        out.append(NodeStatus(t, _get(st, 'name'), _level_of(st), _get(st, 'message'),
                              {_get(kv, 'key'): _get(kv, 'value') for kv in _get(st, 'values')}))
    return out


# -- the procedure ------------------------------------------------------------------------------
#: one cycle's record on ``procedure/cycles`` (little-endian, 40 bytes): count (uint32), step
#: (uint16), flags (uint16: CYCLE_TAPERED), end stamp [ns] (int64), then float32 command hi,
#: lo [m or N], z hi, lo [m], load hi, lo [N]
CYCLE_RECORD = struct.Struct('<IHHqffffff')
CYCLES_LABEL = 'ros_ehs_cycle_v1'
#: a cycle record's flag: its amplitude was tapering in (a start or a resume)
CYCLE_TAPERED = 1
_PROCEDURE_EVENT_KEYS = ('kind', 'what', 'value', 'total_cycles', 'step', 'stamp_ns')


def cycles_to_bytes(rows: Sequence[Sequence[float]]) -> bytes:
    """Pack ``rows`` of (count, step, end_ns, cmd_hi, cmd_lo, z_hi, z_lo, f_hi, f_lo[, flags])."""
    pack = CYCLE_RECORD.pack
    return b''.join(pack(int(r[0]), int(r[1]), int(r[9]) if len(r) > 9 else 0, int(r[2]),
                         *map(float, r[3:9])) for r in rows)


def cycles_from_bytes(data: bytes) -> list[tuple]:
    """
    Unpack records of :data:`CYCLE_RECORD` as (count, step, end_ns, 6 extremes, flags).

    ValueError when the length is not whole records.
    """
    n, rest = divmod(len(data), CYCLE_RECORD.size)
    if rest:
        raise ValueError(f'procedure/cycles: {len(data)} bytes is not a whole number of '
                         f'{CYCLE_RECORD.size}-byte cycle records')
    return [(c, st, ns, *v, fl) for c, st, fl, ns, *v in CYCLE_RECORD.iter_unpack(bytes(data))]


def fill_procedure_event(msg: Any, stamp: int, level: int, kind: str, what: str, value: float,
                         total: int, step: int, message: str, status: Any = None,
                         key_value: Callable[[], Any] | None = None) -> Any:
    """Write one of the procedure's events into a ``diagnostic_msgs/DiagnosticArray``."""
    pairs = [('kind', kind), ('what', what), ('value', f'{value:.9g}'),
             ('total_cycles', str(total)), ('step', str(step)), ('stamp_ns', str(stamp))]
    return _fill_status(msg, stamp, level, f'ros_ehs/procedure/{kind}', message, 'axis',
                        pairs, status, key_value)


# -- the station --------------------------------------------------------------------------------
_STATION_EVENT_KEYS = ('action', 'origin', 'result', 'reason')


def fill_station_event(msg: Any, stamp: int, action: str, origin: str, result: str,
                       reason: str, status: Any = None,
                       key_value: Callable[[], Any] | None = None) -> Any:
    """
    Write one operator's action into a ``diagnostic_msgs/DiagnosticArray`` (``station/events``).

    ``result`` is ``done``, ``refused`` (by the node, or by the station's access rule) or
    ``unanswered``; ``reason`` the answer or why.
    """
    pairs = [('action', action), ('origin', origin), ('result', result), ('reason', reason)]
    return _fill_status(msg, stamp, _OK if result == 'done' else _WARN,
                        f'ros_ehs/station/{action}', f'{action} {result}: {reason}', 'axis',
                        pairs, status, key_value)


def station_event_from_msg(msg: Any) -> dict[str, Any]:
    """Read a ``station/events`` DiagnosticArray (the first status); ValueError if none."""
    st, vals = _status_values(msg, 'station/events', _STATION_EVENT_KEYS)
    return {**{k: vals[k] for k in _STATION_EVENT_KEYS}, 'stamp_ns': stamp_ns(_get(msg, 'header')),
            'message': _get(st, 'message')}


def procedure_event_from_msg(msg: Any) -> dict[str, Any]:
    """Read a ``procedure/events`` DiagnosticArray (the first status); ValueError if none."""
    st, vals = _status_values(msg, 'procedure/events', _PROCEDURE_EVENT_KEYS)
    return {'kind': vals['kind'], 'what': vals['what'], 'value': float(vals['value']),
            'total_cycles': int(vals['total_cycles']), 'step': int(vals['step']),
            'stamp_ns': int(vals['stamp_ns']), 'message': _get(st, 'message'),
            'level': _level_of(st)}
