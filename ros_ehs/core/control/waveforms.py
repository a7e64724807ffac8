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
Reference trajectories z_ref(t) [m] and v_ref(t) [m/s]: sine, step, chirp, cyclic, CSV file.

Each is a callable ``ref(t) -> (z, v)`` on an array of times [s]. The cyclic ones (triangle,
haversine, block loading) are :class:`ros_ehs.core.control.pvc.Cyclic`.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path

import numpy as np

from ros_ehs.core.errors import DataError, InputError, ParameterError
from ros_ehs.core.settings import Setting

__all__ = ['Chirp', 'CsvTrajectory', 'cyclic_blocks', 'first_order_hold', 'KINDS',
           'WAVEFORM', 'Samples', 'Sine', 'Step', 'make', 'sweep_phase']


def _finite(name: str, value: float) -> float:
    if not (isinstance(value, (int, float)) and math.isfinite(value)):
        raise InputError(f'`{name}` = {value!r} must be a finite number')
    return float(value)


def first_order_hold(z_ref: float, v_ref: float, ref_stamp_ns: int, stamp_ns: int,
                     limit_s: float) -> float:
    """
    Return the position demand [m] at ``stamp_ns`` from a reference sample at ``ref_stamp_ns``.

    The sample is carried with its velocity to the instant, forward from an older sample (a
    reference slower than the loop) and back from a newer one (it arrived between the state's
    stamp and the state), by at most ``limit_s`` either way: the demand is the reference at
    the state's instant whatever the phase of the two clocks' periods. Unchecked (the
    controller's hot path): finite inputs give a finite demand.
    """
    dt = min(max((stamp_ns - ref_stamp_ns) * 1e-9, -limit_s), limit_s)
    return z_ref + v_ref * dt


@dataclass(frozen=True)
class Sine:
    """``amplitude * sin(2 pi f t) + offset``: the paper's test is 0.04 m at 1 Hz."""

    amplitude: float = 0.04
    frequency: float = 1.0
    offset: float = 0.0

    def __post_init__(self) -> None:
        """Validate."""
        for k in ('amplitude', 'frequency', 'offset'):
            _finite(k, getattr(self, k))
        if self.frequency <= 0:
            raise InputError(f'`frequency` = {self.frequency!r} Hz must be > 0')

    def __call__(self, t):
        """Return (z_ref, v_ref) at times ``t``."""
        w = 2.0 * math.pi * self.frequency
        t = np.asarray(t, dtype=float)
        return (self.offset + self.amplitude * np.sin(w * t),
                self.amplitude * w * np.cos(w * t))


@dataclass(frozen=True)
class Step:
    """Step of ``amplitude`` at ``t0``, smoothed over ``rise`` seconds (cosine ramp)."""

    amplitude: float = 0.01
    t0: float = 0.1
    rise: float = 0.0

    def __post_init__(self) -> None:
        """Validate."""
        for k in ('amplitude', 't0', 'rise'):
            _finite(k, getattr(self, k))
        if self.rise < 0:
            raise InputError(f'`rise` = {self.rise!r} s must be >= 0')

    def __call__(self, t):
        """Return (z_ref, v_ref) at times ``t``."""
        t = np.asarray(t, dtype=float)
        if self.rise == 0:
            return np.where(t >= self.t0, self.amplitude, 0.0), np.zeros_like(t)
        s = np.clip((t - self.t0) / self.rise, 0.0, 1.0)
        z = self.amplitude * 0.5 * (1 - np.cos(math.pi * s))
        inside = (s > 0) & (s < 1)
        v = np.where(inside, self.amplitude * 0.5 * math.pi / self.rise * np.sin(math.pi * s),
                     0.0)
        return z, v


def sweep_phase(t, f0: float, f1: float, duration: float):
    """
    Return the phase [rad] and frequency [Hz] of a linear sweep at ``t`` [s] (number or array).

    From ``f0`` to ``f1`` over ``duration``: ``2 pi (f0 t + (f1 - f0) t^2 / 2 duration)``;
    held at its ends outside ``[0, duration]``. Unchecked (the callers validate).
    """
    tc = np.clip(t, 0.0, duration)
    k = (f1 - f0) / duration
    return 2 * math.pi * (f0 * tc + 0.5 * k * tc * tc), f0 + k * tc


@dataclass(frozen=True)
class Chirp:
    """Linear chirp from ``f0`` to ``f1`` Hz over ``duration`` s, amplitude [m]."""

    amplitude: float = 0.005
    f0: float = 0.5
    f1: float = 20.0
    duration: float = 10.0

    def __post_init__(self) -> None:
        """Validate."""
        for k in ('amplitude', 'f0', 'f1', 'duration'):
            _finite(k, getattr(self, k))
        if not (self.f0 > 0 and self.f1 > 0 and self.duration > 0):
            raise InputError('`f0`, `f1` and `duration` must be > 0')

    def __call__(self, t):
        """Return (z_ref, v_ref) at times ``t``."""
        t = np.asarray(t, dtype=float)
        phase, f = sweep_phase(t, self.f0, self.f1, self.duration)
        v = self.amplitude * 2 * math.pi * f * np.cos(phase)
        # before and after the sweep the position holds: no velocity
        return self.amplitude * np.sin(phase), np.where((t >= 0.0) & (t < self.duration), v, 0.0)


class Samples:
    """
    A sampled trajectory ``z`` [m] at times ``t`` [s] as a reference (a drive file's).

    Linear interpolation; velocity by central differences. Holds the end values outside.
    """

    def __init__(self, t, z) -> None:
        t, z = np.asarray(t, dtype=float), np.asarray(z, dtype=float)
        if t.shape != z.shape or t.ndim != 1 or t.size < 2:
            raise InputError(f'`t`, `z`: one time per position, at least two (got shapes '
                             f'{t.shape}, {z.shape})')
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(z))):
            raise InputError('`t`, `z` must be finite everywhere')
        if np.any(np.diff(t) <= 0):
            raise InputError('`t` must be increasing strictly')
        self.t, self.z = t, z
        self.v = np.gradient(z, t)

    def __call__(self, t):
        """Return (z_ref, v_ref) at times ``t``."""
        t = np.asarray(t, dtype=float)
        return np.interp(t, self.t, self.z), np.interp(t, self.t, self.v)


class CsvTrajectory(Samples):
    """Trajectory from a CSV file with columns ``t`` [s] and ``z`` [m] (header row required)."""

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        try:
            data = np.genfromtxt(path, delimiter=',', names=True)
        except (OSError, ValueError) as err:
            raise DataError(f'cannot read trajectory CSV {path}: {err}') from err
        names = data.dtype.names or ()
        if 't' not in names or 'z' not in names:
            raise DataError(f'{path}: need header columns `t` and `z`, found {list(names)}')
        t, z = np.atleast_1d(data['t']), np.atleast_1d(data['z'])
        if t.size < 2 or not (np.all(np.isfinite(t)) and np.all(np.isfinite(z))):
            raise DataError(f'{path}: need >= 2 finite rows')
        if np.any(np.diff(t) <= 0):
            raise DataError(f'{path}: column `t` must increase strictly')
        super().__init__(t, z)


KINDS = ('sine', 'step', 'chirp', 'triangle', 'haversine', 'csv')

#: The waveform's settings (the reference node declares them, live), declared once.
WAVEFORM: tuple[Setting, ...] = (
    Setting('kind', '', 'sine', meaning='trajectory: sine, step, chirp, triangle, haversine '
            '(cyclic between offset -+ amplitude, or through `blocks`) or csv (file)',
            choices=KINDS, live=True),
    Setting('amplitude', 'm or N', 0.04, -1.0e7, 1.0e7, 'amplitude (sine, chirp) or height '
            '(step); a force [N] under control_mode force, else a position (within +-2 m)',
            live=True),
    Setting('frequency', 'Hz', 1.0, 1.0e-3, 500.0, 'sine, triangle or haversine frequency',
            live=True),
    Setting('offset', 'm or N', 0.0, -1.0e7, 1.0e7, 'sine, triangle or haversine mean (a '
            'force under control_mode force)', live=True),
    Setting('step_time', 's', 0.1, 0.0, 1.0e6, 'time of the step', live=True),
    Setting('rise', 's', 0.0, 0.0, 100.0, 'step rise time (cosine ramp; 0: sharp)', live=True),
    Setting('f0', 'Hz', 0.5, 1.0e-3, 500.0, 'chirp start frequency', live=True),
    Setting('f1', 'Hz', 20.0, 1.0e-3, 500.0, 'chirp end frequency', live=True),
    Setting('chirp_duration', 's', 10.0, 1.0e-3, 1.0e6, 'chirp sweep time', live=True),
)


def cyclic_blocks(values: dict, blocks: str = '') -> list:
    """
    Return the blocks of a triangle or haversine.

    ``blocks`` (``peak valley cycles; ...``, :func:`ros_ehs.core.control.pvc.parse_blocks`) or,
    without them, one block between ``offset`` -+ ``amplitude``.
    """
    from ros_ehs.core.control.pvc import Block, parse_blocks
    if blocks.strip():
        return parse_blocks(blocks)
    a, m = abs(float(values['amplitude'])), float(values['offset'])
    if a == 0.0:
        raise ParameterError(f'reference `kind` = {values["kind"]}: `amplitude` must not be 0 '
                             '(or give `blocks`)')
    return [Block(m + a, m - a)]


def make(values: dict, csv_path: str = '', blocks: str = ''):
    """Return the trajectory that ``values`` (WAVEFORM names) describe, checked."""
    v = {s.name: s.check(values.get(s.name, s.default)) for s in WAVEFORM}
    kind = v['kind']
    if kind in ('triangle', 'haversine'):
        from ros_ehs.core.control.pvc import Cyclic
        return Cyclic(cyclic_blocks(v, blocks), v['frequency'], kind)
    if kind == 'sine':
        return Sine(v['amplitude'], v['frequency'], v['offset'])
    if kind == 'step':
        return Step(v['amplitude'], v['step_time'], v['rise'])
    if kind == 'chirp':
        return Chirp(v['amplitude'], v['f0'], v['f1'], v['chirp_duration'])
    if not csv_path:
        raise ParameterError('reference `kind` = csv needs `csv_path` (a file with columns t, z)')
    return CsvTrajectory(csv_path)
