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
The loop's JointStates as CDR bytes, without rclpy: the fast path of plant and controller.

rclpy publishes ``bytes`` as they are and hands a ``raw=True`` subscription the bytes that
came, so a node can skip building Python message objects and converting them to and from C.
The bare rclpy ping-pong makes about 1.3 times the round trips a second this way than with
message objects (``python -m ros_ehs.benchmarks lockstep`` prints both).

* :class:`JointStateEncoder`: one fixed layout (joint names, array lengths), built once; each
  message is the template with the stamp and the values packed in (:func:`state_to_cdr`,
  :func:`command_to_cdr`).
* :func:`decode_joint_state`: any JointState, from any client: CDR (XCDR1) and plain XCDR2,
  either byte order; each layout seen is cached (by payload length), so a steady publisher
  costs one ``unpack``. A truncated or foreign payload raises ValueError naming what is wrong.
* :func:`state_from_cdr`, :func:`command_from_cdr`, :func:`reference_from_cdr`: the
  values, by the same rules as :func:`~ros_ehs_msgs_py.conversions.state_from_msg` and the
  other ``*_from_msg``.
* :func:`clock_to_cdr`, :func:`clock_from_cdr`: the lock-step plant's ``/clock``
  (rosgraph_msgs/Clock), which the reference reads raw too.
* :func:`float64_from_cdr`, :func:`float64_array_from_cdr`, :func:`fluid_pressure_from_cdr`:
  what a rig driver publishes (std_msgs/Float64, std_msgs/Float64MultiArray,
  sensor_msgs/FluidPressure), for reading its bags fast.
* :func:`pressure_to_cdr`: the chamber pressures
  (sensor_msgs/FluidPressure, empty frame_id, variance 0): half the publish cost of a message
  object.
* :func:`reference_trajectory_to_cdr`, :func:`reference_trajectory_from_cdr`: the lock-step
  ``reference_trajectory`` (trajectory_msgs/JointTrajectory), the same way: a template per
  point count, and a reader for any JointTrajectory with the last layout cached.

Checked against rclpy's own ``serialize_message``/``deserialize_message`` (test_wire).
"""

from __future__ import annotations

import math
import struct
from typing import NamedTuple, Sequence

from ros_ehs_msgs_py.conversions import (command_from_arrays, joint_index,
                                         reference_from_arrays, state_from_arrays)
from ros_ehs_msgs_py.topics import JOINT_LOAD, JOINT_PISTON, JOINT_SPOOL, JOINT_VALVE
from ros_ehs_msgs_py.values import AxisState, Command, Load, Pressure, Reference

__all__ = ['JointStateData', 'JointStateEncoder', 'clock_from_cdr', 'clock_to_cdr',
           'command_from_cdr', 'command_to_cdr', 'load_from_cdr', 'load_to_cdr',
           'wrench_from_cdr',
           'decode_joint_state', 'float64_array_from_cdr', 'float64_array_to_cdr',
           'float64_from_cdr',
           'fluid_pressure_from_cdr', 'pressure_to_cdr', 'reference_from_cdr', 'reference_to_cdr',
           'reference_trajectory_from_cdr', 'reference_trajectory_to_cdr', 'state_from_cdr',
           'state_to_cdr']

#: encapsulation id -> (byte order, alignment of 8-byte values): CDR and plain XCDR2
_ENCAPSULATION = {b'\x00\x00': ('>', 8), b'\x00\x01': ('<', 8),
                  b'\x00\x06': ('>', 4), b'\x00\x07': ('<', 4)}
_NS = 1_000_000_000


class JointStateData(NamedTuple):
    """A decoded sensor_msgs/JointState (frame_id dropped)."""

    stamp_ns: int
    name: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    effort: tuple[float, ...]


def _pad(off: int, n: int) -> int:
    """Return the padding before a value of alignment ``n`` at body offset ``off``."""
    return -off % n


class JointStateEncoder:
    """Serialize JointStates of one layout (names and array lengths fixed), little-endian CDR."""

    def __init__(self, names: Sequence[str], n_position: int, n_velocity: int,
                 n_effort: int, frame_id: str = '') -> None:
        body = bytearray(struct.pack('<iI', 0, 0))

        def string(s: str) -> None:
            b = s.encode() + b'\0'
            body.extend(b'\0' * _pad(len(body), 4) + struct.pack('<I', len(b)) + b)

        string(frame_id)
        body.extend(b'\0' * _pad(len(body), 4) + struct.pack('<I', len(names)))
        for n in names:
            string(n)
        self._starts = []       # (body offset, count) of each non-empty array
        for count in (n_position, n_velocity, n_effort):
            body.extend(b'\0' * _pad(len(body), 4) + struct.pack('<I', count))
            if count:
                body.extend(b'\0' * _pad(len(body), 8))
                self._starts.append((len(body), count))
                body.extend(b'\0' * 8 * count)
        self._template = bytearray(b'\x00\x01\x00\x00') + body
        self.n_values = n_position + n_velocity + n_effort
        self.layout = (tuple(names), n_position, n_velocity, n_effort)

    def encode(self, stamp_ns: int, values: Sequence[float]) -> bytes:
        """Return the message: ``values`` = positions, then velocities, then efforts."""
        if len(values) != self.n_values:
            raise ValueError(f'expected {self.n_values} values for {self.layout}, got '
                             f'{len(values)}')
        buf = self._template
        sec, nsec = divmod(int(stamp_ns), _NS)
        struct.pack_into('<iI', buf, 4, sec, nsec)
        k = 0
        for start, count in self._starts:
            struct.pack_into(f'<{count}d', buf, 4 + start, *values[k:k + count])
            k += count
        return bytes(buf)


_STATE = JointStateEncoder((JOINT_PISTON, JOINT_SPOOL, JOINT_VALVE), 3, 3, 3)
_STATE_LOAD = JointStateEncoder((JOINT_PISTON, JOINT_SPOOL, JOINT_VALVE, JOINT_LOAD), 4, 4, 4)
_COMMAND = JointStateEncoder((JOINT_VALVE,), 0, 0, 1)
_REFERENCE = JointStateEncoder((JOINT_PISTON,), 1, 1, 0)
_REFERENCE_FORCE = JointStateEncoder((JOINT_PISTON,), 1, 1, 1)
_NAN = math.nan


def state_to_cdr(s: AxisState) -> bytes:
    """
    Return ``s`` as a serialized ``state`` JointState (piston, spool, servo_valve).

    With ``s.load`` known, joint ``load_cell`` too (effort: the specimen force).
    """
    if s.load == s.load:        # not NaN
        return _STATE_LOAD.encode(s.stamp_ns, (s.z, s.x_spool, _NAN, _NAN, s.z_dot, _NAN,
                                               _NAN, _NAN, s.force, _NAN, s.i, s.load))
    return _STATE.encode(s.stamp_ns, (s.z, s.x_spool, _NAN, s.z_dot, _NAN, _NAN,
                                      s.force, _NAN, s.i))


def reference_to_cdr(r: Reference) -> bytes:
    """Return ``r`` as a serialized ``reference`` JointState (``piston``; effort: F_ref)."""
    if r.f_ref == r.f_ref:      # not NaN
        return _REFERENCE_FORCE.encode(r.stamp_ns, (r.z_ref, r.v_ref, r.f_ref))
    return _REFERENCE.encode(r.stamp_ns, (r.z_ref, r.v_ref))


def command_to_cdr(c: Command) -> bytes:
    """Return ``c`` as a serialized ``servo_current`` JointState (``servo_valve`` effort)."""
    return _COMMAND.encode(c.stamp_ns, (c.i,))


class _Reader:
    """Sequential CDR reader over one payload (errors name the field and the offset)."""

    __slots__ = ('data', 'off', 'order', 'align8')

    def __init__(self, data: bytes) -> None:
        if len(data) < 4:
            raise ValueError(f'a CDR payload of {len(data)} bytes has no CDR header')
        enc = _ENCAPSULATION.get(bytes(data[:2]))
        if enc is None:
            raise ValueError(f'unsupported CDR encapsulation 0x{bytes(data[:2]).hex()} '
                             '(expected CDR or plain XCDR2)')
        self.data, self.off = data, 4
        self.order, self.align8 = enc

    def _take(self, fmt: str, size: int, align: int, what: str):
        off = self.off + _pad(self.off - 4, align)
        if off + size > len(self.data):
            raise ValueError(f'CDR payload truncated in {what} (offset {off}, '
                             f'{len(self.data)} bytes)')
        self.off = off + size
        return struct.unpack_from(self.order + fmt, self.data, off)

    def u32(self, what: str) -> int:
        return self._take('I', 4, 4, what)[0]

    def string(self, what: str) -> str:
        n = self.u32(what)
        if n == 0 or self.off + n > len(self.data):
            raise ValueError(f'CDR payload: bad string length {n} in {what}')
        s = bytes(self.data[self.off:self.off + n - 1])
        self.off += n
        return s.decode('utf-8', errors='replace')

    def header_and_names(self, names: str) -> tuple[int, list[str]]:
        """Read ``header`` (stamp [ns]; frame_id dropped) and the string sequence ``names``."""
        sec, nsec = self._take('iI', 8, 4, 'header.stamp')
        self.string('header.frame_id')
        n = self.u32(names)
        if n > len(self.data):
            raise ValueError(f'payload: {names} claims {n} strings')
        return sec * _NS + nsec, [self.string(f'{names}[{k}]') for k in range(n)]

    def doubles(self, what: str) -> tuple[float, ...]:
        n = self.u32(what)
        if n == 0:
            return ()
        if n > len(self.data):
            raise ValueError(f'CDR payload: {what} claims {n} values')
        return self._take(f'{n}d', 8 * n, self.align8, what)


#: layouts seen, by payload length: (encapsulation, prefix, length, Struct, offset, names,
#: counts). A node reads a few (state and reference); a stream of foreign layouts is bounded.
_cache: dict[int, tuple] = {}


def _decode_slow(data: bytes) -> JointStateData:
    r = _Reader(data)
    stamp, names = r.header_and_names('name')
    names = tuple(names)
    mark = r.off
    pos, vel, eff = (r.doubles(w) for w in ('position', 'velocity', 'effort'))
    if r.off == len(data):     # remember this layout: the next message of it is one unpack
        fmt = r.order
        off = mark
        for arr in (pos, vel, eff):
            p = _pad(off - 4, 4)
            fmt += f'{p}xI' if p else 'I'
            off += p + 4
            if arr:
                p = _pad(off - 4, r.align8)
                fmt += (f'{p}x' if p else '') + f'{len(arr)}d'
                off += p + 8 * len(arr)
        if len(_cache) >= 64:
            _cache.clear()
        _cache[len(data)] = (bytes(data[:2]), bytes(data[12:mark]), len(data),
                             struct.Struct(fmt), mark, names, (len(pos), len(vel), len(eff)))
    return JointStateData(stamp, names, pos, vel, eff)


def decode_joint_state(data: bytes) -> JointStateData:
    """Return the JointState serialized in ``data`` (ValueError names what is malformed)."""
    c = _cache.get(len(data))
    if c is not None and data[:2] == c[0] and data[12:c[4]] == c[1]:
        v = c[3].unpack_from(data, c[4])
        counts = c[6]
        if (v[0], v[1 + counts[0]], v[2 + counts[0] + counts[1]]) == counts:
            a, b = 1 + counts[0], 2 + counts[0] + counts[1]
            sec, nsec = struct.unpack_from(_ENCAPSULATION[c[0]][0] + 'iI', data, 4)
            return JointStateData(sec * _NS + nsec, c[5], v[1:a], v[a + 1:b], v[b + 1:])
    return _decode_slow(data)


def state_from_cdr(data: bytes, joint: str = JOINT_PISTON,
                   load_joint: str = JOINT_LOAD) -> AxisState:
    """Read an :class:`AxisState` from a serialized ``state`` JointState (``joint``'s)."""
    m = decode_joint_state(data)
    return state_from_arrays(m.stamp_ns, m.name, m.position, m.velocity, m.effort, joint,
                             load_joint)


def reference_from_cdr(data: bytes) -> Reference:
    """Read a :class:`Reference` from a serialized ``reference`` JointState."""
    m = decode_joint_state(data)
    return reference_from_arrays(m.stamp_ns, m.name, m.position, m.velocity, m.effort)


def command_from_cdr(data: bytes) -> Command:
    """Read a :class:`Command` from a serialized ``servo_current`` JointState."""
    m = decode_joint_state(data)
    return command_from_arrays(m.stamp_ns, m.name, m.effort)


# -- rosgraph_msgs/Clock (the lock-step /clock) ---------------------------------------------
_CLOCK = struct.Struct('<4siI')


def clock_to_cdr(stamp_ns: int) -> bytes:
    """Return a serialized rosgraph_msgs/Clock at ``stamp_ns`` (>= 0) [ns]."""
    return _CLOCK.pack(b'\x00\x01\x00\x00', *divmod(int(stamp_ns), _NS))


def clock_from_cdr(data: bytes) -> int:
    """Return the time [ns] of a serialized rosgraph_msgs/Clock (CDR or XCDR2, any order)."""
    sec, nsec = _Reader(data)._take('iI', 8, 4, 'the Clock')
    return sec * _NS + nsec


# -- what rig drivers publish: std_msgs/Float64, Float64MultiArray, sensor_msgs/FluidPressure --
def float64_from_cdr(data: bytes) -> float:
    """Return the value of a serialized std_msgs/Float64."""
    return _Reader(data)._take('d', 8, 8, 'Float64.data')[0]


def float64_array_to_cdr(values: Sequence[float]) -> bytes:
    """Return a serialized std_msgs/Float64MultiArray of ``values`` (no layout dimensions)."""
    n = len(values)
    # encapsulation, layout.dim (empty), layout.data_offset, data: length, pad to 8, doubles
    pad = '4x' if n else ''
    return struct.pack(f'<4sIII{pad}{n}d', b'\x00\x01\x00\x00', 0, 0, n, *values)


def float64_array_from_cdr(data: bytes) -> tuple[float, ...]:
    """Return the ``data`` of a serialized std_msgs/Float64MultiArray (layout skipped)."""
    r = _Reader(data)
    n = r.u32('layout.dim')
    if n > len(data):
        raise ValueError(f'CDR payload: layout.dim claims {n} dimensions')
    for k in range(n):
        r.string(f'layout.dim[{k}].label')
        r._take('II', 8, 4, f'layout.dim[{k}].size/stride')
    r.u32('layout.data_offset')
    return r.doubles('data')


def fluid_pressure_from_cdr(data: bytes) -> tuple[int, float]:
    """Return (stamp [ns], pressure [Pa]) of a serialized sensor_msgs/FluidPressure."""
    r = _Reader(data)
    sec, nsec = r._take('iI', 8, 4, 'header.stamp')
    r.string('header.frame_id')
    return sec * _NS + nsec, r._take('d', 8, r.align8, 'fluid_pressure')[0]


# -- sensor_msgs/FluidPressure (the chamber pressures) ----------------------------------------
#: encapsulation, stamp, frame_id '' (length 1, its NUL, padding to 8), pressure, variance 0
_PRESSURE = struct.Struct('<4siII4xdd')


def pressure_to_cdr(p: Pressure) -> bytes:
    """Return ``p`` as a serialized FluidPressure (stamp >= 0, empty frame_id, variance 0)."""
    return _PRESSURE.pack(b'\x00\x01\x00\x00', *divmod(int(p.stamp_ns), _NS), 1, p.p, 0.0)


# -- geometry_msgs/WrenchStamped (a load cell: the plant's, a force/torque sensor broadcaster's) -
#: encapsulation, stamp, frame_id 'load_cell' (length 10, its NUL, padding to 8), 6 doubles
_WRENCH = struct.Struct('<4siII10s2x6d')
_WRENCH_AXIS = {'force.x': 0, 'force.y': 1, 'force.z': 2, 'torque.x': 3, 'torque.y': 4,
                'torque.z': 5}


def load_to_cdr(ld: Load) -> bytes:
    """Return ``ld`` as a serialized WrenchStamped: frame ``load_cell``, the force on z."""
    return _WRENCH.pack(b'\x00\x01\x00\x00', *divmod(int(ld.stamp_ns), _NS), 10,
                        b'load_cell\0', 0.0, 0.0, ld.force, 0.0, 0.0, 0.0)


def wrench_from_cdr(data: bytes) -> tuple[int, tuple[float, ...]]:
    """Return (stamp [ns], (fx, fy, fz, tx, ty, tz)) of a serialized WrenchStamped."""
    r = _Reader(data)
    sec, nsec = r._take('iI', 8, 4, 'header.stamp')
    r.string('header.frame_id')
    return sec * _NS + nsec, r._take('6d', 48, r.align8, 'wrench')


def load_from_cdr(data: bytes, axis: str = 'force.z') -> Load:
    """Read a :class:`Load` from a serialized WrenchStamped: the component on ``axis`` [N]."""
    k = _WRENCH_AXIS.get(axis)
    if k is None:
        raise ValueError(f'load cell axis {axis!r} is not one of {list(_WRENCH_AXIS)}')
    stamp, w = wrench_from_cdr(data)
    return Load(stamp, w[k])


# -- trajectory_msgs/JointTrajectory (the lock-step reference_trajectory) -----------------------
def _trajectory_template(n: int, force: bool) -> tuple[bytearray, list[int]]:
    """
    Return the CDR of an ``n``-point trajectory of joint ``piston`` and its value offsets.

    Each point: position, velocity and, with ``force``, effort (F_ref); no accelerations.
    """
    body = bytearray(struct.pack('<iII', 0, 0, 1)) + b'\0\0\0\0'     # stamp, frame_id ''
    name = JOINT_PISTON.encode() + b'\0'
    body += struct.pack('<II', 1, len(name)) + name
    body += b'\0' * _pad(len(body), 4) + struct.pack('<I', n)
    offsets = []      # per point: position, velocity, effort (8-byte aligned), time_from_start
    for _ in range(n):
        for count in (1, 1, 0, int(force)):      # positions, velocities, accelerations, effort
            body += b'\0' * _pad(len(body), 4) + struct.pack('<I', count)
            if count:
                body += b'\0' * _pad(len(body), 8)
                offsets.append(len(body))
                body += b'\0' * 8
        body += b'\0' * _pad(len(body), 4)
        offsets.append(len(body))
        body += b'\0' * 8
    return bytearray(b'\x00\x01\x00\x00') + body, [4 + o for o in offsets]


_TRAJ: dict[tuple[int, bool], tuple[bytearray, list[int]]] = {}


def reference_trajectory_to_cdr(refs: Sequence[Reference]) -> bytes:
    """Return ``refs`` (in time order) as a serialized ``reference_trajectory``."""
    if not refs:
        raise ValueError('a reference trajectory needs at least one point')
    n = len(refs)
    # any F_ref: every point carries one (NaN where a point has none), so a window that
    # turns from displacement to force at a switch keeps its force points
    force = any(r.f_ref == r.f_ref for r in refs)
    key = (n, force)
    if key not in _TRAJ:
        if len(_TRAJ) > 16:
            _TRAJ.clear()
        _TRAJ[key] = _trajectory_template(n, force)
    buf, off = _TRAJ[key]
    t0 = refs[0].stamp_ns
    struct.pack_into('<iI', buf, 4, *divmod(int(t0), _NS))
    pack = struct.pack_into
    w = 3 + force
    for k, r in enumerate(refs):
        o = off[w * k:w * k + w]
        pack('<d', buf, o[0], r.z_ref)
        pack('<d', buf, o[1], r.v_ref)
        if force:
            pack('<d', buf, o[2], r.f_ref)
        pack('<iI', buf, o[-1], *divmod(int(r.stamp_ns - t0), _NS))
    return bytes(buf)


_traj_cache: list = [None]      # (head bytes, length, Struct, offset, k, counts per point)


def reference_trajectory_from_cdr(data: bytes) -> list[Reference]:
    """
    Read the :class:`Reference` of each point of a serialized ``reference_trajectory``.

    Any JointTrajectory: the ``piston`` joint's position and velocity (0 without one) at
    ``header.stamp + time_from_start``, as :func:`~ros_ehs_msgs_py.conversions.
    reference_trajectory_from_msg` reads a message object. ValueError names what is wrong.
    """
    c = _traj_cache[0]
    if c is not None and len(data) == c[1] and data[:2] == c[0][:2] and \
            data[12:c[3]] == c[0][2:]:
        v = c[2].unpack_from(data, c[3])
        if v[0] == c[5] and all(v[i] == w for i, w in c[6]):
            sec, nsec = struct.unpack_from(_ENCAPSULATION[bytes(data[:2])][0] + 'iI', data, 4)
            t0 = sec * _NS + nsec
            return [Reference(t0 + v[ts] * _NS + v[ts + 1], v[zp], v[vp] if vp else 0.0,
                              v[ep] if ep else _NAN)
                    for zp, vp, ep, ts in c[4]]
    return _trajectory_slow(data)


def _trajectory_slow(data: bytes) -> list[Reference]:
    r = _Reader(data)
    t0, names = r.header_and_names('joint_names')
    j = joint_index(names, JOINT_PISTON, 'reference_trajectory')
    mark = r.off + _pad(r.off - 4, 4)      # where the point count starts
    npts = r.u32('points')
    if npts > len(data):
        raise ValueError(f'JointTrajectory payload: points claims {npts} points')
    out, layout = [], []
    fmt, idx, checks = r.order + 'I', 1, []
    off = mark + 4
    for k in range(npts):
        arrays = []
        for field in ('positions', 'velocities', 'accelerations', 'effort'):
            arrays.append(r.doubles(f'points[{k}].{field}'))
        ts, tn = r._take('iI', 8, 4, f'points[{k}].time_from_start')
        pos, vel, eff = arrays[0], arrays[1], arrays[3]
        if len(pos) <= j:
            raise ValueError(f'`reference_trajectory` point {k} has no positions[{j}] '
                             f'(length {len(pos)})')
        out.append(Reference(t0 + ts * _NS + tn, pos[j], vel[j] if len(vel) > j else 0.0,
                             eff[j] if len(eff) > j else _NAN))
        # the same walk as a format, for the cache
        where = []
        for arr in arrays:
            p = _pad(off - 4, 4)
            fmt += (f'{p}x' if p else '') + 'I'
            checks.append((idx, len(arr)))
            idx += 1
            off += p + 4
            if arr:
                p = _pad(off - 4, r.align8)
                fmt += (f'{p}x' if p else '') + f'{len(arr)}d'
                where.append(idx)
                idx += len(arr)
                off += p + 8 * len(arr)
            else:
                where.append(None)
        p = _pad(off - 4, 4)
        fmt += (f'{p}x' if p else '') + 'iI'
        zp = where[0] + j
        vp = where[1] + j if where[1] is not None and len(vel) > j else None
        ep = where[3] + j if where[3] is not None and len(eff) > j else None
        layout.append((zp, vp, ep, idx))
        idx += 2
        off += p + 8
    if r.off == len(data) and off == len(data):
        _traj_cache[0] = (bytes(data[:2]) + bytes(data[12:mark]), len(data),
                          struct.Struct(fmt), mark, layout, npts, checks)
    return out
