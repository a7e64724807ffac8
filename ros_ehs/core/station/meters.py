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
The station's meters: a signal's value, each cycle's peak and valley, min and max since reset.

A :class:`Meter` finds the turning points of its signal itself (the station watches any
waveform, a procedure or none): a peak is the highest value since the last valley, taken
once the signal has fallen from it by more than the band, and a valley alike. The band is
``fraction`` of the signal's recent range (an envelope that forgets over ``memory`` samples),
never below ``floor`` (the signal's noise): a bench's 5 um noise makes no cycles of a held
axis, a 1 mm cycle and a 40 mm one are each found, and the noise on a 4 kN sine of
hydraulic force (hundreds of N) makes no cycles of its own. (A band from the last cycle's
span instead fed on itself: one noise cycle made the band small enough for the next.)

Edge-case policy: a non-finite value is counted (``invalid``) and changes nothing;
:meth:`Meter.reset` forgets min/max and the turning points, not the value or the recent
range.
"""

from __future__ import annotations

import math

__all__ = ['Meter']


class Meter:
    """One signal's meter (see the module docstring)."""

    def __init__(self, floor: float, fraction: float = 0.2, memory: int = 2000) -> None:
        if not (math.isfinite(floor) and floor > 0):
            raise ValueError(f'`floor` = {floor!r} must be finite and > 0')
        if not (math.isfinite(fraction) and 0 < fraction < 1):
            raise ValueError(f'`fraction` = {fraction!r} must be in (0, 1)')
        if not (isinstance(memory, int) and memory >= 1):
            raise ValueError(f'`memory` = {memory!r} samples must be an int >= 1')
        self.floor = float(floor)
        self.fraction = float(fraction)
        self.memory = memory
        self.value = math.nan
        self.invalid = 0
        self._env_hi = math.nan         # the recent range: an envelope that forgets (a reset
        self._env_lo = math.nan         # keeps it: it is the signal's, not the meter's)
        self.reset()

    def reset(self) -> None:
        """Forget min/max since reset and the cycles (the value stays)."""
        self.min = math.nan
        self.max = math.nan
        self.peak = math.nan            #: the last cycle's peak
        self.valley = math.nan          #: the last cycle's valley
        self.cycles = 0                 #: turning points found / 2
        self._hi = -math.inf            # the running extremes since the last turning point
        self._lo = math.inf
        self._rising: bool | None = None

    @property
    def band(self) -> float:
        """Return how far the signal must retreat from an extreme to make it a turning point."""
        span = self._env_hi - self._env_lo
        return max(self.floor, self.fraction * span) if math.isfinite(span) else self.floor

    def add(self, x: float) -> None:
        """Take one sample."""
        if x is None or not math.isfinite(x):
            self.invalid += 1
            return
        self.value = x
        self.min = x if not x >= self.min else self.min
        self.max = x if not x <= self.max else self.max
        if math.isfinite(self._env_hi):
            shrink = (self._env_hi - self._env_lo) / self.memory
            self._env_hi = max(x, self._env_hi - shrink)
            self._env_lo = min(x, self._env_lo + shrink)
        else:
            self._env_hi = self._env_lo = x
        self._hi = max(self._hi, x)
        self._lo = min(self._lo, x)
        band = self.band
        if self._rising is not False and x < self._hi - band:
            self.peak = self._hi             # fell from a peak: the peak is found
            self._rising = False
            self._lo = x
            self.cycles += 0.5
        elif self._rising is not True and x > self._lo + band:
            self.valley = self._lo
            self._rising = True
            self._hi = x
            self.cycles += 0.5

    def as_dict(self) -> dict:
        """Return the meter as JSON-able numbers (NaN as None)."""
        return {k: (None if v != v else v) for k, v in (
            ('value', self.value), ('peak', self.peak), ('valley', self.valley),
            ('min', self.min), ('max', self.max), ('cycles', math.floor(self.cycles)))}
