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
The position controller of section 4: ``i = PID(z_ref - z) + i_sc`` (eq. 18), limited.

One object per axis. ``step(z_ref, v_ref, z, dt)`` is called once per control period; the
policy for bad input is the PID's (see :mod:`ros_ehs.control.pid`): a non-finite
measurement or reference gives 0 A and ``fault``.
"""

from __future__ import annotations

import math

from ros_ehs.control.feedforward import Feedforward
from ros_ehs.control.pid import Pid, PidGains
from ros_ehs.errors import InputError
from ros_ehs.params import Params

__all__ = ['Controller']


class Controller:
    """PID + damping/Stribeck feedforward with the output limit on the total current."""

    def __init__(self, params: Params, dt: float = 1e-3) -> None:
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise InputError(f'`dt` = {dt!r} s must be finite and > 0')
        self.params = params
        self.dt = float(dt)
        self.pid = Pid(PidGains.from_params(params))
        self.ff = Feedforward(params, dt)
        self.ff_enabled = params['ff_enable'] >= 0.5
        self.held = False
        self.last_ff = 0.0

    @property
    def output(self) -> float:
        """Return the last command [A]."""
        return self.pid.last_u

    @property
    def fault(self) -> bool:
        """Return True after a non-finite input, until the next finite one."""
        return self.pid.fault

    def reset(self) -> None:
        """Clear PID and feedforward state (command back to 0 A)."""
        self.pid.reset()
        self.ff.reset()
        self.last_ff = 0.0

    def hold(self, on: bool = True) -> None:
        """Freeze the command at its last value (``step`` returns it unchanged) until released."""
        self.held = bool(on)

    def set_params(self, params: Params) -> None:
        """Apply new gains bumplessly and rebuild the feedforward from ``params``."""
        self.pid.set_gains(PidGains.from_params(params))
        f_p = self.ff.f_p
        self.ff = Feedforward(params, self.dt)
        self.ff.f_p = f_p      # keep the force estimate; restart the derivative (no kick)
        self.ff_enabled = params['ff_enable'] >= 0.5
        self.params = params

    def step(self, z_ref: float, v_ref: float, z: float, dt: float | None = None) -> float:
        """Return the servo current [A] for reference ``z_ref``/``v_ref`` and position ``z``."""
        dt = self.dt if dt is None else dt
        if self.held:
            return self.pid.last_u
        if not all(math.isfinite(v) for v in (z_ref, v_ref, z)):
            return self.pid.update(math.nan, dt if dt > 0 else self.dt)
        ff = 0.0
        if self.ff_enabled and dt > 0:
            ff = self.ff.update(v_ref, self.pid.last_u) + self.ff.velocity_current(v_ref)
        self.last_ff = ff
        return self.pid.update(z_ref - z, dt, ff)
