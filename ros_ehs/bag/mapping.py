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
    input_delay: auto               # or seconds, e.g. 0.002

Accepted message types: state ``sensor_msgs/JointState`` (position always; velocity used when
present, else derived from the position); command ``sensor_msgs/JointState`` (the effort of
``command_joint``), ``std_msgs/Float64`` or ``std_msgs/Float64MultiArray``
(``command_index``); pressures ``sensor_msgs/FluidPressure`` or ``std_msgs/Float64``, per
chamber (``pressure_p``, ``pressure_t``) or as one load pressure ``p_CP - p_CT``
(``pressure_load``), or none.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
import math
import os
from pathlib import Path
from typing import Any, Mapping

from ros_ehs.errors import InputError
import ros_ehs_msgs_py as contract

__all__ = ['COMMAND_TYPES', 'PRESSURE_TYPES', 'STATE_TYPES', 'TopicMap', 'load_topic_map',
           'topic_map']

JOINT_STATE = 'sensor_msgs/msg/JointState'
FLOAT64 = 'std_msgs/msg/Float64'
FLOAT64_ARRAY = 'std_msgs/msg/Float64MultiArray'
FLUID_PRESSURE = 'sensor_msgs/msg/FluidPressure'
STATE_TYPES = (JOINT_STATE,)
COMMAND_TYPES = (JOINT_STATE, FLOAT64, FLOAT64_ARRAY)
PRESSURE_TYPES = (FLUID_PRESSURE, FLOAT64)
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
    input_delay: float | None = None

    def __post_init__(self) -> None:
        """Check every field; errors name it."""
        for name in ('state', 'joint', 'command', 'command_joint'):
            v = getattr(self, name)
            if not isinstance(v, str) or not v:
                raise InputError(f'topic map: `{name}` = {v!r} must be a non-empty string')
        for name in ('pressure_p', 'pressure_t', 'pressure_load'):
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
