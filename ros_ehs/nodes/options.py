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
A node's parameters, declared from the one table: options, specs, live changes.

:class:`Option` declares a node's own setting (name, default, meaning, range or choices);
:func:`declare_specs` declares model and controller parameters from :mod:`ros_ehs.core.params`
with their unit, meaning and range; :func:`validate_changes` checks a live change as a whole
and turns a rejection into ``SetParametersResult`` with the reason; :func:`check_names`
refuses parameters a node does not declare, naming them.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Iterable, NamedTuple, Sequence

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_ehs.core.errors import ParameterError
from ros_ehs.core.params import Params, ParamSpec

__all__ = ['Option', 'check_names', 'declare_options', 'declare_specs', 'node_params',
           'rejected_names', 'update_options', 'validate_changes']


class Option(NamedTuple):
    """A node's own setting (not a model or controller parameter): declared once here."""

    name: str
    default: Any
    description: str
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = True


def _descriptor(description: str, read_only: bool, lo=None, hi=None, integer=False,
                choices=()) -> ParameterDescriptor:
    d = ParameterDescriptor(description=description, read_only=read_only)
    if choices:
        d.additional_constraints = f'one of {list(choices)}'
    if lo is not None and hi is not None and math.isfinite(lo) and math.isfinite(hi):
        if integer:
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                         to_value=float(hi), step=0.0)]
    return d


def _coerce_int_overrides(node: Node, names: Iterable[str]) -> None:
    """Let ``kp: 1`` in a params file mean 1.0 (rclpy rejects integers for doubles)."""
    ov = getattr(node, '_parameter_overrides', None)
    if not isinstance(ov, dict):
        return
    for n in names:
        p = ov.get(n)
        if p is not None and p.type_ == Parameter.Type.INTEGER:
            ov[n] = Parameter(n, Parameter.Type.DOUBLE, float(p.value))


def declare_specs(node: Node, specs: Sequence[ParamSpec], values: Params,
                  read_only: bool = False) -> None:
    """Declare each spec as a ROS parameter: value from ``values``, unit/meaning, range."""
    _coerce_int_overrides(node, [s.name for s in specs if not s.is_choice])
    for s in specs:
        d = _descriptor(f'{s.meaning} [{s.unit}]' if s.unit else s.meaning, read_only,
                        s.lo, s.hi, choices=s.choices)
        v = values[s.name]
        node.declare_parameter(s.name, v if s.is_choice else float(v), d)


def _not_a_choice(o: Option, value: Any) -> str | None:
    """Return why ``value`` is not one of option ``o``'s choices, or None if it is."""
    if o.choices and value not in o.choices:
        return f'parameter `{o.name}` = {value!r} is not one of {list(o.choices)}'
    return None


def declare_options(node: Node, options: Sequence[Option]) -> dict[str, Any]:
    """Declare a node's options; return their values by name (checked against choices)."""
    _coerce_int_overrides(node, [o.name for o in options if isinstance(o.default, float)])
    out = {}
    for o in options:
        integer = isinstance(o.default, int) and not isinstance(o.default, bool)
        d = _descriptor(o.description, o.read_only, o.lo, o.hi, integer, o.choices)
        if isinstance(o.default, list) and not o.default:
            ptype = Parameter.Type.STRING_ARRAY
            v = node.declare_parameter(o.name, ptype, d).value or []
        else:
            v = node.declare_parameter(o.name, o.default, d).value
        why = _not_a_choice(o, v)
        if why:
            raise ParameterError(why)
        out[o.name] = v
    return out


def update_options(values: dict[str, Any], changes: Sequence[Parameter],
                   options: Sequence[Option]) -> None:
    """Apply accepted live changes of ``options`` to a node's option ``values``."""
    live = {o.name for o in options if not o.read_only}
    for p in changes:
        if p.name in live:
            values[p.name] = p.value


def node_params(node: Node, base: Params, specs: Sequence[ParamSpec]) -> Params:
    """Return ``base`` with the values of ``specs`` as the node now holds them (validated)."""
    return base.replace(**{s.name: node.get_parameter(s.name).value for s in specs})


def rejected_names(changes: Sequence[Parameter], declared: Callable[[str], bool]
                   ) -> str | None:
    """
    Return why a live change names no parameter the node can change, or None.

    An empty name, an undeclared one, and ``use_sim_time`` (read when the node starts: its
    clocks and staleness checks follow it) are rejected.
    """
    for p in changes:
        if not p.name or not p.name.strip():
            return 'a parameter with an empty name'
        if not declared(p.name):
            return f'parameter `{p.name}` is not declared by this node'
        if p.name == 'use_sim_time':
            return ('`use_sim_time` is read when the node starts (its clocks and staleness '
                    'checks follow it): restart the node with the new value')
    return None


def check_names(node: Node) -> None:
    """
    Make ``node`` reject live changes whose names :func:`rejected_names` rejects.

    Call it once every parameter is declared (rclpy runs these callbacks on declarations
    too): :func:`run` does, for every node.
    """
    def check(changes):
        why = rejected_names(changes, node.has_parameter)
        if why:
            node.get_logger().warning(f'parameter change rejected: {why}',
                                      throttle_duration_sec=1.0)
        return SetParametersResult(successful=why is None, reason=why or '')

    node.add_on_set_parameters_callback(check)


def validate_changes(current: Params, changes: Sequence[Parameter],
                     specs: Sequence[ParamSpec], options: Sequence[Option] = ()
                     ) -> tuple[SetParametersResult, Params | None]:
    """
    Check a live parameter change: return the result for rclpy and the new Params.

    The new set is validated as a whole (ranges and cross-relations such as F_cc <= F_sc),
    so the reason names the offending parameter. (Names are checked before, for every node:
    :func:`run` registers :func:`check_names`.)
    """
    names = {s.name for s in specs}
    opts = {o.name: o for o in options}
    upd = {}
    for p in changes:
        if p.name in names:
            upd[p.name] = p.value
        elif p.name in opts and (why := _not_a_choice(opts[p.name], p.value)):
            return SetParametersResult(successful=False, reason=why), None
    if not upd:
        return SetParametersResult(successful=True), None
    try:
        new = current.replace(**upd)
    except ParameterError as err:
        return SetParametersResult(successful=False, reason=str(err)), None
    return SetParametersResult(successful=True), new
