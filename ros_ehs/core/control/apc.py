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

so on a linear loop the error shrinks by ``1 - g`` every two cycles (``gain`` g = 0.7 by
default). Convergence rule: ``converged`` once amplitude error, phase error and mean error
have stayed within ``tolerance`` (0.2 % of the amplitude, 0.11 deg) for two consecutive
cycles. A gain change larger than a factor 2 in one cycle is clipped to it (a loop identified
from one cycle is not trusted further). A correction is blended in linearly from the old
complex amplitude to the new one, so the command and its velocity never jump: from ``latency``
[s] after the end of the cycle it was learnt from (a node that sends its samples ahead of time
changes none it has sent) to the end of the next cycle, or over a whole period if that leaves
less than half of one; the cycle it blends in over is not learnt from. Cycles with a sample
before ``learn_from`` [s] (the axis's ramp-on) are not learnt from either.

Harmonics (``harmonics`` K, default 5 for a sine): the loop also adds harmonics of its own
(friction at the reversals, amplified by the loop's resonance), so once the fundamental is
within ``HARMONICS_FROM`` (1 %) of its target the command carries ``C_k`` at ``k f`` for k = 2..K,
corrected towards a zero response with the same gain: ``C_k += -g R_k / H_k``. ``H_k`` is the
secant of the last two clean cycles whose ``C_k`` differ by ``SECANT_FROM`` of the amplitude
or more (the distortion is there without a command, so ``R_k / C_k`` is not the loop's gain);
until one exists the step is a probe of ``PROBE`` (a quarter) of a step taken with the
fundamental's gain. A harmonic is corrected only if the cycle has 10 samples a period of it or
more, and its command never exceeds a quarter of the amplitude.

Sine sweeps (``sweep_to`` f1 [Hz] over ``sweep_time`` T [s]): the specified sine's phase is
``2 pi (f0 t + (f1 - f0) t^2 / 2T)``, a cycle is a turn of that phase, and each cycle's
complex amplitude is taken against it, so the same rule corrects the amplitude and phase as
the frequency moves (the loop's gain changes little over one cycle of a sweep of a few
seconds a decade or slower). After ``T`` the phase stops: the command holds where the sweep
ended. A sweep corrects the fundamental and the mean only (``harmonics`` = 1): the loop's gain
at ``k f`` changes k times faster than at ``f``, and near its resonance the secant lags it
and diverges (measured: 5 harmonics on a 1-20 Hz, 20 s sweep went from 1.5 % to 31 % RMS).

Edge-case policy: :meth:`freeze` (an interlock, lost feedback) stops the updates; the cycle
under way is discarded and the command keeps its last amplitude and phase, so it resumes
without a jump; a non-finite position discards the cycle.
"""

from __future__ import annotations

import cmath
import math

import numpy as np
from ros_ehs.core.control.cycles import CycleCorrection, HISTORY
from ros_ehs.core.control.waveforms import sweep_phase
from ros_ehs.core.errors import InputError

__all__ = ['AmplitudePhaseControl', 'MAX_HARMONICS']

#: the highest harmonic APC can correct
MAX_HARMONICS = 10
#: a harmonic's first correction, as a fraction of a full step
PROBE = 0.25
#: harmonics are corrected once the fundamental's complex error is under this
HARMONICS_FROM = 0.01
#: a harmonic's secant needs its command to have moved this much of the amplitude
SECANT_FROM = 1e-4


def _positive(name: str, v: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
            or v <= 0:
        raise InputError(f'`{name}` = {v!r} must be finite and > 0')
    return float(v)


class AmplitudePhaseControl(CycleCorrection):
    """A sine ``mean + amplitude sin(2 pi f t)`` whose command APC corrects each cycle."""

    def __init__(self, amplitude: float, frequency: float, mean: float = 0.0,
                 gain: float = 0.7, tolerance: float = 2e-3, harmonics: int | None = None,
                 latency: float = 0.0, learn_from: float = 0.0,
                 sweep_to: float | None = None, sweep_time: float | None = None) -> None:
        super().__init__()
        self.amplitude = _positive('amplitude', amplitude)
        self.frequency = _positive('frequency', frequency)
        if (sweep_to is None) != (sweep_time is None):
            raise InputError('`sweep_to` and `sweep_time` go together (a linear sweep from '
                             '`frequency` to `sweep_to` over `sweep_time`)')
        self.sweep_to = self.frequency if sweep_to is None else _positive('sweep_to', sweep_to)
        self.sweep_time = (math.inf if sweep_time is None
                           else _positive('sweep_time', sweep_time))
        self._rate = (self.sweep_to - self.frequency) / self.sweep_time     # [Hz/s]
        if harmonics is None:              # 5 for a sine, the fundamental only for a sweep
            harmonics = 1 if sweep_to is not None else 5
        if sweep_to is not None and harmonics != 1:
            raise InputError(f'`harmonics` = {harmonics!r}: a sweep corrects the fundamental '
                             "only (harmonics=1); its harmonics move through the loop's "
                             'resonance faster than a secant follows')
        if not math.isfinite(mean):
            raise InputError(f'`mean` = {mean!r} must be finite')
        if not 0.0 < gain <= 1.0:
            raise InputError(f'`gain` = {gain!r} must be in (0, 1]')
        if isinstance(harmonics, bool) or not isinstance(harmonics, int) \
                or not 1 <= harmonics <= MAX_HARMONICS:
            raise InputError(f'`harmonics` = {harmonics!r} must be a whole number in '
                             f'[1, {MAX_HARMONICS}]')
        if isinstance(latency, bool) or not isinstance(latency, (int, float)) \
                or not 0.0 <= latency < 1.0 / max(self.frequency, self.sweep_to):
            raise InputError(f'`latency` = {latency!r} s must be >= 0 and under a period')
        self.mean = float(mean)
        self.gain = float(gain)
        self.tolerance = _positive('tolerance', tolerance)
        self.harmonics = harmonics
        self.latency = float(latency)
        if isinstance(learn_from, bool) or not isinstance(learn_from, (int, float)) \
                or not math.isfinite(learn_from):
            raise InputError(f'`learn_from` = {learn_from!r} s must be finite')
        self.learn_from = float(learn_from)
        self.omega = 2.0 * math.pi * self.frequency
        self.period = 1.0 / self.frequency
        self._k = np.arange(1, harmonics + 1)
        # command: complex amplitudes of sin at each harmonic (z = Im(sum C_k e^{i k w t}))
        # and the mean; each correction a segment (start [s], length [s], C and mean before,
        # C and mean after) blended linearly, the newest last (three kept: a sample is never
        # asked for further back than a period)
        c0 = np.zeros(harmonics, complex)
        c0[0] = self.amplitude
        self._segments: list[tuple] = [(-math.inf, self.period, c0, self.mean, c0, self.mean)]
        self._acc = np.zeros(harmonics, complex)
        self._zero = np.zeros(harmonics, complex)      # no change (read only)
        self._sum = 0.0
        self._n = 0
        self._w = 0.0
        self._gain_k = np.full(harmonics, np.nan + 0j)   # the loop's gain at each harmonic
        self._last: tuple | None = None                  # (C, R) of the last clean cycle
        self.cycles = 0                  #: cycles measured
        self.converged_at: int | None = None   #: the cycle the convergence rule was met
        self._ok = 0
        #: per cycle: amplitude ratio, phase [deg], mean error [m], harmonics [% of amplitude];
        #: the newest HISTORY to twice that cycles (a fatigue test runs for days)
        self.history: list[dict] = []

    def phase(self, t):
        """Return the sine's phase [rad] at ``t`` [s] (a sweep's: ``2 pi (f0 t + r t^2 / 2)``)."""
        if self._rate == 0.0:
            return self.omega * t
        return sweep_phase(t, self.frequency, self.sweep_to, self.sweep_time)[0]

    def frequency_at(self, t):
        """Return the instantaneous frequency [Hz] at ``t`` [s]."""
        if self._rate == 0.0:
            return self.frequency
        return sweep_phase(t, self.frequency, self.sweep_to, self.sweep_time)[1]

    def cycle_of(self, t: float) -> int:
        """Return the number of the cycle (of the phase) that time ``t`` [s] falls in."""
        if self._rate == 0.0:
            return super().cycle_of(t)
        return int(math.floor(self.phase(t) / (2.0 * math.pi) + 1e-9))

    def cycle_start(self, n: int) -> float:
        """Return the time [s] at which cycle ``n`` starts."""
        if self._rate == 0.0:
            return super().cycle_start(n)
        # f0 t + r t^2 / 2 = n; within the sweep (after it the phase stops)
        f0, r = self.frequency, self._rate
        return min((-f0 + math.sqrt(max(f0 * f0 + 2.0 * r * n, 0.0))) / r, self.sweep_time)

    @property
    def _c_new(self) -> np.ndarray:
        """Return the command's complex amplitudes once the newest correction is in."""
        return self._segments[-1][4]

    def _blend(self, t: float) -> tuple[np.ndarray, float, np.ndarray, float]:
        """Return the command's C, mean and their rates [1/s] at ``t`` [s]."""
        for t0, dur, c0, m0, c1, m1 in reversed(self._segments):
            if t >= t0 - 1e-12 or t0 == -math.inf:
                break
        s = (t - t0) / dur
        if s >= 1.0:
            return c1, m1, self._zero, 0.0
        s = max(s, 0.0)
        return c0 + (c1 - c0) * s, m0 + (m1 - m0) * s, (c1 - c0) / dur, (m1 - m0) / dur

    def reference(self, t: float) -> tuple[float, float]:
        """Return the command (position [m], velocity [m/s]) at time ``t`` [s]."""
        c, m, dc, dm = self._blend(t)
        w = 2.0 * math.pi * self.frequency_at(t) if t < self.sweep_time else 0.0
        # the sum over the harmonics in Python complex arithmetic: a few terms, where numpy's
        # call overhead is most of the cost (the loop's hot path)
        e1 = cmath.exp(1j * self.phase(t))
        e = e1
        z = v = 0.0
        for k, (ck, dk) in enumerate(zip(c.tolist(), dc.tolist()), 1):
            z += (ck * e).imag
            v += ((1j * w * k * ck + dk) * e).imag
            e *= e1
        return z + m, v + dm

    def desired(self, t):
        """Return the specified position [m] at ``t`` (a number or an array) [s]."""
        return self.mean + self.amplitude * np.sin(self.phase(np.asarray(t, dtype=float)))

    def _take(self, t: float, z: float) -> None:
        # a sweep's samples are weighted by its frequency, so that the sums are over its phase
        # (a DFT in the phase: the harmonics stay orthogonal to the fundamental)
        w = 1.0 if self._rate == 0.0 else self.frequency_at(t) / self.frequency
        e1 = cmath.exp(-1j * self.phase(t))
        e, wz, acc = e1, w * z, self._acc
        for k in range(self.harmonics):
            acc[k] += wz * e
            e *= e1
        self._sum += w * z
        self._n += 1
        self._w += w

    def _end_cycle(self, cycle: int) -> None:
        n, acc, tot, bad, wsum = self._n, self._acc, self._sum, self._bad, self._w
        clipped = self._clipped
        self._acc, self._sum, self._n, self._bad, self._w = \
            np.zeros(self.harmonics, complex), 0.0, 0, False, 0.0
        self._clipped = False
        prev = self._cycle
        start = self.cycle_start(prev)              # the cycle that ended: [start, end)
        end = self.cycle_start(prev + 1)
        t0, dur, _, _, c_used, m_used = self._segments[-1]
        blended = t0 + dur > start + 1e-12          # a correction blended in over it
        self._cycle = cycle
        if bad or n < 8 or self.frozen:
            return
        # z = Im(sum R_k e^{ikwt}) + r: the DFT bins give R_k = 2i/n sum z e^{-ikwt}
        resp = 2j * acc / wsum
        mean = tot / wsum
        self.cycles += 1
        ratio = abs(resp[0]) / self.amplitude
        phase = math.degrees(cmath.phase(resp[0]))
        self.history.append({'cycle': self.cycles, 'amp_ratio': ratio, 'phase_deg': phase,
                             'mean_err': mean - self.mean,
                             'harmonics_pct': float(np.sqrt(np.sum(np.abs(resp[1:]) ** 2))
                                                    / self.amplitude * 100.0)})
        if len(self.history) > 2 * HISTORY:
            del self.history[:-HISTORY]
        ok = abs(ratio - 1.0) <= self.tolerance and abs(phase) <= math.degrees(
            self.tolerance) and abs(mean - self.mean) <= self.tolerance * self.amplitude
        self._ok = self._ok + 1 if ok else 0
        if self._ok >= 2 and self.converged_at is None:
            self.converged_at = self.cycles
        if blended:            # the command changed during that cycle: measure again first
            return
        c_next = c_used + self._steps(c_used, resp, n)
        if clipped:        # (clip()): the fundamental no larger, the harmonics as they were
            if abs(c_next[0]) > abs(c_used[0]):
                c_next[0] *= abs(c_used[0]) / abs(c_next[0])
            c_next[1:] = c_used[1:]
        m_next = m_used + self.gain * (self.mean - mean)
        # bounded: the fundamental at most (1 + limit) times the amplitude, the harmonics
        # and the mean's correction at most ``limit`` of it
        lim, a = self.limit, self.amplitude
        limited = False
        if abs(c_next[0]) > (1.0 + lim) * a:
            c_next[0] *= (1.0 + lim) * a / abs(c_next[0])
            limited = True
        h = float(np.sum(np.abs(c_next[1:])))
        if h > lim * a:
            c_next[1:] *= lim * a / h
            limited = True
        if abs(m_next - self.mean) > lim * a:
            m_next = self.mean + math.copysign(lim * a, m_next - self.mean)
            limited = True
        self.limited_cycles = self.limited_cycles + 1 if limited else 0
        # in from ``latency`` after the cycle's end, to the end of the next cycle (a whole
        # cycle if that leaves less than half of one), so the cycle after it is clean
        t0 = end + self.latency
        period = self.cycle_start(prev + 2) - end           # the next cycle's
        if period <= 0.0:          # a sweep's end: the phase stopped, nothing to correct
            return
        dur = period - self.latency if self.latency <= 0.5 * period else period
        self._segments = self._segments[-2:] + [(t0, dur, c_used, m_used, c_next, m_next)]

    def _steps(self, c: np.ndarray, resp: np.ndarray, n: int) -> np.ndarray:
        """Return the command's change at each harmonic after a cycle measured at ``c``."""
        want = np.zeros(self.harmonics, complex)
        want[0] = self.amplitude
        step = np.zeros(self.harmonics, complex)
        h1 = resp[0] / c[0] if c[0] != 0 else 1.0
        if h1 == 0:
            return step
        step[0] = self.gain * (want[0] - resp[0]) / h1
        new = c[0] + step[0]
        if abs(new) > 2.0 * abs(c[0]):
            step[0] = new / abs(new) * 2.0 * abs(c[0]) - c[0]
        # the harmonics the loop distorts the sine with, once the fundamental is within
        # HARMONICS_FROM of its target (the distortion moves with it; a secant across a
        # large change of the fundamental is not the loop's gain at the harmonic)
        if abs(resp[0] / self.amplitude - 1.0) > HARMONICS_FROM:
            self._last = None
            return step
        # their gain from the last two cycles' commands and responses (a secant: the
        # distortion is there without any command, so R_k / C_k says nothing)
        if self._last is not None:
            dc, dr = c - self._last[0], resp - self._last[1]
            moved = np.abs(dc) > SECANT_FROM * self.amplitude
            self._gain_k = np.where(moved, dr / np.where(moved, dc, 1.0), self._gain_k)
        self._last = (c, resp)
        # harmonics the cycle's samples resolve (10 samples a period or more)
        k = np.arange(1, self.harmonics)
        k = k[(k + 1) * 10 <= n]
        known = ~np.isnan(self._gain_k[k])
        g = np.where(known, self._gain_k[k], h1)
        g = np.where(np.abs(g) < 0.1, 0.1 * np.exp(1j * np.angle(g)), g)    # not unbounded
        # a harmonic's first step is a probe, a quarter of a step: the loop's gain there may
        # be far from the fundamental's (a resonance), and the step sets the secant
        step[k] = -self.gain * np.where(known, 1.0, PROBE) * resp[k] / g
        # a harmonic's command never exceeds a quarter of the amplitude
        over = np.abs(c[k] + step[k]) > 0.25 * self.amplitude
        step[k] = np.where(over, (c[k] + step[k]) / np.maximum(np.abs(c[k] + step[k]), 1e-300)
                           * 0.25 * self.amplitude - c[k], step[k])
        return step
