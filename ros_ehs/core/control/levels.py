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
A cycle's peak and valley under sensor noise: the extremes of a harmonic fit of its samples.

A cycle's raw extremes are biased by noise: the largest of a thousand noisy samples is some
three standard deviations above the true peak, so peak/valley control that drives the raw
extremes to the levels leaves the specimen's true range short (2.7 % of a 1-10 kN range with
100 N on the load cell, measured). :class:`CycleLevels` fits the cycle's samples, by least
squares, with its mean and its first ``h`` harmonics at the cycle's own frequency (IEEE Std
1057's sine fit, with the harmonics a loop's distortion puts in: a 1-10 kN force sine at 10
Hz carries 30 N at its 7th, and a fit to the 5th put the peak 43 N high), ``h`` the
smaller of ``HARMONICS`` and one per 4 samples (a cycle sampled 12 times, 85 Hz at 1 kHz, is
fitted with 2: with one, a distorted cycle's peak read 24 N inside the specimen's), and
returns the extremes of the fitted
waveform, with a scatter of about ``sigma sqrt((2 h + 1) / n)`` for ``n`` samples. Their
bias under white noise is what the fitted curve's own noise lifts its extremes by: 0.13 % of a
9 kN range with 100 N of noise at 100 samples a cycle, where the raw range is 2.5 % long
(``test/test_levels.py``). Sinusoidal waveforms (sine,
haversine) are fitted; a triangle's corners need more harmonics than noise allows, so its
raw extremes stand (:data:`FITTED`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ['CycleLevels', 'FITTED', 'HARMONICS']

#: the most harmonics fitted besides the mean (fewer with fewer samples: one per 4)
HARMONICS = 9
#: the waveforms whose cycles are fitted (the others keep their raw extremes)
FITTED = ('sine', 'haversine')


class CycleLevels:
    """
    One cycle's samples: raw and fitted extremes.

    The cycle starts at time ``t0`` and lasts ``period`` (its samples' phases are ``(t - t0) /
    period``; by default ``t`` is the phase itself).
    """

    __slots__ = ('t', 'v', 'fit', 't0', 'period')

    def __init__(self, fit: bool = True, t0: float = 0.0, period: float = 1.0) -> None:
        self.fit = bool(fit)
        self.t0, self.period = float(t0), float(period)
        self.t: list[float] = []
        self.v: list[float] = []

    def add(self, t: float, v: float) -> None:
        """Take a sample at time ``t`` (a non-finite value spoils the cycle)."""
        self.t.append(t)
        self.v.append(v)

    def raw(self) -> tuple[float, float]:
        """Return the largest and smallest sample (NaN after a non-finite one)."""
        v = self.v
        if not v:
            return -math.inf, math.inf
        s = math.fsum(v)
        if s - s != 0.0:                   # a NaN or an infinity among them
            return math.nan, math.nan
        return max(v), min(v)

    def levels(self) -> tuple[float, float]:
        """Return the fitted waveform's peak and valley (the raw ones when it cannot fit)."""
        n = len(self.v)
        h = min(HARMONICS, n // 4)
        hi, lo = self.raw()
        if not self.fit or h < 1 or not (math.isfinite(hi) and math.isfinite(lo)):
            return hi, lo
        k = np.arange(1, h + 1)
        x = (np.asarray(self.t) - self.t0) / self.period
        solver = _solver(x, h)
        if solver is None:                  # samples that do not span the cycle
            return hi, lo
        a, pinv = solver
        c = pinv @ np.asarray(self.v)
        # the fitted curve's extremes: at its samples, refined by a parabola through the
        # best one and its neighbours in phase (a sine at 100 samples a cycle: 2e-6 of it)
        w = a @ c
        return (_refine(x, w, int(np.argmax(w)), c, k, 1.0),
                _refine(x, w, int(np.argmin(w)), c, k, -1.0))


_SOLVERS: dict[tuple, tuple] = {}
#: the sample layouts whose solvers are kept (a steady test has one or two)
SOLVERS = 16


def _solver(x: np.ndarray, h: int) -> tuple | None:
    """
    Return the design matrix of phases ``x`` with ``h`` harmonics and its pseudo-inverse.

    A loop samples every cycle of a steady step at the same phases: the pair is kept for
    evenly spaced samples (``SOLVERS`` layouts), so a cycle's fit is one product.
    """
    n = x.size
    dx = (x[-1] - x[0]) / (n - 1)
    even = bool(np.all(np.abs(np.diff(x) - dx) < 1e-6 * max(dx, 1e-12)))
    key = (n, h, round(float(x[0]), 9), round(float(dx), 12)) if even else None
    got = _SOLVERS.get(key) if key else None
    if got is not None:
        return got
    k = np.arange(1, h + 1)
    e = np.exp(2j * math.pi * np.outer(x, k))
    a = np.hstack([np.ones((n, 1)), e.real, e.imag])
    try:              # the normal equations: well posed for samples that span the cycle
        pinv = np.linalg.solve(a.T @ a, a.T)
    except np.linalg.LinAlgError:
        return None
    if key:
        if len(_SOLVERS) >= SOLVERS:
            _SOLVERS.pop(next(iter(_SOLVERS)))
        _SOLVERS[key] = (a, pinv)
    return a, pinv


def _refine(x: np.ndarray, w: np.ndarray, j: int, c: np.ndarray, k: np.ndarray,
            sign: float) -> float:
    """Return the fitted curve's extreme near sample ``j`` (a parabola in phase)."""
    h = k.size
    dx = 0.5 / max(len(x), 1)
    xs = x[j] + np.array([-dx, 0.0, dx])
    e = np.exp(2j * math.pi * np.outer(xs, k))
    y = c[0] + e.real @ c[1:h + 1] + e.imag @ c[h + 1:]
    den = y[0] - 2.0 * y[1] + y[2]
    if sign * den >= 0.0:                    # not an extreme of the parabola: the sample's
        return float(max(w[j], y.max()) if sign > 0 else min(w[j], y.min()))
    t = 0.5 * (y[0] - y[2]) / den            # the vertex, in steps of dx
    t = min(max(t, -1.0), 1.0)
    return float(y[1] + 0.5 * (y[2] - y[0]) * t + 0.5 * den * t * t)
