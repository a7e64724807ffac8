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
the chi-square quantile of one degree of freedom) for the slope, the median life at a design
load and the load at a design life: the interval a lab signs, not a Wald interval that
assumes the estimate is normal with a dozen specimens. The 10/50/90 % curves are the fitted
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
import math
from typing import Sequence

import numpy as np
from ros_ehs.core.errors import InputError

__all__ = ['BasquinFit', 'E739Fit', 'SNData', 'dixon_mood', 'fit_basquin', 'fit_e739']


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

    @property
    def x(self) -> np.ndarray:
        """Return log10 of the loads."""
        return np.log10(self.load)

    @property
    def y(self) -> np.ndarray:
        """Return log10 of the lives."""
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

        def nll_at(m):
            # a = m + k x: the median at x fixed to m, (k, log s) free
            return _profile(self.data, lambda q: (m + q[0] * x, q[0], q[1]),
                            (self.k, math.log(self.s)))
        lo, hi = _interval(nll_at, mu, self._nll_max(), self.confidence, 0.05 + 3 * self.s)
        return 10.0 ** lo, 10.0 ** hi

    def load_interval(self, cycles: float) -> tuple[float, float]:
        """Return the profile-likelihood interval of the load whose median life is ``cycles``."""
        yd = math.log10(cycles)
        xd = (self.a - yd) / self.k

        def nll_at(xx):
            # a = yd + k xx: the median life at xx fixed to cycles
            return _profile(self.data, lambda q: (yd + q[0] * xx, q[0], q[1]),
                            (self.k, math.log(self.s)))
        lo, hi = _interval(nll_at, xd, self._nll_max(), self.confidence,
                           0.02 + 3 * self.s / max(self.k, 1e-3))
        return 10.0 ** lo, 10.0 ** hi

    def _nll_max(self) -> float:
        return -self.loglik


_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


def _nll(data: SNData, a: float, k: float, log_s: float) -> float:
    """Return the negative log-likelihood (failures: density; run-outs: survival)."""
    from scipy.special import log_ndtr
    s = math.exp(log_s)
    r = (data.y - (a - k * data.x)) / s
    f = data.failed
    rf = r[f]
    return float(0.5 * np.dot(rf, rf) + rf.size * (_LOG_SQRT_2PI + log_s) -
                 np.sum(log_ndtr(-r[~f])))


def _minimise(fun, x0, methods=('BFGS', 'Nelder-Mead')):
    from scipy.optimize import minimize
    best = None
    for method in methods:
        res = minimize(fun, x0, method=method,
                       options={'xatol': 1e-10, 'fatol': 1e-12, 'maxiter': 20000}
                       if method == 'Nelder-Mead' else {'gtol': 1e-9})
        if best is None or res.fun < best.fun:
            best = res
        x0 = best.x
    return best


def _profile(data: SNData, params, start) -> float:
    """Return the least negative log-likelihood over the free parameters of ``params(q)``."""
    res = _minimise(lambda q: _nll(data, *params(q)), np.asarray(start, dtype=float),
                    ('BFGS',))
    return float(res.fun)


def _interval(nll_at, theta: float, nll_min: float, confidence: float,
              step: float) -> tuple[float, float]:
    """Return where the profile's likelihood-ratio statistic meets its chi-square quantile."""
    from scipy.optimize import brentq
    from scipy.stats import chi2
    crit = 0.5 * float(chi2.ppf(confidence, 1))

    def g(t):
        return nll_at(t) - nll_min - crit
    out = []
    for sign in (-1.0, 1.0):
        d = step
        for _ in range(60):
            if g(theta + sign * d) > 0:
                break
            d *= 1.6
        else:
            out.append(-sign * math.inf if sign < 0 else math.inf)
            continue
        lo, hi = sorted((theta, theta + sign * d))
        out.append(brentq(g, lo, hi, xtol=1e-10))
    return out[0], out[1]


def fit_basquin(data: SNData, confidence: float = 0.9) -> BasquinFit:
    """
    Fit Basquin with log-normal scatter by maximum likelihood, run-outs right-censored.

    Needs failures at two loads at least (a slope); ``confidence`` is the intervals'.
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

    def nll_k(kk):
        # the slope fixed; the median at the data's mean log-load and the scatter free
        return _profile(data, lambda q: (q[0] + kk * x_mid, kk, q[1]),
                        (a - k * x_mid, log_s))
    k_int = _interval(nll_k, k, -fit.loglik, confidence, 0.1 + 0.2 * abs(k))
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
