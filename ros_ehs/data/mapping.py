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
Where the axis's signals are in a bag: a :class:`TopicMap`, written once per rig.

The default map is this package's own topic contract. A rig whose driver follows
ros2_control's conventions needs a few lines of YAML (``--topics rig.yaml``)::

    state: /joint_states            # sensor_msgs/JointState
    joint: actuator_z               # the axis's joint among the others
    command: /servo_valve_controller/commands   # std_msgs/Float64MultiArray
    command_index: 0                # which element is this axis's current
    command_scale: 0.001            # A per unit the driver commands (here mA)
    pressure_p: /hydraulics/chamber_a     # FluidPressure [Pa], or Float64 in pressure_unit
    pressure_t: /hydraulics/chamber_b
    pressure_unit: bar
    load_cell: /fts_broadcaster/wrench    # geometry_msgs/WrenchStamped: a specimen's force
    load_axis: force.z              # its component that is the load (tension positive)
    input_delay: auto               # or seconds, e.g. 0.002

Accepted message types: state ``sensor_msgs/JointState`` (position always; velocity used when
present, else derived from the position); command ``sensor_msgs/JointState`` (the effort of
``command_joint``), ``std_msgs/Float64`` or ``std_msgs/Float64MultiArray``
(``command_index``); pressures ``sensor_msgs/FluidPressure`` or ``std_msgs/Float64``, per
chamber (``pressure_p``, ``pressure_t``) or as one load pressure ``p_CP - p_CT``
(``pressure_load``), or none; the load cell ``geometry_msgs/WrenchStamped`` (the component
``load_axis``; ros2_control's force_torque_sensor_broadcaster), or none.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
import math
import os
from pathlib import Path
from typing import Any, Callable, Mapping

from ros_ehs.core.errors import InputError
import ros_ehs_msgs_py as contract

__all__ = ['COMMAND_TYPES', 'LOAD_TYPES', 'PRESSURE_TYPES', 'ROLES', 'STATE_TYPES',
           'TopicDecoder', 'TopicMap', 'decoder', 'load_topic_map', 'topic_map', 'topic_map_of']

JOINT_STATE = 'sensor_msgs/msg/JointState'
FLOAT64 = 'std_msgs/msg/Float64'
FLOAT64_ARRAY = 'std_msgs/msg/Float64MultiArray'
FLUID_PRESSURE = 'sensor_msgs/msg/FluidPressure'
WRENCH = 'geometry_msgs/msg/WrenchStamped'
STATE_TYPES = (JOINT_STATE,)
COMMAND_TYPES = (JOINT_STATE, FLOAT64, FLOAT64_ARRAY)
PRESSURE_TYPES = (FLUID_PRESSURE, FLOAT64)
LOAD_TYPES = (WRENCH,)
#: Pa per unit of a Float64 pressure (FluidPressure is Pa by definition)
PRESSURE_UNITS = {'Pa': 1.0, 'kPa': 1.0e3, 'MPa': 1.0e6, 'bar': 1.0e5}


@dataclass(frozen=True)
class TopicMap:
    """
    Topic names, joints and units of the axis's signals in a bag (see the module docstring).

    Relative topic names match in any namespace (``state`` finds ``/axis1/state``).
    ``input_delay``: the time [s] from a command's stamp (or, without a header, its receive
    time) to the valve acting on it; ``None`` estimates it in the fit (where the bag records
    the current the valve got, as our plant does, it is 0).
    """

    state: str = contract.STATE.name
    joint: str = contract.JOINT_PISTON
    command: str = contract.COMMAND.name
    command_joint: str = contract.JOINT_VALVE
    command_index: int = 0
    command_scale: float = 1.0
    pressure_p: str | None = contract.PRESSURE_P.name
    pressure_t: str | None = contract.PRESSURE_T.name
    pressure_load: str | None = None
    pressure_unit: str = 'Pa'
    load_cell: str | None = contract.LOAD_CELL.name
    load_axis: str = 'force.z'
    input_delay: float | None = None

    def __post_init__(self) -> None:
        """Check every field; errors name it."""
        for name in ('state', 'joint', 'command', 'command_joint'):
            v = getattr(self, name)
            if not isinstance(v, str) or not v:
                raise InputError(f'topic map: `{name}` = {v!r} must be a non-empty string')
        for name in ('pressure_p', 'pressure_t', 'pressure_load', 'load_cell'):
            v = getattr(self, name)
            if v is not None and (not isinstance(v, str) or not v):
                raise InputError(f'topic map: `{name}` = {v!r} must be a topic name or null')
        if (self.pressure_p is None) != (self.pressure_t is None):
            raise InputError('topic map: give both `pressure_p` and `pressure_t`, or neither '
                             f'(got {self.pressure_p!r}, {self.pressure_t!r})')
        if self.pressure_load is not None and self.pressure_p is not None:
            raise InputError('topic map: give chamber pressures (`pressure_p`, `pressure_t`) '
                             'or a load pressure (`pressure_load`), not both')
        if isinstance(self.command_index, bool) or not isinstance(self.command_index, int) \
                or self.command_index < 0:
            raise InputError(f'topic map: `command_index` = {self.command_index!r} must be an '
                             'integer >= 0')
        if isinstance(self.command_scale, bool) or not isinstance(
                self.command_scale, (int, float)) or not math.isfinite(self.command_scale) \
                or self.command_scale == 0:
            raise InputError(f'topic map: `command_scale` = {self.command_scale!r} must be a '
                             'finite, non-zero number [A per unit]')
        if self.load_axis not in contract.WRENCH_AXES:
            raise InputError(f'topic map: `load_axis` = {self.load_axis!r} is not one of '
                             f'{list(contract.WRENCH_AXES)}')
        if self.pressure_unit not in PRESSURE_UNITS:
            raise InputError(f'topic map: `pressure_unit` = {self.pressure_unit!r} is not one '
                             f'of {list(PRESSURE_UNITS)}')
        d = self.input_delay
        if d is not None and (isinstance(d, bool) or not isinstance(d, (int, float))
                              or not math.isfinite(d) or not 0.0 <= d <= 0.5):
            raise InputError(f'topic map: `input_delay` = {d!r} s must be in [0, 0.5] s, or '
                             'auto')

    @property
    def pressures(self) -> str:
        """Return 'chambers', 'load' or 'none'."""
        if self.pressure_p is not None:
            return 'chambers'
        return 'load' if self.pressure_load is not None else 'none'

    def without_pressures(self) -> 'TopicMap':
        """Return this map with no pressure topics (a fit of position and velocity only)."""
        return replace(self, pressure_p=None, pressure_t=None, pressure_load=None)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any], where: str = 'topic map') -> 'TopicMap':
        """Build from a mapping (a YAML file's); unknown keys raise naming the known ones."""
        if not isinstance(values, Mapping):
            raise InputError(f'{where}: expected a mapping of {[f.name for f in fields(cls)]}, '
                             f'got {type(values).__name__}')
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise InputError(f'{where}: unknown keys {unknown}; known: {sorted(known)}')
        v = dict(values)
        if ('pressure_p' in v) != ('pressure_t' in v):
            raise InputError(f'{where}: give both `pressure_p` and `pressure_t`, or neither '
                             f"(got only {'pressure_p' if 'pressure_p' in v else 'pressure_t'})")
        if v.get('pressure_load') and 'pressure_p' not in v:
            v['pressure_p'] = v['pressure_t'] = None    # a load pressure instead of chambers
        if isinstance(v.get('input_delay'), str):
            if v['input_delay'].strip().lower() != 'auto':
                raise InputError(f"{where}: `input_delay` = {v['input_delay']!r} must be a "
                                 'number [s] or auto')
            v['input_delay'] = None
        if isinstance(v.get('command_scale'), int) and not isinstance(v['command_scale'], bool):
            v['command_scale'] = float(v['command_scale'])
        try:
            return cls(**v)
        except InputError as err:
            raise InputError(f'{where}: {err}'.replace('topic map: ', '')) from None

    def as_dict(self) -> dict[str, Any]:
        """Return the map as plain values (``input_delay`` None as 'auto')."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        if d['input_delay'] is None:
            d['input_delay'] = 'auto'
        return d


def load_topic_map(path: str | os.PathLike, **overrides: Any) -> TopicMap:
    """Read a topic map from a YAML file; ``overrides`` (not None) replace its entries."""
    import yaml
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text()) or {}
    except (OSError, yaml.YAMLError) as err:
        raise InputError(f'cannot read the topic map {str(p)!r}: {err}') from None
    doc = {**doc, **{k: v for k, v in overrides.items() if v is not None}} \
        if isinstance(doc, dict) else doc
    return TopicMap.from_dict(doc, where=f'topic map {str(p)!r}')


def topic_map_of(options: Mapping[str, Any], where: str = 'the options') -> TopicMap:
    """
    Return the map that the identify options say (the node's and ``ehs_sim identify``'s).

    ``topic_map`` (a file, or the contract), then the topic options that are set over it
    (``state_topic``, ``joint``, ``command_topic``, ``command_index`` >= 0,
    ``pressure_p_topic``, ``pressure_t_topic``, ``load_topic``, ``input_delay`` >= 0), without
    pressures when ``use_pressures`` is false.
    """
    o = options
    tmap = topic_map(o['topic_map'] or None, where, state=o['state_topic'] or None,
                     joint=o['joint'] or None, command=o['command_topic'] or None,
                     command_index=None if o['command_index'] < 0 else o['command_index'],
                     pressure_p=o['pressure_p_topic'] or None,
                     pressure_t=o['pressure_t_topic'] or None,
                     load_cell=o.get('load_topic') or None,
                     input_delay=None if o['input_delay'] < 0 else o['input_delay'])
    return tmap if o['use_pressures'] else tmap.without_pressures()


def topic_map(path: str | os.PathLike | None = None, where: str = 'the options',
              **overrides: Any) -> TopicMap:
    """
    Return the map in the YAML file ``path`` (none: the contract's), then ``overrides``.

    An override of None is not given. ``where`` names the overrides' source in errors when
    there is no file (a command line, a node's parameters).
    """
    if path:
        return load_topic_map(path, **overrides)
    return TopicMap.from_dict({k: v for k, v in overrides.items() if v is not None},
                              where=where)


#: The signals a map places, and the message types each may come as.
ROLES = {'state': STATE_TYPES, 'command': COMMAND_TYPES, 'pressure_p': PRESSURE_TYPES,
         'pressure_t': PRESSURE_TYPES, 'pressure_load': PRESSURE_TYPES,
         'load_cell': LOAD_TYPES}


class TopicDecoder:
    """
    Read one mapped signal from a message's CDR bytes, one message at a time.

    What a bag's reader (:mod:`ros_ehs.data.experiments`) and the live identifier both call.

    Calling it returns, for the ``state``, ``(stamp [ns], z [m], z_dot [m/s] or NaN, applied
    current [A] or NaN)``, and for a command, a pressure or the load cell ``(stamp [ns], value
    [A, Pa or N])``;
    the stamp is None for a message without a header (``Float64``, ``Float64MultiArray``: the
    caller puts its receive time on the state's clock). A message without the mapped joint
    gives None and its joints are kept in :attr:`seen` (the first 20), for an error that names
    them. A malformed message raises ValueError naming what is wrong.
    """

    def __init__(self, role: str, msg_type: str, read: Callable[[bytes], Any],
                 joint: str = '') -> None:
        self.role, self.msg_type, self.joint = role, msg_type, joint
        self.stamped = msg_type in (JOINT_STATE, FLUID_PRESSURE)
        self.seen: set[str] = set()
        self._read = read

    def __call__(self, data: bytes) -> tuple | None:
        """Return the signal in the message (see the class docstring)."""
        return self._read(data)


def decoder(tmap: TopicMap, role: str, msg_type: str) -> TopicDecoder:
    """
    Return the :class:`TopicDecoder` of ``role`` (a key of :data:`ROLES`) for ``msg_type``.

    Raises :class:`InputError` naming the role, the type and the types it takes.
    """
    if role not in ROLES:
        raise InputError(f'unknown signal {role!r}; known: {list(ROLES)}')
    if msg_type not in ROLES[role]:
        want = ROLES[role][0] if len(ROLES[role]) == 1 else f'one of {list(ROLES[role])}'
        raise InputError(f'the {role} topic has type {msg_type}, expected {want}')
    index: dict[tuple, int] = {}
    joint = {'state': tmap.joint, 'command': tmap.command_joint}.get(role, '')
    dec = TopicDecoder(role, msg_type, lambda data: None, joint)

    def joint_of(names: tuple, joint: str) -> int:
        key = (names, joint)
        k = index.get(key)
        if k is None:
            k = index[key] = names.index(joint) if joint in names else -1
        return k

    def missing(names: tuple) -> None:
        if len(dec.seen) < 20:
            dec.seen.update(names)

    if role == 'state':
        def read(data: bytes):
            d = contract.decode_joint_state(data)
            k = joint_of(d.name, joint)
            if k < 0:
                missing(d.name)
                return None
            if k >= len(d.position):
                raise ValueError(f'joint {joint!r} has no position ({len(d.position)} '
                                 f'positions for {len(d.name)} joints)')
            j = joint_of(d.name, contract.JOINT_VALVE)
            return (d.stamp_ns, d.position[k],
                    d.velocity[k] if k < len(d.velocity) else math.nan,
                    d.effort[j] if 0 <= j < len(d.effort) else math.nan)
    elif role == 'command':
        scale = float(tmap.command_scale)
        if msg_type == JOINT_STATE:
            def read(data: bytes):
                d = contract.decode_joint_state(data)
                k = joint_of(d.name, joint)
                if k < 0 or k >= len(d.effort):
                    missing(d.name)
                    return None
                return d.stamp_ns, d.effort[k] * scale
        elif msg_type == FLOAT64:
            def read(data: bytes):
                return None, contract.float64_from_cdr(data) * scale
        else:
            ci = tmap.command_index

            def read(data: bytes):
                values = contract.float64_array_from_cdr(data)
                if ci >= len(values):
                    raise ValueError(f'`command_index` = {ci} but its Float64MultiArray '
                                     f'message has {len(values)} values')
                return None, values[ci] * scale
    elif role == 'load_cell':
        axis = tmap.load_axis

        def read(data: bytes):
            r = contract.load_from_cdr(data, axis)
            return r.stamp_ns, r.force
    elif msg_type == FLUID_PRESSURE:
        read = contract.fluid_pressure_from_cdr
    else:
        unit = PRESSURE_UNITS[tmap.pressure_unit]

        def read(data: bytes):
            return None, contract.float64_from_cdr(data) * unit
    dec._read = read
    return dec
