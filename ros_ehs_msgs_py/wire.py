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
Measured on the project's VM, the bare ping-pong makes 11000-12000 round trips/s this way
against 8200-9200 with message objects (``bench lockstep`` prints both).

* :class:`JointStateEncoder`: one fixed layout (joint names, array lengths), built once; each
  message is the template with the stamp and the values packed in (:func:`state_to_cdr`,
  :func:`command_to_cdr`).
* :func:`decode_joint_state`: any JointState, from any client: CDR (XCDR1) and plain XCDR2,
  either byte order; the last layout seen is cached, so a steady publisher costs one
  ``unpack``. A truncated or foreign payload raises ValueError naming what is wrong.
* :func:`state_from_cdr`, :func:`command_from_cdr`: the records, by the same rules as
  :func:`~ros_ehs_msgs_py.conversions.state_from_msg` and ``command_from_msg``.

Checked against rclpy's own ``serialize_message``/``deserialize_message`` (test_node_core).
"""

from __future__ import annotations

import math
import struct
from typing import NamedTuple, Sequence

from ros_ehs_msgs_py.conversions import command_from_arrays, state_from_arrays
from ros_ehs_msgs_py.records import AxisState, Command
from ros_ehs_msgs_py.topics import JOINT_PISTON, JOINT_SPOOL, JOINT_VALVE

__all__ = ['JointStateData', 'JointStateEncoder', 'command_from_cdr', 'command_to_cdr',
           'decode_joint_state', 'state_from_cdr', 'state_to_cdr']

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
_COMMAND = JointStateEncoder((JOINT_VALVE,), 0, 0, 1)
_NAN = math.nan


def state_to_cdr(s: AxisState) -> bytes:
    """Return ``s`` as a serialized ``state`` JointState (piston, spool, servo_valve)."""
    return _STATE.encode(s.stamp_ns, (s.z, s.x_spool, _NAN, s.z_dot, _NAN, _NAN,
                                      s.force, _NAN, s.i))


def command_to_cdr(c: Command) -> bytes:
    """Return ``c`` as a serialized ``servo_current`` JointState (``servo_valve`` effort)."""
    return _COMMAND.encode(c.stamp_ns, (c.i,))


class _Reader:
    """Sequential CDR reader over one payload (errors name the field and the offset)."""

    __slots__ = ('data', 'off', 'order', 'align8')

    def __init__(self, data: bytes) -> None:
        if len(data) < 4:
            raise ValueError(f'a JointState payload of {len(data)} bytes has no CDR header')
        enc = _ENCAPSULATION.get(bytes(data[:2]))
        if enc is None:
            raise ValueError(f'unsupported CDR encapsulation 0x{bytes(data[:2]).hex()} '
                             '(expected CDR or plain XCDR2)')
        self.data, self.off = data, 4
        self.order, self.align8 = enc

    def _take(self, fmt: str, size: int, align: int, what: str):
        off = self.off + _pad(self.off - 4, align)
        if off + size > len(self.data):
            raise ValueError(f'JointState payload truncated in {what} (offset {off}, '
                             f'{len(self.data)} bytes)')
        self.off = off + size
        return struct.unpack_from(self.order + fmt, self.data, off)

    def u32(self, what: str) -> int:
        return self._take('I', 4, 4, what)[0]

    def string(self, what: str) -> str:
        n = self.u32(what)
        if n == 0 or self.off + n > len(self.data):
            raise ValueError(f'JointState payload: bad string length {n} in {what}')
        s = bytes(self.data[self.off:self.off + n - 1])
        self.off += n
        return s.decode('utf-8', errors='replace')

    def doubles(self, what: str) -> tuple[float, ...]:
        n = self.u32(what)
        if n == 0:
            return ()
        if n > len(self.data):
            raise ValueError(f'JointState payload: {what} claims {n} values')
        return self._take(f'{n}d', 8 * n, self.align8, what)


_cache: list = [None]      # the last layout: (prefix, length, Struct, offset, names, counts)


def _decode_slow(data: bytes) -> JointStateData:
    r = _Reader(data)
    sec, nsec = r._take('iI', 8, 4, 'header.stamp')
    r.string('header.frame_id')
    n = r.u32('name')
    if n > len(data):
        raise ValueError(f'JointState payload: name claims {n} strings')
    names = tuple(r.string(f'name[{k}]') for k in range(n))
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
        _cache[0] = (bytes(data[:2]), bytes(data[12:mark]), len(data), struct.Struct(fmt),
                     mark, names, (len(pos), len(vel), len(eff)))
    return JointStateData(sec * _NS + nsec, names, pos, vel, eff)


def decode_joint_state(data: bytes) -> JointStateData:
    """Return the JointState serialized in ``data`` (ValueError names what is malformed)."""
    c = _cache[0]
    if c is not None and len(data) == c[2] and data[:2] == c[0] and data[12:c[4]] == c[1]:
        v = c[3].unpack_from(data, c[4])
        counts = c[6]
        if (v[0], v[1 + counts[0]], v[2 + counts[0] + counts[1]]) == counts:
            a, b = 1 + counts[0], 2 + counts[0] + counts[1]
            sec, nsec = struct.unpack_from(_ENCAPSULATION[c[0]][0] + 'iI', data, 4)
            return JointStateData(sec * _NS + nsec, c[5], v[1:a], v[a + 1:b], v[b + 1:])
    return _decode_slow(data)


def state_from_cdr(data: bytes) -> AxisState:
    """Read an :class:`AxisState` from a serialized ``state`` JointState."""
    m = decode_joint_state(data)
    return state_from_arrays(m.stamp_ns, m.name, m.position, m.velocity, m.effort)


def command_from_cdr(data: bytes) -> Command:
    """Read a :class:`Command` from a serialized ``servo_current`` JointState."""
    m = decode_joint_state(data)
    return command_from_arrays(m.stamp_ns, m.name, m.effort)
