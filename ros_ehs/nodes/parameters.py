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
A node's ROS parameters, declared from the settings (:mod:`ros_ehs.core.settings`).

:func:`declare_settings` declares a node's options (:mod:`ros_ehs.core.options`) and its model
and controller parameters (:mod:`ros_ehs.core.params`) with their unit, meaning, range or
choices, read-only unless live, and returns the values the node starts with, checked;
:func:`validate_changes` checks a live change as a whole and turns a rejection into
``SetParametersResult`` with the reason; :func:`check_names` refuses parameters a node does
not declare, naming them.
"""

from __future__ import annotations

from typing import Any, Callable, Iterable, Mapping, Sequence

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_ehs.core.errors import ParameterError
from ros_ehs.core.params import Params, ParamSpec
from ros_ehs.core.settings import by_name, Setting

__all__ = ['check_names', 'declare_settings', 'node_params', 'rejected_names',
           'update_settings', 'validate_changes']


def _descriptor(s: Setting) -> ParameterDescriptor:
    """Return the ROS descriptor of setting ``s``: its meaning, range or choices, read-only."""
    d = ParameterDescriptor(description=s.describe().replace('; *live*', ''),
                            read_only=not s.live)
    if s.choices:
        d.additional_constraints = f'one of {list(s.choices)}'
    if s.ranged:
        if s.kind == 'int':
            d.integer_range = [IntegerRange(from_value=int(s.lo), to_value=int(s.hi), step=1)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(s.lo),
                                                         to_value=float(s.hi), step=0.0)]
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


def declare_settings(node: Node, settings: Sequence[Setting],
                     values: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """
    Declare each setting as a ROS parameter; return the values the node starts with, checked.

    The default is ``values[name]`` when given (a :class:`~ros_ehs.core.params.Params`), else
    the setting's. A value given at start (``-p``, a params file) outside the range or the
    choices raises :class:`ParameterError` naming it.
    """
    _coerce_int_overrides(node, [s.name for s in settings if s.kind == 'float'])
    out = {}
    for s in settings:
        default = values[s.name] if values is not None and s.name in values else s.default
        if s.kind == 'float':
            default = float(default)
        if s.kind == 'list':
            v = node.declare_parameter(s.name, Parameter.Type.STRING_ARRAY,
                                       _descriptor(s)).value
            v = v if v else list(default)
        else:
            v = node.declare_parameter(s.name, default, _descriptor(s)).value
        out[s.name] = s.check(v)
    return out


def update_settings(values: dict[str, Any], changes: Sequence[Parameter],
                    settings: Sequence[Setting]) -> None:
    """Apply accepted live changes of ``settings`` to a node's ``values``."""
    live = {s.name for s in settings if s.live}
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
                     specs: Sequence[ParamSpec], options: Sequence[Setting] = ()
                     ) -> tuple[SetParametersResult, Params | None]:
    """
    Check a live parameter change: return the result for rclpy and the new Params.

    The new parameter set is validated as a whole (ranges and cross-relations such as F_cc <=
    F_sc), so the reason names the offending parameter; a live option is checked against its
    setting. (Names are checked before, for every node: :func:`run` registers
    :func:`check_names`.)
    """
    names = {s.name for s in specs}
    opts = by_name(options)
    upd = {}
    for p in changes:
        if p.name in names:
            upd[p.name] = p.value
        elif p.name in opts:
            try:
                opts[p.name].check(p.value)
            except ParameterError as err:
                return SetParametersResult(successful=False, reason=str(err)), None
    if not upd:
        return SetParametersResult(successful=True), None
    try:
        new = current.replace(**upd)
    except ParameterError as err:
        return SetParametersResult(successful=False, reason=str(err)), None
    return SetParametersResult(successful=True), new
