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
Drive-file iteration's mathematics: the loop's FRF, its regularised inverse, the iteration.

What road-load simulation does (time waveform replication): the loop does not follow an
arbitrary target ``r(t)`` by itself, so the command ("drive") is built from the loop's own
frequency response and refined by playing it:

1. **FRF**: a broadband drive (a random-phase multisine, :func:`multisine`) is played and
   the loop's frequency response ``H(f) = S_dy / S_dd`` estimated (Welch over segments of a
   quarter of the run, 4 s at most; :func:`frf`);
2. **inverse**: ``G = conj(H) / (|H|^2 + lam max|H|^2)`` (Tikhonov-regularised, so bins
   where the loop hardly responds do not blow up; ``lam`` 1e-3), only in the bins where the
   FRF is known (:class:`DriveIteration`);
3. **iterate**: ``d_0 = F^-1(G F(r))``; play ``d_k``, record ``y_k``, then
   ``d_k+1 = d_k + F^-1(beta_f G F(r - y_k))``, ``beta_f`` starting at ``beta`` (0.8) in
   every bin and halved in each bin whose error grew since the last run (its power summed
   over ``BACKOFF_BINS`` neighbours: one bin alone is noisy), unless that error is under
   ``BACKOFF_FLOOR`` of the target's there (converged: what is left is noise). Where the
   loop cannot do what the inverse asks (a target's edges faster than the valve can move
   the piston, content the FRF measured at another amplitude does not describe) a fixed
   step pushed the drive on, saturated the valve and spread the error over the whole band;
   the halved step stops pushing there and leaves the rest converging.

Playing the runs and keeping them as bags and CSVs is :mod:`ros_ehs.data.drive_files`; on the
bench's nodes, :mod:`ros_ehs.nodes.drive_bench`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np
from ros_ehs.core.errors import DataError, InputError

__all__ = ['DriveIteration', 'band_error', 'band_rms_error_pct', 'frf', 'multisine',
           'rms_error_pct', 'target_band']


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


def frf(drive, response, fs: float, nperseg: int | None = None, velocity: bool = False
        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Return ``(f, H, coherence)``: the H1 estimate of the response over the drive.

    Zero where the drive carried no energy: below 1e-4 of its peak spectral density (with
    ``velocity``, of its velocity's, ``S_dd f^2``: a multisine flat in velocity over more
    than two decades has a displacement density that spans more than four).
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
    dens = sdd * f * f if velocity else sdd
    live = dens > 1e-4 * dens.max()
    h = np.where(live, sdy / np.where(live, sdd, 1.0), 0.0)
    return f, h, np.where(live, coh, 0.0)


def rms_error_pct(target, response) -> float:
    """Return the RMS of ``target - response`` over the RMS of ``target`` [%]."""
    r = np.asarray(target, dtype=float)
    return float(np.sqrt(np.mean((r - np.asarray(response)) ** 2)) / np.sqrt(np.mean(r ** 2))
                 * 100.0)


def target_band(target, fs: float, tail_pct: float = 0.1, f_max: float | None = None
                ) -> tuple[float, float]:
    """
    Return the band [Hz] outside which the target's content is under ``tail_pct`` % of its RMS.

    The target's mean apart (the loop holds it itself), each tail (below ``f_lo``, above
    ``f_hi``) holds at most half of that content's energy, so the part no drive corrects
    makes an RMS error of ``tail_pct`` % at most; then widened by a quarter each way (an FRF
    is not known up to its band's very edge: Welch's windows spread it). ``f_max`` (default
    0.4 ``fs``) caps it.
    """
    r = np.asarray(target, dtype=float)
    if r.size < 16 or not np.all(np.isfinite(r)):
        raise DataError(f'target_band: need 16 finite samples or more, got {r.size}')
    p = np.abs(np.fft.rfft(r - r.mean())) ** 2
    f = np.fft.rfftfreq(r.size, 1.0 / fs)
    p[0] = 0.0
    total = p.sum()
    f_max = 0.4 * fs if f_max is None else f_max
    if total <= 0.0:
        return float(f[1]), float(f_max)
    allowed = 0.5 * (tail_pct / 100.0) ** 2 * total
    lo = int(np.searchsorted(np.cumsum(p), allowed, 'right'))
    hi = int(p.size - 1 - np.searchsorted(np.cumsum(p[::-1]), allowed, 'right'))
    f_lo = float(f[max(lo, 1)]) / 1.25
    f_hi = float(min(1.25 * f[max(hi, lo + 1)], f_max))
    return f_lo, max(f_hi, f_lo * 1.5)


def band_rms_error_pct(target, response, fs: float, f_lo: float, f_hi: float) -> float:
    """Return the RMS of ``target - response`` in [f_lo, f_hi] over the target's there [%]."""
    r = np.fft.rfft(np.asarray(target, dtype=float))
    e = r - np.fft.rfft(np.asarray(response, dtype=float))
    f = np.fft.rfftfreq(len(target), 1.0 / fs)
    band = (f >= f_lo) & (f <= f_hi)
    den = np.sqrt(np.sum(np.abs(r[band]) ** 2))
    return float(np.sqrt(np.sum(np.abs(e[band]) ** 2)) / den * 100.0) if den > 0 else math.nan


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


#: how many neighbouring bins an error's growth is judged over (see the module docstring)
BACKOFF_BINS = 9
#: an error under this fraction of the target's (in those bins) has converged: no back-off
BACKOFF_FLOOR = 0.01


def _bin_power(x: np.ndarray, spec: np.ndarray | None = None) -> np.ndarray:
    """Return each FFT bin's power summed over its ``BACKOFF_BINS`` neighbours."""
    spec = np.fft.rfft(x) if spec is None else spec
    return np.convolve(np.abs(spec) ** 2, np.ones(BACKOFF_BINS), 'same')


@dataclass
class DriveIteration:
    """
    Iterate a drive for ``target`` (samples at ``fs``) from the loop's FRF ``(f_h, h)``.

    ``history`` holds the RMS error [%] of each response given to :meth:`update`; ``step``
    each bin's step now (``beta``, halved wherever the error grew).
    """

    target: np.ndarray
    fs: float
    f_h: np.ndarray
    h: np.ndarray
    beta: float = 0.8
    lam: float = 1e-3
    coherence: np.ndarray | None = None
    min_coherence: float = 0.9
    band_hz: tuple | None = None       #: and only in this band [Hz] (None: wherever known)
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
        if self.band_hz is not None:
            self.band &= (f >= self.band_hz[0]) & (f <= self.band_hz[1])
        peak = np.abs(h[self.band]).max() if self.band.any() else 1.0
        self.g = np.where(self.band, np.conj(h) / (np.abs(h) ** 2 + self.lam * peak ** 2),
                          0.0)
        self.step = np.full(f.size, float(self.beta))
        self._last_power: np.ndarray | None = None
        self._r_power = _bin_power(self.target)

    def uncovered_pct(self) -> float:
        """Return the target's content the inverse does not act on [% of its RMS, mean apart]."""
        spec = np.fft.rfft(self.target - self.target.mean())
        total = np.sum(np.abs(spec) ** 2)
        out = np.sum(np.abs(spec[~self.band]) ** 2)
        return float(np.sqrt(out / total) * 100.0) if total > 0 else 0.0

    def _apply(self, x: np.ndarray) -> np.ndarray:
        return np.fft.irfft(self.g * np.fft.rfft(x), self.target.size)

    def first(self) -> np.ndarray:
        """Return the first drive: the inverse applied to the target."""
        return self._apply(self.target)

    def update(self, drive: np.ndarray, response: np.ndarray) -> np.ndarray:
        """Record ``response`` to ``drive``; return the next drive."""
        e = self.target - np.asarray(response, dtype=float)
        self.history.append(rms_error_pct(self.target, response))
        spec = np.fft.rfft(e)
        power = _bin_power(e, spec)
        if self._last_power is not None:
            # grown, and not just a converged bin's numerical floor
            grew = (power > self._last_power) & (power > BACKOFF_FLOOR ** 2 * self._r_power)
            self.step = np.where(grew, 0.5 * self.step, self.step)
        self._last_power = power
        return np.asarray(drive, dtype=float) + np.fft.irfft(self.step * self.g * spec,
                                                             self.target.size)
