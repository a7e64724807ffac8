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
"""The contract's plain values: what a message means, in SI units, without ROS."""

from __future__ import annotations

import math
from typing import NamedTuple

__all__ = ['AxisState', 'Command', 'Load', 'NodeStatus', 'ParameterEstimate', 'Pressure',
           'Reference', 'SafetyEvent']


class AxisState(NamedTuple):
    """Measured piston state: position [m], velocity [m/s], hydraulic force [N], spool [m]."""

    stamp_ns: int
    z: float
    z_dot: float
    force: float = math.nan
    x_spool: float = math.nan
    i: float = math.nan     #: current [A] applied over the period that ended here (if known)
    load: float = math.nan  #: the specimen's force, the load cell's reading [N] (if known)


class Reference(NamedTuple):
    """Position reference [m] and its velocity [m/s]; a force reference [N] (NaN: none)."""

    stamp_ns: int
    z_ref: float
    v_ref: float
    f_ref: float = math.nan


class Load(NamedTuple):
    """A load cell's reading: the force the specimen carries [N] (tension positive)."""

    stamp_ns: int
    force: float


class Command(NamedTuple):
    """Servo-valve current [A]."""

    stamp_ns: int
    i: float


class Pressure(NamedTuple):
    """A chamber pressure [Pa]."""

    stamp_ns: int
    p: float


class SafetyEvent(NamedTuple):
    """
    One safety event of the controller: a detector's trip, a reset, hydraulics on or off.

    ``stamp_ns`` is the stamp of the state on which it happened; ``value`` and ``limit`` are
    in ``unit`` (NaN where none applies); ``action`` is the trip's action (for the other
    kinds, the action in force).
    """

    stamp_ns: int
    #: trip, reset, reset_refused, enabled, disabled, enable_refused, mode, mode_refused,
    #: clipped, unclipped
    kind: str
    detector: str    #: the detector (a trip), the detectors concerned, or ''
    value: float
    limit: float
    unit: str
    action: str      #: off, indicate, hold, stop, power_off
    message: str


class ParameterEstimate(NamedTuple):
    """
    One live refit of the plant's parameters over a window of the running loop.

    ``stamp_ns`` is the window's last state stamp; ``values`` and ``stderr`` map each fitted
    parameter to its value and standard error (SI units of the parameter table);
    ``adequate`` is the fit's verdict (the sensor noise explains the residuals) and
    ``verdict`` says why or why not, ``failed`` the verdict's rules it failed (as
    ``summary.json``'s ``failed_rules``: ``rate``, ``agreement:F_cc``...; empty when adequate);
    ``pushed`` whether these values were set on the controller, and ``reason`` why (or why
    not).
    """

    stamp_ns: int
    values: dict
    stderr: dict
    adequate: bool
    verdict: str
    pushed: bool = False
    reason: str = ''
    window_s: float = math.nan      #: the data fitted [s]
    wall_s: float = math.nan        #: the refit's wall time [s]
    iterations: int = 0
    failed: tuple = ()


class NodeStatus(NamedTuple):
    """
    One node's status in ``diagnostics``: what it is doing, and whether it is ready.

    ``level`` is DiagnosticStatus's (0 OK, 1 WARN, 2 ERROR, 3 STALE); ``values`` its key-value
    pairs as strings. The readiness each node reports is listed with the status names in
    :mod:`ros_ehs_msgs_py.topics`.
    """

    stamp_ns: int
    name: str
    level: int
    message: str
    values: dict

    def listed(self, key: str) -> set[str]:
        """Return the comma-separated items of value ``key`` (empty if absent)."""
        return {x for x in self.values.get(key, '').split(',') if x}
