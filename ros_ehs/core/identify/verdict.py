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
The verdict of a fit: do the fitted parameters describe the rig? Checked on held-out data.

A replay's residual against the sensor noise cannot answer that on a real rig: the rig is
never exactly the model, and a replay's position integrates every small model error, so
against a fine encoder every fit fails it. The verdict therefore asks what an engineer asks of
a model (docs/identification.md, "The verdict"): fitted on one half of the record, does it
predict the other half, and do the halves agree on the values?

* :func:`halves` cuts the record in two, each half alternate quarters of it;
  :func:`ros_ehs.core.identify.estimator.judge` refits each half warm from the joint fit;
* **prediction**: each half replayed with the other half's values (but its own null shape,
  :data:`NULL_SHAPE`), against its own fit, per
  signal where a replay's drift cannot accumulate (velocity, pressures, load cell): a residual
  both :data:`PREDICTION_RATIO` times its own fit's and adding (:func:`added_residual`) more
  than :data:`PREDICTION_LIMIT` of the signal's spread says the values describe the data they
  were fitted to, not the rig;
* **agreement**: each free parameter's values from the two halves and from the whole record
  span at most :data:`AGREEMENT` of the whole record's (the valve's null shape,
  :data:`NULL_SHAPE`, is not judged: the data rarely determine it);
* **jackknife**, instead of the agreement for a record without pressures slower than
  :data:`SLOW_RATE_HZ`: the record is refitted without each of its quarters in turn
  (:func:`leave_one_out`), and each free parameter's standard error from those refits
  (:func:`jackknife`) is at most :data:`JACKKNIFE_LIMIT` of its value;
* **sensed signals**: the pressures' and the load cell's residuals, against their sensors'
  noise, at most :data:`SENSED_LIMIT`;
* the solver converged (or stopped at its evaluation limit with the values settled within
  their standard errors, :func:`settled`), the fitted values are a valid parameter set, and
  the states of runs fitted without pressures were recorded at :data:`MIN_RATE_HZ` or faster
  (:func:`judged_rate`).

:func:`fit_metrics` gives per experiment and signal the NRMSE, R^2, RMS, the ratio of the
residual to the noise and its lag-1 autocorrelation: reported, and the basis of the
standard errors' widening, not of the verdict.
"""

from __future__ import annotations

from dataclasses import replace
import math
from typing import Sequence

import numpy as np
from ros_ehs.core.identify.experiment import Experiment
from ros_ehs.core.identify.problem import CELL, LOAD, Problem, SIGNALS

__all__ = ['AGREEMENT', 'DRIFT_FREE', 'JACKKNIFE_LIMIT', 'LEAD_IN', 'MIN_RATE_HZ', 'NULL_SHAPE',
           'PREDICTION_LIMIT', 'PREDICTION_RATIO', 'QUARTERS', 'RESTART',
           'RULES', 'SENSED', 'SENSED_LIMIT', 'SETTLED', 'SETTLE_ITERATIONS',
           'SLOW_RATE_HZ',
           'SMALL_MODEL_ERROR', 'added_residual', 'spread', 'why_adequate', 'adequacy',
           'fit_metrics', 'halves', 'jackknife', 'judged_on_jackknife', 'leave_one_out',
           'halves_check', 'judged_rate', 'median_noise_ratios', 'restart', 'settled',
           'worst_noise_ratio']


#: The verdict's rules, each failed one named in a fit's ``failed`` (``summary.json``:
#: ``failed_rules``), beside its reason, as ``rule`` or ``rule:what`` (the signal or the
#: parameter it judged: ``prediction:z_dot``, ``agreement:F_cc``), so that a program reads
#: why a fit failed without parsing the reason's text.
RULES = {
    'rate': 'the states of a run fitted without pressures were recorded below MIN_RATE_HZ',
    'solver': 'the solver stopped at its evaluation limit before the values settled',
    'invalid': 'the fitted values are not a valid parameter set',
    'sensed': "a sensed signal's residual is above SENSED_LIMIT times its sensor noise",
    'prediction': "a half replayed with the other half's values: a residual above "
                  "PREDICTION_RATIO times its own fit's that adds above PREDICTION_LIMIT of the "
                  "signal's spread",
    'agreement': "the halves' and the whole record's values of a parameter spread above "
                 'AGREEMENT',
    'jackknife': "a record without pressures slower than SLOW_RATE_HZ: a parameter's "
                 'standard error from the refits without each quarter of the record is above '
                 'JACKKNIFE_LIMIT of its value',
    'half_invalid': "a half's fit is not a valid parameter set",
    'jackknife_invalid': 'the fit of the record without one of its quarters is not a valid '
                         'parameter set',
}


#: Held-out prediction: a half replayed with the other half's values fails when its residual is
#: both more than this factor of its own fit's (the values predict it noticeably worse) ...
PREDICTION_RATIO = 1.25

#: ... and adds (:func:`added_residual`) more than this fraction of the signal's spread (the
#: difference matters). Either alone flags good fits: the ratio divides by the half's own fit,
#: so a close fit reads 1.25-1.45x for an added 0.3-0.6 % of the signal (the velocity of 4
#: good fits with pressures at 1-2 kHz, their own residual 0.4-0.7 % of it); the added
#: residual reads 5-6 % on position-only records whose own velocity residual is 20-30 % of the
#: signal, for a ratio of 1.02-1.04 (2 good fits at 0.5-1 kHz; both examples judged per run).
#: Measured per replay segment (benchmark ``verdict``, seeds 0-59 and 140-199): of the 110
#: good reduced fits the ratio alone would flag 1, the added residual alone 3, both none; no
#: reduced fit fails the prediction, 1 of the 120 simplified fits does (also failing another
#: rule).
PREDICTION_LIMIT = 0.01

#: Agreement: the halves' values of a parameter may differ by this fraction of the joint value.
#: Each half holds alternate quarters of the record (:func:`halves`), yet they see different
#: stretches of excitation, so their values differ by more than the joint value's error: on
#: the benchmark's rigs (``python -m ros_ehs.benchmarks verdict``, seeds 0-59 and 140-199)
#: the good reduced fits' halves spread up to 20 % on friction without pressures at 500 Hz-4
#: kHz, 5 % with; of the 101 good fits this rule judges 2 spread over 12 % (both at 500 Hz
#: without pressures), 1 over 15 %. (At 250 Hz without pressures they spread up to 24 %, and
#: the records are judged on their jackknife instead: :data:`SLOW_RATE_HZ`.) (Their standard
#: errors do not help: widened for the correlated residuals of a model that is not the rig, a
#: half's are tens of % where the halves agree within a few.)
AGREEMENT = 0.12

#: The slowest state rate of a run fitted *without pressures* that the verdict judges [Hz]:
#: the slowest it is tested at (below it, a reason of its own).
MIN_RATE_HZ = 250.0

#: Below this state rate [Hz], a record fitted *without pressures* is judged on its
#: jackknife (:data:`JACKKNIFE_LIMIT`), not on its halves' agreement. A replay of position
#: alone carries the chamber pressures open-loop, and the slower the record the more a
#: breakaway falls between samples, where the breakaway and the Coulomb friction trade off
#: against each other; there one pair of halves scatters too widely to be read. Measured
#: (benchmark ``verdict``, seeds 0-59 and 140-199, the reduced model, the 13 records at 250 Hz
#: without pressures): 9 fits within 5 %, 2 between 5 and 10 % off, 2 more than 10 % off
#: (F_cc high and F_sc low); the good fits' halves spread 1.9-23.7 % on friction, the bad
#: ones' 8.6 % and 15.5 %, so no limit on the halves separates them. Of the 12 at 500 Hz,
#: 11 within 5 % and one between 5 and 10 %. With their pressures all 11 records at 250 Hz
#: fit within 5 %.
SLOW_RATE_HZ = 500.0

#: The standard error from the jackknife (:func:`jackknife`) a parameter of a record slower
#: than :data:`SLOW_RATE_HZ` without pressures may have, as a fraction of its value: two
#: standard errors span the 10 % that the benchmark ``verdict`` calls a bad fit. Its four
#: refits each see three quarters of the record, so that one quarter poor in excitation moves
#: one of four values, and their spread is read with three degrees of freedom, where the
#: halves' spread has one. Measured on the 23 records at 250 Hz without pressures of seeds
#: 0-59, 140-199 and 200-319 (reduced model): the 14 good fits' largest standard errors
#: 0.6-4.7 %, the two bad ones' 7.7 % and 17.1 % (the third stopped at the solver's limit).
JACKKNIFE_LIMIT = 0.05


#: The record is cut into this many pieces of equal length for the held-out check
#: (:func:`halves`), alternately given to the two halves.
QUARTERS = 4

#: How long before a cut a piece of :func:`halves` or :func:`leave_one_out` is replayed from
#: (its warm-up) [s]. A record without pressures carries them open-loop, and a piece started
#: mid-motion from the equilibrium guess replays its first tens of ms with the wrong force on
#: the piston.
#: Measured on Table 1's reduced model driven by a 2 Hz sine, from three instants: the load
#: pressure 6-196 bar off at the start, 1.6 mm of position error after 10 ms; after 100 ms
#: at most 0.13 bar, after 200 ms none.
LEAD_IN = 0.2


def _below(rate_hz: float, limit_hz: float) -> bool:
    """Return whether ``rate_hz`` is below ``limit_hz`` (a driver's mean period is not exact)."""
    return rate_hz < 0.98 * limit_hz


def judged_on_jackknife(rate_hz: float) -> bool:
    """
    Return whether a record is judged on its jackknife, not on its halves' agreement.

    ``rate_hz``: the slowest state rate of its runs fitted without pressures
    (:func:`judged_rate`); below :data:`SLOW_RATE_HZ` (:data:`JACKKNIFE_LIMIT`).
    """
    return _below(rate_hz, SLOW_RATE_HZ)


def judged_rate(experiments, signals) -> float:
    """
    Return the slowest state rate [Hz] of the runs fitted without pressures (inf: none).

    A run is fitted with pressures when it recorded both chamber pressures and ``signals``
    names ``p_CP``, or it recorded a load pressure and ``signals`` names ``p_L``.
    """
    def pressured(e) -> bool:
        return ('p_CP' in signals and e.p_a is not None and e.p_b is not None) or \
            (LOAD in signals and getattr(e, 'p_load', None) is not None)

    return min((1.0 / e.dt for e in experiments if not pressured(e)), default=math.inf)


#: Measured signals whose residual is judged against their sensor noise: a pressure
#: transducer's or a load cell's noise is the sensor's own and white, and a replay's pressures
#: restart from the measured ones each segment. (The position is not judged: a replay's
#: position drifts, and a quantised encoder's error is not white; nor a velocity derived from
#: it, whose noise is the encoder's through a filter.)
SENSED = ('p_CP', 'p_CT', LOAD, CELL)

#: The most a sensed signal's residual may be, in its sensor noise (median of the runs).
#: Measured on full-model rigs (benchmark ``verdict``, seeds 0-59 and 140-199, the worst
#: pressure of each fit): the reduced model's 57 good fits with pressures 0.44-1.97 (the
#: highest a 2 kHz record with every value within 4.5 %), the simplified model's 3.3-21.
SENSED_LIMIT = 2.0

#: The metering edges' rounding radius and null offset shape the flow only within a few um of
#: the null: a fit sees them through the few samples at small openings, and halves rarely agree
#: on them. They are judged by neither the agreement nor the prediction, which replays each
#: half with the other half's values and its own null shape: a half of a 250 Hz record holds
#: few samples near the null, and one half's r_c 74 % or 94 % off failed the prediction of
#: good fits (2 of the 102 of the benchmark ``verdict``'s seeds 0-59 and 140-199, measured
#: on records cut at each lost state, each half one side of the middle); of the fits there
#: and on seeds 200-319 that were not good, none failed the prediction alone. (Held at the
#: whole record's values in the halves' refits instead, the false alarms and misses moved
#: between rigs without falling.) The halves' values of both are reported.
NULL_SHAPE = ('r_c', 'x_bias')

#: Signals a replay's drift does not accumulate in: the prediction is judged on these; the
#: position's ratio is reported beside.
DRIFT_FREE = ('z_dot', 'p_CP', 'p_CT', LOAD, CELL)

#: A fit whose worst residual is above this many times the sensor noise carries a warning: a
#: model error remains, and it can bias the values by more than their standard errors (the
#: reduced model on full-model bags sits at about 1.15).
SMALL_MODEL_ERROR = 1.1


#: A solver stopped at its evaluation limit has still converged for every purpose when its last
#: :data:`SETTLE_ITERATIONS` iterations moved no value by more than :data:`SETTLED` of its
#: standard error. (Measured: fits of position-only records creep along a valley of the cost,
#: a unit of noise an iteration, for hundreds of evaluations, each value moving 1e-4 to 1e-3
#: of its standard error an iteration.)
SETTLED = 0.05
SETTLE_ITERATIONS = 10


def settled(history: Sequence[dict], stderr: dict[str, float]) -> bool:
    """
    Return whether the values of a fit's ``history`` have settled within their ``stderr``.

    ``history``: one ``{'x': {name: value}}`` per iteration (the last is the result);
    True when the last :data:`SETTLE_ITERATIONS` iterations moved no value by more than
    :data:`SETTLED` of its standard error (a value without a finite one must not move).
    """
    if len(history) <= SETTLE_ITERATIONS:
        return False
    last, before = history[-1]['x'], history[-1 - SETTLE_ITERATIONS]['x']
    for n, v in last.items():
        s = stderr.get(n, math.nan)
        moved = abs(v - before[n])
        if not (moved <= SETTLED * s if math.isfinite(s) else moved == 0.0):
            return False
    return True


def _signal_metrics(y: np.ndarray, e: np.ndarray, sigma: float) -> dict[str, float]:
    """Fit figures of one signal ``y`` with residual ``e`` and sensor noise ``sigma``."""
    sst = float(np.sum((y - y.mean()) ** 2))
    sse = float(np.sum(e ** 2))
    c = e - e.mean()
    cc = float(np.dot(c, c))
    return {'nrmse': math.sqrt(sse / y.size) / (float(np.std(y)) or 1.0),
            'r2': 1.0 - sse / sst if sst > 0 else math.nan,
            'rms': math.sqrt(sse / y.size),
            'noise_ratio': math.sqrt(sse / y.size) / float(sigma),
            'acf1': float(np.dot(c[1:], c[:-1])) / cc if cc > 0 else math.nan}


def _residuals(problem: Problem, theta: np.ndarray, fitted: dict | None = None):
    """
    Yield each experiment of ``problem`` replayed with ``theta``: ``(ex, {signal: (y, e, s)})``.

    ``e`` is the replay's residual against the measurement ``y`` (the position's without its
    offset per segment), ``s`` the sensor's noise; ``fitted`` (if given) gets the traces.
    """
    for ex, o in zip(problem.exps, problem.simulate(theta)):
        fit = {n: o[:, problem.names.index(n)] for n in SIGNALS if n in problem.names}
        res = {}
        for j, sigma in zip(ex.measured, ex.sigma):
            name = problem.names[j]
            y, f = ex.y[:, j], o[:, j]
            e = f - y
            if name == 'z':
                ex.offset_free(e)
                fit['z'] = y + e     # position is fitted up to an offset per segment
            res[name] = (y, e, sigma)
        if ex.load is not None:
            f = o[:, problem.ipa] - o[:, problem.ipb]
            fit[LOAD] = f
            res[LOAD] = (ex.load, f - ex.load, ex.load_sigma)
        if ex.cell is not None:
            f = problem.cell_force(theta, ex)
            fit[CELL] = f
            res[CELL] = (ex.cell, f - ex.cell, ex.cell_sigma)
        if fitted is not None:
            fitted[ex.name] = fit
        yield ex, res


def fit_metrics(problem: Problem, theta: np.ndarray, fitted: dict | None = None
                ) -> dict[str, dict[str, dict[str, float]]]:
    """Return fit metrics per experiment and signal; ``fitted`` (if given) gets the traces."""
    return {ex.name: {name: _signal_metrics(y[ex.warmup:], e[ex.warmup:], sigma)
                      for name, (y, e, sigma) in res.items()}
            for ex, res in _residuals(problem, theta, fitted)}


def segment_errors(problem: Problem, theta: np.ndarray) -> dict[str, dict[str, np.ndarray]]:
    """
    Return per experiment and signal each replay segment's residual RMS, in the signal's spread.

    The spread is the signal's standard deviation over its whole run (as in ``nrmse``), so a
    segment's figure reads as the run's would if every segment were like it. A segment with
    no residual compared (a derived velocity's segment shorter than its filter) reads 0.
    """
    out = {}
    for ex, res in _residuals(problem, theta):
        per = {}
        for name, (y, e, _) in res.items():
            spread_ = float(np.std(y[ex.warmup:])) or 1.0
            per[name] = np.array([math.sqrt(float(np.mean(e[a:b] ** 2))) / spread_
                                  for a, b in ex.segments() if b > a and a >= ex.warmup])
        out[ex.name] = per
    return out


def median_noise_ratios(metrics: dict) -> dict[str, float]:
    """Return per signal the median over the runs of ``metrics`` of its ``noise_ratio``."""
    ratios: dict[str, list[float]] = {}
    for sig in metrics.values():
        for name, m in sig.items():
            ratios.setdefault(name, []).append(m['noise_ratio'])
    return {name: float(np.median(v)) for name, v in ratios.items()}


def worst_noise_ratio(metrics: dict) -> float:
    """Return the largest ``noise_ratio`` of any signal in ``metrics`` (NaN when none)."""
    return max((m['noise_ratio'] for sig in metrics.values() for m in sig.values()
                if math.isfinite(m.get('noise_ratio', math.nan))), default=math.nan)


def _quarters(experiments: Sequence[Experiment]) -> list[tuple[int, int]]:
    """Return the record's :data:`QUARTERS` pieces as sample ranges, its runs one after another."""
    total = sum(e.t.size for e in experiments)
    edges = [total * k // QUARTERS for k in range(QUARTERS + 1)]
    return list(zip(edges[:-1], edges[1:]))


def _keep(experiments: Sequence[Experiment], ranges: Sequence[tuple[int, int]]
          ) -> list[Experiment]:
    """
    Return the samples of ``experiments`` in ``ranges`` (of the runs one after another).

    Adjacent ranges join; a run holding a range's edge is cut there. A piece that starts
    mid-run is replayed from :data:`LEAD_IN` before its start (its ``warmup``, not
    compared), so that the states no sensor measured reach it as the piece's own values
    carry them, not as a guess.
    """
    joined: list[list[int]] = []
    for a, b in sorted(ranges):
        if joined and a == joined[-1][1]:
            joined[-1][1] = b
        else:
            joined.append([a, b])
    part: list[Experiment] = []
    seen = 0
    for e in experiments:
        n = e.t.size
        for ga, gb in joined:
            a, b = max(ga - seen, 0), min(gb - seen, n)
            if b - a < 2:
                continue
            if (a, b) == (0, n):
                part.append(e)
                continue
            lead = min(a, int(round(LEAD_IN / e.dt)))
            piece = e.window(a - lead, b)
            part.append(replace(piece, warmup=max(piece.warmup, lead)))
        seen += n
    return part


def halves(experiments: Sequence[Experiment]) -> tuple[list[Experiment], list[Experiment]]:
    """
    Cut ``experiments`` in two halves, each of alternate quarters (:data:`QUARTERS`).

    The record (its runs one after the other) is cut into quarters of its samples: the first
    half holds the first and third, the second half the second and fourth, so that each sees
    the record's early and late excitation (a chirp's low and its high frequencies). A run
    holding a cut is cut there. A piece after a cut starts mid-motion: it is replayed from
    :data:`LEAD_IN` before the cut (its ``warmup``, not compared), so that the states no sensor
    measured reach the cut as the piece's own values carry them, not as a guess.
    """
    exps = list(experiments)
    quarters = _quarters(exps)
    return _keep(exps, quarters[0::2]), _keep(exps, quarters[1::2])


def leave_one_out(experiments: Sequence[Experiment]) -> list[list[Experiment]]:
    """
    Return the record without each of its quarters in turn (:data:`QUARTERS` parts).

    Part ``k`` holds every quarter but the ``k``-th (the record's samples, its runs one after
    the other, as :func:`halves` cuts them), the quarters around the gap joined, a piece
    after the gap replayed from :data:`LEAD_IN` before it.
    """
    exps = list(experiments)
    quarters = _quarters(exps)
    return [_keep(exps, quarters[:k] + quarters[k + 1:]) for k in range(len(quarters))]


def jackknife(values: Sequence[dict[str, float]], whole: dict[str, float]) -> dict:
    """
    Return the jackknife's standard errors of ``whole``'s values (JSON-ready).

    ``values``: the fits of the record without each of its quarters in turn
    (:func:`leave_one_out`), each warm from ``whole``'s. Keys: ``values`` (those fits'),
    ``stderr`` (per parameter, ``sqrt((K - 1) / K * sum((v_k - mean)^2))`` over the ``K``
    fits, as a fraction of the whole record's value; inf when that is 0): the standard error
    of a value fitted to ``K`` pieces whose errors are not white, estimated from the record
    itself with ``K - 1`` degrees of freedom (the halves' spread has one).
    """
    k = len(values)
    stderr = {}
    for n, v in whole.items():
        vals = np.array([x[n] for x in values], dtype=float)
        se = math.sqrt((k - 1) / k * float(np.sum((vals - vals.mean()) ** 2)))
        stderr[n] = se / abs(v) if v else math.inf
    return {'values': [dict(x) for x in values], 'stderr': stderr}


def spread(first: float, second: float, whole: float) -> float:
    """
    Return how far apart a parameter's values from the halves and the whole record are.

    The span of the three as a fraction of the whole record's value (inf when that is 0):
    halves that agree with each other but not with the whole say the whole record's fit
    stopped elsewhere, and count as much as halves that disagree.
    """
    vals = (first, second, whole)
    return (max(vals) - min(vals)) / abs(whole) if whole else math.inf


#: The halves' mean this far from the whole record's value of a parameter (a fraction of it)
#: starts a second fit of the whole record from that mean (:func:`restart`). A rule of the
#: fit, not a limit of the verdict: kept apart from :data:`AGREEMENT`, so that judging the
#: halves more or less strictly does not change which fits are refitted. Measured on the
#: benchmark ``verdict`` (seeds 0-59 and 140-199, its ``restarts``): the halves point apart on
#: 29 of the 120 reduced fits, and the second fit, kept on all 29, ends closer to the truth on
#: 26 (6 bad fits made good, among them 21.9 % and 15.4 % off before, 3.3 % and 2.0 % after)
#: and farther on 3, by at most 1.6 points (5.4 to 7.0 %).
RESTART = 0.04


def restart(first: dict[str, float], second: dict[str, float],
            whole: dict[str, float]) -> dict[str, float] | None:
    """
    Return where to refit the whole record from, when its halves point elsewhere; else None.

    ``first``, ``second``: the halves' values (each refitted warm from ``whole``'s); the
    mean of the two when it is apart from ``whole`` by more than :data:`RESTART` on a
    parameter other than the valve's null shape: halves that both left the whole record's
    values for the same side found what may be a better optimum of the whole record too
    (:func:`ros_ehs.core.identify.estimator.judge` keeps the refit when its cost is lower).
    """
    mean = {n: 0.5 * (first[n] + second[n]) for n in whole}
    apart = any(abs(mean[n] - v) > RESTART * abs(v) for n, v in whole.items()
                if n not in NULL_SHAPE)
    return mean if apart else None


def added_residual(own: float, other: float) -> float:
    """
    Return the residual a replay with other values adds to its own fit, in signal spreads.

    ``own``, ``other``: one signal's residual RMS over its spread (:func:`segment_errors`) in
    the same replay segment replayed with its own fit's values and with the other half's;
    ``sqrt(other^2 - own^2)``, 0 when the other values fit as well or better: the error the
    other values add to the model's own, independent of each other when the values describe
    the rig.
    """
    a, b = float(own), float(other)
    if not (math.isfinite(a) and math.isfinite(b)):
        return math.inf
    return math.sqrt(max(b * b - a * a, 0.0))


def halves_check(parts: Sequence[Sequence[Experiment]], refits: Sequence, joint: dict,
                 problem_of) -> dict:
    """
    Return the held-out check of a fit as data (JSON-ready).

    ``parts``: the two halves; ``refits``: each half's fit (an ``IdentificationResult``);
    ``joint``: the joint fit's values; ``problem_of(experiments, params)``: the
    :class:`Problem` that replays ``experiments`` with ``params`` (same model and settings).
    Keys: ``prediction`` (per signal, the median over the replay segments of both halves of
    the residual the other half's values add to the segment's own fit,
    :func:`added_residual`, in the signal's spread), ``prediction_ratio`` (the same medians
    of the ratio of the two residual RMS; the verdict reads both), ``judged``
    (the signals the verdict reads), ``halves`` (each half's values and sample count) and
    ``disagreement`` (per parameter, the spread of the two halves' values and the joint one,
    as a fraction of the joint value).

    Judged per replay segment, not per run: one segment the other values replay far worse,
    while they replay the rest as well, is a threshold the values differ on by a hair (the
    moment of a breakaway from rest moves with F_sc), not values that describe only their
    own half; values that do replay most segments worse.
    """
    added: dict[str, list[float]] = {}
    ratios: dict[str, list[float]] = {}
    for b, a in ((0, 1), (1, 0)):
        # the half replayed with its own fit's values, and with the other half's values but
        # this half's own null shape (NULL_SHAPE)
        own = refits[b].params
        other = refits[a].params.replace(**{n: own[n] for n in NULL_SHAPE if n in refits[b].x})
        replays = []
        for params in (own, other):
            po = problem_of(parts[b], params)
            replays.append(segment_errors(po, np.array([params[n] for n in po.free]) / po.scale))
        for mine, theirs in zip(replays[0].values(), replays[1].values()):
            for name, m in mine.items():
                for r, o in zip(m, theirs[name]):
                    if r == 0.0 and o == 0.0:    # nothing compared in this segment
                        continue
                    added.setdefault(name, []).append(added_residual(r, o))
                    ratios.setdefault(name, []).append(
                        o / r if r > 0 and math.isfinite(o) else math.inf)
    prediction = {name: float(np.median(v)) for name, v in added.items()}
    disagreement = {n: spread(refits[0].x[n], refits[1].x[n], v) for n, v in joint.items()}
    return {'prediction': prediction,
            'prediction_ratio': {name: float(np.median(v)) for name, v in ratios.items()},
            'judged': [n for n in prediction if n in DRIFT_FREE],
            'halves': [{'samples': int(sum(e.t.size - e.warmup for e in part)),
                        'runs': len(part), 'values': dict(r.x)}
                       for part, r in zip(parts, refits)],
            'joint': dict(joint), 'disagreement': disagreement}


def adequacy(status: int, max_nfev: int, model: str, invalid: str, check: dict | None,
             metrics: dict, is_settled: bool = False, rate_hz: float = math.inf,
             spread_of: dict | None = None) -> tuple[list[str], list[str], list[str]]:
    """
    Return the reasons a fit is not adequate (empty: adequate), the advice, the rules failed.

    The rules (:data:`RULES`) go one to a reason, in its order.

    ``status``: scipy's (0: the evaluation limit); ``invalid``: why the fitted values are not
    a valid parameter set (empty: they are); ``check``: :func:`halves_check`'s answer, or
    None when the fit was not checked on its halves; ``metrics``: :func:`fit_metrics`'s;
    ``is_settled``: the values had settled when the solver stopped (:func:`settled`), so a
    stop at the evaluation limit is no reason; ``rate_hz``: the slowest state rate of the
    runs fitted without pressures (:func:`judged_rate`; below :data:`MIN_RATE_HZ`, a reason
    of its own; below :data:`SLOW_RATE_HZ`, :func:`judged_on_jackknife`); ``spread_of``:
    :func:`jackknife`'s answer, read instead of the halves' agreement for a record judged on
    its jackknife (a ``ValueError`` when such a record with a ``check`` has none).
    """
    why: list[str] = []
    advice: list[str] = []
    failed: list[str] = []
    if _below(rate_hz, MIN_RATE_HZ):
        failed.append('rate')
        why.append(f'the states were recorded at {rate_hz:.0f} Hz, below {MIN_RATE_HZ:.0f} Hz, '
                   'without pressures: the verdict is not tested so slow, where a breakaway '
                   'falls between samples and a fit of the position alone can put the '
                   'friction (F_cc, F_sc) off unseen (docs/identification.md)')
        advice.append(f'record the chamber pressures, or the states at {MIN_RATE_HZ:.0f} Hz or '
                      'faster (the rate the rig driver publishes them at)')
    if status == 0 and not is_settled:
        failed.append('solver')
        why.append(f'the solver stopped at its evaluation limit (max_nfev = {max_nfev}) '
                   'before converging: the values are not an optimum')
        advice.append('raise max_nfev, or start nearer (--initial)')
    if invalid:
        failed.append('invalid')
        why.append(f'the fitted values are not a valid parameter set ({invalid}): the model '
                   'cannot describe what the data show')
    recorded = {n for m in metrics.values() for n in m}
    pressures = any(n in recorded for n in ('p_CP', 'p_CT', LOAD))
    wrong_model = bool(invalid)
    medians = median_noise_ratios(metrics)
    for name in SENSED:
        ratio = medians.get(name)
        if ratio is not None and not ratio <= SENSED_LIMIT:      # a NaN ratio fails too
            wrong_model = True
            failed.append(f'sensed:{name}')
            why.append(f'the {name} residual is {ratio:.1f}x its sensor noise (median of the '
                       f'runs; limit {SENSED_LIMIT:g}): the model does not explain what this '
                       'sensor measured')
    if check is not None:
        for name in check['judged']:
            added = check['prediction'][name]
            ratio = check['prediction_ratio'][name]
            if added > PREDICTION_LIMIT and ratio > PREDICTION_RATIO:
                wrong_model = True
                failed.append(f'prediction:{name}')
                why.append(f'held out: each half replayed with the values fitted to the other '
                           f"leaves a {name} residual {ratio:.2f}x its own fit's, adding "
                           f"{100 * added:.1f} % of the signal's spread (medians of the replay "
                           f'segments; limits {PREDICTION_RATIO:g}x and '
                           f'{100 * PREDICTION_LIMIT:g} %): the values describe the data they '
                           'were fitted to, not the rig')
        slow = judged_on_jackknife(rate_hz)
        if slow and spread_of is None:
            raise ValueError(f'a record at {rate_hz:.0f} Hz without pressures is judged on its '
                             'jackknife: pass `spread_of` (verdict.jackknife)')
        if slow:
            loose = [n for n, se in spread_of['stderr'].items()
                     if n not in NULL_SHAPE and not se <= JACKKNIFE_LIMIT]
            for n in loose:
                v = [x[n] for x in spread_of['values']]
                failed.append(f'jackknife:{n}')
                why.append(f'held out: refitted without each quarter of the record in turn, '
                           f'{n} = {min(v):.4g} to {max(v):.4g}, the whole {check["joint"][n]:.4g}'
                           f': a standard error of {100 * spread_of["stderr"][n]:.1f} % '
                           f'(jackknife; limit {100 * JACKKNIFE_LIMIT:g} %, states at '
                           f'{rate_hz:.0f} Hz without pressures): the data do not determine it')
        else:
            loose = [n for n, d in check['disagreement'].items()
                     if n not in NULL_SHAPE and d > AGREEMENT]
            for n in loose:
                d = check['disagreement'][n]
                v = [h['values'][n] for h in check['halves']]
                failed.append(f'agreement:{n}')
                why.append(f'held out: the two halves of the record give {n} = {v[0]:.4g} and '
                           f'{v[1]:.4g}, the whole {check["joint"][n]:.4g}: {100 * d:.1f} % '
                           f'apart (limit {100 * AGREEMENT:g} %): the data do not determine it')
        if loose and not pressures and any(n in ('F_cc', 'F_sc', 'c_c') for n in loose):
            # a slow record: faster states would help as much as pressures
            faster = (f', or the states at {SLOW_RATE_HZ:.0f} Hz or faster (the rate the rig '
                      'driver publishes them at)') if slow else ''
            advice.append('record the chamber pressures (pressure_p and pressure_t, or '
                          f'pressure_load, in the topic map){faster}: without them the replay '
                          'carries the pressures open-loop through each record, and friction '
                          '(F_cc, F_sc, c_c) is the least certain (docs/identification.md)')
        if loose:
            advice.append('record more excitation: several amplitudes and frequencies (a chirp '
                          'from the reference node) in several runs, so that each '
                          + ('quarter' if slow else 'half') + ' of the record shows '
                          + ', '.join(loose))
    if wrong_model:
        if model == 'simplified':
            advice.append('fit the reduced model (--model reduced): the simplified one leaves '
                          "out the valve's lag and its opening under load, which the reduced "
                          'one takes from the full model (docs/model.md); or the full model '
                          '(--model full), slower')
        elif model == 'reduced':
            advice.append('fit the full model (--model full): the reduced one leaves out the '
                          "valve's own dynamics (docs/model.md)")
        else:
            advice.append('free other parameters (--free): the fixed values may not be the '
                          "rig's")
    return why, advice, failed


def why_adequate(check: dict, spread_of: dict | None = None) -> str:
    """
    Return what an adequate fit's verdict rests on, in a line.

    ``held out: predicts the other half within 0.4 % of the signal, 1.08x its own fit
    (z_dot); halves agree within 3.1 % (F_sc)``; with ``spread_of`` (:func:`jackknife`'s
    answer, a record judged on it), ``... ; standard errors within 2.1 % (F_sc, jackknife)``
    in place of the halves' agreement; without a held-out check, that none was run.
    """
    if not check:
        return 'not checked on held-out data (verdict=False): converged, a valid set'
    pred = {n: check['prediction'][n] for n in check['judged']}
    judged = spread_of['stderr'] if spread_of else check['disagreement']
    agree = {n: d for n, d in judged.items() if n not in NULL_SHAPE}
    parts = []
    if pred:
        worst = max(pred, key=pred.get)
        parts.append(f'predicts the other half within {100 * pred[worst]:.1f} % of the '
                     f"signal, {check['prediction_ratio'][worst]:.2f}x its own fit ({worst})")
    if agree:
        worst = max(agree, key=agree.get)
        parts.append(f'standard errors within {100 * agree[worst]:.1f} % ({worst}, jackknife)'
                     if spread_of else
                     f'halves agree within {100 * agree[worst]:.1f} % ({worst})')
    return 'held out: ' + '; '.join(parts)
