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
What amplitude/phase and peak/valley control share: a command corrected once a cycle.

:class:`CycleCorrection` takes the measured position every control period, hands each
sample of a cycle to :meth:`~CycleCorrection._take` and, at the first sample of the next
cycle, calls :meth:`~CycleCorrection._end_cycle`. Edge-case policy: while frozen (an
interlock, lost feedback) and for a non-finite position the cycle under way is marked bad
(not learnt from); the subclass keeps its command as it was, so it resumes without a jump.
A cycle with a sample before ``learn_from`` [s] is not learnt from either: the axis ramps
onto the trajectory over its first second (``ramp_time``), and a response attenuated by a
ramp is not the loop's (learnt from, it doubled the command: 1.97 times the amplitude once
the ramp was over).
"""

from __future__ import annotations

import math

__all__ = ['CycleCorrection', 'HISTORY']

#: the cycles a correction's ``history`` keeps, the newest (a fatigue test runs for days)
HISTORY = 100


class CycleCorrection:
    """Cycle bookkeeping of a correction at ``period`` [s]; subclasses set ``period``."""

    period: float

    def __init__(self) -> None:
        self._cycle = 0
        self._bad = False
        self._clipped = False           # the cycle under way was clipped (:meth:`clip`)
        self.frozen = False
        #: the most the correction may move the command from the specified one, as a fraction
        #: of the specified amplitude (inf: no bound)
        self.limit = math.inf
        self.limited_cycles = 0         #: consecutive learnt cycles that met the bound
        #: the newest ended cycle's (number, peak, valley) where the correction measures them
        #: (peak/valley control), else None
        self.last_levels: tuple[int, float, float] | None = None
        self.learn_from = 0.0           #: no cycle with a sample before this time [s] counts

    def cycle_of(self, t: float) -> int:
        """Return the number of the cycle that time ``t`` [s] falls in."""
        return int(math.floor(t / self.period + 1e-9))

    def cycle_start(self, n: int) -> float:
        """Return the time [s] at which cycle ``n`` starts."""
        return n * self.period

    def spoil(self) -> None:
        """Do not learn from the cycle under way (the loop did not apply it as commanded)."""
        self._bad = True

    def clip(self) -> None:
        """
        Learn from the cycle under way only what asks less of the rig (its command clipped).

        A cycle whose command the controller clipped (the valve at its current limit) fell
        short of what was asked: a larger command learnt from it would only wind further into
        the limit, so the amplitude is not raised from it; lowered it may be (a rig that
        overshoots while it saturates needs less).
        """
        self._clipped = True

    def freeze(self, on: bool = True) -> None:
        """Stop (or resume) the corrections; the cycle under way is not used."""
        self.frozen = bool(on)
        self._bad = True

    def measure(self, t: float, z: float) -> None:
        """Take the measured position ``z`` [m] at time ``t`` [s] (once per control period)."""
        cycle = self.cycle_of(t)
        if cycle != self._cycle:
            self._end_cycle(cycle)
        if self.frozen or not math.isfinite(z) or t < self.learn_from:
            self._bad = True
            return
        self._take(t, z)

    def _take(self, t: float, z: float) -> None:
        raise NotImplementedError

    def _end_cycle(self, cycle: int) -> None:
        raise NotImplementedError
