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

One object per axis. ``step(z_ref, v_ref, z, dt, force)`` is called once per control period;
the policy for bad input is the PID's (see :mod:`ros_ehs.core.control.pid`): a non-finite
measurement or reference gives 0 A and ``fault``.

Delta-P stabilisation (``dp_gain`` > 0), what servo-hydraulic test controllers add to damp
the oil column: ``i -= dp_gain * HP(F)``, with ``F`` the hydraulic force ``A_p (p_P - p_T)``
and ``HP`` a first-order high-pass of time constant ``dp_tau``, so that a load held longer
than ``dp_tau`` is not opposed. The valve's flow then falls with the dynamic load pressure,
as if its flow-pressure coefficient were larger: the loop's hydraulic resonance is damped.
It needs the force in every state: with ``dp_gain`` > 0 a non-finite ``force`` is bad input
(0 A and ``fault``). The high-pass starts from the first force it sees (no kick) and
restarts with :meth:`Controller.reset`.
"""

from __future__ import annotations

import math

from ros_ehs.core.control.feedforward import Feedforward
from ros_ehs.core.control.pid import Pid, PidGains
from ros_ehs.core.errors import InputError
from ros_ehs.core.params import Params

__all__ = ['Controller', 'DeltaP']


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
        self.dp = DeltaP(params['dp_gain'], params['dp_tau'])

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
        self.dp.reset()
        self.last_ff = 0.0

    def hold(self, on: bool = True) -> None:
        """Freeze the command at its last value (``step`` returns it unchanged) until released."""
        self.held = bool(on)

    def set_params(self, params: Params) -> None:
        """Apply PID and delta-P gains bumplessly; rebuild the feedforward from ``params``."""
        self.pid.set_gains(PidGains.from_params(params))
        f_p = self.ff.f_p
        self.ff = Feedforward(params, self.dt)
        self.ff.f_p = f_p      # keep the force estimate; restart the derivative (no kick)
        self.ff_enabled = params['ff_enable'] >= 0.5
        old = self.dp.last
        self.dp.set_gains(params['dp_gain'], params['dp_tau'])
        if self.pid.prev_error is not None:     # bumpless: the integrator takes the step
            self.pid.i_term += self.dp.last - old
        self.params = params

    def force_missing(self, force: float) -> bool:
        """Return True if delta-P is on and ``force`` [N] is no measurement (bad input)."""
        return self.dp.gain > 0 and not math.isfinite(force)

    def step(self, z_ref: float, v_ref: float, z: float, dt: float | None = None,
             force: float = math.nan) -> float:
        """
        Return the servo current [A] for reference ``z_ref``/``v_ref`` and position ``z``.

        ``force`` [N]: the measured hydraulic force, read by delta-P stabilisation only.
        """
        dt = self.dt if dt is None else dt
        if self.held:
            if dt > 0 and self.dp.gain > 0 and math.isfinite(force):
                self.dp.update(force, dt)       # follows the load, so release has no kick
            return self.pid.last_u
        if not all(math.isfinite(v) for v in (z_ref, v_ref, z)) or self.force_missing(force):
            return self.pid.update(math.nan, dt if dt > 0 else self.dt)
        ff = 0.0
        if self.ff_enabled and dt > 0:
            ff = self.ff.update(v_ref, self.pid.last_u) + self.ff.velocity_current(v_ref)
        self.last_ff = ff
        if dt > 0 and self.dp.gain > 0:
            ff -= self.dp.update(force, dt)
        return self.pid.update(z_ref - z, dt, ff)


class DeltaP:
    """
    The delta-P current [A]: ``gain`` times the force [N] high-passed with ``tau`` [s].

    ``update(force, dt)`` returns ``gain * HP(force)``; the first force after :meth:`reset`
    sets the filter's memory, so the first output is 0 A, unless the reset gave the memory
    (then the first output is ``gain`` times the force's difference from it, high-passed).
    """

    def __init__(self, gain: float, tau: float) -> None:
        self.gain, self.tau = float(gain), float(tau)
        self.reset()

    def set_gains(self, gain: float, tau: float) -> None:
        """
        Take a new gain [A/N] and time constant [s]; ``last`` is the current they give now.

        The filter's memory stays, unless the gain is 0: then it is forgotten, and a later
        restart takes its memory from a fresh force.
        """
        self.gain, self.tau = float(gain), float(tau)
        if self.gain == 0:
            self.reset()
        self.last = self.gain * self.hp

    def reset(self, memory: float | None = None) -> None:
        """Forget the filter's memory, or start it at the force ``memory`` [N]."""
        self.prev: float | None = memory
        self.hp = 0.0
        self.last = 0.0

    def update(self, force: float, dt: float) -> float:
        """Return the delta-P current for this period's ``force`` after ``dt`` [s]."""
        if self.prev is not None:
            self.hp = self.tau / (self.tau + dt) * (self.hp + force - self.prev)
        self.prev = force
        self.last = self.gain * self.hp
        return self.last
