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
What a bag can and cannot tell, and which excitation would tell the rest.

:func:`identifiability` reads a fit's standard errors: a parameter is *pinned down* when its
relative standard error is at most ``PINNED`` (2-sigma within 5 %). :func:`recommend`
searches reference trajectories the ``reference`` node can play (``CANDIDATES``: sines and
chirps, 10 s each) for the one that, recorded as a second bag and fitted jointly with the
first, pins the weak parameters down best. Each candidate is simulated in closed loop with
the fitted parameters and the bag's sensor noise; its Fisher information ``J'J`` (J of the
same normalised replay residuals the fit uses) is added to the first bag's, and the predicted
standard errors are ``sqrt(diag((J0'J0 + J'J)^-1))``, scaled as the fit's are (pi/2 for the
SAE cost) and by the fit's largest widening for correlated residuals (conservative: the new
bag is assumed as correlated as the old). The prediction assumes the fitted model is right;
the fit of the new bag checks it.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ros_ehs.core.control.waveforms import Chirp, Sine
from ros_ehs.core.errors import InputError
from ros_ehs.core.identify.estimator import IdentificationResult
from ros_ehs.core.identify.experiment import Experiment
from ros_ehs.core.identify.problem import _fd_jacobian, FIT_H, Problem, SIGNALS
from ros_ehs.core.sim.closed_loop import run_closed_loop

__all__ = ['CANDIDATES', 'PINNED', 'command', 'describe', 'identifiability', 'recommend',
           'trajectory']

#: Relative standard error at which a parameter counts as pinned down (2-sigma within 5 %).
PINNED = 0.025

#: Peak reference velocity the candidates stay under [m/s]: the G761 on Table 1's cylinder
#: saturates near 0.6 m/s (the controller's 15 mA limit).
V_PEAK = 0.45


def _candidates() -> list[dict]:
    out = []
    for a in (0.002, 0.005, 0.01, 0.02, 0.04):
        for f in (0.2, 0.5, 1.0, 2.0, 4.0):
            if 2 * math.pi * f * a <= V_PEAK:
                out.append({'kind': 'sine', 'amplitude': a, 'frequency': f})
    for a in (0.005, 0.01, 0.02):
        out.append({'kind': 'chirp', 'amplitude': a, 'f0': 0.2, 'f1': min(5.0, V_PEAK / (
            2 * math.pi * a)), 'chirp_duration': 10.0})
    return out


#: The trajectories :func:`recommend` tries, as ``reference`` node parameters.
CANDIDATES: tuple[dict, ...] = tuple(_candidates())


def trajectory(c: dict):
    if c['kind'] == 'sine':
        return Sine(c['amplitude'], c['frequency'])
    return Chirp(c['amplitude'], c['f0'], c['f1'], c['chirp_duration'])


def describe(c: dict) -> str:
    """Return a candidate in words: ``sine 5 mm at 0.5 Hz``."""
    if c['kind'] == 'sine':
        return f'sine {c["amplitude"] * 1e3:g} mm at {c["frequency"]:g} Hz'
    return (f'chirp {c["amplitude"] * 1e3:g} mm from {c["f0"]:g} to {c["f1"]:.3g} Hz over '
            f'{c["chirp_duration"]:g} s')


def command(c: dict) -> str:
    """Return the ``ros2 run`` line that plays candidate ``c``."""
    args = ' '.join(f'-p {k}:={v:g}' if isinstance(v, float) else f'-p {k}:={v}'
                    for k, v in c.items())
    return f'ros2 run ros_ehs reference --ros-args {args}'


def identifiability(result: IdentificationResult, pinned: float = PINNED) -> dict:
    """
    Per free parameter: its relative standard error and whether the bag pins it down.

    Also names the pairs correlated beyond 0.95, which the data tell apart only together.
    """
    out = {}
    for k, n in enumerate(result.free):
        v, se = result.x[n], result.stderr[n]
        rel = se / abs(v) if v and math.isfinite(se) else math.inf
        out[n] = {'rel_stderr': rel, 'pinned': bool(rel <= pinned)}
    corr = np.asarray(result.correlation)
    pairs = [[a, b, round(float(corr[i, j]), 3)]
             for i, a in enumerate(result.free) for j, b in enumerate(result.free)
             if i < j and math.isfinite(corr[i, j]) and abs(corr[i, j]) > 0.95]
    return {'parameters': out, 'correlated': pairs, 'threshold': pinned,
            'weak': [n for n, d in out.items() if not d['pinned']]}


def _information(problem: Problem, theta: np.ndarray) -> np.ndarray:
    J = _fd_jacobian(problem, theta, np.full(theta.size, np.inf), None)
    return J.T @ J


def _synthetic(result: IdentificationResult, c: dict, dt: float, sigma: dict,
               seed: int, duration: float) -> Experiment:
    run = run_closed_loop(result.params, trajectory(c), duration, model=result.model, dt=dt)
    rng = np.random.default_rng(seed)
    n = run.t.size

    def noisy(x, name):
        return x + sigma.get(name, 0.0) * rng.standard_normal(n)
    pressures = 'p_CP' in sigma and 'p_CT' in sigma
    return Experiment(f'candidate {describe(c)}', run.t, run.i, noisy(run.z, 'z'),
                      noisy(run.z_dot, 'z_dot'),
                      noisy(run.p_a, 'p_CP') if pressures else None,
                      noisy(run.p_b, 'p_CT') if pressures else None)


def recommend(result: IdentificationResult, experiments: Sequence[Experiment], *,
              candidates: Sequence[dict] = CANDIDATES, duration: float = 10.0,
              signals: Sequence[str] = SIGNALS, segment: float | None = 1.0,
              pinned: float = PINNED, seed: int = 0) -> dict:
    """
    Return what ``result``'s bags pin down and the excitation that would pin down the rest.

    JSON-ready: ``identifiability``, ``recommended`` (None when nothing is weak) with the
    predicted relative standard errors, every ``candidates`` row, and a ``message``.
    ``experiments`` are the bags ``result`` was fitted to; the recommendation is a second
    bag of ``duration`` s recorded with one of ``candidates`` and fitted jointly with them.
    """
    if result.params is None:
        raise InputError('`result` has no valid parameter set to simulate candidates with')
    if not candidates:
        raise InputError('`candidates` is empty')
    ident = identifiability(result, pinned)
    out = {'identifiability': ident, 'recommended': None, 'candidates': []}
    if not ident['weak']:
        out['message'] = 'every parameter is pinned down by this excitation'
        return out
    free = list(result.free)
    h = FIT_H[result.model]
    problem = Problem(list(experiments), result.params, free, result.model, signals,
                      segment, h)
    theta = np.array([result.x[n] for n in free]) / problem.scale
    info0 = _information(problem, theta)
    scale_sae = math.pi / 2.0 if result.cost_kind == 'sae' else 1.0
    widen = result.stderr_widening
    sigma = {}
    for sig in result.sigma.values():
        for name, s in sig.items():
            sigma[name] = max(sigma.get(name, 0.0), s)
    weak = [free.index(n) for n in ident['weak']]
    values = np.abs(theta * problem.scale)
    rows = []
    for k, c in enumerate(candidates):
        exp = _synthetic(result, c, experiments[0].dt, sigma, seed + k, duration)
        p = Problem([exp], result.params, free, result.model, signals, segment, h)
        cov = np.linalg.pinv(info0 + _information(p, theta)) * scale_sae * widen ** 2
        rel = np.sqrt(np.clip(np.diag(cov), 0, None)) * problem.scale / values
        rows.append({'reference': c, 'describe': describe(c),
                     'worst_weak_rel_stderr': float(max(rel[j] for j in weak)),
                     'rel_stderr': {n: float(r) for n, r in zip(free, rel)}})
    rows.sort(key=lambda r: (r['worst_weak_rel_stderr'], max(r['rel_stderr'].values())))
    best = rows[0]
    out['candidates'] = rows
    out['recommended'] = dict(best, command=command(best['reference']))
    names = ', '.join(ident['weak'])
    before = ', '.join(f'{n} {100 * ident["parameters"][n]["rel_stderr"]:.1f} %'
                       for n in ident['weak'])
    after = ', '.join(f'{n} {100 * best["rel_stderr"][n]:.1f} %' for n in ident['weak'])
    verdict = ('pins them down' if best['worst_weak_rel_stderr'] <= pinned
               else 'is the best of the candidates but does not pin them all down')
    out['message'] = (f'this excitation does not pin down {names} (relative standard error '
                      f'{before}); record {duration:g} s more with a {best["describe"]} '
                      f'({command(best["reference"])}) and fit both bags together, starting '
                      f'from this fit (--initial identified_params.yaml): predicted {after}, '
                      f'which {verdict}')
    return out
