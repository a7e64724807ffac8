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
The S-N analysis against libraries we did not write, on the same data.

``reliability``'s ``Fit_Lognormal_Power`` (the same model, natural logs), pyLife's
``Elementary`` (least squares over the failures, as E739), scipy's log-normal distribution
for an independent log-likelihood.
"""

import math
import warnings

import numpy as np
import pytest
from ros_ehs.core.campaign.sn import dixon_mood, fit_basquin, fit_e739, SNData
from ros_ehs.core.errors import InputError

LOADS = np.repeat([9000.0, 7000.0, 5500.0, 4500.0], 3)


def _drawn(seed: int, run_out: float = math.inf, k: float = 5.0, s: float = 0.15):
    """12 specimens from a known Basquin law (k, s decades), censored at ``run_out``."""
    rng = np.random.default_rng(seed)
    n = 10.0 ** (6.0 - k * np.log10(LOADS / 5500.0) + rng.normal(0.0, s, LOADS.size))
    failed = n < run_out
    return SNData.of(LOADS, np.minimum(n, run_out), failed)


def _reliability(d: SNData):
    from reliability.ALT_fitters import Fit_Lognormal_Power
    f = d.failed
    kw = ({'right_censored': d.cycles[~f], 'right_censored_stress': d.load[~f]}
          if (~f).any() else {})
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return Fit_Lognormal_Power(failures=d.cycles[f], failure_stress=d.load[f],
                                   show_probability_plot=False, show_life_stress_plot=False,
                                   print_results=False, **kw)


def _loglik(d: SNData, ln_a: float, n: float, sigma: float) -> float:
    """Return the log-likelihood of the log-normal power law by scipy's distribution."""
    from scipy.stats import lognorm
    scale = np.exp(ln_a + n * np.log(d.load))
    f = d.failed
    return float(np.sum(lognorm.logpdf(d.cycles[f], sigma, scale=scale[f])) +
                 np.sum(lognorm.logsf(d.cycles[~f], sigma, scale=scale[~f])))


@pytest.mark.parametrize('seed', [1, 7, 11])
def test_without_run_outs_the_fit_is_reliabilitys_within_half_a_percent(seed):
    d = _drawn(seed)
    ours, theirs = fit_basquin(d), _reliability(d)
    assert ours.k == pytest.approx(-theirs.n, rel=0.005)
    assert ours.s == pytest.approx(theirs.sigma / math.log(10.0), rel=0.005)
    assert ours.a == pytest.approx(math.log10(theirs.a), rel=0.005)


@pytest.mark.parametrize('seed', [1, 7, 11])
def test_with_run_outs_the_fit_is_the_maximum_reliability_stops_short_of(seed):
    # the data: k = 5, 0.15 decades, 12 specimens, 3 run-outs
    n = _drawn(seed).cycles
    d = _drawn(seed, run_out=float(np.sort(n)[-3]) * 0.999)
    assert d.failed.sum() == 9
    ours, theirs = fit_basquin(d), _reliability(d)
    mine = _loglik(d, ours.a * math.log(10.0), -ours.k, ours.s * math.log(10.0))
    assert mine == pytest.approx(ours.loglik + _jacobian(d), abs=1e-6)   # the same model
    # reliability's own log-likelihood at its estimate is never above ours at ours
    assert mine >= theirs.loglik - 1e-6
    assert ours.k == pytest.approx(5.0, rel=0.25) and 0.05 < ours.s < 0.3


def _jacobian(d: SNData) -> float:
    # the density of N against that of log10 N: -log(N ln 10) per failure
    f = d.failed
    return float(-np.sum(np.log(d.cycles[f] * math.log(10.0))))


def test_e739_is_pylifes_elementary_slope_and_its_band_holds_the_line():
    import pandas as pd
    from pylife.materialdata import woehler
    d = _drawn(3)
    e = fit_e739(d)
    df = pd.DataFrame({'load': d.load, 'cycles': d.cycles, 'fracture': True})
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        el = woehler.Elementary(df.fatigue_data).analyze()
    assert e.k == pytest.approx(float(el['k_1']), rel=1e-9)
    slope, icpt = np.polyfit(d.x, d.y, 1)
    assert -e.k == pytest.approx(slope) and e.a == pytest.approx(icpt)
    lo, hi = e.band(5500.0)
    assert lo < 10 ** (e.a - e.k * math.log10(5500.0)) < hi
    # replicated at four levels: the linearity test is there
    assert e.linearity_f is not None and 0.0 <= e.linearity_p <= 1.0


def test_the_profile_intervals_hold_the_estimates_and_meet_their_quantile():
    from ros_ehs.core.campaign import sn
    d = _drawn(5, run_out=10 ** 6.4)
    fit = fit_basquin(d, confidence=0.9)
    lo, hi = fit.k_interval
    assert lo < fit.k < hi
    crit = sn.crit(0.9, fit.failures)
    x_mid = float(np.mean(d.x))
    for kk in (lo, hi):      # the profile at an end is the quantile above the maximum
        nll = sn._profile(d, lambda q: (q[0] + kk * x_mid, kk, q[1]),
                          (fit.a - fit.k * x_mid, math.log(fit.s)))
        assert nll + fit.loglik == pytest.approx(crit, abs=1e-4)
    n_lo, n_hi = fit.life_interval(5000.0)
    assert n_lo < fit.life(5000.0) < n_hi
    s_lo, s_hi = fit.load_interval(1.0e6)
    assert s_lo < fit.load_at(1.0e6) < s_hi
    # the 10/50/90 % curves, in order, 2 z(0.9) s decades apart
    n10, n50, n90 = (fit.life(5000.0, p) for p in (0.1, 0.5, 0.9))
    assert n10 < n50 < n90 and math.log10(n90 / n10) == pytest.approx(
        2 * 1.2815516 * fit.s, rel=1e-6)
    assert fit.load_at(fit.life(6000.0)) == pytest.approx(6000.0)


def test_without_run_outs_the_intervals_are_the_exact_t_intervals_of_least_squares():
    # the median life at a load and the slope, by OLS and Student's t (scipy), not our code
    from scipy.stats import t as student
    from ros_ehs.core.campaign.sn import crit
    d = _drawn(2)
    fit = fit_basquin(d, confidence=0.9)
    x, y = d.x, d.y
    n = x.size
    b, a = np.polyfit(x, y, 1)
    res = y - (a + b * x)
    s = math.sqrt(np.sum(res ** 2) / (n - 2))
    sxx = np.sum((x - x.mean()) ** 2)
    q = student.ppf(0.95, n - 2)
    x0 = math.log10(5000.0)
    half = q * s * math.sqrt(1.0 / n + (x0 - x.mean()) ** 2 / sxx)
    lo, hi = (math.log10(v) for v in fit.life_interval(5000.0))
    assert (lo, hi) == pytest.approx((a + b * x0 - half, a + b * x0 + half), abs=1e-6)
    k_lo, k_hi = fit.k_interval
    half_k = q * s / math.sqrt(sxx)
    assert (k_lo, k_hi) == pytest.approx((-b - half_k, -b + half_k), abs=1e-6)
    assert crit(0.9, 10 ** 7) == pytest.approx(0.5 * 2.705543, rel=1e-5)   # chi-square's


def test_dixon_mood_on_a_worked_staircase():
    # 10 specimens at 100 N steps: failures (x) and run-outs (o)
    levels = [500, 400, 500, 400, 300, 400, 500, 400, 300, 400]
    failed = [1, 0, 1, 1, 0, 1, 1, 1, 0, 0]
    # run-outs are fewer (4): at 300 (i = 0) twice, 400 (i = 1) twice: N = 4, A = 2, B = 2
    mean, std = dixon_mood(levels, [bool(f) for f in failed], 100.0)
    assert mean == pytest.approx(300 + 100 * (2 / 4 + 0.5))
    assert std == pytest.approx(1.62 * 100 * ((4 * 2 - 2 ** 2) / 4 ** 2 + 0.029))


@pytest.mark.parametrize('call, says', [
    (lambda: SNData.of([1.0, -2.0], [1e5, 1e6], [True, True]), 'specimen 2: load'),
    (lambda: SNData.of([1.0, 2.0], [1e5, math.nan], [True, True]), 'specimen 2: cycles'),
    (lambda: SNData.of([1.0, 2.0], [1e5], [True, True]), 'one length'),
    (lambda: fit_basquin(SNData.of([5.0, 5.0, 4.0], [1e5, 2e5, 1e7], [True, True, False])),
     'failures at two loads'),
    (lambda: fit_basquin(_drawn(1), confidence=1.0), '`confidence`'),
    (lambda: dixon_mood([1.0, 2.0], [True, True], 1.0), 'both outcomes'),
])
def test_bad_data_is_named(call, says):
    with pytest.raises(InputError, match=says):
        call()
