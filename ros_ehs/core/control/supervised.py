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
The supervised axis controller: the safety supervisor in front of PID + feedforward.

:class:`~ros_ehs.core.control.safety.Supervisor` in front of
:class:`~ros_ehs.core.control.controller.Controller`, one call per control period. This is what
the controller node runs and what :func:`ros_ehs.core.sim.closed_loop.run_closed_loop` runs with
``supervised=True``: the same arithmetic in process and over DDS. While the supervisor
demands no power (power off, hydraulics off, waiting for a finite position) the command is 0
A and the PID and feedforward stay at rest, so power returns without a kick.
"""

from __future__ import annotations

import math

from ros_ehs.core.control.controller import Controller
from ros_ehs.core.control.safety import Demand, Event, SafetyConfig, Supervisor
from ros_ehs.core.params import Params

__all__ = ['AxisController']


class AxisController:
    """Detectors, actions and ramp-on around PID + feedforward."""

    def __init__(self, params: Params, dt: float = 1e-3, enabled: bool = True) -> None:
        self.ctrl = Controller(params, dt)
        self.supervisor = Supervisor(SafetyConfig.from_params(params), dt, enabled)
        self.demand = Demand('waiting', math.nan, 0.0, False)
        self.events: list[Event] = []     # the newest step's events

    @property
    def output(self) -> float:
        """Return the last command [A]."""
        return self.ctrl.output

    def set_params(self, params: Params) -> None:
        """Apply new gains, feedforward values, limits and actions (latches stay)."""
        self.ctrl.set_params(params)
        self.supervisor.set_config(SafetyConfig.from_params(params))

    def restart(self) -> None:
        """Start a new run (epoch): PID from rest, ramp on again; latches stay."""
        self.ctrl.reset()
        self.supervisor.restart()

    def step(self, stamp_ns: int, z: float, z_dot: float, force: float, z_traj: float,
             v_traj: float) -> float:
        """Return the servo current [A] for one state; ``events`` holds what happened."""
        c = self.ctrl
        d, self.events = self.supervisor.update(stamp_ns, z, z_dot, force, z_traj, v_traj,
                                                c.output, c.pid.saturated)
        self.demand = d
        if not d.power:
            if c.output != 0.0 or c.pid.prev_error is not None:
                c.reset()
            return 0.0
        return c.step(d.z_ref, d.v_ref, z, force=force)
