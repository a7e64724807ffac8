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
Drive-file iteration: make the axis reproduce a measured time history (ROS-free).

What road-load simulation does (time waveform replication): the loop does not follow an
arbitrary target ``r(t)`` by itself, so the command ("drive") is built from the loop's own
frequency response and refined by playing it:

1. **FRF**: play a broadband drive (a random-phase multisine), record it, and estimate the
   loop's frequency response ``H(f) = S_dy / S_dd`` (Welch over segments of a quarter of the
   run, 4 s at most; :func:`frf`, from arrays or a bag of the run: ``reference`` is the
   drive, ``state`` the response);
2. **inverse**: ``G = conj(H) / (|H|^2 + lam max|H|^2)`` (Tikhonov-regularised, so bins
   where the loop hardly responds do not blow up; ``lam`` 1e-3), only in the bins where the
   target has content (outside them the error is the loop's own distortion, which an
   inverse would feed back and grow: it diverged after 3 iterations without);
3. **iterate**: ``d_0 = F^-1(G F(r))``; play ``d_k``, record ``y_k``, then
   ``d_k+1 = d_k + beta F^-1(G F(r - y_k))`` (``beta`` 0.8), until the RMS error is at
   most ``target_pct`` of the target's RMS or ``iterations`` runs were played.

Drives are saved as CSV (``t [s], z [m]``, :func:`save_drive`): the reference node plays one
with ``kind: csv``. Targets and drives start and end at rest (a cosine taper), so the
circular FFT sees no jump at the wrap. :func:`iterate` plays each run through a player:
:class:`InProcessPlayer` (the simulated loop in process) or :class:`BenchPlayer` (the bench's
nodes over DDS, lock-step or real time); either keeps each run as a bag and its drive as a
CSV, and :func:`run_from_bag` reads a run back.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import os
from pathlib import Path
import time

import numpy as np

from ros_ehs.errors import DataError, InputError
from ros_ehs.reference import CsvTrajectory, Samples

__all__ = ['BenchPlayer', 'DriveIteration', 'InProcessPlayer', 'Samples', 'band_error', 'frf',
           'frf_from_bag', 'iterate', 'load_drive', 'multisine', 'record_run', 'rms_error_pct',
           'run_from_bag', 'save_drive']

T0_NS = 1_700_000_000_000_000_000     # the bags' epoch, so equal runs give equal bags
#: a disturbed run is played again this many times at most
REPLAYS = 2
#: each run holds the drive's first value this long before it [s]: the axis ramps onto its
#: trajectory over its first second (``ramp_time``), which would scale a drive's start
LEAD_IN = 1.5


def _lead_in(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    fs = 1.0 / float(np.median(np.diff(t)))
    n = int(round(LEAD_IN * fs))
    tt = np.arange(n + t.size) / fs
    return tt, np.concatenate([np.full(n, x[0]), x]), n


def _taper(n: int, fs: float, seconds: float) -> np.ndarray:
    w = np.ones(n)
    k = min(n // 2, int(round(seconds * fs)))
    if k > 0:
        ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(k) / k)
        w[:k] = ramp
        w[n - k:] = ramp[::-1]
    return w


def multisine(duration: float, fs: float, f_lo: float, f_hi: float, v_rms: float,
              seed: int = 0, taper: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """
    Return ``(t, z)``: a displacement whose velocity spectrum is flat over [f_lo, f_hi].

    Random phases (``seed``), velocity RMS ``v_rms`` [m/s] over the untapered middle; the ends
    are tapered over ``taper`` s to rest at zero.
    """
    n = int(round(duration * fs))
    if n < 16 or not 0 < f_lo < f_hi < fs / 2:
        raise InputError(f'multisine: need 16 samples or more and 0 < f_lo < f_hi < fs/2 '
                         f'(got {n} samples, {f_lo}-{f_hi} Hz at {fs} Hz)')
    rng = np.random.default_rng(seed)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    band = (f >= f_lo) & (f <= f_hi)
    spec = np.zeros(f.size, complex)
    spec[band] = np.exp(2j * np.pi * rng.random(band.sum())) / (2j * np.pi * f[band])
    z = np.fft.irfft(spec, n) * _taper(n, fs, taper)
    z -= z[0]
    t = np.arange(n) / fs
    v = np.gradient(z, t)
    mid = _taper(n, fs, taper) == 1.0
    if mid.sum() < n // 4:         # a record too short for its tapers: all of it
        mid[:] = True
    z *= v_rms / np.sqrt(np.mean(v[mid] ** 2))
    return t, z


def frf(drive, response, fs: float, nperseg: int | None = None
        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Return ``(f, H, coherence)``: the H1 estimate of the response over the drive.

    Zero where the drive carried no energy (below 1e-4 of its peak spectral density).
    """
    from scipy.signal import coherence, csd, welch
    d = np.asarray(drive, dtype=float)
    y = np.asarray(response, dtype=float)
    if d.shape != y.shape or d.size < 64 or not (np.all(np.isfinite(d))
                                                 and np.all(np.isfinite(y))):
        raise DataError('frf: the drive and the response need one finite value each per '
                        f'sample, 64 or more (got {d.shape}, {y.shape})')
    nperseg = nperseg or min(d.size // 4, int(4 * fs))
    f, sdd = welch(d, fs, nperseg=nperseg)
    _, sdy = csd(d, y, fs, nperseg=nperseg)
    _, coh = coherence(d, y, fs, nperseg=nperseg)
    # only where the drive put energy (1e-4 of its peak density): elsewhere the ratio is
    # noise over nothing, and the inverse must not act there
    live = sdd > 1e-4 * sdd.max()
    h = np.where(live, sdy / np.where(live, sdd, 1.0), 0.0)
    return f, h, np.where(live, coh, 0.0)


def rms_error_pct(target, response) -> float:
    """Return the RMS of ``target - response`` over the RMS of ``target`` [%]."""
    r = np.asarray(target, dtype=float)
    return float(np.sqrt(np.mean((r - np.asarray(response)) ** 2)) / np.sqrt(np.mean(r ** 2))
                 * 100.0)


def band_error(target, response, fs: float, f_lo: float, f_hi: float) -> tuple[float, float]:
    """
    Return the worst |gain| [dB] and |phase| [deg] of response over target in the band.

    Over the bins that carry 1 % or more of the target's largest amplitude there, in the
    FFT of the whole records.
    """
    r = np.fft.rfft(np.asarray(target, dtype=float))
    y = np.fft.rfft(np.asarray(response, dtype=float))
    f = np.fft.rfftfreq(len(target), 1.0 / fs)
    band = (f >= f_lo) & (f <= f_hi)
    strong = band & (np.abs(r) >= 0.01 * np.abs(r[band]).max())
    ratio = y[strong] / r[strong]
    return (float(np.abs(20 * np.log10(np.abs(ratio))).max()),
            float(np.abs(np.degrees(np.angle(ratio))).max()))


@dataclass
class DriveIteration:
    """
    Iterate a drive for ``target`` (samples at ``fs``) from the loop's FRF ``(f_h, h)``.

    ``history`` holds the RMS error [%] of each response given to :meth:`update`.
    """

    target: np.ndarray
    fs: float
    f_h: np.ndarray
    h: np.ndarray
    beta: float = 0.8
    lam: float = 1e-3
    coherence: np.ndarray | None = None
    min_coherence: float = 0.9
    history: list = field(default_factory=list)

    def __post_init__(self) -> None:
        """Build the regularised inverse on the target's FFT grid."""
        self.target = np.asarray(self.target, dtype=float)
        if not 0 < self.beta <= 1:
            raise InputError(f'`beta` = {self.beta!r} must be in (0, 1]')
        if not self.lam > 0:
            raise InputError(f'`lam` = {self.lam!r} must be > 0')
        n = self.target.size
        f = np.fft.rfftfreq(n, 1.0 / self.fs)
        hr = np.interp(f, self.f_h, self.h.real)
        hi = np.interp(f, self.f_h, self.h.imag)
        h = hr + 1j * hi
        # act only where the FRF is known: the coherence of the broadband run over
        # ``min_coherence`` (or, without it, where the target has content: 1e-3 of its
        # strongest bin). Elsewhere an inverse feeds the loop's own distortion back and
        # grows it: unlimited, the iteration diverged after 3 runs
        if self.coherence is not None:
            self.band = np.interp(f, self.f_h, self.coherence) >= self.min_coherence
        else:
            spec = np.abs(np.fft.rfft(self.target))
            self.band = spec >= 1e-3 * spec.max()
        peak = np.abs(h[self.band]).max() if self.band.any() else 1.0
        self.g = np.where(self.band, np.conj(h) / (np.abs(h) ** 2 + self.lam * peak ** 2),
                          0.0)

    def _apply(self, x: np.ndarray) -> np.ndarray:
        return np.fft.irfft(self.g * np.fft.rfft(x), self.target.size)

    def first(self) -> np.ndarray:
        """Return the first drive: the inverse applied to the target."""
        return self._apply(self.target)

    def update(self, drive: np.ndarray, response: np.ndarray) -> np.ndarray:
        """Record ``response`` to ``drive``; return the next drive."""
        e = self.target - np.asarray(response, dtype=float)
        self.history.append(rms_error_pct(self.target, response))
        return np.asarray(drive, dtype=float) + self.beta * self._apply(e)


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
    from ros_ehs.bag.writer import BagWriter
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
    from ros_ehs.bag.reader import open_bag
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
        from ros_ehs.sim.closed_loop import run_closed_loop
        tt, xx, n = _lead_in(np.asarray(t, dtype=float), np.asarray(x, dtype=float))
        tt, xx = load_drive(save_drive(self.out / f'{name}.csv', tt, xx))
        fs = 1.0 / float(np.median(np.diff(tt)))
        run = run_closed_loop(self.plant_params, Samples(tt, xx), tt.size / fs,
                              model=self.model, controller_params=self.controller_params,
                              dt=1.0 / fs, supervised=True)
        record_run(self.out / name, run)
        return run.z[n:-1]


class BenchPlayer:
    """
    Play drives on the bench's nodes over DDS, each run a bag under ``out``.

    For each run the recorder, controller, reference (``kind: csv``, the drive's CSV) and
    plant start (:meth:`ros_ehs.processes.NodeProcesses.start_loop`), in ``mode`` lock-step
    (faster than real time, the in-process loop's figures to 1e-9 m) or real time; the
    response is read back from the run's bag. ``plant``, ``controller``: the nodes' parameters
    (e.g. a parameter preset and the plant's model). A run in which the plant's watchdog
    zeroed the valve more than ``max_trips`` times (real time: late commands; each moves the
    piston on for a few ms unheld, 0.2 mm at 0.08 m/s) is marked in ``disturbed``, and
    :func:`iterate` plays it again rather than learn from it.
    """

    def __init__(self, out: str | os.PathLike, *, mode: str = 'lockstep',
                 plant: dict | None = None, controller: dict | None = None,
                 domain_id: int | None = None, timeout: float = 120.0,
                 max_trips: int = 2) -> None:
        if mode not in ('lockstep', 'realtime'):
            raise InputError(f'`mode` = {mode!r} is not lockstep or realtime')
        self.out, self.mode = Path(out), mode
        self.plant, self.controller = dict(plant or {}), dict(controller or {})
        self.domain_id, self.timeout = domain_id, timeout
        self.max_trips = int(max_trips)
        #: per run: the plant's watchdog trips, and why its response is not the loop's or None
        self.trips: dict[str, int] = {}
        self.disturbed: dict[str, str | None] = {}

    def __call__(self, name: str, t: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Play drive ``x`` at times ``t`` as run ``name``; return the response on ``t``."""
        import ros_ehs_msgs_py as contract
        from ros_ehs.errors import EhsError
        from ros_ehs.processes import NodeProcesses
        tt, xx, n = _lead_in(np.asarray(t, dtype=float), np.asarray(x, dtype=float))
        csv = save_drive(self.out / f'{name}.csv', tt, xx)
        fs = 1.0 / float(np.median(np.diff(tt)))
        duration = tt.size / fs
        lock = self.mode == 'lockstep'
        bag = self.out / name
        with NodeProcesses(self.domain_id, self.out / 'logs' / name) as procs:
            procs.start_loop(self.mode, bag=bag,
                             plant={'duration': duration, **self.plant} if lock else self.plant,
                             controller=self.controller,
                             reference={'kind': 'csv', 'csv_path': str(csv), 'rate_hz': fs,
                                        'duration': duration},
                             timeout=self.timeout)
            if lock:
                done = procs.wait_status(contract.PLANT_STATUS,
                                         lambda st: 'complete' in st.message, self.timeout)
            else:
                done = procs.wait_status(
                    contract.REFERENCE_STATUS,
                    lambda st: float(st.values.get('time_s', 0)) > duration + 0.2,
                    duration + self.timeout)
            time.sleep(0.5)           # the last messages on their way to the recorder
            codes = procs.stop(['recorder', 'reference', 'controller', 'plant'])
            figures = procs['plant'].figures() if codes.get('plant') == 0 else {}
        if not done or any(codes.values()):
            raise EhsError(f'run {name}: the bench did not finish it (exit codes {codes}; '
                           f'logs in {self.out / "logs" / name})')
        trips = int(figures.get('watchdog_trips', 0))
        self.trips[name] = trips
        self.disturbed[name] = (f"the plant's watchdog zeroed the valve {trips} times (at "
                                f'most {self.max_trips})' if trips > self.max_trips else None)
        tr, _, y = run_from_bag(bag)
        if tr[-1] < tt[-1] - 0.5 / fs:
            raise DataError(f'{bag}: the run covers {tr[-1]:.3f} s of the {tt[-1]:.3f} s drive')
        return np.interp(tt, tr, y)[n:]


def iterate(play, target_t, target_z, out: str | os.PathLike, *, iterations: int = 6,
            rms_target_pct: float = 1.0, frf_bag: str | os.PathLike | None = None,
            beta: float = 0.8, progress=None) -> dict:
    """
    Iterate a drive for a target; ``play(name, t, drive)`` plays each run and records it.

    ``play``: an :class:`InProcessPlayer` or a :class:`BenchPlayer`, which keep each run as a
    bag and its drive as a CSV under ``out``. ``frf_bag``: a recorded broadband run to take the
    FRF from (default: play a 0.2-40 Hz multisine as long as the target as run
    ``broadband``). Plays ``target_pass`` (the target as it is) and ``iteration_<k>``, writes
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

    if frf_bag is None:
        _, d = multisine(t.size / fs, fs, 0.2, min(40.0, 0.4 * fs), 0.08, seed=2)
        f, h, coh = frf(d, run('broadband', d), fs)
    else:
        f, h, coh, _ = frf_from_bag(frf_bag)
    errs = [rms_error_pct(r, run('target_pass', r))]
    it = DriveIteration(r, fs, f, h, beta=beta, coherence=coh)
    drive, best = it.first(), (np.inf, None)
    for k in range(1, iterations + 1):
        y = run(f'iteration_{k}', drive)
        errs.append(rms_error_pct(r, y))
        if progress is not None:
            progress(k, errs[-1])
        if errs[-1] < best[0]:
            best = (errs[-1], drive)
        if errs[-1] <= rms_target_pct:
            break
        drive = it.update(drive, y)
    save_drive(out / 'drive.csv', t, best[1])
    db, deg = band_error(r, y, fs, 0.5, min(20.0, 0.4 * fs))
    return {'rms_err_pct': errs, 'best_pct': best[0], 'band_db_max': db, 'band_deg_max': deg,
            'drive': str(out / 'drive.csv'), 'replayed': replays}
