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
smaller of ``HARMONICS`` and one per 8 samples, and returns the extremes of the fitted
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

__all__ = ['CycleLevels', 'FITTED', 'GRID', 'HARMONICS']

#: the most harmonics fitted besides the mean (fewer with fewer samples: one per 8)
HARMONICS = 9
#: the fitted waveform's extremes are searched on this many points of the cycle
GRID = 512
#: the waveforms whose cycles are fitted (the others keep their raw extremes)
FITTED = ('sine', 'haversine')


class CycleLevels:
    """One cycle's samples (its phase in [0, 1) and value); raw and fitted extremes."""

    __slots__ = ('x', 'v', 'hi', 'lo', 'fit')

    def __init__(self, fit: bool = True) -> None:
        self.fit = bool(fit)
        self.x: list[float] = []
        self.v: list[float] = []
        self.hi, self.lo = -math.inf, math.inf

    def add(self, x: float, v: float) -> None:
        """Take a sample at phase ``x`` of the cycle (a non-finite one makes both NaN)."""
        if v - v != 0.0:                   # NaN or infinite: the cycle cannot be judged
            self.hi = self.lo = math.nan
        elif v > self.hi:
            self.hi = v
        if v < self.lo:
            self.lo = v
        if self.fit:
            self.x.append(x)
            self.v.append(v)

    def raw(self) -> tuple[float, float]:
        """Return the largest and smallest sample (NaN after a non-finite one)."""
        return self.hi, self.lo

    def levels(self) -> tuple[float, float]:
        """Return the fitted waveform's peak and valley (the raw ones when it cannot fit)."""
        n = len(self.v)
        h = min(HARMONICS, n // 8)
        if not self.fit or h < 1 or not (math.isfinite(self.hi) and math.isfinite(self.lo)):
            return self.hi, self.lo
        x = 2.0 * math.pi * np.asarray(self.x)
        k = np.arange(1, h + 1)
        a = np.hstack([np.ones((n, 1)), np.cos(np.outer(x, k)), np.sin(np.outer(x, k))])
        c, *_ = np.linalg.lstsq(a, np.asarray(self.v), rcond=None)
        g = 2.0 * math.pi * np.arange(GRID) / GRID
        w = c[0] + np.cos(np.outer(g, k)) @ c[1:h + 1] + np.sin(np.outer(g, k)) @ c[h + 1:]
        return float(w.max()), float(w.min())
