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
Peak/valley control (PVC) of cyclic waveforms that are not sines (ROS-free).

A fatigue test specifies each cycle's peak and valley: a triangle, a haversine, or a
block-loading sequence of such cycles at several levels. The command is
``c_mean + c_amp * s(phase)`` with the waveform ``s`` between -1 (valley) and +1 (peak); after
each cycle the measured peak ``p`` and valley ``v`` correct it:

    c_amp *= 1 + g ((P - V) / (p - v) - 1),      c_mean += g ((P + V) / 2 - (p + v) / 2)

(``gain`` g 0.7). Each block of a sequence keeps its own correction, learnt over its cycles
and kept when the sequence repeats; a correction blends in over the next cycle (no jump) and
that cycle is not used to learn. Between blocks at other levels the command starts from where
the last cycle ended and the step decays linearly over the first cycle (no jump); that cycle
is not judged (its valley is the transition), so a block needs two cycles or more to be
corrected. ``converged_at``: the first cycle after which every block's peak and valley are
within ``tolerance`` of its range (0.5 %). :meth:`freeze` stops the learning, as APC's.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Sequence

import numpy as np
from ros_ehs.control.cycles import CycleCorrection
from ros_ehs.errors import InputError

__all__ = ['Block', 'PeakValleyControl', 'WAVEFORMS']

WAVEFORMS = ('triangle', 'haversine', 'sine')


def _shape(kind: str, phase: float) -> tuple[float, float]:
    """Return ``s`` and ``ds/dphase`` at ``phase`` in cycles (valley at 0, peak at 0.5)."""
    x = phase - math.floor(phase)
    if kind == 'triangle':
        return (4.0 * x - 1.0, 4.0) if x < 0.5 else (3.0 - 4.0 * x, -4.0)
    w = 2.0 * math.pi
    if kind == 'haversine':           # rests at the valley: 1 - cos from there
        return -math.cos(w * x), w * math.sin(w * x)
    return math.sin(w * (x - 0.25)), w * math.cos(w * (x - 0.25))


@dataclass(frozen=True)
class Block:
    """``cycles`` cycles between ``valley`` and ``peak`` [m]."""

    peak: float
    valley: float
    cycles: int = 1

    def __post_init__(self) -> None:
        """Check the block."""
        if not (math.isfinite(self.peak) and math.isfinite(self.valley)
                and self.peak > self.valley):
            raise InputError(f'block: `peak` = {self.peak!r} m must be finite and above '
                             f'`valley` = {self.valley!r} m')
        if isinstance(self.cycles, bool) or not isinstance(self.cycles, int) \
                or self.cycles < 1:
            raise InputError(f'block: `cycles` = {self.cycles!r} must be a whole number >= 1')


class PeakValleyControl(CycleCorrection):
    """A cyclic waveform through a sequence of blocks, its peaks and valleys corrected."""

    def __init__(self, blocks: Sequence[Block], frequency: float, waveform: str = 'triangle',
                 gain: float = 0.7, tolerance: float = 5e-3) -> None:
        super().__init__()
        if not blocks:
            raise InputError('`blocks`: give at least one block')
        if waveform not in WAVEFORMS:
            raise InputError(f'`waveform` = {waveform!r} is not one of {list(WAVEFORMS)}')
        if not (math.isfinite(frequency) and frequency > 0):
            raise InputError(f'`frequency` = {frequency!r} must be finite and > 0')
        if not 0.0 < gain <= 1.0:
            raise InputError(f'`gain` = {gain!r} must be in (0, 1]')
        self.blocks = list(blocks)
        self.frequency = float(frequency)
        self.waveform = waveform
        self.gain = float(gain)
        self.tolerance = float(tolerance)
        self.period = 1.0 / self.frequency
        self._starts = np.cumsum([0] + [b.cycles for b in self.blocks])
        self.cycles_per_pass = int(self._starts[-1])
        # per block: command amplitude and mean (start: the specified ones)
        self.amp = [0.5 * (b.peak - b.valley) for b in self.blocks]
        self.mean = [0.5 * (b.peak + b.valley) for b in self.blocks]
        self._used = list(zip(self.amp, self.mean))    # what each block's last cycle ran
        self._start_jump = 0.0         # the command's step at this cycle's start, decaying
        self._last_end = None          # the command at the end of the cycle before
        self._hi, self._lo = -math.inf, math.inf
        self.errors = [math.inf] * len(self.blocks)   # newest peak/valley error per block
        self.converged_at: int | None = None
        self.history: list[dict] = []

    def _block(self, cycle: int) -> int:
        return int(np.searchsorted(self._starts, cycle % self.cycles_per_pass, 'right') - 1)

    def desired(self, t):
        """Return the specified waveform [m] at ``t`` (a number or an array) [s]."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.empty(t.shape)
        for k, tk in enumerate(t):
            c = self.cycle_of(tk)
            b = self.blocks[self._block(c)]
            s, _ = _shape(self.waveform, tk / self.period)
            out[k] = 0.5 * (b.peak + b.valley) + 0.5 * (b.peak - b.valley) * s
        return out

    def _command(self, c: int, x: float) -> tuple[float, float, float, float]:
        """Return amplitude, mean and their rates [per cycle] of cycle ``c`` at fraction x."""
        b = self._block(c)
        (a0, m0), a1, m1 = self._used[b], self.amp[b], self.mean[b]
        return a0 + (a1 - a0) * x, m0 + (m1 - m0) * x, a1 - a0, m1 - m0

    def reference(self, t: float) -> tuple[float, float]:
        """Return the command (position [m], velocity [m/s]) at ``t`` [s]."""
        c = self.cycle_of(t)
        if c != self._cycle:        # measure() was not called for this cycle yet
            self._end_cycle(c)
        x = t / self.period - c
        a, m, da, dm = self._command(c, x)
        s, ds = _shape(self.waveform, t / self.period)
        z = m + a * s + self._start_jump * (1.0 - x)
        v = (a * ds + da * s + dm - self._start_jump) / self.period
        return z, v

    def _take(self, t: float, z: float) -> None:
        self._hi = max(self._hi, z)
        self._lo = min(self._lo, z)

    def _end_cycle(self, c: int) -> None:
        """End cycle ``self._cycle``: learn from it, and start cycle ``c`` without a jump."""
        prev = self._cycle
        b = self._block(prev)
        a_end, m_end, _, _ = self._command(prev, 1.0)
        end = m_end + a_end * _shape(self.waveform, 1.0)[0] + 0.0
        jumped = self._start_jump != 0.0      # a transition from another level's end
        blended = (self.amp[b], self.mean[b]) != self._used[b]
        self._used[b] = (self.amp[b], self.mean[b])
        hi, lo, bad = self._hi, self._lo, self._bad
        self._hi, self._lo, self._bad = -math.inf, math.inf, False
        self._cycle = c
        a0, m0, _, _ = self._command(c, 0.0)
        self._start_jump = end - (m0 + a0 * _shape(self.waveform, 0.0)[0])
        if abs(self._start_jump) < 1e-12:
            self._start_jump = 0.0
        if bad or self.frozen or not hi > lo or c != prev + 1 or jumped:
            return
        blk = self.blocks[b]
        rng = blk.peak - blk.valley
        err = max(abs(hi - blk.peak), abs(lo - blk.valley)) / rng
        self.errors[b] = err
        self.history.append({'cycle': prev, 'block': b, 'peak': hi, 'valley': lo,
                             'error': err})
        if self.converged_at is None and all(e <= self.tolerance for e in self.errors):
            self.converged_at = prev
        if blended:        # the command changed during that cycle: measure again first
            return
        self.amp[b] *= 1.0 + self.gain * (rng / (hi - lo) - 1.0)
        self.mean[b] += self.gain * (0.5 * (blk.peak + blk.valley) - 0.5 * (hi + lo))
