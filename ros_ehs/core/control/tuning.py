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
r"""
Gains for a loop and a specimen from the model: PI(D) for a bandwidth and a stability margin.

The servo current's loop is linearised where it runs (:func:`linear_loop`): the model (the
reduced one by default: the valve's dynamics with the cylinder, the load string and the
specimen) at rest at the piston's position, with the seals' Coulomb and Stribeck friction left
out (at rest they are not a gain but a dead band: they cost a test its accuracy, which the
feedforward and APC take back, not its stability; the viscous ``c_c`` stays). Its output is
the position or the load cell's force ``k_L (z - z_L) + c_L z_dot``. The plant is discretised
with a zero-order hold at the loop's period, and the controller is
:class:`ros_ehs.core.control.pid.Pid` itself (the derivative's filter and difference as it
runs), so the loop gain :math:`L(e^{j \omega T})` and the closed loop's step are the
controller's, not an approximation of it.

:func:`tune` picks the proportional gain for the closed loop's -3 dB ``bandwidth`` and puts
the integral's zero a decade below the crossover (``ki = kp 2 pi f_c / 10``: the plant is an
integrator of flow, so the I term only removes the valve's null bias; test controllers keep it
low under amplitude control). If the phase margin or the gain margin would fall under the ones
asked for, it lowers the gain until both hold and says so: a stiff specimen's loop is bounded
by the hydraulic resonance (the piston's mass on the oil column and the specimen in parallel),
whose peak sets the gain margin. The prediction (:class:`Tuning`) carries the margins, the
crossover, the bandwidth and the closed loop's step: overshoot and 2 % settling time.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import math
from typing import Mapping

import numpy as np
from ros_ehs.core.control.pid import Pid, PidGains
from ros_ehs.core.errors import InputError
from ros_ehs.core.model.plant import Plant
from ros_ehs.core.params import Params

__all__ = ['LOOPS', 'LinearLoop', 'Tuning', 'linear_loop', 'loop_gain', 'margins',
           'step_response', 'tune']

#: The loops :func:`tune` tunes, and the prefix of their gains among the parameters.
LOOPS = {'displacement': '', 'force': 'force_'}


@dataclass(frozen=True)
class LinearLoop:
    """A plant discretised at ``dt``: x+ = Ad x + Bd i, y = C x (about its rest state)."""

    Ad: np.ndarray
    Bd: np.ndarray
    C: np.ndarray
    dt: float
    output: str          #: 'position' [m] or 'force' [N]


@dataclass(frozen=True)
class Tuning:
    """Gains for a loop and what the linear model predicts of them (SI units)."""

    loop: str
    gains: PidGains
    crossover_hz: float
    bandwidth_hz: float
    phase_margin_deg: float
    gain_margin_db: float
    overshoot_pct: float
    settling_s: float
    step: np.ndarray = field(repr=False)    #: the closed loop's unit step, per period
    note: str = ''

    def values(self) -> dict[str, float]:
        """Return the gains by their parameter names (``force_kp``, ... for the force loop)."""
        pre = LOOPS[self.loop]
        g = self.gains
        return {pre + 'kp': g.kp, pre + 'ki': g.ki, pre + 'kd': g.kd}


def linear_loop(params: Params, loop: str = 'force', *, model: str = 'reduced',
                dt: float = 1e-3, z: float | None = None, current: float = 0.0) -> LinearLoop:
    """
    Return the loop's plant, linearised at rest at ``z`` (default: ``z_L``) and discretised.

    ``loop``: ``displacement`` (output z) or ``force`` (the load cell; needs ``k_L`` > 0).
    ``current`` [A]: the valve is linearised over the spool's opening at this current, a
    secant through ``-+K_x current`` (its flow gain changes with the opening: the rounded
    edges and the clearance at null); 0: the tangent at null.
    """
    from scipy.signal import cont2discrete

    if loop not in LOOPS:
        raise InputError(f'`loop` = {loop!r} is not one of {list(LOOPS)}')
    if loop == 'force' and not float(params['k_L']) > 0:
        raise InputError('a force loop needs a specimen: `k_L` must be > 0 N/m')
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(f'`dt` = {dt!r} s must be finite and > 0')
    lin = params.replace(F_cc=0.0, F_sc=0.0)
    plant = Plant(lin, model)
    z0 = float(params['z_L']) if z is None else float(z)
    x0 = plant.equilibrium(z=z0)
    n = plant.n
    scale = plant._xscale
    A = np.empty((n, n))
    names = plant.state_names
    opening = abs(float(current)) * float(params['K_x'])
    for j in range(n):
        h = 1e-6 * scale[j]
        if names[j] == 'x':
            h = max(h, opening)
        xp, xm = x0.copy(), x0.copy()
        xp[j] += h
        xm[j] -= h
        A[:, j] = (plant.dynamics(0.0, xp, [0.0, 0.0]) -
                   plant.dynamics(0.0, xm, [0.0, 0.0])) / (2 * h)
    hi = 1e-6
    B = ((plant.dynamics(0.0, x0, [hi, 0.0]) - plant.dynamics(0.0, x0, [-hi, 0.0])) /
         (2 * hi)).reshape(n, 1)
    C = np.zeros((1, n))
    if loop == 'displacement':
        C[0, names.index('z')] = 1.0
    else:
        C[0, names.index('z')] = float(params['k_L'])
        C[0, names.index('z_dot')] = float(params['c_L'])
    Ad, Bd, Cd, _, _ = cont2discrete((A, B, C, np.zeros((1, 1))), dt, method='zoh')
    return LinearLoop(Ad, Bd, Cd, float(dt), 'position' if loop == 'displacement' else 'force')


def _plant_response(lin: LinearLoop, w: np.ndarray) -> np.ndarray:
    zz = np.exp(1j * w * lin.dt)
    n = lin.Ad.shape[0]
    eye = np.eye(n)
    return np.array([(lin.C @ np.linalg.solve(z * eye - lin.Ad, lin.Bd))[0, 0] for z in zz])


def _pid_response(g: PidGains, dt: float, w: np.ndarray) -> np.ndarray:
    """Return the discrete PID as :class:`Pid` runs it: I summed, D differenced, filtered."""
    zi = np.exp(-1j * w * dt)            # z^-1
    a = dt / (g.d_filter_tau + dt) if g.d_filter_tau > 0 else 1.0
    # u_k = kp e_k + I_k + kd d_k, with I_k = I_{k-1} + dt ki e_{k-1} and
    # d_k = d_{k-1} + a ((e_k - e_{k-1}) / dt - d_{k-1})
    integ = g.ki * dt * zi / (1 - zi)
    deriv = g.kd * a * (1 - zi) / dt / (1 - (1 - a) * zi)
    return g.kp + integ + deriv


def loop_gain(lin: LinearLoop, gains: PidGains, f_hz: np.ndarray,
              plant: np.ndarray | None = None) -> np.ndarray:
    """Return the open loop ``L = C(z) P(z)`` at ``f_hz`` (``plant``: P there, if known)."""
    w = 2 * np.pi * np.asarray(f_hz, dtype=float)
    return _pid_response(gains, lin.dt, w) * (_plant_response(lin, w) if plant is None
                                              else plant)


def margins(lin: LinearLoop, gains: PidGains, f_hz: np.ndarray | None = None,
            plant: np.ndarray | None = None) -> tuple[float, float, float, float]:
    """
    Return (crossover [Hz], phase margin [deg], gain margin [dB], closed-loop -3 dB [Hz]).

    On a log grid up to the Nyquist frequency (or ``f_hz``, with the plant's response there
    ``plant`` if known); the gain margin is the smallest over every crossing of -180 deg (inf
    when there is none); the bandwidth is the first frequency at which the closed loop falls
    3 dB under its low-frequency gain.
    """
    nyq = 0.5 / lin.dt
    f = np.geomspace(0.01, nyq * 0.999, 4000) if f_hz is None else np.asarray(f_hz)
    L = loop_gain(lin, gains, f, plant)
    mag = np.abs(L)
    cross = np.nonzero((mag[:-1] >= 1) & (mag[1:] < 1))[0]
    if cross.size:
        k = cross[0]
        fc = float(np.interp(0.0, [-math.log(mag[k]), -math.log(mag[k + 1])],
                             [f[k], f[k + 1]]))
        ph = np.angle(loop_gain(lin, gains, np.array([fc])))[0]
        pm = math.degrees(math.pi + ph) % 360.0
        if pm > 180.0:
            pm -= 360.0
    else:
        fc, pm = math.nan, math.nan
    phase = np.unwrap(np.angle(L))
    # -180 deg crossings (of the unwrapped phase, any turn)
    turns = np.floor((phase + math.pi) / (2 * math.pi))
    gm = math.inf
    for k in np.nonzero(np.diff(turns) != 0)[0]:
        gm = min(gm, -20 * math.log10(max(mag[k], 1e-300)))
    T = np.abs(L / (1 + L))
    t0 = T[0]
    below = np.nonzero(T < t0 / math.sqrt(2))[0]
    bw = float(f[below[0]]) if below.size else math.inf
    return fc, pm, gm, bw


def step_response(lin: LinearLoop, gains: PidGains, n: int) -> np.ndarray:
    """Return the closed loop's response to a unit step of the reference over ``n`` periods."""
    # a linear loop: a step small enough never to reach the output limit, scaled back
    pid = Pid(replace(gains, u_max=0.1))
    a = 1e-4 / max(gains.kp, 1e-300)
    x = np.zeros(lin.Ad.shape[0])
    y = np.empty(n)
    for k in range(n):
        y[k] = (lin.C @ x)[0]
        i = pid.update(a - y[k], lin.dt)
        x = lin.Ad @ x + lin.Bd[:, 0] * i
    return y / a


def _overshoot(y: np.ndarray, dt: float) -> tuple[float, float]:
    final = float(np.mean(y[-max(1, len(y) // 10):]))
    if not (math.isfinite(final) and final > 0):
        return math.inf, math.inf
    over = max(0.0, (float(np.max(y)) - final) / final * 100.0)
    out = np.nonzero(np.abs(y - final) > 0.02 * abs(final))[0]
    settle = (out[-1] + 1) * dt if out.size else 0.0
    return over, settle


def tune(params: Params, loop: str = 'force', *, bandwidth_hz: float = 10.0,
         phase_margin_deg: float = 45.0, gain_margin_db: float = 6.0,
         model: str = 'reduced', dt: float = 1e-3, step: float = 0.0,
         shared: Mapping[str, object] | None = None) -> Tuning:
    """
    Return gains for ``loop`` from the model of ``params`` (see the module docstring).

    ``bandwidth_hz``: the closed loop's -3 dB bandwidth asked for; the margins are the least
    accepted. ``step``: the size of the steps the loop is to take [m or N] (a square wave's
    peak to peak): the valve is then linearised over the opening they command (``kp step``,
    from a first tuning at null). ``shared``: the derivative filter, output limit and
    anti-windup (default: those of ``params``).
    """
    if not (isinstance(step, (int, float)) and math.isfinite(step) and step >= 0):
        raise InputError(f'`step` = {step!r} must be a number >= 0')
    first = _tune(params, loop, bandwidth_hz, phase_margin_deg, gain_margin_db, model, dt,
                  0.0, shared)
    if step == 0:
        return first
    i_a = min(first.gains.u_max, first.gains.kp * step)
    return _tune(params, loop, bandwidth_hz, phase_margin_deg, gain_margin_db, model, dt,
                 i_a, shared)


def _tune(params, loop, bandwidth_hz, phase_margin_deg, gain_margin_db, model, dt, current,
          shared) -> Tuning:
    for name, v in (('bandwidth_hz', bandwidth_hz), ('phase_margin_deg', phase_margin_deg),
                    ('gain_margin_db', gain_margin_db)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise InputError(f'`{name}` = {v!r} must be a positive number')
    if bandwidth_hz >= 0.25 / dt:
        raise InputError(f'`bandwidth_hz` = {bandwidth_hz:g} Hz must be under a quarter of the '
                         f'loop rate ({0.25 / dt:g} Hz)')
    lin = linear_loop(params, loop, model=model, dt=dt, current=current)
    base = PidGains.from_params(shared or params, LOOPS[loop])
    f = np.geomspace(0.01, 0.4995 / dt, 3000)
    P = _plant_response(lin, 2 * np.pi * f)

    def gains(kp: float) -> PidGains:
        g = replace(base, kp=kp, ki=0.0, kd=0.0)
        fc = margins(lin, g, f, P)[0]
        ki = kp * 2 * math.pi * (fc if math.isfinite(fc) else bandwidth_hz) / 10.0
        return replace(g, ki=ki)

    def judge(kp: float) -> tuple[float, float, float, float]:
        return margins(lin, gains(kp), f, P)

    # the plant's gain at the bandwidth sets the scale of kp
    p_bw = abs(_plant_response(lin, np.array([2 * math.pi * bandwidth_hz]))[0])
    k_lo, k_hi = 1e-4 / p_bw, 1e2 / p_bw

    def ok(m) -> bool:
        return m[1] >= phase_margin_deg and m[2] >= gain_margin_db

    # the largest kp with the margins (bisection in log), and the kp of the bandwidth
    lo, hi = math.log(k_lo), math.log(k_hi)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if ok(judge(math.exp(mid))):
            lo = mid
        else:
            hi = mid
    k_max = math.exp(lo)
    lo, hi = math.log(k_lo), math.log(k_hi)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        bw = judge(math.exp(mid))[3]
        if math.isfinite(bw) and bw >= bandwidth_hz:
            hi = mid
        else:
            lo = mid
    k_bw = math.exp(hi)
    note = ''
    kp = k_bw
    if k_bw > k_max:
        kp = k_max
        note = (f'the margins asked for hold only up to kp = {k_max:.4g}: the bandwidth is '
                f'{judge(k_max)[3]:.3g} Hz, not {bandwidth_hz:g} Hz')
    g = gains(kp)
    fc, pm, gm, bw = margins(lin, g, f, P)
    n = int(round(max(1.0, 20.0 / bw if math.isfinite(bw) and bw > 0 else 1.0) / dt))
    y = step_response(lin, g, n)
    over, settle = _overshoot(y, dt)
    return Tuning(loop, g, fc, bw, pm, gm, over, settle, y, note)
