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
the last cycle ended and rises (or falls) to the new peak over the first half cycle along the
waveform's own shape (no jump, and nothing beyond the two levels: a step decayed linearly
over the whole cycle stood half of it on the new peak, an overload at every transition);
that cycle is not judged (its valley is the transition), so a block needs two cycles or more to be
corrected. ``converged_at``: the first cycle after which every block's peak and valley are
within ``tolerance`` of its range (0.5 %). :meth:`freeze` stops the learning, as APC's.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Sequence

import numpy as np
from ros_ehs.core.control.cycles import CycleCorrection, HISTORY
from ros_ehs.core.control.levels import CycleLevels, FITTED
from ros_ehs.core.errors import InputError

__all__ = ['Block', 'Cyclic', 'PeakValleyControl', 'parse_blocks', 'WAVEFORMS', 'waveform']

WAVEFORMS = ('triangle', 'haversine', 'sine')


def waveform(kind: str, phase: float) -> tuple[float, float]:
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


def parse_blocks(text: str) -> list[Block]:
    """
    Read a block-loading sequence: ``peak valley cycles`` per block, blocks apart by ``;``.

    ``'0.01 -0.01 4; 0.02 0 4'``: 4 cycles between -10 and +10 mm, then 4 between 0 and
    20 mm [m]. Commas may stand for spaces. InputError names the block that is wrong.
    """
    blocks = []
    for k, part in enumerate(p for p in text.split(';') if p.strip()):
        fields = part.replace(',', ' ').split()
        try:
            if len(fields) != 3:
                raise ValueError(f'{len(fields)} numbers')
            peak, valley, cycles = float(fields[0]), float(fields[1]), float(fields[2])
            if cycles != int(cycles):
                raise ValueError('a whole number of cycles')
        except ValueError as err:
            raise InputError(f'`blocks`: block {k + 1} {part.strip()!r} must be '
                             f'`peak valley cycles` ({err})') from None
        blocks.append(Block(peak, valley, int(cycles)))
    if not blocks:
        raise InputError(f'`blocks` = {text!r}: give at least one `peak valley cycles`')
    return blocks


class Cyclic:
    """The specified waveform through ``blocks`` at ``frequency`` as a reference (no PVC)."""

    def __init__(self, blocks: Sequence[Block], frequency: float, waveform: str) -> None:
        self._spec = PeakValleyControl(blocks, frequency, waveform)

    def __call__(self, t):
        """Return (z_ref, v_ref) at times ``t``."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = [self._spec.specified(float(x)) for x in t]
        return np.array([z for z, _ in out]), np.array([v for _, v in out])


class PeakValleyControl(CycleCorrection):
    """A cyclic waveform through a sequence of blocks, its peaks and valleys corrected."""

    def __init__(self, blocks: Sequence[Block], frequency: float, waveform: str = 'triangle',
                 gain: float = 0.7, tolerance: float = 5e-3, latency: float = 0.0,
                 learn_from: float = 0.0) -> None:
        super().__init__()
        if not blocks:
            raise InputError('`blocks`: give at least one block')
        if waveform not in WAVEFORMS:
            raise InputError(f'`waveform` = {waveform!r} is not one of {list(WAVEFORMS)}')
        if not (math.isfinite(frequency) and frequency > 0):
            raise InputError(f'`frequency` = {frequency!r} must be finite and > 0')
        if not 0.0 < gain <= 1.0:
            raise InputError(f'`gain` = {gain!r} must be in (0, 1]')
        if not (math.isfinite(latency) and 0.0 <= latency < 0.5 / frequency):
            raise InputError(f'`latency` = {latency!r} s must be >= 0 and under half a period')
        if not math.isfinite(learn_from):
            raise InputError(f'`learn_from` = {learn_from!r} s must be finite')
        self.blocks = list(blocks)
        self.frequency = float(frequency)
        self.waveform = waveform
        self.gain = float(gain)
        self.tolerance = float(tolerance)
        self.latency = float(latency)
        self.learn_from = float(learn_from)
        self.period = 1.0 / self.frequency
        self._starts = np.cumsum([0] + [b.cycles for b in self.blocks])
        self.cycles_per_pass = int(self._starts[-1])
        # per block: the learnt command amplitude and mean (start: the specified ones), and
        # what its newest planned cycle ends with
        self.amp = [0.5 * (b.peak - b.valley) for b in self.blocks]
        self.mean = [0.5 * (b.peak + b.valley) for b in self.blocks]
        self._planned = list(zip(self.amp, self.mean))
        # per cycle, planned when it starts: (block, a0, m0, a1, m1, blend start [fraction of
        # the cycle], start jump); before that, reference() computes the plan it would be
        # without keeping it, and a correction learnt at its start blends in only from
        # ``latency`` on, so no sample computed ahead of time changes
        self._plans: dict[int, tuple] = {}
        self._plans[0] = self._make_plan(0, 0.0)
        self._planned[self._block(0)] = self._plans[0][3:5]
        self._levels = CycleLevels(waveform in FITTED, 0.0, self.period)   # the cycle under way
        # last_levels: fitted or raw as the waveform is; +-inf for a cycle it took no sample
        # of (before ``learn_from``, frozen)
        self.errors = [math.inf] * len(self.blocks)   # newest peak/valley error per block
        self.converged_at: int | None = None
        #: the newest cycles judged (HISTORY to twice that: a fatigue test runs for days)
        self.history: list[dict] = []
        self.judged = 0                    #: cycles judged in all

    def _block(self, cycle: int) -> int:
        return int(np.searchsorted(self._starts, cycle % self.cycles_per_pass, 'right') - 1)

    def _make_plan(self, c: int, x0: float) -> tuple:
        b = self._block(c)
        a0, m0 = self._planned[b]
        a1, m1 = self.amp[b], self.mean[b]
        jump = 0.0
        prev = self._plans.get(c - 1)
        if prev is not None:          # start where the cycle before ended: no jump
            jump = prev[4] + prev[3] * waveform(self.waveform, 1.0)[0] - (
                m0 + a0 * waveform(self.waveform, 0.0)[0])
            if abs(jump) < 1e-12:
                jump = 0.0
        return (b, a0, m0, a1, m1, x0, jump)

    def specified(self, t: float) -> tuple[float, float]:
        """Return the specified position [m] and velocity [m/s] at ``t`` [s]."""
        b = self.blocks[self._block(self.cycle_of(t))]
        s, ds = waveform(self.waveform, t / self.period)
        return (0.5 * (b.peak + b.valley) + 0.5 * (b.peak - b.valley) * s,
                0.5 * (b.peak - b.valley) * ds / self.period)

    def desired(self, t):
        """Return the specified waveform [m] at ``t`` (a number or an array) [s]."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return np.array([self.specified(float(x))[0] for x in t])

    def reference(self, t: float) -> tuple[float, float]:
        """Return the command (position [m], velocity [m/s]) at ``t`` [s]."""
        c = self.cycle_of(t)
        plan = self._plans.get(c)
        if plan is None:              # ahead of the measurement: what it would be now
            plan = self._make_plan(c, 0.0)
        _, a0, m0, a1, m1, x0, jump = plan
        x = t / self.period - c
        w = min(max((x - x0) / (1.0 - x0), 0.0), 1.0)        # the blend's progress
        dw = 1.0 / (1.0 - x0) if x0 < x < 1.0 else 0.0
        a, m = a0 + (a1 - a0) * w, m0 + (m1 - m0) * w
        s, ds = waveform(self.waveform, t / self.period)
        # the step from the last cycle's end fades as the waveform rises from its valley
        # (0) to its peak (x = 0.5): from where it was to the new peak, monotonically
        rising = jump != 0.0 and x < 0.5        # (x a hair under 0 at the start)
        left, dleft = (0.5 * (1.0 - s), -0.5 * ds) if rising else (0.0, 0.0)
        z = m + a * s + jump * left
        v = (a * ds + ((a1 - a0) * s + (m1 - m0)) * dw + jump * dleft) / self.period
        return z, v

    def _take(self, t: float, z: float) -> None:
        self._levels.add(t, z)

    def _end_cycle(self, c: int) -> None:
        """End cycle ``self._cycle``: learn from it, and plan the cycles up to ``c``."""
        prev = self._cycle
        # a sinusoid's levels from a fit of its samples (noise does not move them), others'
        # raw extremes (ros_ehs.core.control.levels)
        hi, lo = self._levels.levels()
        self.last_levels = (prev, hi, lo)
        bad = self._bad or not (math.isfinite(hi) and math.isfinite(lo))
        clipped = self._clipped
        self._levels = CycleLevels(self.waveform in FITTED, c * self.period, self.period)
        self._bad = self._clipped = False
        self._cycle = c
        learnt = self._learn(prev, hi, lo, bad or c != prev + 1, clipped)
        for k in range(prev + 1, c + 1):
            # a correction learnt just now, for the cycle starting now: in from `latency` on
            # (before, reference() has computed the cycle without it)
            now = learnt and k == prev + 1 and self._block(k) == self._plans[prev][0]
            x0 = self.latency / self.period if now else 0.0
            self._plans[k] = self._make_plan(k, x0)
            self._planned[self._plans[k][0]] = self._plans[k][3:5]
        for old in [k for k in self._plans if k < c - 2]:
            del self._plans[old]

    def _learn(self, c: int, hi: float, lo: float, bad: bool, clipped: bool = False) -> bool:
        """
        Judge cycle ``c`` and learn from it; return whether its block's command changed.

        A ``clipped`` cycle (:meth:`clip`) lowers the amplitude or leaves it.
        """
        b, a0, m0, a1, m1, _, jump = self._plans[c]
        if bad or self.frozen or not hi > lo or jump != 0.0:
            return False    # a transition from another level's end is not judged
        blk = self.blocks[b]
        rng = blk.peak - blk.valley
        err = max(abs(hi - blk.peak), abs(lo - blk.valley)) / rng
        self.errors[b] = err
        self.history.append({'cycle': c, 'block': b, 'peak': hi, 'valley': lo,
                             'error': err})
        self.judged += 1
        if len(self.history) > 2 * HISTORY:
            del self.history[:-HISTORY]
        if self.converged_at is None and all(e <= self.tolerance for e in self.errors):
            self.converged_at = c
        if (a0, m0) != (a1, m1):
            return False    # the command changed during that cycle: measure again first
        amp = a1 * (1.0 + self.gain * (rng / (hi - lo) - 1.0))
        if clipped:
            amp = min(amp, a1)
        mean = m1 + self.gain * (0.5 * (blk.peak + blk.valley) - 0.5 * (hi + lo))
        # bounded: at most ``limit`` of the specified amplitude from the specified command
        a_s, m_s, lim = 0.5 * rng, 0.5 * (blk.peak + blk.valley), self.limit
        self.amp[b] = min(max(amp, a_s / (1.0 + lim)), a_s * (1.0 + lim))
        self.mean[b] = min(max(mean, m_s - lim * a_s), m_s + lim * a_s)
        limited = (self.amp[b], self.mean[b]) != (amp, mean)
        self.limited_cycles = self.limited_cycles + 1 if limited else 0
        return True
