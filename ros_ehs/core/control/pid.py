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
Discrete PID of eq. (19) with derivative filter, output limit and a choice of anti-windup.

Edge-case policy (each branch is tested in ``test/test_control.py``):

* ``dt == 0``: return the previous command; no state changes.
* ``dt < 0`` or non-finite ``dt``: raise :class:`~ros_ehs.core.errors.InputError`.
* non-finite error: return **0 A** (valve to null, the hydraulic fail-safe), set
  ``fault``, keep the integrator and filter states unchanged. The next finite sample clears
  ``fault``.
* windup (``antiwindup``, control_toolbox's strategy names; ``u_sat`` is the *total*
  command, PID + feedforward, after the +-u_max limit, ``u`` the same before it):

  - ``conditional_integration`` (default): ``I += dt * ki e`` unless the output is limited
    and the error pushes further into the limit (``u_sat != u`` and ``e u > 0``);
  - ``back_calculation``: ``I += dt * (ki e + (u_sat - u) / T_t)``, with
    ``T_t = tracking_tau`` or ``sqrt(kd / ki)`` (``kp / ki`` if kd = 0);
  - ``none``: ``I += dt * ki e``.

  Why conditional integration is the default here: the paper's gains put nearly all the
  authority in P (``kp / ki`` = 15 s). A 40 mm error saturates the valve on P alone, and
  back-calculation then drives the integrator towards ``u_sat - kp e``, i.e. -15 mA: the loop
  leaves saturation with an integrator of several mA of the wrong sign, which ``ki`` takes
  ~15 s to unwind (a 2-3 mm offset on the 1 Hz sine after a start mid-stroke, measured in
  ``test/test_control.py``). Conditional integration leaves the integrator where it was.
* derivative on the error, first-order low-pass with ``d_filter_tau`` (0: unfiltered).
* gain changes are bumpless: the integrator is rescaled so the output does not jump.
* a handover (:meth:`Pid.handover`, a loop taking the valve over from another, or from 0 A):
  the loop starts at rest with its integrator holding the output it takes over, so its first
  command is that output when its first error and feedforward are zero (the blends of
  :mod:`ros_ehs.core.control.modes` start at the measured value, so they are).
* an output limited further by the caller (:meth:`Pid.limited`, specimen protect's force
  limit): the command is the caller's; the integration of that period is undone when the
  error pushes further into the limit (conditional integration against the new limit).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import math

from ros_ehs.core.errors import InputError, ParameterError
from ros_ehs.core.params import spec

__all__ = ['Pid', 'PidGains']

_NAMES = ('kp', 'ki', 'kd', 'd_filter_tau', 'u_max', 'tracking_tau', 'antiwindup')


@dataclass(frozen=True)
class PidGains:
    """PID gains [A/m, A/(m s), A s/m], D filter [s], limit [A], tracking [s], anti-windup."""

    kp: float = 0.75
    ki: float = 0.051
    kd: float = 0.00049
    d_filter_tau: float = 2.0e-3
    u_max: float = 0.015
    tracking_tau: float = 0.0
    antiwindup: str = 'conditional_integration'

    def __post_init__(self) -> None:
        """Validate every gain against its declaration in ros_ehs.core.params."""
        for name in _NAMES:
            spec(name).check(getattr(self, name))

    @property
    def t_track(self) -> float:
        """Back-calculation time constant [s]."""
        if self.tracking_tau > 0:
            return self.tracking_tau
        if self.ki <= 0:
            return math.inf
        return math.sqrt(self.kd / self.ki) if self.kd > 0 else self.kp / self.ki or math.inf

    @classmethod
    def from_params(cls, params, prefix: str = '') -> 'PidGains':
        """
        Build from a :class:`~ros_ehs.core.params.Params` (or any mapping with the names).

        ``prefix``: the loop's own gains (``force_``: ``force_kp``, ``force_ki``,
        ``force_kd``); the filter, limit and anti-windup are shared.
        """
        own = ('kp', 'ki', 'kd')
        return cls(**{k: params[prefix + k if k in own else k] for k in _NAMES})


class Pid:
    """Stateful discrete PID; ``update(error, dt, ff)`` returns the limited total command."""

    def __init__(self, gains: PidGains | None = None) -> None:
        if gains is not None and not isinstance(gains, PidGains):
            raise ParameterError(f'`gains` must be PidGains, got {type(gains).__name__}')
        self.gains = gains or PidGains()
        self.reset()

    def reset(self, i_term: float = 0.0) -> None:
        """Clear all state; optionally keep an integrator value [A]."""
        self.i_term = float(i_term)
        self.d_state = 0.0
        self.prev_error: float | None = None
        self.last_u = 0.0
        self.last_unsat = 0.0
        self.fault = False
        self.saturated = False
        self._i_before = self.i_term

    def handover(self, u: float) -> None:
        """
        Take the valve over at command ``u`` [A]: at rest, the integrator holding ``u``.

        The next :meth:`update` returns ``u`` when its error and feedforward are zero.
        """
        self.reset(u if math.isfinite(u) else 0.0)
        self.last_u = self.last_unsat = self.i_term

    def limited(self, u: float) -> None:
        """
        Record that the caller limited the last output further, to ``u`` [A].

        When the error pushes beyond that limit, the last period's integration is undone.
        """
        if u != self.last_u and self.prev_error is not None and \
                self.prev_error * (self.last_u - u) > 0.0:
            self.i_term = self._i_before
        self.last_u = u

    def set_gains(self, gains: PidGains) -> None:
        """Change gains bumplessly (the P + D output jump is absorbed by the integrator)."""
        if not isinstance(gains, PidGains):
            raise ParameterError(f'`gains` must be PidGains, got {type(gains).__name__}')
        if self.prev_error is not None:
            e = self.prev_error
            old = self.gains.kp * e + self.gains.kd * self.d_state
            new = gains.kp * e + gains.kd * self.d_state
            self.i_term += old - new
        self.gains = gains

    def update(self, error: float, dt: float, ff: float = 0.0) -> float:
        """
        Return the command [A] for position ``error`` = z_ref - z [m] after ``dt`` [s].

        ``ff`` [A] is added before the output limit (the limit applies to the total).
        """
        if not isinstance(dt, (int, float)) or not math.isfinite(dt) or dt < 0:
            raise InputError(f'`dt` = {dt!r} s must be finite and >= 0')
        if dt == 0:
            return self.last_u
        if not (math.isfinite(error) and math.isfinite(ff)):
            self.fault = True
            self.last_u = 0.0
            return 0.0
        self.fault = False
        g = self.gains
        if self.prev_error is None:
            raw_d = 0.0
        else:
            raw_d = (error - self.prev_error) / dt
        if g.d_filter_tau > 0:
            a = dt / (g.d_filter_tau + dt)
            self.d_state += a * (raw_d - self.d_state)
        else:
            self.d_state = raw_d
        self.prev_error = error
        u = g.kp * error + self.i_term + g.kd * self.d_state + ff
        u_sat = min(max(u, -g.u_max), g.u_max)
        self.saturated = u_sat != u
        self._i_before = self.i_term
        if g.antiwindup == 'back_calculation':
            self.i_term += dt * (g.ki * error + (u_sat - u) / g.t_track)
        elif g.antiwindup == 'none' or not (self.saturated and error * u > 0.0):
            self.i_term += dt * g.ki * error
        self.last_unsat = u
        self.last_u = u_sat
        return u_sat

    def with_gains(self, **changes: float) -> PidGains:
        """Return the current gains with ``changes`` (validated), for :meth:`set_gains`."""
        return replace(self.gains, **changes)
