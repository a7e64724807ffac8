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
Refit plant parameters from experiments: bounded trust-region-reflective least squares.

The paper's section 3, shaped like ``scipy.optimize.least_squares``: :func:`identify`
validates every input first (naming the argument) and returns an
:class:`IdentificationResult` with ``x``, ``cost``, ``status``, ``message``, the iteration
history, standard errors, the correlation matrix, fit metrics and identifiability warnings.

How the fit works (docs/identification.md):

* The model is driven by the *recorded* servo current (open-loop replay) and compared with
  the measured velocity (the paper's signal), position and chamber pressures when recorded.
  Each residual is divided by that signal's noise level, estimated from the data.
* The record is cut into segments (default 1 s). Each segment starts from the measured
  state; unmeasured states carry over from the previous segment. Position is compared up
  to a constant per segment, so the noise of the starting sample does not bias the fit.
  Without this, a noisy start offsets the whole open-loop position trace.
* Parameters are scaled by Table 1's scale gains and bounded by its bounds. The Jacobian is
  a forward difference in scaled units with a step of 1e-3 (the simulator's round-off makes
  scipy's default 1.5e-8 step useless); its columns run in parallel on ``workers``
  threads.
* ``cost='sae'`` (the paper) is the pseudo-Huber ``soft_l1`` loss with ``f_scale`` 0.1 noise
  sigma: |r| to within 5 % above 0.1 sigma, smooth for the Gauss-Newton model at zero.
  ``cost='sse'`` is plain least squares.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
import math
import os
import time
from typing import Callable, Sequence
import warnings

import numpy as np
from ros_ehs.bag.experiment import Experiment
from ros_ehs.errors import IdentificationWarning, InputError, ParameterError
from ros_ehs.model import kernels as K
from ros_ehs.model.coefficients import pack
from ros_ehs.model.plant import DEFAULT_H, DEFAULT_JAC_EVERY, MODELS, Plant
from ros_ehs.params import ESTIMATED, Params, preset, spec
from scipy.optimize import least_squares

__all__ = ['IdentificationResult', 'NOISE_RATIO_LIMIT', 'Problem', 'adequacy', 'identify',
           'multistart', 'noise_sigma', 'score']

SIGNALS = ('z_dot', 'z', 'p_CP', 'p_CT', 'p_L')
#: the load pressure p_CP - p_CT: fitted where a rig records only that (not a state)
LOAD = 'p_L'
_FD_STEP = 1e-3
#: Relative step and cost-change tolerances (``xtol``, ``ftol``) of the solve and of the SSE
#: stage before an SAE one. The parameters' standard errors are 4e-4 to 1e-2 of their values
#: on a 10 s bag, and a cost change of 1e-8 of some 2e4 is far below one unit of noise: the
#: last iterations at 1e-10 moved no value by more than 2e-4 of its standard error.
_TOL = 1e-8
_TOL_FIRST = 1e-5


def noise_sigma(y: np.ndarray, t: np.ndarray | None = None) -> float:
    """
    Robust white-noise level of a sampled signal [its unit].

    The third difference of a smooth signal is tiny while white noise of sigma gives
    sigma * sqrt(20); the median absolute deviation keeps stick-slip spikes out. With the
    sample times ``t`` [s] of a signal sampled unevenly (a driver's jitter), the third
    *divided* difference scaled by ``6 h^3`` (``h`` the mean step) is used instead: zero for
    a quadratic at any sample times, so the jitter does not pass for noise.
    """
    y = np.asarray(y, dtype=float)
    x = None if t is None or y.size < 8 else np.asarray(t, dtype=float)
    if x is not None and np.any(np.abs(np.diff(x, 2)) > 1e-9 * (x[-1] - x[0])):
        d = y
        for order in (1, 2, 3):
            d = (d[1:] - d[:-1]) / (x[order:] - x[:-order])
        d = 6.0 * float(np.mean(np.diff(x))) ** 3 * d
    else:
        d = np.diff(y, 3)
    mad = np.median(np.abs(d - np.median(d))) * 1.4826
    floor = 1e-6 * max(np.ptp(y), np.finfo(float).tiny)
    return float(max(mad / math.sqrt(20.0), floor))


@dataclass
class _Exp:
    """An experiment prepared for the fast path."""

    name: str
    u: np.ndarray                # (N, 2) held inputs
    y: np.ndarray                # (N+1, n_state) measurements placed at state indices
    measured: np.ndarray         # state indices measured and fitted
    sigma: np.ndarray            # per measured index
    edges: list[int]             # segment k covers samples edges[k] .. edges[k+1] - 1
    dt: float
    x0: np.ndarray               # full initial state (unmeasured from equilibrium)
    load: np.ndarray | None = None    # measured load pressure p_CP - p_CT (chambers not)
    load_sigma: float = 1.0

    def segments(self):
        """Yield (first, end) sample indices of each replay segment; the last ends at N+1."""
        return zip(self.edges[:-1], self.edges[1:])

    def offset_free(self, e: np.ndarray) -> np.ndarray:
        """Remove the mean of ``e`` (a position error) per segment, in place."""
        for a, b in self.segments():
            e[a:b] -= e[a:b].mean()
        return e


class Problem:
    """
    The residual of a set of experiments as a function of the scaled free parameters.

    The fast path (no checks): ``residual(theta)`` with ``theta = value / scale``.
    """

    def __init__(self, experiments: Sequence[Experiment], base: Params, free: Sequence[str],
                 model: str, signals: Sequence[str], segment: float, h: float | None) -> None:
        self.base = dict(base)
        self.free = tuple(free)
        self.scale = np.array([spec(n).scale or abs(base[n]) or 1.0 for n in self.free])
        self.model = model
        plant = Plant(base, model, h=h)
        self.plant = plant
        self.mid = MODELS[model][0]
        self.names = plant.state_names
        self.xscale = plant._xscale
        self.jac_every = DEFAULT_JAC_EVERY[model]
        self.exps: list[_Exp] = []
        names: list[str] = []
        for e in experiments:
            # results are keyed by name: two bags called alike get '#2', '#3'
            name = e.name if e.name not in names else f'{e.name} #{names.count(e.name) + 1}'
            names.append(e.name)
            sig = e.signals()
            use = [s for s in signals if s in sig]
            measured = np.array([self.names.index(s) for s in use])
            y = np.zeros((e.t.size, plant.n))
            for s in use:
                y[:, self.names.index(s)] = sig[s]
            # a derived signal's noise is known from what it was derived from (the
            # experiment's ``noise``); a measured one's is estimated from the signal
            known = getattr(e, 'noise', None) or {}
            sigma = np.array([known[s] if s in known else noise_sigma(sig[s]) for s in use])
            x0 = plant.equilibrium(z=float(e.z[0]), i=float(e.i[0]))
            x0[measured] = y[0, measured]
            load = getattr(e, 'p_load', None)
            if load is not None and (LOAD not in signals or 'p_CP' in use):
                load = None
            if load is not None:      # only the difference is measured: split it evenly
                self._split(x0, float(load[0]))
            if getattr(e, 'after_gap', False):      # it starts mid-motion
                x0 = plant.settle_valve(x0, float(e.i[0]))
            seg = max(1, int(round(segment / e.dt))) if segment else e.t.size
            edges = list(range(0, e.t.size - 1, seg)) + [e.t.size]
            self.exps.append(_Exp(name, np.column_stack([e.i[:-1], np.zeros(e.t.size - 1)]),
                                  y, measured, sigma, edges, e.dt, x0, load,
                                  known.get(LOAD) or (noise_sigma(load) if load is not None
                                                      else 1.0)))
        self.ipa, self.ipb = self.names.index('p_CP'), self.names.index('p_CT')
        self.nsub = [max(1, int(math.ceil(ex.dt / plant.h - 1e-9))) for ex in self.exps]
        self.nfev = 0
        self._last: tuple[np.ndarray, np.ndarray] | None = None

    def _split(self, x: np.ndarray, p_load: float) -> None:
        """Set the chamber pressures to a measured load pressure, keeping their sum."""
        a, b = self.names.index('p_CP'), self.names.index('p_CT')
        total = x[a] + x[b]
        x[a], x[b] = 0.5 * (total + p_load), 0.5 * (total - p_load)

    def values(self, theta: np.ndarray) -> dict[str, float]:
        """Scaled vector -> parameter values."""
        return {n: float(v) for n, v in zip(self.free, np.asarray(theta) * self.scale)}

    def simulate(self, theta: np.ndarray) -> list[np.ndarray]:
        """Segment-wise replay of every experiment; list of (N+1, n_state) trajectories."""
        d = dict(self.base)
        d.update(self.values(theta))
        c = pack(d)
        outs = []
        for ex, nsub in zip(self.exps, self.nsub):
            n = ex.u.shape[0]
            o = np.empty((n + 1, len(self.names)))
            x = ex.x0.copy()
            for k0, end in ex.segments():
                k1 = min(n, end)
                x[ex.measured] = ex.y[k0, ex.measured]
                if ex.load is not None:
                    self._split(x, float(ex.load[k0]))
                buf = o[k0:k1 + 1]
                ok = K.simulate(self.mid, x.copy(), ex.u[k0:k1], c, ex.dt, nsub, self.xscale,
                                self.jac_every, buf)
                if ok <= k1 - k0:
                    buf[ok:] = np.nan
                x = buf[-1].copy()
                if not np.all(np.isfinite(x)):
                    x = ex.x0.copy()
            outs.append(o)
        return outs

    def residual_parts(self, theta: np.ndarray) -> list[np.ndarray]:
        """Normalised residuals per experiment, shape (N+1, n_measured)."""
        parts = []
        iz = self.names.index('z')
        for ex, o in zip(self.exps, self.simulate(theta)):
            r = (o[:, ex.measured] - ex.y[:, ex.measured]) / ex.sigma
            cols = list(ex.measured)
            if iz in cols:
                j = cols.index(iz)
                r[:, j] = ex.offset_free(r[:, j])
            if ex.load is not None:
                r = np.column_stack([r, (o[:, self.ipa] - o[:, self.ipb] - ex.load) /
                                     ex.load_sigma])
            bad = ~np.isfinite(r)
            if bad.any():
                r[bad] = 1e3     # diverged: a large, finite penalty keeps TRF going
            parts.append(r)
        return parts

    def blocks(self, seconds: float) -> np.ndarray:
        """Label of each entry of :meth:`residual`: its experiment's ``seconds``-long block."""
        out, first = [], 0
        for ex in self.exps:
            n = ex.y.shape[0]
            per = max(1, int(round(seconds / ex.dt)))
            b = np.arange(n) // per
            out.append(np.repeat(first + b, len(ex.measured) + (ex.load is not None)))
            first += int(b[-1]) + 1
        return np.concatenate(out)

    def residual(self, theta: np.ndarray) -> np.ndarray:
        """All normalised residuals as one vector (the fast, unchecked path)."""
        if self._last is not None and np.array_equal(self._last[0], theta):
            return self._last[1]          # the Jacobian reuses the step's simulation
        self.nfev += 1
        r = self.evaluate(theta)
        self._last = (np.array(theta, dtype=float), r)
        return r

    def evaluate(self, theta: np.ndarray) -> np.ndarray:
        """:meth:`residual` without its cache or count: safe from several threads at once."""
        return np.concatenate([p.ravel() for p in self.residual_parts(theta)])


# -- parallel Jacobian ---------------------------------------------------------------------
def _fd_jacobian(problem: Problem, theta: np.ndarray, hi: np.ndarray, pool) -> np.ndarray:
    """
    Forward-difference Jacobian in scaled units (steps turn back at an upper bound).

    ``pool``: a thread pool, or None for serial columns. The kernels release the GIL
    (``nogil``), so the columns' replays run on as many cores as the pool has threads.
    """
    r0 = problem.residual(theta)
    steps = [_FD_STEP * max(1.0, abs(t)) for t in theta]
    steps = [-h if t + h > b else h for t, h, b in zip(theta, steps, hi)]

    def column(k: int) -> np.ndarray:
        t = theta.copy()
        t[k] += steps[k]
        return (problem.evaluate(t) - r0) / steps[k]

    run = pool.map if pool is not None else map
    return np.column_stack(list(run(column, range(len(steps)))))


@dataclass
class IdentificationResult:
    """What :func:`identify` found. ``x``: fitted values by name (SI units)."""

    x: dict[str, float]
    x0: dict[str, float]
    params: Params | None
    cost: float
    sae: float
    sse: float
    status: int
    message: str
    success: bool
    nfev: int
    njev: int
    iterations: int
    history: list[dict]
    stderr: dict[str, float]
    correlation: np.ndarray
    free: tuple[str, ...]
    metrics: dict[str, dict[str, dict[str, float]]]
    sigma: dict[str, dict[str, float]]
    warnings: list[str] = field(default_factory=list)
    #: the fitted model's signals per experiment (``z`` with the per-segment offsets the fit
    #: allows), on the experiment's samples; for plots, not in the summary
    fitted: dict[str, dict[str, np.ndarray]] = field(default_factory=dict, repr=False)
    wall_s: float = 0.0
    model: str = 'simplified'
    cost_kind: str = 'sae'
    #: the model-adequacy verdict: False when the sensor noise does not explain the fit or
    #: the solver stopped at its evaluation limit; ``inadequacy`` says why, ``advice`` what
    #: to run instead
    adequate: bool = True
    inadequacy: list[str] = field(default_factory=list)
    advice: list[str] = field(default_factory=list)
    #: the largest factor a standard error was widened by for correlated residuals (1: white)
    stderr_widening: float = 1.0
    #: :func:`multistart`'s summary when it was run (how many random starts reach this fit)
    starts: dict = field(default_factory=dict)
    #: :func:`ros_ehs.identify.design.recommend`'s answer when it was run: what the bags pin
    #: down and the excitation that would pin down the rest
    excitation: dict = field(default_factory=dict)
    #: the input delay the current was built with: ``value_s``, and when the fit estimated
    #: it (:mod:`ros_ehs.identify.delay`) ``stderr_s`` and the profile; empty when every run
    #: records the current the valve got
    input_delay: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """Return a JSON-ready summary."""
        return {
            'model': self.model, 'cost_kind': self.cost_kind, 'success': self.success,
            'status': self.status, 'message': self.message, 'cost': self.cost,
            'sae': self.sae, 'sse': self.sse, 'nfev': self.nfev, 'njev': self.njev,
            'iterations': self.iterations, 'wall_s': self.wall_s,
            'parameters': {n: {'value': self.x[n], 'initial': self.x0[n],
                               'stderr': self.stderr[n], 'unit': spec(n).unit,
                               'rel_stderr': (self.stderr[n] / abs(self.x[n])
                                              if self.x[n] else math.inf)}
                           for n in self.free},
            'correlation': {'names': list(self.free),
                            'matrix': np.round(self.correlation, 4).tolist()},
            'adequate': self.adequate, 'inadequacy': self.inadequacy, 'advice': self.advice,
            'stderr_widening': self.stderr_widening, 'starts': self.starts,
            'excitation': self.excitation, 'input_delay': self.input_delay,
            'fit': self.metrics, 'noise_sigma': self.sigma, 'warnings': self.warnings,
            'history': self.history,
        }


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


def _metrics(problem: Problem, theta: np.ndarray, fitted: dict | None = None
             ) -> dict[str, dict[str, dict[str, float]]]:
    """Fit metrics per experiment and signal; ``fitted`` (if given) gets the model traces."""
    out = {}
    for ex, o in zip(problem.exps, problem.simulate(theta)):
        fit = {n: o[:, problem.names.index(n)] for n in SIGNALS if n in problem.names}
        m = {}
        for j, sigma in zip(ex.measured, ex.sigma):
            name = problem.names[j]
            y, f = ex.y[:, j], o[:, j]
            e = f - y
            if name == 'z':
                ex.offset_free(e)
                fit['z'] = y + e     # position is fitted up to an offset per segment
            m[name] = _signal_metrics(y, e, sigma)
        if ex.load is not None:
            y, f = ex.load, o[:, problem.ipa] - o[:, problem.ipb]
            fit[LOAD] = f
            m[LOAD] = _signal_metrics(y, f - y, ex.load_sigma)
        out[ex.name] = m
        if fitted is not None:
            fitted[ex.name] = fit
    return out


def _check(experiments, free, model, signals, cost, base, x0, segment, h, workers,
           max_nfev) -> tuple[list[Experiment], tuple[str, ...], Params]:
    if isinstance(experiments, Experiment):
        experiments = [experiments]
    experiments = list(experiments)
    if not experiments or not all(isinstance(e, Experiment) for e in experiments):
        raise InputError('`experiments` must be one or more Experiment records '
                         '(ros_ehs.bag.load_experiment)')
    if model not in MODELS:
        raise InputError(f'`model` = {model!r} is not one of {sorted(MODELS)}')
    if cost not in ('sae', 'sse'):
        raise InputError(f"`cost` = {cost!r} is not one of ['sae', 'sse']")
    free = tuple(free)
    if not free:
        raise InputError('`free` is empty: name at least one parameter to fit')
    for n in free:
        try:
            s = spec(n)
        except (KeyError, ParameterError):
            raise InputError(f'`free`: {n!r} is not a parameter') from None
        if s.is_choice:
            raise InputError(f'`free`: {n!r} is a choice, not a number')
    if len(set(free)) != len(free):
        raise InputError(f'`free` names a parameter twice: {list(free)}')
    bad = [s for s in signals if s not in SIGNALS]
    if bad or 'z_dot' not in signals:
        raise InputError(f'`signals` = {list(signals)} must include z_dot and be among '
                         f'{list(SIGNALS)}')
    if not isinstance(base, Params):
        raise InputError(f'`base` must be a Params, got {type(base).__name__}')
    if x0 is not None:
        unknown = [k for k in x0 if k not in free]
        if unknown:
            raise InputError(f'`x0` names parameters that are not free: {unknown}')
        base = base.replace(**x0)
    if segment is not None and not (isinstance(segment, (int, float)) and segment > 0):
        raise InputError(f'`segment` = {segment!r} s must be > 0 or None')
    if workers is not None and not (isinstance(workers, int) and workers >= 1):
        raise InputError(f'`workers` = {workers!r} must be an integer >= 1 (or None: auto)')
    if not (isinstance(max_nfev, int) and max_nfev >= 1):
        raise InputError(f'`max_nfev` = {max_nfev!r} must be an integer >= 1')
    dts = {round(e.dt, 12) for e in experiments}
    if h is not None and not (isinstance(h, (int, float)) and 0 < h <= min(dts)):
        raise InputError(f'`h` = {h!r} s must be in (0, sample period]')
    return experiments, free, base


def _bounds(free, base):
    lo, hi = [], []
    for n in free:
        s = spec(n)
        a = s.est_lo if s.est_lo is not None else s.lo
        b = s.est_hi if s.est_hi is not None else s.hi
        lo.append(max(a, s.lo))
        hi.append(min(b, s.hi))
        if not lo[-1] <= base[n] <= hi[-1]:
            raise InputError(f'initial {n} = {base[n]!r} {s.unit} is outside its bounds '
                             f'[{lo[-1]:g}, {hi[-1]:g}]')
    return np.array(lo), np.array(hi)


#: Integration step of the replay [s], per model. The full model's is seven substeps of a
#: 1 ms sample (143 us, 2.9x its plant's 50 us): on the identify bench's full-model rig the
#: cold fit took 3.0 s against 3.5 s at eight (125 us), every value within 0.55 % of the
#: truth at either (the closed-loop error at 125 us stays <= 1.6e-5 m, docs/model.md).
FIT_H = {'full': 1e-3 / 7, 'reduced': DEFAULT_H['reduced'],
         'simplified': DEFAULT_H['simplified']}


def identify(experiments, *, free: Sequence[str] = ESTIMATED, model: str = 'simplified',
             signals: Sequence[str] = SIGNALS, cost: str = 'sae', base: Params | None = None,
             x0: dict[str, float] | None = None, segment: float | None = 1.0,
             h: float | None = None, workers: int | None = None, max_nfev: int = 100,
             warm: bool = False,
             progress: Callable[[dict], None] | None = None) -> IdentificationResult:
    """
    Fit the ``free`` parameters of ``model`` to ``experiments`` (jointly).

    Parameters
    ----------
    experiments : Experiment or sequence of Experiment
        Recorded runs (:func:`ros_ehs.bag.experiment.load_experiment`).
    free : names
        Parameters to fit (default: the paper's seven of Table 1). Others stay at ``base``.
    model : {'simplified', 'reduced', 'full'}
        The plant model to fit: the paper's simplified one; the reduced one (the simplified
        one with the full model's valve lag and load-dependent gain: the one to fit to a real
        rig, ``docs/model.md``); or the full 10-state model.
    signals : names
        Fitted outputs among ``z_dot`` (required), ``z``, ``p_CP``, ``p_CT``; those an
        experiment did not record are skipped.
    cost : {'sae', 'sse'}
        Sum of absolute errors (the paper) or of squared errors.
    base : Params
        Starting point and fixed values (default: Table 1's initial values).
    x0 : dict, optional
        Override starting values of free parameters.
    segment : float or None
        Replay segment length [s] (None: one open-loop replay of the whole record).
    h : float, optional
        Integration step [s] (default ``FIT_H[model]``).
    workers : int or None
        Threads for the Jacobian's columns (the kernels release the GIL). None (default):
        2 where the machine has 2 CPUs (the simplified model's cold fit of a 10 s bag
        measured 0.65-0.8 s against 0.8-1.0 s serially, ``python -m ros_ehs.bench
        identify``). A live refit beside a running loop takes 1, so it keeps to its CPU.
    max_nfev : int
        Limit on residual evaluations (not counting Jacobian columns).
    warm : bool
        The starting values are a recent estimate of the same system (a live refit): the
        SAE solve starts from them directly, without the SSE stage that brings a cold start
        close first.
    progress : callable, optional
        Called with ``{'iteration', 'cost', 'x'}`` after each iteration.

    """
    t_start = time.perf_counter()
    base = base if base is not None else preset('table1_initial')
    experiments, free, base = _check(experiments, free, model, signals, cost, base, x0,
                                     segment, h, workers, max_nfev)
    h = FIT_H[model] if h is None else h
    if workers is None:
        workers = min(2, os.cpu_count() or 1)
    lo, hi = _bounds(free, base)
    problem = Problem(experiments, base, free, model, signals, segment, h)
    sc = problem.scale
    theta0 = np.array([base[n] for n in free]) / sc
    lo_s, hi_s = lo / sc, hi / sc
    history: list[dict] = []
    njev = [0]
    last_jac: list[np.ndarray] = []
    problem.residual(theta0)   # compile/warm the kernels before the threads use them
    pool = None
    if workers > 1 and len(free) > 1:
        pool = ThreadPoolExecutor(min(workers, len(free)), thread_name_prefix='ehs-jac')

    def jac(theta: np.ndarray) -> np.ndarray:
        J = _fd_jacobian(problem, theta, hi_s, pool)
        njev[0] += 1
        last_jac[:] = [J, theta.copy()]
        entry = {'iteration': njev[0], 'cost': _loss(problem.residual(theta), cost),
                 'x': problem.values(theta)}
        history.append(entry)
        if progress:
            progress(entry)
        return J

    def solve(start, loss, budget, tol):
        return least_squares(problem.residual, start, jac=jac, bounds=(lo_s, hi_s),
                             method='trf', loss=loss, f_scale=0.1 if loss != 'linear' else 1.0,
                             max_nfev=budget, xtol=tol, ftol=tol, gtol=1e-10)

    try:
        if cost == 'sae' and warm:
            sol = solve(theta0, 'soft_l1', max_nfev, _TOL)
        elif cost == 'sae':
            # Continuation: far from the optimum nearly every residual sits in soft_l1's
            # linear (L1) branch and TRF can stall in a poor point (seen on real-time bench
            # bags). An SSE solve first brings the parameters close, then SAE refines.
            # Both stages count in the iterations and evaluations.
            # The first stage only has to come close: its tolerance is looser.
            first = solve(theta0, 'linear', max(1, max_nfev // 2), _TOL_FIRST)
            sol = solve(first.x, 'soft_l1', max(1, max_nfev - first.nfev), _TOL)
            sol.nfev += first.nfev
        else:
            sol = solve(theta0, 'linear', max_nfev, _TOL)
    finally:
        if pool is not None:
            pool.shutdown()
    theta = sol.x
    r = sol.fun
    if last_jac and np.array_equal(last_jac[1], theta):
        J = last_jac[0]
    else:
        J = _fd_jacobian(problem, theta, hi_s, None)
    final = {'iteration': njev[0] + 1, 'cost': _loss(r, cost), 'x': problem.values(theta)}
    if not history or history[-1]['x'] != final['x']:
        history.append(final)
    cov, corr, notes = _covariance(J, r, len(free), cost, free, theta)
    fitted: dict[str, dict[str, np.ndarray]] = {}
    metrics = _metrics(problem, theta, fitted)
    widen = _autocorrelation_factor(metrics)
    se_white = np.sqrt(np.clip(np.diag(cov), 0, None))
    if widen > 1.0:
        # correlated residuals: the larger of the AR(1)-widened and the block-robust error
        robust = _block_robust_variance(J, r, problem.blocks(_BLOCK_S), cost)
        cov = _rescale(cov, np.maximum(widen * np.diag(cov), robust))
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid='ignore', divide='ignore'):
        ratio = se / se_white
    widening = float(np.nanmax(ratio)) if np.any(np.isfinite(ratio)) else 1.0
    if widening > 2.0:
        notes.append(f'the residuals are correlated: standard errors widened up to '
                     f'{widening:.1f}x for it (they assume independent samples)')
    se = se * sc
    worst = worst_noise_ratio(metrics)
    if SMALL_MODEL_ERROR < worst <= NOISE_RATIO_LIMIT:
        notes.append(f'the worst residual is {worst:.2f}x the sensor noise: a small model '
                     'error remains, and it can bias the values by more than their standard '
                     'errors (docs/identification.md)')
    xv = problem.values(theta)
    for n, v in xv.items():
        k = free.index(n)
        if v != 0 and math.isfinite(se[k]) and se[k] / abs(v) > 0.5:
            notes.append(f'{n} is not identifiable from these data: standard error '
                         f'{se[k]:.3g} {spec(n).unit} is {100 * se[k] / abs(v):.0f} % of '
                         'its value')
        if np.isclose(theta[k], lo_s[k]) or np.isclose(theta[k], hi_s[k]):
            notes.append(f'{n} = {v:.6g} {spec(n).unit} ended on a bound; the data push it '
                         "beyond Table 1's range")
    try:
        params = base.replace(**xv)
    except ParameterError as e:
        params = None
        notes.append(f'the fitted set is not a valid parameter set: {e}')
    for note in notes:
        warnings.warn(note, IdentificationWarning, stacklevel=2)
    inadequacy, advice = adequacy(metrics, int(sol.status), max_nfev, model)
    return IdentificationResult(
        x=xv, x0={n: float(base[n]) for n in free}, params=params, cost=float(sol.cost),
        sae=float(np.sum(np.abs(r))), sse=float(np.sum(r ** 2)), status=int(sol.status),
        message=str(sol.message), success=bool(sol.success), nfev=int(sol.nfev),
        njev=njev[0], iterations=njev[0], history=history,
        stderr={n: float(s) for n, s in zip(free, se)}, correlation=corr, free=free,
        metrics=metrics, fitted=fitted,
        sigma={ex.name: {**{problem.names[j]: float(s) for j, s in zip(ex.measured, ex.sigma)},
                         **({LOAD: float(ex.load_sigma)} if ex.load is not None else {})}
               for ex in problem.exps},
        warnings=notes, wall_s=time.perf_counter() - t_start, model=model, cost_kind=cost,
        adequate=not inadequacy, inadequacy=inadequacy, advice=advice,
        stderr_widening=widening)


#: A fit whose residual RMS exceeds this many times the estimated sensor noise, on any
#: signal, is not explained by the noise: the model misses something. Measured: a fit of
#: the model that made the data sits at 0.99-1.01 (lag-1 autocorrelation 0.00); the
#: simplified model fitted to a full-model bag at 6.5-20 (autocorrelation 0.93-0.99).
NOISE_RATIO_LIMIT = 2.0
#: Above this ratio (and up to the limit) an adequate fit carries a warning: the reduced
#: model on full-model bags sits at about 1.15 and its values were up to 1.6 % off, beyond their
#: standard errors for 4 of 7 parameters.
SMALL_MODEL_ERROR = 1.1


def worst_noise_ratio(metrics: dict) -> float:
    """Return the largest ``noise_ratio`` of any signal in ``metrics`` (NaN when none)."""
    return max((m['noise_ratio'] for sig in metrics.values() for m in sig.values()
                if math.isfinite(m.get('noise_ratio', math.nan))), default=math.nan)


def adequacy(metrics: dict, status: int, max_nfev: int, model: str
             ) -> tuple[list[str], list[str]]:
    """
    Return the reasons a fit is not adequate (empty: adequate) and the advice they imply.

    ``metrics`` as :func:`identify` computes them (``noise_ratio``, ``acf1`` per signal);
    ``status`` scipy's (0: the evaluation limit).
    """
    why = []
    for exp, sig in metrics.items():
        for name, m in sig.items():
            if m['noise_ratio'] > NOISE_RATIO_LIMIT:
                why.append(f'{exp}: the {name} residual is {m["noise_ratio"]:.1f}x the '
                           f'sensor noise (lag-1 autocorrelation {m["acf1"]:.2f}): the '
                           'noise does not explain the fit')
    advice = []
    if why:
        if model == 'simplified':
            advice.append('fit the reduced model (--model reduced): the simplified one leaves '
                          "out the valve's lag and its opening under load, which the reduced "
                          'one takes from the full model (docs/model.md); or the full model '
                          '(--model full), slower')
        advice.append('free other parameters (--free), or fix those the report names as not '
                      'identifiable')
        advice.append('record more excitation: several amplitudes and frequencies (a chirp '
                      'from the reference node) so each parameter shows in the data')
    if status == 0:
        why.append(f'the solver stopped at its evaluation limit (max_nfev = {max_nfev}) '
                   'before converging: the values are not an optimum')
        advice.append('raise max_nfev, or start nearer (--initial)')
    return why, advice


def _loss(r: np.ndarray, cost: str) -> float:
    return float(np.sum(np.abs(r)) if cost == 'sae' else 0.5 * np.sum(r ** 2))


def _autocorrelation_factor(metrics: dict) -> float:
    """
    Return the variance inflation for correlated residuals, (1 + rho) / (1 - rho).

    rho is the largest lag-1 autocorrelation of any signal's residual (``acf1`` of
    :func:`_metrics`; AR(1): n samples carry the information of n (1 - rho) / (1 + rho)
    independent ones); 1 for white residuals, rho capped at 0.995.
    """
    rho = max((m['acf1'] for sig in metrics.values() for m in sig.values()
               if math.isfinite(m['acf1'])), default=0.0)
    rho = min(rho, 0.995)
    return (1.0 + rho) / (1.0 - rho) if rho > 0.05 else 1.0


#: Block length [s] of the block-robust standard errors: residuals 0.1 s apart are taken as
#: independent (the model-error patterns of a reduced fit decorrelate within ~20 ms).
_BLOCK_S = 0.1


def _block_robust_variance(J, r, blocks, cost) -> np.ndarray:
    """
    Diagonal of the block-robust (sandwich) covariance, scaled units.

    ``(J'J)^-1 (sum_b J_b' r_b r_b' J_b) (J'J)^-1 G / (G - 1)`` over the G blocks of residuals
    ``blocks`` labels: it holds when residuals are correlated within a block, whatever the
    pattern (Liang & Zeger's cluster estimator). Scaled by pi/2 for the SAE cost, as the
    plain estimate is.
    """
    inv = np.linalg.pinv(J.T @ J)
    g = int(blocks.max()) + 1
    scores = np.zeros((g, J.shape[1]))
    np.add.at(scores, blocks, J * r[:, None])
    meat = scores.T @ scores
    var = np.diag(inv @ meat @ inv) * g / max(g - 1, 1)
    return var * (math.pi / 2.0 if cost == 'sae' else 1.0)


def _rescale(cov: np.ndarray, var: np.ndarray) -> np.ndarray:
    """``cov`` with its diagonal set to ``var``, the correlations kept."""
    d = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    with np.errstate(invalid='ignore'):
        s = np.sqrt(np.clip(var, 0, None)) / d
    s = np.where(np.isfinite(d) & np.isfinite(s), s, 1.0)    # unidentifiable: stays inf
    return cov * np.outer(s, s)


def _covariance(J, r, n, cost, free, theta):
    """Asymptotic covariance (scaled units), correlation, and conditioning notes."""
    notes: list[str] = []
    m = r.size
    s2 = float(np.sum(r ** 2)) / max(m - n, 1)
    if cost == 'sae':
        s2 *= math.pi / 2.0   # L1 estimator variance under Gaussian noise (efficiency 2/pi)
    norms = np.linalg.norm(J, axis=0)
    dead = norms <= 1e-9 * max(float(norms.max()), 1e-300)
    for k in np.flatnonzero(dead):
        notes.append(f'{free[k]} is not identifiable: it has no effect on the fitted '
                     'signals with this model and data')
    JtJ = J.T @ J
    try:
        cov = np.linalg.inv(JtJ) * s2
        if not np.all(np.isfinite(cov)):
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(JtJ) * s2
        notes.append('the Jacobian is singular: some parameters have no effect on the fitted '
                     'signals')
    cov[dead, :] = np.nan
    cov[:, dead] = np.nan
    cov[dead, dead] = np.inf
    d = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    with np.errstate(invalid='ignore'):
        corr = cov / np.outer(d, d)
    corr[dead, dead] = 1.0
    for a in range(n):
        for b in range(a + 1, n):
            if abs(corr[a, b]) > 0.99:
                notes.append(f'{free[a]} and {free[b]} are correlated {corr[a, b]:+.3f}: '
                             'the data cannot tell them apart')
    return cov, corr, notes


def score(params: Params, experiments, *, model: str = 'simplified',
          signals: Sequence[str] = SIGNALS, segment: float | None = 1.0,
          h: float | None = None) -> dict[str, dict[str, dict[str, float]]]:
    """Fit metrics (NRMSE, R^2, RMS per signal) of ``params`` on held-out ``experiments``."""
    experiments, _, params = _check(experiments, ('c_c',), model, signals, 'sse', params,
                                    None, segment, h, 1, 1)
    h = FIT_H[model] if h is None else h
    problem = Problem(experiments, params, ('c_c',), model, signals, segment, h)
    return _metrics(problem, np.array([params['c_c']]) / problem.scale)


def multistart(experiments, result: IdentificationResult, *, starts: int = 10, seed: int = 0,
               within: float = 0.01, **kwargs) -> dict:
    """
    Refit from ``starts`` seeded random starting points; report how many reach ``result``.

    Starts are drawn log-uniformly (uniformly for ``x_bias``) within the fit's bounds and a
    factor 20 around Table 1's initial values (``x0`` of ``result``), F_cc at most F_sc. A
    start reaches the same optimum when every parameter lands within ``within`` (relative)
    or two standard errors of ``result``'s value. ``kwargs`` go to :func:`identify` (the
    same model, free set, cost...). Returns a JSON-ready summary.
    """
    if not (isinstance(starts, int) and starts >= 1):
        raise InputError(f'`starts` = {starts!r} must be an integer >= 1')
    rng = np.random.default_rng(seed)
    free = list(result.free)
    lo, hi = _bounds(free, kwargs.get('base') or preset('table1_initial'))
    runs = []
    for _ in range(starts):
        x0 = {}
        for k, n in enumerate(free):
            a, b = lo[k], hi[k]
            if a > 0:
                a, b = max(a, result.x0[n] / 20), min(b, result.x0[n] * 20)
                x0[n] = float(np.exp(rng.uniform(np.log(a), np.log(b))))
            else:
                x0[n] = float(rng.uniform(a, b))
        if 'F_cc' in x0 and 'F_sc' in x0 and x0['F_cc'] > x0['F_sc']:
            x0['F_cc'], x0['F_sc'] = x0['F_sc'], x0['F_cc']
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', IdentificationWarning)
            r = identify(experiments, x0=x0, **kwargs)
        same = all(abs(r.x[n] - result.x[n])
                   <= max(within * abs(result.x[n]), 2.0 * result.stderr[n]) for n in free)
        runs.append({'x0': x0, 'x': r.x, 'cost': r.cost, 'same_optimum': bool(same),
                     'adequate': r.adequate})
    n_same = sum(r['same_optimum'] for r in runs)
    return {'starts': starts, 'seed': seed, 'same_optimum': n_same,
            'message': f'{n_same} of {starts} random starts reached the same optimum '
                       f'(every parameter within {within:.0%} or 2 standard errors)',
            'best_cost_found': min([result.cost] + [r['cost'] for r in runs]),
            'runs': runs}
