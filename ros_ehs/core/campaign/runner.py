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
A campaign's rules: the next specimen and its level, when the campaign ends, and a test's result.

ROS-free and clock-free, like the axis's rules: the specimens' results so far go in (as the
store holds them: the store is the truth, so a restarted campaign judges from it), and the
verdict comes out as data (:class:`Verdict`). The same rules run a campaign in process
(:func:`ros_ehs.data.campaign.run_campaign`), on the lock-step bench and on the rig.

**The rules** (:func:`judge`), in this order:

1. The fit. After every specimen the S-N curve is refitted (its slope's interval once the
   campaign has ended)
   (:func:`~ros_ehs.core.campaign.sn.fit_basquin`, run-outs censored) once three failures
   at two levels at least allow it and its slope is positive; the invalid specimens are
   left out.
2. The target. A campaign with a ``target`` ends when the target's interval, at its
   confidence, is within its ``width`` (the interval's half-width over the estimate) and at
   least its ``min_specimens`` valid specimens are in: ``target met``.
3. Invalid specimens are replaced (the plan counts the valid ones); :data:`INVALID_IN_A_ROW`
   invalid in a row end the campaign (``invalid``: the rig or the procedure needs attention,
   not another coupon).
4. The plan. ``levels``, ``pearl_string`` and ``staircase`` give their next level
   (:meth:`~ros_ehs.core.campaign.spec.Campaign.next_level`); an ``adaptive`` plan chooses
   it (:func:`adaptive_level`); a plan with no next level has ended: ``plan done``.

**The adaptive level.** Among :data:`CANDIDATES` levels log-spaced over ``low..high``, the one
whose specimen is expected to narrow the target's interval most per hour on the rig. With
the fit's ``(a, k, s)`` and ``x = log10 S``, a specimen at ``x`` adds the expected Fisher
information of one censored normal observation of ``log10 N`` (mean ``a - k x``, censored at
the run-out) to that of the specimens so far; the target's variance is the delta method's
``g' I^-1 g`` (``g`` the gradient of ``log10`` of the target's quantity), and the hours its
expected tested life ``E[min(N, run_out)]`` over the level's frequency. Without a target the
variance of the load at the median life of the specimens so far is narrowed. Before a fit
it takes ``high``, ``low`` and their geometric midpoint
in turn.
The expected information is the standard one of the Tobit model, computed by quadrature.

**A test's result** (:func:`specimen_result`): ``failed`` (a failure detector or the break),
``run_out`` (the run-out count reached), otherwise ``invalid`` with the test's reason (stopped,
interrupted, a hold not resumed); a specimen whose achieved levels (the median of its untapered
cycles' fitted peaks and valleys) are further than ``level_tolerance`` of the specified range
from the specified ones is ``invalid`` too, named: its point would sit where it was not loaded.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Sequence

import numpy as np
from ros_ehs.core.campaign.sn import BasquinFit, fit_basquin, SNData, with_slope_interval
from ros_ehs.core.campaign.spec import Campaign
from ros_ehs.core.errors import InputError

__all__ = ['CANDIDATES', 'INVALID_IN_A_ROW', 'Achieved', 'Next', 'Verdict', 'achieved_levels',
           'adaptive_level', 'judge', 'sn_data', 'specimen_result']

#: invalid specimens in a row that end a campaign
INVALID_IN_A_ROW = 3
#: the levels an adaptive plan chooses among (log-spaced over low..high)
CANDIDATES = 25
#: the cycle table's columns this module reads (ros_ehs.data.fatigue.CYCLE_COLUMNS)
_Z_HI, _Z_LO, _F_HI, _F_LO, _FLAGS = 5, 6, 7, 8, 9
_TAPERED, _EXTRAPOLATED = 1, 2


@dataclass(frozen=True)
class Next:
    """The next specimen: its id, its level and its place in the campaign (1-based)."""

    specimen: str
    level: float
    index: int


@dataclass(frozen=True)
class Verdict:
    """What the rules say after the specimens so far."""

    done: bool
    reason: str                    #: why it ended ('' while it runs)
    next_specimen: Next | None
    fit: BasquinFit | None
    #: the target's estimate and interval, and whether it is met (None: no target or no fit)
    target: dict | None = None
    counts: dict = field(default_factory=dict)   #: failed, run_out, invalid


@dataclass(frozen=True)
class Achieved:
    """A specimen's achieved levels, from its cycle table (SI units)."""

    peak: float
    valley: float
    mean: float
    amplitude: float
    r_ratio: float
    amplitude_spread: float       #: the standard deviation of the cycles' amplitudes
    cycles: int                   #: the untapered cycles they are from


def achieved_levels(table: np.ndarray | None, control_mode: str) -> Achieved:
    """
    Return the achieved levels of a cycle table (n x 10, ``CYCLE_COLUMNS``).

    The controlled signal's fitted peaks and valleys (the load in force control, the position
    otherwise) of the untapered cycles carried (a virtual test's jumped cycles, which repeat
    the last simulated one, left out): their medians, the mean, amplitude and R of those,
    and the spread of the amplitude. NaN throughout with no such cycle.
    """
    nan = math.nan
    if table is None or not len(table):
        return Achieved(nan, nan, nan, nan, nan, nan, 0)
    t = np.asarray(table, dtype=float)
    t = t[(t[:, _FLAGS].astype(int) & (_TAPERED | _EXTRAPOLATED)) == 0]
    hi_c, lo_c = (_F_HI, _F_LO) if control_mode == 'force' else (_Z_HI, _Z_LO)
    hi, lo = t[:, hi_c], t[:, lo_c]
    ok = np.isfinite(hi) & np.isfinite(lo)
    hi, lo = hi[ok], lo[ok]
    if not hi.size:
        return Achieved(nan, nan, nan, nan, nan, nan, 0)
    peak, valley = float(np.median(hi)), float(np.median(lo))
    amp = 0.5 * (hi - lo)
    return Achieved(peak, valley, 0.5 * (peak + valley), 0.5 * (peak - valley),
                    valley / peak if peak else nan, float(np.std(amp)), int(hi.size))


def specified_levels(campaign: Campaign, level: float) -> tuple[float, float]:
    """Return the peak and valley a level specifies."""
    if campaign.level_kind == 'max_load':
        return float(level), float(campaign.level_value * level)
    return campaign.level_value + level, campaign.level_value - level


def specimen_result(campaign: Campaign, level: float, result: str, reason: str,
                    achieved: Achieved) -> tuple[str, str]:
    """
    Return a test's result for the campaign, and its reason (module docstring).

    ``result``, ``reason``: the procedure's (``failed``, ``run_out``, ``completed``,
    ``interrupted``, ``stopped``...).
    """
    if result not in ('failed', 'run_out'):
        return 'invalid', f'the test ended {result}: {reason}' if reason else \
            f'the test ended {result}'
    peak, valley = specified_levels(campaign, level)
    rng = peak - valley
    off = max(abs(achieved.peak - peak), abs(achieved.valley - valley)) / rng
    tol = campaign.level_tolerance
    if not off <= tol:                   # NaN: no cycle to judge it by
        why = (f'achieved levels {achieved.peak:.6g}/{achieved.valley:.6g} against '
               f'{peak:.6g}/{valley:.6g}: {off * 100:.3g} % of the range off, beyond '
               f'level_tolerance ({tol * 100:g} %)' if math.isfinite(off) else
               'no untapered cycle to judge its levels by')
        return 'invalid', f'{result} ({reason}), but {why}'
    return result, reason


# -- the rules ---------------------------------------------------------------------------------
def sn_data(results: Sequence[Any]) -> SNData | None:
    """Return the valid results (failed, run out) as the S-N fit's data (None: none)."""
    valid = [r for r in results if r.result in ('failed', 'run_out') and r.cycles > 0]
    if not valid:
        return None
    return SNData.of([r.level for r in valid], [r.cycles for r in valid],
                     [r.result == 'failed' for r in valid])


def _fit(data: SNData | None, confidence: float) -> BasquinFit | None:
    # three failures at two levels at least: two points leave no scatter to estimate
    if data is None or np.count_nonzero(data.failed) < 3 or \
            len(np.unique(data.load[data.failed])) < 2:
        return None
    try:
        fit = fit_basquin(data, confidence, slope_interval=False)
    except InputError:
        return None
    # lives longer at the higher loads (a few scattered failures): no curve to judge by yet
    return fit if fit.k > 0 else None


def _sloped(fit: BasquinFit | None) -> BasquinFit | None:
    """Return the fit with its slope interval (an ended campaign's), or None."""
    if fit is None:
        return None
    try:
        return with_slope_interval(fit)
    except (OverflowError, ValueError, FloatingPointError):
        return fit                  # an interval beyond numbers: left NaN


def _target(campaign: Campaign, fit: BasquinFit | None) -> dict | None:
    t = campaign.target
    if t is None or fit is None:
        return None
    try:
        if t['kind'] == 'load_at_life':
            est = float(fit.load_at(t['life']))
            lo, hi = fit.load_interval(t['life'])
        else:
            est = float(fit.life(t['load']))
            lo, hi = fit.life_interval(t['load'])
    except (OverflowError, ValueError, FloatingPointError):
        return None                 # an interval beyond numbers: nothing to judge yet
    # an interval unbounded on a side (the data cannot close it) is infinitely wide
    width = 0.5 * (hi - lo) / est if lo > 0.0 and math.isfinite(hi) else math.inf
    enough = fit.failures + fit.run_outs >= t.get('min_specimens', 0)
    return {'kind': t['kind'], 'estimate': est, 'interval': (float(lo), float(hi)),
            'confidence': t['confidence'], 'width': width,
            'met': bool(width <= t['width'] and enough)}


def judge(campaign: Campaign, results: Sequence[Any], prefix: str = 'S') -> Verdict:
    """
    Return the verdict after ``results``, in the order tested (a store's records).

    Each result has ``specimen``, ``level``, ``result``, ``cycles`` and ``reason``. The next
    specimen's id is ``prefix`` and its place.
    """
    results = list(results)
    counts = {k: sum(r.result == k for r in results) for k in ('failed', 'run_out', 'invalid')}
    conf = campaign.target['confidence'] if campaign.target else 0.9
    fit = _fit(sn_data(results), conf)
    target = _target(campaign, fit)
    if target is not None and target['met']:
        fit = _sloped(fit)
        return Verdict(True, f"target met: {target['kind']} {target['estimate']:.6g}, its "
                       f"{conf * 100:g} % interval {target['interval'][0]:.6g}.."
                       f"{target['interval'][1]:.6g} within +-{campaign.target['width']:g}",
                       None, fit, target, counts)
    run = 0
    for r in reversed(results):
        if r.result != 'invalid':
            break
        run += 1
    if run >= INVALID_IN_A_ROW:
        fit = _sloped(fit)
        return Verdict(True, f'invalid: {run} specimens in a row invalid (the last: '
                       f'{results[-1].reason}): the rig or the procedure needs attention',
                       None, fit, target, counts)
    valid = [r for r in results if r.result != 'invalid']
    if campaign.plan['method'] == 'adaptive':
        level = (adaptive_level(campaign, valid, fit)
                 if len(valid) < int(campaign.plan['specimens']) else None)
    else:
        level = campaign.next_level([(r.level, r.result == 'failed') for r in valid])
    if level is None:
        fit = _sloped(fit)
        return Verdict(True, f'plan done: {len(valid)} valid specimens'
                       + (f" (target not met: +-{target['width']:.3g})" if target else ''),
                       None, fit, target, counts)
    n = len(results) + 1
    return Verdict(False, '', Next(f'{prefix}{n:02d}', float(level), n), fit, target, counts)


# -- the adaptive level ------------------------------------------------------------------------
_GL_X, _GL_W = np.polynomial.legendre.leggauss(64)


def _info_one(x: float, a: float, k: float, s: float, c: float) -> np.ndarray:
    """Return the expected Fisher information of one specimen at log-load ``x`` in (a, k, s)."""
    from scipy.stats import norm
    mu = a - k * x
    zc = (c - mu) / s
    # uncensored part: u = (y - mu) / s over (-8, zc), Gauss-Legendre
    lo = -8.0
    hi = min(zc, 8.0)
    info = np.zeros((2, 2))                              # in (mu, s)
    if hi > lo:
        u = 0.5 * (hi - lo) * _GL_X + 0.5 * (hi + lo)
        w = 0.5 * (hi - lo) * _GL_W * norm.pdf(u)
        d_mu, d_s = u / s, (u * u - 1.0) / s
        info += np.array([[np.sum(w * d_mu * d_mu), np.sum(w * d_mu * d_s)],
                          [np.sum(w * d_mu * d_s), np.sum(w * d_s * d_s)]])
    surv = float(norm.sf(zc))
    if surv > 1e-300:
        lam = float(norm.pdf(zc)) / surv
        g = np.array([lam / s, lam * zc / s])
        info += surv * np.outer(g, g)
    j = np.array([[1.0, 0.0], [-x, 0.0], [0.0, 1.0]])      # d(mu, s)/d(a, k, s)
    return j @ info @ j.T


def _tested_life(x: float, a: float, k: float, s: float, c: float) -> float:
    """Return the expected cycles a specimen at ``x`` is tested for: E[min(N, run-out)]."""
    from scipy.stats import norm
    mu = a - k * x
    zc = (c - mu) / s
    lo, hi = -8.0, min(zc, 8.0)
    tested = 0.0
    if hi > lo:
        u = 0.5 * (hi - lo) * _GL_X + 0.5 * (hi + lo)
        tested = float(np.sum(0.5 * (hi - lo) * _GL_W * norm.pdf(u) * 10.0 ** (mu + s * u)))
    return tested + float(norm.sf(zc)) * 10.0 ** c


def _frequency(campaign: Campaign, level: float) -> float:
    for step in campaign.procedure(level).steps:
        if step.name == campaign.level_step:
            return float(step['frequency'])
    return 1.0


def adaptive_level(campaign: Campaign, valid: Sequence[Any], fit: BasquinFit | None) -> float:
    """Return the level an adaptive plan tests next (module docstring)."""
    p = campaign.plan
    lo, hi = float(p['low']), float(p['high'])
    if fit is None:
        return (hi, lo, math.sqrt(lo * hi))[len(valid) % 3]
    a, k, s = fit.a, fit.k, max(fit.s, 1e-3)
    c = math.log10(campaign.run_out)
    info = sum((_info_one(math.log10(r.level), a, k, s, c) for r in valid),
               np.zeros((3, 3))) + 1e-9 * np.eye(3)
    t = campaign.target
    if t is not None and t['kind'] == 'life_at_load':
        xl = math.log10(t['load'])
        g = np.array([1.0, -xl, 0.0])
    else:
        yd = math.log10(t['life']) if t is not None else \
            float(np.median(np.log10([r.cycles for r in valid])))
        g = np.array([1.0 / k, -(a - yd) / k ** 2, 0.0])
    var0 = float(g @ np.linalg.solve(info, g))
    best, best_gain = hi, -math.inf
    for level in np.geomspace(lo, hi, CANDIDATES):
        x = math.log10(level)
        var1 = float(g @ np.linalg.solve(info + _info_one(x, a, k, s, c), g))
        hours = _tested_life(x, a, k, s, c) / _frequency(campaign, float(level)) / 3600.0
        gain = (var0 - var1) / max(hours, 1e-9)
        if gain > best_gain:
            best, best_gain = float(level), gain
    return best
