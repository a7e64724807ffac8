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
Damping and Stribeck-friction feedforward of the paper, eqs. (9)-(20), one function a term.

* :func:`stribeck_estimate` - friction estimate f_c(z_dot, F_oc), eqs. (14)-(16);
* :func:`psc_force` - force to counteract, F_psc = -F_c + c_visc z_dot, eq. (12);
* :class:`DelayLine` - the delay e^{-tau s} of eq. (17), applied to the reference;
* :class:`Feedforward` - eq. (20): i_sc = (1 / K_ff) d/dt F_psc(delayed ref, F_p).

Two documented departures from the printed equations (docs/controller.md):

1. F_p of eq. (11), ``K_ff * integral(i dt)``, holds only while the piston is still (eq. 9).
   We subtract the current that the delayed reference velocity consumes,
   ``A z_dot_d / (K_q K_x)``, and let the estimate leak with ``ff_leak_tau``: otherwise it
   grows without bound during motion.
2. The derivative is a backward difference of a smoothed (tanh, soft-saturation) F_psc,
   so it is bounded by construction, then limited to +-ff_max.
"""

from __future__ import annotations

from collections import deque
import math

from ros_ehs.core.errors import InputError
from ros_ehs.core.model.coefficients import ff_force_gain, flow_gain_kq
from ros_ehs.core.model.smooth import smooth_clip

__all__ = ['DelayLine', 'Feedforward', 'MODEL_PARAMS', 'psc_force', 'stribeck_estimate',
           'xi_blend']

#: The plant parameters the feedforward reads (the controller node declares them too).
MODEL_PARAMS = ('A_p', 'K_x', 'C_d', 'd_s', 'd_c', 'p_s', 'p_t', 'rho', 'beta_e', 'l_iac',
                'F_cc', 'F_sc', 'c_c', 'v_c', 'eps_v', 'friction_law')

_XI0 = 0.5 * (math.tanh(-1.0) + 1.0)


def xi_blend(v: float, v_c: float, renormalised: bool = True) -> float:
    """Stribeck transition xi of eq. (15); renormalised to xi(0) = 0 unless told not to."""
    xi = 0.5 * (math.tanh(abs(v) / v_c - 1.0) + 1.0)
    return (xi - _XI0) / (1.0 - _XI0) if renormalised else xi


def stribeck_estimate(v: float, f_oc: float, f_cc: float, f_sc: float, v_c: float,
                      eps_v: float, renormalised: bool = True) -> float:
    """
    Friction force estimate [N], eq. (14): ``-[(1-xi) sat(F_oc, +-F_sc) + xi sign(v) F_cc]``.

    ``sign`` is ``tanh(v / eps_v)`` and ``sat`` a soft saturation (smooth, bounded slope).
    """
    xi = xi_blend(v, v_c, renormalised)
    return -((1.0 - xi) * smooth_clip(f_oc, f_sc) + xi * math.tanh(v / eps_v) * f_cc)


def psc_force(v: float, f_p: float, f_cc: float, f_sc: float, v_c: float, eps_v: float,
              c_visc: float, renormalised: bool = True) -> float:
    """Force the feedforward must supply, F_psc = -F_c + c_visc v [N], eq. (12)."""
    return -stribeck_estimate(v, f_p, f_cc, f_sc, v_c, eps_v, renormalised) + c_visc * v


class DelayLine:
    """Pure delay of ``tau`` seconds on a signal sampled every ``dt`` (eq. 17), zero-filled."""

    def __init__(self, tau: float, dt: float) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise InputError(f'`dt` = {dt!r} s must be finite and > 0')
        if not (math.isfinite(tau) and tau >= 0):
            raise InputError(f'`tau` = {tau!r} s must be finite and >= 0')
        self.n = int(round(tau / dt))
        self._buf: deque[float] = deque([0.0] * self.n, maxlen=self.n or None)

    def push(self, value: float) -> float:
        """Insert ``value`` and return the value ``tau`` seconds old."""
        if self.n == 0:
            return value
        old = self._buf[0]
        self._buf.append(value)
        return old


class Feedforward:
    """
    The feedforward current of eq. (20), evaluated once per control period ``dt``.

    ``update(v_ref, i_prev)`` takes the reference velocity and the total current applied in
    the previous period and returns i_sc [A].
    """

    def __init__(self, params, dt: float) -> None:
        self.dt = float(dt)
        self.k_ff = ff_force_gain(params)
        self.i_per_speed = params['A_p'] / (flow_gain_kq(params) * params['K_x'])
        self.f_cc, self.f_sc = params['F_cc'], params['F_sc']
        self.v_c, self.eps_v, self.c_visc = params['v_c'], params['eps_v'], params['c_c']
        self.renormalised = params['friction_law'] == 'renormalised'
        self.leak_tau = params['ff_leak_tau']
        self.i_max = params['ff_max']
        self.k_vel = params['ff_velocity']
        self.delay = DelayLine(params['tau_delay'], self.dt)
        self.reset()

    def reset(self) -> None:
        """Clear the pressure-force estimate and the derivative memory."""
        self.f_p = 0.0
        self.g_prev: float | None = None
        self.v_d = 0.0

    def velocity_current(self, v_ref: float) -> float:
        """Return ``ff_velocity * A v_ref / (K_q K_x)`` [A]: the flow the motion needs."""
        return self.k_vel * self.i_per_speed * v_ref

    def update(self, v_ref: float, i_prev: float) -> float:
        """
        Return i_sc [A] for reference velocity ``v_ref`` [m/s] (eq. 20).

        A period whose force estimate or law comes out non-finite (an absurd reference)
        returns NaN, which the PID answers with 0 A and ``fault``, and leaves the estimate
        and the derivative's memory as they were: one such period does not poison the next.
        """
        self.v_d = self.delay.push(v_ref)
        # eq. (11) with the flow of the moving piston removed, and a leak
        i_force = i_prev - self.i_per_speed * self.v_d
        f_p = self.f_p + self.dt * (self.k_ff * i_force - self.f_p / self.leak_tau)
        g = psc_force(self.v_d, f_p, self.f_cc, self.f_sc, self.v_c, self.eps_v,
                      self.c_visc, self.renormalised)
        if not (math.isfinite(f_p) and math.isfinite(g)):
            return math.nan
        self.f_p = f_p
        if self.g_prev is None:
            self.g_prev = g
        i_sc = (g - self.g_prev) / (self.k_ff * self.dt)
        self.g_prev = g
        return min(max(i_sc, -self.i_max), self.i_max)
