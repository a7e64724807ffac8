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
Identification experiments: one recorded run on a uniform grid, and cutting runs from series.

:class:`Experiment` is what the estimator fits. :func:`experiments_from_series` cuts the
contiguous runs of time series (stamps in ns on the state's clock) into experiments, as a
bag's are cut (:mod:`ros_ehs.data.experiments` reads the series from a bag, the live
identifier from the running loop):

* states closer than 0.45 of the median period to the one kept before them are dropped (a
  stray publisher, another clock); the experiment's name says how many;
* a run goes on over a missed sample or two (:data:`BRIDGE`): its grid holds them, filled
  by the splines through the samples either side; a longer gap splits the series into runs,
  and runs too short to fit (:data:`MIN_SAMPLES`) are dropped, as are runs in which the
  piston does not move when another run does;
* a run whose stamps jitter (a driver's timestamps) is resampled onto a uniform grid at its
  mean period by cubic splines through the samples (:func:`resample`), the position (and
  velocity) as the pressures and the load cell;
* the current of each period is the applied current the state reports where it does (our
  plant's joint ``servo_valve``), otherwise the command in force, averaged over the period,
  ``delay`` later than its stamp, counted along the driver's cycles (:func:`takeover_times`);
* a missing velocity is derived from the position by a Savitzky-Golay derivative (quadratic,
  about 5 ms wide, :func:`derivative_coefficients`) and its noise is the position's noise
  times that filter's gain; a fit compares it with the model's position through the same
  derivative (:class:`ros_ehs.core.identify.problem.Problem`), not with the model's velocity;
* a load cell (a specimen's force), where recorded, is interpolated onto the grid as the
  pressures are.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import math

import numpy as np
from ros_ehs.core.errors import DataError
from ros_ehs.core.noise import noise_sigma

__all__ = ['Experiment', 'MIN_SAMPLES', 'NoExcitation', 'Series', 'cut_experiment',
           'derivative_coefficients', 'experiment_from_arrays', 'experiments_from_series',
           'on_grid', 'require_finite', 'resample', 'run_bounds', 'sorted_by_time', 'split_runs',
           'state_rate', 'takeover_times']

#: Fewer state samples than this is "too little data" for a 7-parameter fit.
MIN_SAMPLES = 500
#: The most samples missed in a row that a run goes on over (more split the record): the
#: replay integrates across them, the grid filled by the splines through the samples either
#: side.
BRIDGE = 2
#: Width of the Savitzky-Golay derivative that derives a missing velocity [s] (>= 5 samples).
DERIVATIVE_WIDTH = 5.0e-3


@dataclass(frozen=True)
class Experiment:
    """
    One recorded run on a uniform grid: ``t`` [s], ``i`` [A], ``z`` [m], ``v`` [m/s], ...

    ``noise`` holds a known noise level [unit] per signal (the derived velocity's), used
    instead of an estimate from the signal; ``derived`` names the signals computed rather
    than measured. ``commands`` (times [s] on ``t``'s clock, values [A]) is the command
    series ``i`` was built from with ``delay`` [s], kept so the fit can try another delay
    (:meth:`with_delay`); None when ``i`` is the current the valve got. ``cycles``: the
    driver's cycles (its states' stamps [s] on ``t``'s clock) where they jitter, along which a
    delay is counted (:func:`takeover_times`); None where the grid is the stamps.
    """

    name: str
    t: np.ndarray
    i: np.ndarray
    z: np.ndarray
    v: np.ndarray
    p_a: np.ndarray | None = None
    p_b: np.ndarray | None = None
    noise: dict | None = None
    derived: tuple[str, ...] = ()
    commands: tuple[np.ndarray, np.ndarray] | None = None
    delay: float = 0.0
    p_load: np.ndarray | None = None
    t0_ns: int = 0      #: the state clock's stamp of ``t = 0`` [ns]
    #: the run starts after a gap in the recording, mid-motion: the fit settles the valve's
    #: states for the first sample instead of starting them at rest
    after_gap: bool = False
    #: the load cell [N] on the grid, where the run recorded one (a specimen's force)
    load_cell: np.ndarray | None = None
    cycles: np.ndarray | None = None
    #: the first ``warmup`` samples are replayed, not compared: they carry the states no
    #: sensor measured (the pressures of a record without them) into the samples after,
    #: where a piece cut from a run mid-motion would otherwise start from a guess
    warmup: int = 0

    @property
    def dt(self) -> float:
        """Sample period [s]."""
        return float(self.t[1] - self.t[0])

    @property
    def duration(self) -> float:
        """Length of the record [s]."""
        return float(self.t[-1] - self.t[0])

    def signals(self) -> dict[str, np.ndarray]:
        """Measured outputs by name: ``z_dot``, ``z`` and, when recorded, ``p_CP``, ``p_CT``."""
        out = {'z_dot': self.v, 'z': self.z}
        if self.p_a is not None and self.p_b is not None:
            out['p_CP'] = self.p_a
            out['p_CT'] = self.p_b
        return out

    def window(self, a: int, b: int) -> 'Experiment':
        """Return samples ``a:b`` of this run as a run of its own (its clock starts at 0)."""
        n = self.t.size
        a, b = max(0, int(a)), min(n, int(b))
        if b - a < 2:
            raise DataError(f'{self.name}: samples {a}:{b} of {n} are not a run')
        t0 = float(self.t[a])

        def cut(y):
            return None if y is None else y[a:b]

        commands = None
        if self.commands is not None:
            tc, vc = self.commands
            commands = (tc - t0, vc)
        return replace(self, name=f'{self.name}[{a}:{b}]', t=self.t[a:b] - t0, i=cut(self.i),
                       cycles=None if self.cycles is None else self.cycles - t0,
                       z=cut(self.z), v=cut(self.v), p_a=cut(self.p_a), p_b=cut(self.p_b),
                       p_load=cut(self.p_load), load_cell=cut(self.load_cell),
                       commands=commands, t0_ns=self.t0_ns + int(round(t0 * 1e9)),
                       after_gap=self.after_gap or a > 0, warmup=max(0, self.warmup - a))

    def held(self, per: int) -> np.ndarray:
        """
        Return the current held over each period in ``per`` equal pieces: (N * per,) [A].

        Piece j of period k is the mean of the command in force over it (from the commands,
        ``delay`` later along the ``cycles``, as ``i`` is built); ``per`` = 1 is ``i``'s
        periods. Where ``i`` is the current the valve got (no command series), each period's
        is repeated.
        """
        n = self.t.size - 1
        if per == 1 or self.commands is None:
            return np.repeat(self.i[:-1], per)
        edges = np.interp(np.arange(n * per + 1) / per, np.arange(n + 1), self.t)
        tc, vc = self.commands
        return _held_average(tc, vc, edges, self.delay, self.cycles)[:-1]

    def with_delay(self, delay: float) -> 'Experiment':
        """Return this run with the current rebuilt from its commands ``delay`` [s] later."""
        if self.commands is None:
            raise DataError(f'{self.name}: the current is the one the valve got; it has no '
                            'command series to delay')
        tc, vc = self.commands
        return replace(self, i=_held_average(tc, vc, self.t, delay, self.cycles),
                       delay=float(delay))


class NoExcitation(DataError):
    """A run in which the piston did not move (a hold before the trajectory started)."""


def takeover_times(tc: np.ndarray, delay: float, cycles: np.ndarray | None) -> np.ndarray:
    """
    Return when commands stamped (or received) at ``tc`` [s] take over, ``delay`` [s] later.

    A driver acts on a command at one of its cycles (ros2_control's read, update, write), so
    its delay is a number of cycles, and where its cycles jitter the delay is counted along
    them: ``tc`` is placed among the ``cycles`` (the states' stamps [s], sorted), moved on by
    ``delay`` in mean periods, and placed back. A command received a fraction of a period
    after cycle k and applied at cycle k + 1 then takes over at cycle k + 1's stamp, not up
    to the jitter away from it as ``tc + delay`` would. Without ``cycles`` (uniform stamps):
    ``tc + delay``.
    """
    tc = np.asarray(tc, dtype=float)
    if cycles is None or cycles.size < 2:
        return tc + delay
    n = cycles.size
    period = float(cycles[-1] - cycles[0]) / (n - 1)
    far = 1e9       # periods: the warp goes on at the mean period beyond the cycles
    c = np.concatenate([[cycles[0] - far * period], cycles, [cycles[-1] + far * period]])
    k = np.concatenate([[-far], np.arange(n, dtype=float), [n - 1 + far]])
    return np.interp(np.interp(tc, c, k) + delay / period, k, c)


def resample(ts: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """
    Return ``y``, sampled at ``ts`` [s] (sorted), at the times ``t`` [s]: a cubic spline.

    A driver's jittered samples onto the fit's uniform grid: the error of a straight line
    between samples is the signal's curvature times the jitter (at 250 Hz, 1.3 um of a
    piston accelerating at 1 m/s^2 and 0.8 ms off), a spline's is of the fourth order in
    the period. Beyond the samples it holds the end values; with fewer than four distinct
    stamps, stamps that repeat, or a value that is not finite, it is a straight line (a NaN
    then stays where it was, for the checks downstream to name it: a spline would spread it,
    or fail in scipy).
    """
    ts = np.asarray(ts, dtype=float)
    y = np.asarray(y, dtype=float)
    if ts.size < 4 or not np.all(np.diff(ts) > 0) or not np.all(np.isfinite(y)):
        return np.interp(t, ts, y)
    from scipy.interpolate import CubicSpline
    return CubicSpline(ts, y)(np.clip(t, ts[0], ts[-1]))


def _held_average(tc: np.ndarray, vc: np.ndarray, t: np.ndarray, delay: float,
                  cycles: np.ndarray | None = None) -> np.ndarray:
    """
    Return the mean over each period ``[t_k, t_k+1]`` of the command ``delay`` earlier.

    ``tc`` (sorted) / ``vc``: when each command was stamped (or received) and its value; it
    takes over ``delay`` later, counted along ``cycles`` (:func:`takeover_times`); before the
    first command, the first value. The last sample repeats the last period's value.
    """
    if t.size < 2:
        return np.full(t.shape, vc[0] if vc.size else math.nan)
    on = takeover_times(tc, delay, cycles)
    # the cumulative integral of the held command: piecewise linear, exact under np.interp
    edges = np.concatenate([[min(on[0], t[0]) - 1.0], on[1:], [max(on[-1], t[-1]) + 1.0]])
    area = np.concatenate([[0.0], np.cumsum(vc * np.diff(edges))])
    a = np.interp(t, edges, area)
    out = np.empty(t.shape)
    out[:-1] = np.diff(a) / np.diff(t)
    out[-1] = out[-2]
    return out


def experiment_from_arrays(name: str, t, i, z, v, p_a=None, p_b=None) -> Experiment:
    """Build and check an :class:`Experiment` from arrays (``t`` uniform, seconds)."""
    t = np.asarray(t, dtype=float)
    arrs = {'i': np.asarray(i, dtype=float), 'z': np.asarray(z, dtype=float),
            'v': np.asarray(v, dtype=float)}
    sensed = {k: np.asarray(a, dtype=float) for k, a in (('p_a', p_a), ('p_b', p_b))
              if a is not None}
    for k, a in {**arrs, **sensed}.items():
        if a.shape != t.shape:
            raise DataError(f'{name}: `{k}` has shape {a.shape}, `t` has {t.shape}')
    n = t.size
    if n < MIN_SAMPLES:
        raise DataError(f'{name}: too little data: {n} samples (need at least {MIN_SAMPLES}, '
                        f'e.g. {MIN_SAMPLES / 1000:g} s at 1 kHz)')
    dts = np.diff(t)
    dt = float(np.median(dts))
    if not dt > 0 or np.max(np.abs(dts - dt)) > 0.25 * dt:
        k = int(np.argmax(np.abs(dts - dt)))
        raise DataError(f'{name}: samples are not on a uniform grid (period {dt:g} s, but '
                        f'{dts[k]:g} s between t = {t[k]:g} and {t[k + 1]:g} s)')
    require_finite(name, t, arrs)
    if np.ptp(arrs['i']) < 1e-5 or np.ptp(arrs['z']) < 1e-4:
        raise NoExcitation(
            f'{name}: no excitation: the current spans {np.ptp(arrs["i"]):.3g} A and the '
            f'piston {np.ptp(arrs["z"]):.3g} m (need a moving piston, e.g. a 1 Hz sine of a '
            'few cm)')
    require_finite(name, t, sensed)       # a run that does not move is named first
    return Experiment(name, t - t[0], arrs['i'], arrs['z'], arrs['v'], sensed.get('p_a'),
                      sensed.get('p_b'))


def require_finite(name: str, t: np.ndarray, signals: dict) -> None:
    """
    Raise :class:`DataError` naming the first signal of ``signals`` with a value not finite.

    A NaN or infinite sample (a sensor's dropout, a driver's unset interface) is named with
    its time ``t`` [s], for every signal a fit reads: the position and velocity, the current,
    the pressures and the load cell. Let through, one NaN pressure made that signal's noise
    NaN, and so its whole residual a constant penalty: the fit dropped it without a word.
    """
    for k, a in signals.items():
        if a is not None and not np.all(np.isfinite(a)):
            j = int(np.flatnonzero(~np.isfinite(a))[0])
            raise DataError(f'{name}: `{k}` is not finite at t = {t[j]:g} s')


def state_rate(experiments) -> float:
    """Return the slowest state rate of ``experiments`` [Hz] (the rate the verdict judges)."""
    return min(1.0 / e.dt for e in experiments)


def on_grid(ts: np.ndarray) -> np.ndarray:
    """
    Return the mask of the states on the record's sample grid (sorted, distinct stamps [ns]).

    A state closer than 0.45 of the median period to the one kept before it is a stranger (a
    stray publisher, another clock, a replay into a live bench) and is dropped.
    """
    keep = np.ones(ts.size, dtype=bool)
    d = np.diff(ts)
    if d.size == 0:
        return keep
    close = 0.45 * np.median(d)
    if not np.any(d < close):
        return keep
    last = ts[0]
    for j in range(1, ts.size):
        if ts[j] - last < close:
            keep[j] = False
        else:
            last = ts[j]
    return keep


def sorted_by_time(t: np.ndarray, *vals: np.ndarray):
    """
    Return ``t`` and ``vals`` sorted by ``t``, a repeated time kept once (its first sample).

    A lock-step plant resends a state it has no answer to, stamped as before, and its
    sensors with it: the same sample again, not a new one (two samples at one time made the
    noise's divided differences divide by zero).
    """
    o = np.argsort(t, kind='stable')
    t = t[o]
    keep = np.concatenate([[True], np.diff(t) > 0]) if t.size else np.zeros(0, bool)
    return (t[keep],) + tuple(v[o][keep] for v in vals)


@dataclass
class Series:
    """Time series of one source (a bag, the live loop) on the state's clock [ns]."""

    name: str
    ts: np.ndarray
    z: np.ndarray
    v: np.ndarray
    applied: np.ndarray
    tc: np.ndarray
    vc: np.ndarray
    pressures: list        # [(t [ns], Pa)] per chamber, one (load), or none
    load: bool
    delay: float
    cell: tuple | None = None     # the load cell: (t [ns], N), or None


def _savgol_width(dt: float) -> int:
    n = max(3, int(round(DERIVATIVE_WIDTH / dt)))
    return n + 1 - n % 2


def derivative_coefficients(dt: float) -> np.ndarray:
    """
    Return the convolution coefficients that derive a missing velocity from positions ``dt`` apart.

    ``np.convolve(z, c, 'valid')`` is the velocity at the middle sample of each window: the
    derivative :func:`cut_experiment` applies to a run (away from its ends).
    """
    from scipy.signal import savgol_coeffs
    return savgol_coeffs(_savgol_width(dt), 2, deriv=1, delta=dt, use='conv')


def cut_experiment(rec: Series, a: int, b: int, name: str) -> Experiment:
    """Build the experiment of samples ``a:b`` (one contiguous run)."""
    ts = rec.ts[a:b]
    span = (ts - ts[0]) * 1e-9
    dts = np.diff(span)
    z, v, applied = rec.z[a:b], rec.v[a:b], rec.applied[a:b]
    # each stamp's cycle: a gap of k + 1 periods is k missed samples (BRIDGE at most)
    period = float(np.median(dts)) if dts.size else 1e-3
    steps = np.maximum(1, np.rint(dts / period)).astype(np.int64)
    idx = np.concatenate([[0], np.cumsum(steps)])
    n_grid = int(idx[-1]) + 1
    dt = float(span[-1] / (n_grid - 1)) if span.size > 1 else 1e-3
    exact = dts.size == 0 or float(np.max(np.abs(dts - steps * period))) <= 1e-6 * period
    # each measured signal's noise, on its raw samples, before the grid averages neighbours
    noise = {'z': noise_sigma(z, span)}
    if np.all(np.isfinite(v)):
        noise['z_dot'] = noise_sigma(v, span)
    if rec.cell is not None:
        tl, fl = rec.cell
        m = (tl >= ts[0]) & (tl <= ts[-1])
        if m.sum() >= 8:
            noise['load_cell'] = noise_sigma(fl[m], (tl[m] - ts[0]) * 1e-9)
    for key, (tp, pv) in zip(('p_CP', 'p_CT') if not rec.load else ('p_L',), rec.pressures):
        m = (tp >= ts[0]) & (tp <= ts[-1])
        if m.sum() >= 8:
            noise[key] = noise_sigma(pv[m], (tp[m] - ts[0]) * 1e-9)
    cycles = None
    if exact and n_grid == span.size:
        t = span
    else:        # a driver's jittered stamps, or missed samples: onto a uniform grid
        t = np.arange(n_grid) * dt
        z = resample(span, z, t)
        v = resample(span, v, t) if np.all(np.isfinite(v)) else np.full(t.shape, np.nan)
        if exact:        # the missed samples' current: between their neighbours'
            applied = np.interp(np.arange(n_grid), idx, applied)
        else:            # the driver's cycles, a missed sample's where it would have been
            applied = np.full(t.shape, np.nan)
            cycles = np.interp(np.arange(n_grid), idx, span)
    t0_ns = int(ts[0])
    commands = None
    if applied.size > 1 and np.all(np.isfinite(applied)):
        # state k reports the current of the period that ended at it: shift by one
        c = np.append(applied[1:], applied[-1])
    else:
        tc = (rec.tc - t0_ns) * 1e-9
        commands = (tc, rec.vc)
        first = tc[0] + rec.delay        # no command in force before this
        k0 = int(np.searchsorted(t, first - 1e-12))
        if k0 and t.size - k0 < MIN_SAMPLES:     # (nearly) all before the first command
            raise NoExcitation(f'{name}: {k0} of its {t.size} samples come before the first '
                               'command; too few are left')
        if k0:
            t0_ns += int(round(float(t[k0]) * 1e9))
            t, z, v = t[k0:] - t[k0], z[k0:], v[k0:]
            shift = (t0_ns - int(ts[0])) * 1e-9
            commands = (tc - shift, rec.vc)
            cycles = None if cycles is None else cycles - shift
        c = _held_average(commands[0], commands[1], t, rec.delay, cycles)
    derived = ()
    if not np.all(np.isfinite(v)) and np.all(np.isfinite(z)) and t.size >= 5:
        from scipy.signal import savgol_coeffs, savgol_filter
        w = min(_savgol_width(dt), t.size - (1 - t.size % 2))
        v = savgol_filter(z, w, 2, deriv=1, delta=dt, mode='interp')
        gain = float(np.sqrt(np.sum(savgol_coeffs(w, 2, deriv=1) ** 2))) / dt
        noise['z_dot'], derived = noise['z'] * gain, ('z_dot',)

    # the sensed signals' own samples over the run: a run that does not move is named first
    # (split_runs skips it, whatever its pressures), then a sample that is not finite, at its
    # own time rather than the grid's
    raw = dict(zip(('p_load',) if rec.load else ('p_a', 'p_b'),
                   (_near(tp, pv, ts, t0_ns) for tp, pv in rec.pressures)))
    if rec.cell is not None and rec.cell[0].size >= 2:
        raw['load_cell'] = _near(*rec.cell, ts, t0_ns)
    e = experiment_from_arrays(name, t, c, z, v)
    for key, (tx, vx) in raw.items():
        require_finite(name, tx, {key: vx})
    grid = {key: resample(tx, vx, t) for key, (tx, vx) in raw.items()}
    return replace(e, noise=noise, derived=derived, commands=commands, delay=rec.delay,
                   p_a=grid.get('p_a'), p_b=grid.get('p_b'), p_load=grid.get('p_load'),
                   t0_ns=t0_ns, after_gap=a > 0, load_cell=grid.get('load_cell'),
                   cycles=None if commands is None else cycles)


def _near(tx: np.ndarray, vx: np.ndarray, ts: np.ndarray, t0_ns: int) -> tuple:
    """Return the samples ``tx`` [ns] / ``vx`` over stamps ``ts`` (4 beyond each end), [s]."""
    a = max(0, int(np.searchsorted(tx, ts[0])) - 4)
    b = int(np.searchsorted(tx, ts[-1], side='right')) + 4
    return (tx[a:b] - t0_ns) * 1e-9, vx[a:b]


def run_bounds(ts: np.ndarray) -> tuple[list[tuple[int, int]], list[int]]:
    """Return the (start, end) index pairs of the gapless runs of stamps ``ts``, and the cuts."""
    d = np.diff(ts)
    cuts = np.flatnonzero(d > (BRIDGE + 1.5) * np.median(d)) + 1 if d.size else \
        np.array([], int)
    edges = [0, *cuts.tolist(), ts.size]
    return list(zip(edges[:-1], edges[1:])), cuts.tolist()


def experiments_from_series(name: str, ts, z, v, applied=None, commands=None,
                            pressures=(), load: bool = False,
                            delay: float = 0.0, cell=None) -> list[Experiment]:
    """
    Cut the contiguous runs of series held in memory, as :func:`load_experiments` cuts a bag's.

    What a live refit fits: ``ts`` [ns] are the states' stamps (sorted or not) with position
    ``z`` [m], velocity ``v`` [m/s] (NaN: derived from the position) and ``applied`` current
    [A] (NaN or None: unknown, then ``commands`` = (stamps [ns, the state's clock], currents
    [A]) held ``delay`` [s] later are used); ``pressures``: (stamps [ns], values [Pa]) per
    chamber, or one load pressure with ``load``; ``cell``: the load cell's (stamps [ns],
    values [N]) or None. Raises :class:`DataError` as the bag path does (too little data, no
    excitation).
    """
    ts = np.asarray(ts, dtype=np.int64)
    z = np.asarray(z, dtype=float)
    v = np.asarray(v, dtype=float)
    applied = np.full(z.shape, np.nan) if applied is None else np.asarray(applied, float)
    ts, z, v, applied = sorted_by_time(ts, z, v, applied)
    tc, vc = (np.zeros(0, np.int64), np.zeros(0)) if commands is None else (
        np.asarray(commands[0], dtype=np.int64), np.asarray(commands[1], dtype=float))
    if ts.size < 2 or (tc.size == 0 and not np.all(np.isfinite(applied))):
        raise DataError(f'{name}: too little data: {ts.size} states and {tc.size} commands')
    tc, vc = sorted_by_time(tc, vc)
    press = [sorted_by_time(np.asarray(t, dtype=np.int64), np.asarray(p, dtype=float))
             for t, p in pressures]
    if cell is not None:
        cell = sorted_by_time(np.asarray(cell[0], dtype=np.int64),
                              np.asarray(cell[1], dtype=float))
    return split_runs(Series(name, ts, z, v, applied, tc, vc, press, load, float(delay),
                             cell))


def split_runs(rec: Series) -> list[Experiment]:
    """Return the experiments of a record's contiguous runs (see :func:`load_experiments`)."""
    runs, cuts = run_bounds(rec.ts)
    long_ = [(a, b) for a, b in runs if b - a >= MIN_SAMPLES]
    if not long_:
        longest = max(b - a for a, b in runs)
        raise DataError(f'{rec.name}: too little data: the longest run without missing '
                        f'samples has {longest} samples (need at least {MIN_SAMPLES}); '
                        f'{len(cuts)} gaps')
    if len(long_) == 1:
        return [cut_experiment(rec, *long_[0], rec.name)]
    out, still = [], []
    for k, (a, b) in enumerate(long_):
        try:
            out.append(cut_experiment(rec, a, b, f'{rec.name} [{k + 1}/{len(long_)}]'))
        except NoExcitation as err:      # e.g. the hold before the reference started
            still.append(str(err))
    if not out:
        raise DataError(f'{rec.name}: no run moves the piston: ' + '; '.join(still))
    return out
