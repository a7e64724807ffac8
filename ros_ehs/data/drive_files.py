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
Drive files and their runs: CSVs, bags, players in process, and the iteration that plays them.

Drives are saved as CSV (``t [s], z [m]``, :func:`save_drive`): the reference node plays one
with ``kind: csv``. :func:`iterate` plays each run through a player: :class:`InProcessPlayer`
(the simulated loop in process) or :class:`ros_ehs.nodes.drive_bench.BenchPlayer` (the
bench's nodes over DDS); either keeps each run as a bag and its drive as a CSV, and
:func:`run_from_bag` reads a run back. The mathematics (FRF, inverse, update) is
:mod:`ros_ehs.core.control.drive`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ros_ehs.core.control.drive import (band_error, band_rms_error_pct, DriveIteration, frf,
                                        multisine, rms_error_pct, target_band)
from ros_ehs.core.control.waveforms import CsvTrajectory, Samples
from ros_ehs.core.errors import DataError, InputError

__all__ = ['InProcessPlayer', 'frf_from_bag', 'iterate', 'lead_in', 'load_drive', 'record_run',
           'run_from_bag', 'save_drive']

T0_NS = 1_700_000_000_000_000_000     # the bags' epoch, so equal runs give equal bags
#: a disturbed run is played again this many times at most
REPLAYS = 2
#: each run holds the drive's first value this long before it [s]: the axis ramps onto its
#: trajectory over its first second (``ramp_time``), which would scale a drive's start
LEAD_IN = 1.5


def lead_in(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Return ``t``, ``x`` after ``LEAD_IN`` at the drive's first value, and its samples."""
    fs = 1.0 / float(np.median(np.diff(t)))
    n = int(round(LEAD_IN * fs))
    tt = np.arange(n + t.size) / fs
    return tt, np.concatenate([np.full(n, x[0]), x]), n


def save_drive(path: str | os.PathLike, t, z) -> Path:
    """Write a drive (or target) as CSV: a header ``t,z``, then rows of ``t [s], z [m]``."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(p, np.column_stack([t, z]), delimiter=',', header='t,z', comments='',
               fmt='%.17g')        # every bit: the drive played is the drive computed
    return p


def load_drive(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a drive CSV written by :func:`save_drive` (or any ``t, z`` CSV with a header)."""
    c = CsvTrajectory(path)
    return c.t, c.z


def record_run(path: str | os.PathLike, run) -> Path:
    """Write a closed-loop run as a bag: ``reference`` (the drive) and ``state`` per period."""
    import ros_ehs_msgs_py as contract
    from ros_ehs.data.bag.writer import BagWriter
    msg = {tp.name: contract.empty_msg(tp.msg_type)
           for tp in (contract.REFERENCE, contract.STATE)}
    with BagWriter(path) as bag:
        for tp in (contract.REFERENCE, contract.STATE):
            bag.add_topic('/' + tp.name, tp.msg_type, tp.qos)
        for k in range(run.t.size - 1):
            ns = T0_NS + int(round(run.t[k] * 1e9))
            bag.write_msg('/reference', contract.fill_reference(msg['reference'], (
                contract.Reference(ns, float(run.z_ref[k]), float(run.v_ref[k])))), ns)
            bag.write_msg('/state', contract.fill_state(msg['state'], contract.AxisState(
                ns, float(run.z[k]), float(run.z_dot[k]))), ns)
    return Path(path)


def run_from_bag(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Return ``(t [s], reference [m], response [m])`` of a recorded run, per period.

    The reference from ``reference_trajectory`` (lock-step: the window the controller read)
    or ``reference``; time zero its first sample; the measured position on ``state`` at each
    reference sample (interpolated between states in real time, where the stamps differ).
    """
    import ros_ehs_msgs_py as contract
    from ros_ehs.data.bag.reader import open_bag
    bag = open_bag(path)
    refs: dict[int, float] = {}
    if '/reference_trajectory' in bag.topics:
        for _, m in bag.decoded(['/reference_trajectory']):
            for r in contract.reference_trajectory_from_msg(m):
                refs.setdefault(r.stamp_ns, r.z_ref)
    if '/reference' in bag.topics:
        for _, m in bag.decoded(['/reference']):
            r = contract.reference_from_msg(m)
            refs.setdefault(r.stamp_ns, r.z_ref)
    if not refs or '/state' not in bag.topics:
        raise DataError(f'{path}: a run needs reference (or reference_trajectory) and state; '
                        f'it has: {bag.describe()}')
    states = {}
    for _, m in bag.decoded(['/state']):
        s = contract.state_from_msg(m)
        states[s.stamp_ns] = s.z
    ks = np.array(sorted(states))
    rs = np.array(sorted(refs))
    rs = rs[(rs >= ks[0]) & (rs <= ks[-1])] if ks.size else rs[:0]
    if rs.size < 64:
        raise DataError(f'{path}: {rs.size} reference samples within the recorded states')
    y = np.interp(rs, ks, [states[k] for k in ks])
    t0 = min(refs)
    return (rs - t0) * 1e-9, np.array([refs[k] for k in rs]), y


def frf_from_bag(path: str | os.PathLike, nperseg: int | None = None):
    """Return ``(f, H, coherence, fs)`` of a recorded broadband run: the reference -> ``state``."""
    t, ref, y = run_from_bag(path)
    fs = 1.0 / float(np.median(np.diff(t)))
    f, h, coh = frf(ref, y, fs, nperseg)
    return f, h, coh, fs


class InProcessPlayer:
    """
    Play drives on the simulated loop in process, each run a bag under ``out``.

    The loop is the bench's, safety layer and ramp-on included (``supervised``), so a bench
    run in lock-step is this one to 1e-9 m: the drive is played from the CSV it was saved to,
    after ``LEAD_IN`` at its first value (the ramp-on), which the response leaves out.
    """

    def __init__(self, plant_params, out: str | os.PathLike, *, controller_params=None,
                 model: str = 'full') -> None:
        self.plant_params, self.controller_params = plant_params, controller_params
        self.model, self.out = model, Path(out)

    def __call__(self, name: str, t: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Play drive ``x`` at times ``t`` as run ``name``; return the response on ``t``."""
        from ros_ehs.core.sim.closed_loop import run_closed_loop
        tt, xx, n = lead_in(np.asarray(t, dtype=float), np.asarray(x, dtype=float))
        tt, xx = load_drive(save_drive(self.out / f'{name}.csv', tt, xx))
        fs = 1.0 / float(np.median(np.diff(tt)))
        run = run_closed_loop(self.plant_params, Samples(tt, xx), tt.size / fs,
                              model=self.model, controller_params=self.controller_params,
                              dt=1.0 / fs, supervised=True)
        record_run(self.out / name, run)
        return run.z[n:-1]


def iterate(play, target_t, target_z, out: str | os.PathLike, *, iterations: int = 6,
            rms_target_pct: float = 1.0, frf_bag: str | os.PathLike | None = None,
            beta: float = 0.8, progress=None, band=None) -> dict:
    """
    Iterate a drive for a target; ``play(name, t, drive)`` plays each run and records it.

    ``play``: an :class:`InProcessPlayer` or a :class:`BenchPlayer`, which keep each run as a
    bag and its drive as a CSV under ``out``. ``frf_bag``: a recorded broadband run to take the
    FRF from (default: play a multisine as long as the target as run ``broadband``, over
    ``band``: (f_lo, f_hi) [Hz], ``'auto'`` the band the target's spectrum needs
    (:func:`~ros_ehs.core.control.drive.target_band`, its tails under a tenth of
    ``rms_target_pct``), or None 0.2-40 Hz).

    The result says where the drive cannot act: ``uncovered_pct`` (the target's content
    outside the FRF's coherent band, % of its RMS), ``warnings`` (that content, and the
    ranges in the band where the coherence is low and the target has content), and the
    best run's error overall and in the band (``band_rms_err_pct``).

    Plays ``target_pass`` (the target as it is) and ``iteration_<k>``, writes
    ``out/drive.csv`` (the best drive) and returns the RMS errors [%] (first pass, then each
    iteration) and the runs played again (``replayed``: a player's ``disturbed`` named them).
    ``progress(k, rms_pct)`` after each iteration, ``progress(run, why)`` for a replay.
    """
    out = Path(out)
    old = sorted(p.name for p in out.glob('*') if p.name in ('broadband', 'target_pass')
                 or p.name.startswith('iteration_')) if out.is_dir() else []
    if old:
        raise DataError(f'{out} holds runs already ({", ".join(old)}): give another folder '
                        'or remove them')
    t = np.asarray(target_t, dtype=float)
    r = np.asarray(target_z, dtype=float)
    fs = 1.0 / float(np.median(np.diff(t)))
    replays = []

    def run(name, x):
        # a run the player marks disturbed (a watchdog trip on the bench) is not learnt
        # from: it is played again, twice at most, each time as a run of its own
        for attempt in range(1 + REPLAYS):
            title = name if attempt == 0 else f'{name}_again_{attempt}'
            y = play(title, t, x)
            why = getattr(play, 'disturbed', {}).get(title)
            if why is None:
                return y
            replays.append(f'{title}: {why}')
            if progress is not None:
                progress(title, why)
        raise DataError(f'run {name}: disturbed {1 + REPLAYS} times ({"; ".join(replays)})')

    given = band is not None
    if band == 'auto':
        band = target_band(r, fs, 0.1 * rms_target_pct)
    f_lo, f_hi = band if given else (0.2, min(40.0, 0.4 * fs))
    if not 0 < f_lo < f_hi < fs / 2:
        raise InputError(f'the band {f_lo:g}-{f_hi:g} Hz must lie in (0, {fs / 2:g}) Hz')
    if frf_bag is None:
        # not below 0.2 Hz: the loop holds slow content itself, and a multisine flat in
        # velocity over more decades leaves its top too weak to measure
        _, d = multisine(t.size / fs, fs, max(f_lo, min(0.2, 0.5 * f_hi)), f_hi, 0.08, seed=2)
        # a band asked for is measured whole (its velocity density); the inverse acts in it
        f, h, coh = frf(d, run('broadband', d), fs, velocity=given)
    else:
        f, h, coh, _ = frf_from_bag(frf_bag)
    errs = [rms_error_pct(r, run('target_pass', r))]
    it = DriveIteration(r, fs, f, h, beta=beta, coherence=coh,
                        band_hz=(f_lo, f_hi) if given else None)
    warnings = _coverage(it, r, fs, f, coh, rms_target_pct)
    drive, best = it.first(), (np.inf, None, None)
    for k in range(1, iterations + 1):
        y = run(f'iteration_{k}', drive)
        errs.append(rms_error_pct(r, y))
        if progress is not None:
            progress(k, errs[-1])
        if errs[-1] < best[0]:
            best = (errs[-1], drive, y)
        if errs[-1] <= rms_target_pct:
            break
        drive = it.update(drive, y)
    save_drive(out / 'drive.csv', t, best[1])
    db, deg = band_error(r, y, fs, 0.5, min(20.0, 0.4 * fs))
    return {'rms_err_pct': errs, 'best_pct': best[0], 'band_db_max': db, 'band_deg_max': deg,
            'drive': str(out / 'drive.csv'), 'replayed': replays, 'band_hz': [f_lo, f_hi],
            'band_rms_err_pct': band_rms_error_pct(r, best[2], fs, f_lo, f_hi),
            'uncovered_pct': it.uncovered_pct(), 'warnings': warnings}


def _coverage(it: DriveIteration, r, fs: float, f, coh, rms_target_pct: float) -> list[str]:
    """Say where the target has content the drive cannot act on (see :func:`iterate`)."""
    out = []
    un = it.uncovered_pct()
    if un > 0.1 * rms_target_pct:
        out.append(f'{un:.3g} % of the target (RMS) lies where the FRF is not known (coherence '
                   f'under {it.min_coherence:g}): the iteration cannot correct it; the RMS '
                   f'error stays above about that much')
    spec = np.abs(np.fft.rfft(r - r.mean()))
    fr = np.fft.rfftfreq(r.size, 1.0 / fs)
    has = np.interp(f, fr, spec) >= 0.01 * spec.max()
    low = (np.asarray(coh) < it.min_coherence) & has & (f > 0)
    if low.any():
        edges = np.flatnonzero(np.diff(np.concatenate([[0], low.astype(int), [0]])))
        spans = [f'{f[a]:.3g}-{f[b - 1]:.3g} Hz' for a, b in zip(edges[::2], edges[1::2])]
        out.append('low coherence where the target has content: ' + ', '.join(spans[:8]) +
                   (' ...' if len(spans) > 8 else ''))
    return out
