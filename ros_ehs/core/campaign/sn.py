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
r"""
The S-N (Woehler) analysis of a campaign's specimens: Basquin with log-normal scatter.

**The model.** A specimen loaded at ``S`` (a force amplitude or range [N], or a stress; the
campaign says which, the fit does not care) has a life whose decimal logarithm is normal,

.. math:: \log_{10} N \sim \mathcal{N}(a - k \log_{10} S,\ s^2)

(Basquin's power law, slope ``k``, the same scatter ``s`` [decades] at every level; ASTM
E739 and ISO 12107 assume as much). A run-out, a specimen stopped unbroken at ``N``, is a
right-censored life: all it says is that its life exceeds ``N``.

:func:`fit_basquin` maximises the likelihood (failures: the normal density of ``log10 N``;
run-outs: its survival function), the fit ``reliability``'s ``Fit_Lognormal_Power`` makes of
the same data (natural logarithms, ``n = -k``: the tests compare them), and gives
profile-likelihood intervals (the set of values whose likelihood-ratio statistic is within
the chi-square quantile of one degree of freedom, calibrated for small samples:
:func:`crit`) for the slope, the median life at a design load and the load at a design life:
the interval a lab signs, not a Wald interval that assumes the estimate is normal with a
dozen specimens. For failures alone the calibrated intervals are the exact t intervals of
E739's regression; with run-outs, approximately so (the rehearsal benchmark measures how
often they hold the truth). The 10/50/90 % curves are the fitted
quantiles (``life(S, p)``); the scatter is the ML estimate, biased low by some
``sqrt((n - 3) / n)`` with ``n`` failures.

:func:`fit_e739` is ASTM E739's least squares of ``log10 N`` on ``log10 S`` over the
failures alone (run-outs left out, as the standard says), with its confidence band for the
median line (Working-Hotelling, the standard's eq. (9)) and, where levels are replicated, its
F-test of linearity. :func:`dixon_mood` is the staircase's mean and standard deviation (ISO
12107 / Dixon-Mood, on the less frequent outcome).

pyLife's ``MaxLikeFull`` fits another model (a fatigue limit, with a run-out as a
pass/fail outcome at its level rather than a censored life): docs/campaigns.md shows its
estimates beside these, and the tests compare pyLife's ``Elementary`` slope with
:func:`fit_e739`'s where both fit the same failures by least squares.
"""

from __future__ import annotations

from dataclasses import dataclass
import functools
import math
from typing import Sequence

import numpy as np
from ros_ehs.core.errors import InputError

__all__ = ['BasquinFit', 'E739Fit', 'SNData', 'crit', 'dixon_mood', 'fit_basquin', 'fit_e739',
           'with_slope_interval']


@dataclass(frozen=True)
class SNData:
    """A campaign's specimens: load ``S`` [N or Pa], life ``N`` [cycles], failed or run out."""

    load: np.ndarray
    cycles: np.ndarray
    failed: np.ndarray

    @classmethod
    def of(cls, load: Sequence[float], cycles: Sequence[float],
           failed: Sequence[bool]) -> 'SNData':
        """Return the data, checked: each load and life finite and > 0, the lengths equal."""
        s = np.asarray(load, dtype=float)
        n = np.asarray(cycles, dtype=float)
        f = np.asarray(failed, dtype=bool)
        if not (s.ndim == n.ndim == f.ndim == 1 and s.size == n.size == f.size):
            raise InputError(f'load, cycles and failed must be 1-D of one length, got '
                             f'{s.shape}, {n.shape}, {f.shape}')
        for name, v in (('load', s), ('cycles', n)):
            bad = np.flatnonzero(~(np.isfinite(v) & (v > 0)))
            if bad.size:
                raise InputError(f'specimen {bad[0] + 1}: {name} = {v[bad[0]]!r} must be '
                                 'finite and > 0')
        return cls(s, n, f)

    @functools.cached_property
    def x(self) -> np.ndarray:
        """Return log10 of the loads (computed once: every likelihood evaluation reads it)."""
        return np.log10(self.load)

    @functools.cached_property
    def y(self) -> np.ndarray:
        """Return log10 of the lives (computed once)."""
        return np.log10(self.cycles)


def _z(p: float) -> float:
    from scipy.stats import norm
    return float(norm.ppf(p))


@dataclass(frozen=True)
class BasquinFit:
    """A maximum-likelihood Basquin fit: ``log10 N = a - k log10 S``, scatter ``s`` [decades]."""

    a: float
    k: float
    s: float
    loglik: float
    failures: int
    run_outs: int
    confidence: float
    k_interval: tuple[float, float]
    data: SNData

    method = 'maximum likelihood, run-outs right-censored (Basquin, log-normal scatter)'

    def life(self, load: float | np.ndarray, p: float = 0.5) -> float | np.ndarray:
        """Return the life [cycles] a fraction ``p`` of specimens fail by at ``load``."""
        return 10.0 ** (self.a - self.k * np.log10(load) + _z(p) * self.s)

    def load_at(self, cycles: float | np.ndarray, p: float = 0.5) -> float | np.ndarray:
        """Return the load at which a fraction ``p`` of specimens fail by ``cycles``."""
        return 10.0 ** ((self.a + _z(p) * self.s - np.log10(cycles)) / self.k)

    @property
    def scatter_tn(self) -> float:
        """Return the scatter as pyLife's TN: the life at 90 % failure probability over 10 %'s."""
        return 10.0 ** (2.0 * _z(0.9) * self.s)

    def life_interval(self, load: float) -> tuple[float, float]:
        """Return the profile-likelihood interval of the median life at ``load`` [cycles]."""
        x = math.log10(load)
        mu = self.a - self.k * x

        warm: list = []

        def nll_at(m):
            # a = m + k x: the median at x fixed to m, (k, log s) free
            return _profile(self.data, lambda q: (m + q[0] * x, q[0], q[1]),
                            (self.k, math.log(self.s)), warm)
        lo, hi = _interval(nll_at, mu, self._nll_max(), self.confidence, 0.05 + 3 * self.s,
                           self.failures)
        return 10.0 ** lo, 10.0 ** hi

    def load_interval(self, cycles: float) -> tuple[float, float]:
        """Return the profile-likelihood interval of the load whose median life is ``cycles``."""
        yd = math.log10(cycles)
        xd = (self.a - yd) / self.k

        warm: list = []

        def nll_at(xx):
            # a = yd + k xx: the median life at xx fixed to cycles
            return _profile(self.data, lambda q: (yd + q[0] * xx, q[0], q[1]),
                            (self.k, math.log(self.s)), warm)
        lo, hi = _interval(nll_at, xd, self._nll_max(), self.confidence,
                           0.02 + 3 * self.s / max(self.k, 1e-3), self.failures)
        return 10.0 ** lo, 10.0 ** hi

    def _nll_max(self) -> float:
        return -self.loglik


_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


def _nll(data: SNData, a: float, k: float, log_s: float) -> float:
    """Return the negative log-likelihood (failures: density; run-outs: survival)."""
    return _nll_grad(data, a, k, log_s)[0]


def _nll_grad(data: SNData, a: float, k: float, log_s: float) -> tuple[float, np.ndarray]:
    """Return :func:`_nll` and its gradient in (a, k, log s), in closed form."""
    from scipy.special import log_ndtr
    s = math.exp(log_s)
    x = data.x
    r = (data.y - (a - k * x)) / s
    f = data.failed
    rf, rr, xf, xr = r[f], r[~f], x[f], x[~f]
    lsf = log_ndtr(-rr)
    nll = float(0.5 * np.dot(rf, rf) + rf.size * (_LOG_SQRT_2PI + log_s) - np.sum(lsf))
    # d/dr of -log Phi(-r): the inverse Mills ratio phi(r) / Phi(-r), computed in logs
    with np.errstate(over='ignore', invalid='ignore'):
        lam = np.exp(-0.5 * rr * rr - _LOG_SQRT_2PI - lsf)
    bad = ~np.isfinite(lam)
    if bad.any():                     # far in the tail (a search's extreme step): ~ r
        lam[bad] = np.maximum(rr[bad], 0.0)
    g = np.array([(-np.sum(rf) - np.sum(lam)) / s,
                  (np.dot(rf, xf) + np.dot(lam, xr)) / s,
                  -np.dot(rf, rf) + rf.size - np.dot(lam, rr)])
    return nll, g


def _minimise(fun, x0, methods=('BFGS', 'Nelder-Mead'), jac=None):
    from scipy.optimize import minimize
    best = None
    for method in methods:
        res = minimize(fun, x0, method=method, jac=jac if method == 'BFGS' else None,
                       options={'xatol': 1e-10, 'fatol': 1e-12, 'maxiter': 20000}
                       if method == 'Nelder-Mead' else {'gtol': 1e-9})
        if best is None or res.fun < best.fun:
            best = res
        x0 = best.x
    return best


def _profile(data: SNData, params, start, warm: list | None = None) -> float:
    """
    Return the least negative log-likelihood over the free parameters of ``params(q)``.

    ``params`` is affine in ``q`` (each profile fixes one combination): its Jacobian is
    read off once, and BFGS gets the exact gradient through it. ``warm``: a list that keeps
    the last optimum, where the next profile of the same interval starts.
    """
    q0 = np.asarray(warm[0] if warm else start, dtype=float)
    p0 = np.asarray(params(q0), dtype=float)
    jm = np.stack([np.asarray(params(q0 + e), dtype=float) - p0 for e in np.eye(q0.size)],
                  axis=1)

    def fun(q):
        v, g = _nll_grad(data, *params(q))
        return v, g @ jm
    res = _minimise(lambda q: fun(q)[0], q0, ('BFGS',), jac=lambda q: fun(q)[1])
    if warm is not None and np.all(np.isfinite(res.x)):
        warm[:] = [res.x]
    return float(res.fun)


def crit(confidence: float, failures: int) -> float:
    """
    Return the rise of the negative log-likelihood that bounds a profile interval.

    ``(n / 2) ln(1 + F / (n - 2))``, ``F`` the ``confidence`` quantile of Fisher's F with 1
    and ``n - 2`` degrees of freedom, ``n`` the failures: for failures alone (a normal linear
    model) the likelihood ratio of a linear hypothesis is exactly that function of its F
    statistic, so the interval is the exact t interval; with run-outs it is the same
    small-sample correction, approximately. Half the chi-square quantile as ``n`` grows.
    """
    from scipy.stats import chi2, f as fdist
    if failures <= 2:
        return math.inf
    d = failures - 2
    if d > 10 ** 6:
        return 0.5 * float(chi2.ppf(confidence, 1))
    return 0.5 * failures * math.log1p(float(fdist.ppf(confidence, 1, d)) / d)


def _interval(nll_at, theta: float, nll_min: float, confidence: float,
              step: float, failures: int) -> tuple[float, float]:
    """Return where the profile's rise from its minimum meets :func:`crit`."""
    from scipy.optimize import brentq
    crit_ = crit(confidence, failures)

    def g(t):
        return nll_at(t) - nll_min - crit_
    out = []
    for sign in (-1.0, 1.0):
        d = step
        for _ in range(60):
            if g(theta + sign * d) > 0:
                break
            d *= 1.6
        else:
            out.append(sign * math.inf)     # unbounded on this side
            continue
        lo, hi = sorted((theta, theta + sign * d))
        out.append(brentq(g, lo, hi, xtol=1e-10))
    return out[0], out[1]


def fit_basquin(data: SNData, confidence: float = 0.9, slope_interval: bool = True
                ) -> BasquinFit:
    """
    Fit Basquin with log-normal scatter by maximum likelihood, run-outs right-censored.

    Needs failures at two loads at least (a slope); ``confidence`` is the intervals'.
    ``slope_interval=False`` leaves ``k_interval`` NaN (:func:`with_slope_interval` adds it
    later: a campaign's rules refit after every specimen and need it only at the end).
    """
    if not 0.0 < confidence < 1.0:
        raise InputError(f'`confidence` = {confidence!r} must be between 0 and 1')
    f = data.failed
    if len(np.unique(data.load[f])) < 2:
        raise InputError('the S-N fit needs failures at two loads at least, got '
                         f'{np.count_nonzero(f)} failures at '
                         f'{len(np.unique(data.load[f]))} load(s)')
    e = fit_e739(data)
    if not e.s > 0.0:
        raise InputError(f'the S-N fit needs scatter: the {e.n} failures lie exactly on a '
                         'line (their likelihood has no maximum)')
    s0 = max(e.s, 0.05)
    x_mid = float(np.mean(data.x))
    # centred at the mean log-load: a and k are nearly collinear otherwise (a ~ 25, k ~ 5
    # with log-loads near 3.7), and the optimiser stops short of the maximum
    res = _minimise(lambda q: _nll(data, q[0] + q[1] * x_mid, q[1], q[2]),
                    np.array([e.a - e.k * x_mid, e.k, math.log(s0)]))
    c, k, log_s = (float(v) for v in res.x)
    a = c + k * x_mid
    fit = BasquinFit(a, k, math.exp(log_s), -float(res.fun), int(np.count_nonzero(f)),
                     int(np.count_nonzero(~f)), confidence, (math.nan, math.nan), data)
    return with_slope_interval(fit) if slope_interval else fit


def with_slope_interval(fit: BasquinFit) -> BasquinFit:
    """Return ``fit`` with its slope's profile-likelihood interval (at its confidence)."""
    if math.isfinite(fit.k_interval[0]):
        return fit
    data, a, k, log_s = fit.data, fit.a, fit.k, math.log(fit.s)
    x_mid = float(np.mean(data.x))
    confidence = fit.confidence
    warm: list = []

    def nll_k(kk):
        # the slope fixed; the median at the data's mean log-load and the scatter free
        return _profile(data, lambda q: (q[0] + kk * x_mid, kk, q[1]),
                        (a - k * x_mid, log_s), warm)
    k_int = _interval(nll_k, k, -fit.loglik, confidence, 0.1 + 0.2 * abs(k), fit.failures)
    return BasquinFit(a, k, math.exp(log_s), fit.loglik, fit.failures, fit.run_outs,
                      confidence, k_int, data)


@dataclass(frozen=True)
class E739Fit:
    """ASTM E739's least squares over the failures: ``log10 N = a - k log10 S``."""

    a: float
    k: float
    s: float                 #: the residual standard deviation [decades], n - 2 d.o.f.
    n: int
    x_mean: float
    sxx: float
    linearity_f: float | None       #: the F statistic of E739's linearity test, if replicated
    linearity_p: float | None
    method = 'least squares over the failures (ASTM E739), run-outs left out'

    def band(self, load: float | np.ndarray, confidence: float = 0.95) -> tuple:
        """Return E739's confidence band of the median life at ``load`` (Working-Hotelling)."""
        from scipy.stats import f as fdist
        x = np.log10(load)
        y = self.a - self.k * x
        w = math.sqrt(2.0 * float(fdist.ppf(confidence, 2, self.n - 2)))
        h = w * self.s * np.sqrt(1.0 / self.n + (x - self.x_mean) ** 2 / self.sxx)
        return 10.0 ** (y - h), 10.0 ** (y + h)


def fit_e739(data: SNData) -> E739Fit:
    """Fit ASTM E739's least squares over the failures, with its linearity F-test."""
    from scipy.stats import f as fdist
    f = data.failed
    x, y = data.x[f], data.y[f]
    n = x.size
    if n < 3 or len(np.unique(x)) < 2:
        raise InputError(f'E739 needs three failures at two loads at least, got {n} at '
                         f'{len(np.unique(x))}')
    xm, ym = x.mean(), y.mean()
    sxx = float(np.sum((x - xm) ** 2))
    b = float(np.sum((x - xm) * (y - ym)) / sxx)
    a = float(ym - b * xm)
    res = y - (a + b * x)
    s = math.sqrt(float(np.sum(res ** 2)) / (n - 2))
    levels = np.unique(x)
    fstat = pval = None
    if levels.size > 2 and n > levels.size:
        # lack of fit against pure error over the replicated levels (E739, section 8)
        ss_pe = sum(float(np.sum((y[x == v] - y[x == v].mean()) ** 2)) for v in levels)
        ss_lof = float(np.sum(res ** 2)) - ss_pe
        l_ = levels.size
        if ss_pe > 0:
            fstat = (ss_lof / (l_ - 2)) / (ss_pe / (n - l_))
            pval = float(fdist.sf(fstat, l_ - 2, n - l_))
    return E739Fit(a, -b, s, n, float(xm), sxx, fstat, pval)


def dixon_mood(levels: Sequence[float], failed: Sequence[bool], step: float
               ) -> tuple[float, float]:
    """
    Return a staircase's mean and standard deviation (Dixon-Mood, ISO 12107).

    ``levels``: each specimen's load in turn; ``failed``: its outcome; ``step``: the
    staircase's step (its levels ``d`` apart). The less frequent outcome's counts ``n_i`` at
    its levels ``i = 0, 1, ...`` from the lowest: ``A = sum(i n_i)``, ``B = sum(i^2 n_i)``,
    ``N = sum(n_i)``; mean ``S0 + d (A/N -+ 1/2)`` (failures: minus), standard deviation
    ``1.62 d ((N B - A^2) / N^2 + 0.029)``, valid where ``(N B - A^2) / N^2 > 0.3``.
    """
    s = np.asarray(levels, dtype=float)
    f = np.asarray(failed, dtype=bool)
    if s.size != f.size or s.size < 2 or not step > 0:
        raise InputError('a staircase needs its levels and outcomes (two at least) and a '
                         'step > 0')
    use_failures = np.count_nonzero(f) <= np.count_nonzero(~f)
    pick = s[f] if use_failures else s[~f]
    if not pick.size:
        raise InputError('a staircase needs both outcomes')
    s0 = pick.min()
    i = np.rint((pick - s0) / step).astype(int)
    n_tot = pick.size
    a_ = float(np.sum(i))
    b_ = float(np.sum(i * i))
    mean = s0 + step * (a_ / n_tot + (-0.5 if use_failures else 0.5))
    ratio = (n_tot * b_ - a_ * a_) / n_tot ** 2
    std = 1.62 * step * (ratio + 0.029)
    return float(mean), float(std)
