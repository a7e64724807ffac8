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
Amplitude/phase control (APC) of a sine: the command corrected cycle by cycle (ROS-free).

A position loop attenuates or amplifies a sine and lags it, more the higher its frequency.
Servo-hydraulic test controllers correct this the same way: measure the response's
fundamental over each cycle and adjust the command's amplitude, phase and mean so that the
response hits the specified ones.

Each cycle ``n`` the response's complex amplitude at the fundamental ``R_n`` (a one-bin DFT of
the measured position over exactly that cycle) and its mean ``r_n`` are compared with the
specified ``D = A`` (phase 0) and ``m``; with ``C_n`` the command's complex amplitude over
that cycle the loop's gain there is ``H = R_n / C_n``, and the next command is

    C_n+1 = C_n + g (D - R_n) / H,        c_n+1 = c_n + g (m - r_n)

so on a linear loop the error shrinks by ``1 - g`` a cycle (``gain`` g = 0.7 by default:
0.3 a cycle, 0.1 % in 6 cycles). Convergence rule: ``converged`` once amplitude error,
phase error and mean error have stayed within ``tolerance`` (0.2 % of the amplitude, 0.2
deg) for two consecutive cycles. A correction is applied over the whole next cycle, blended
linearly from the old complex amplitude to the new one, so the command and its velocity
never jump. A gain change larger than a factor 2 in one cycle is clipped to it (a loop
identified from one cycle is not trusted further).

Edge-case policy: :meth:`freeze` (an interlock, lost feedback) stops the updates; the cycle
under way is discarded and the command keeps its last amplitude and phase, so it resumes
without a jump; a non-finite position discards the cycle.
"""

from __future__ import annotations

import cmath
import math

import numpy as np
from ros_ehs.control.cycles import CycleCorrection
from ros_ehs.errors import InputError

__all__ = ['AmplitudePhaseControl']


def _positive(name: str, v: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
            or v <= 0:
        raise InputError(f'`{name}` = {v!r} must be finite and > 0')
    return float(v)


class AmplitudePhaseControl(CycleCorrection):
    """A sine ``mean + amplitude sin(2 pi f t)`` whose command APC corrects each cycle."""

    def __init__(self, amplitude: float, frequency: float, mean: float = 0.0,
                 gain: float = 0.7, tolerance: float = 2e-3) -> None:
        super().__init__()
        self.amplitude = _positive('amplitude', amplitude)
        self.frequency = _positive('frequency', frequency)
        if not math.isfinite(mean):
            raise InputError(f'`mean` = {mean!r} must be finite')
        if not 0.0 < gain <= 1.0:
            raise InputError(f'`gain` = {gain!r} must be in (0, 1]')
        self.mean = float(mean)
        self.gain = float(gain)
        self.tolerance = _positive('tolerance', tolerance)
        self.omega = 2.0 * math.pi * self.frequency
        self.period = 1.0 / self.frequency
        # command: complex amplitude of sin (z = Im(C e^{i w t})) and mean, blended over a cycle
        self._c_old = self._c_new = complex(self.amplitude, 0.0)
        self._m_old = self._m_new = self.mean
        self._acc = 0j
        self._sum = 0.0
        self._n = 0
        self.cycles = 0                  #: cycles measured
        self.converged_at: int | None = None   #: the cycle the convergence rule was met
        self._ok = 0
        self.history: list[dict] = []   #: per cycle: amplitude ratio, phase [deg], mean error

    def _blend(self, t: float) -> tuple[complex, float, complex, float]:
        s = t / self.period - self._cycle       # 0..1 across the current cycle
        s = min(max(s, 0.0), 1.0)
        c = self._c_old + (self._c_new - self._c_old) * s
        m = self._m_old + (self._m_new - self._m_old) * s
        dc = (self._c_new - self._c_old) / self.period
        dm = (self._m_new - self._m_old) / self.period
        return c, m, dc, dm

    def reference(self, t: float) -> tuple[float, float]:
        """Return the command (position [m], velocity [m/s]) at time ``t`` [s]."""
        c, m, dc, dm = self._blend(t)
        e = cmath.exp(1j * self.omega * t)
        z = (c * e).imag + m
        v = (1j * self.omega * c * e + dc * e).imag + dm
        return z, v

    def desired(self, t):
        """Return the specified position [m] at ``t`` (a number or an array) [s]."""
        return self.mean + self.amplitude * np.sin(self.omega * np.asarray(t, dtype=float))

    def _take(self, t: float, z: float) -> None:
        self._acc += z * cmath.exp(-1j * self.omega * t)
        self._sum += z
        self._n += 1

    def _end_cycle(self, cycle: int) -> None:
        n, acc, tot, bad = self._n, self._acc, self._sum, self._bad
        self._acc, self._sum, self._n, self._bad = 0j, 0.0, 0, False
        c_used, m_used = self._c_new, self._m_new     # in force over the whole cycle? only
        blended = self._c_old != self._c_new or self._m_old != self._m_new
        self._c_old, self._m_old = self._c_new, self._m_new
        self._cycle = cycle
        if bad or n < 8 or self.frozen:
            return
        # z = Im(R e^{iwt}) + r: the DFT bin gives conj-free R = 2i/n sum z e^{-iwt}
        resp = 2j * acc / n
        mean = tot / n
        self.cycles += 1
        err = complex(self.amplitude, 0.0) - resp
        ratio = abs(resp) / self.amplitude
        phase = math.degrees(cmath.phase(resp))
        self.history.append({'cycle': self.cycles, 'amp_ratio': ratio, 'phase_deg': phase,
                             'mean_err': mean - self.mean})
        ok = abs(ratio - 1.0) <= self.tolerance and abs(phase) <= math.degrees(
            self.tolerance) and abs(mean - self.mean) <= self.tolerance * self.amplitude
        self._ok = self._ok + 1 if ok else 0
        if self._ok >= 2 and self.converged_at is None:
            self.converged_at = self.cycles
        if blended:            # the command changed during that cycle: measure again first
            return
        h = resp / c_used if c_used != 0 else 1.0
        if h == 0:
            return
        step = self.gain * err / h
        new = c_used + step
        if abs(new) > 2.0 * abs(c_used):
            new = new / abs(new) * 2.0 * abs(c_used)
        self._c_new = new
        self._m_new = m_used + self.gain * (self.mean - mean)
