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
The residual a fit minimises, and its Jacobian.

:class:`Problem` replays each experiment's recorded current into the model segment by
segment (each from the measured state; unmeasured states carry over), and returns the
normalised residuals of the fitted signals (each divided by its noise, position up to a
constant per segment) as a function of the scaled free parameters: the unchecked fast path
of :func:`ros_ehs.core.identify.estimator.identify` (each signal's noise from
:func:`ros_ehs.core.noise.noise_sigma`); :func:`_fd_jacobian` differentiates the residual by
forward differences, its columns on threads.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Sequence

import numpy as np
from ros_ehs.core.errors import DataError
from ros_ehs.core.identify.experiment import derivative_coefficients, Experiment
from ros_ehs.core.model import kernels as K
from ros_ehs.core.model.kernels import coefficients
from ros_ehs.core.model.plant import DEFAULT_H, DEFAULT_JAC_EVERY, MODELS, Plant
from ros_ehs.core.noise import noise_sigma
from ros_ehs.core.params import Params, spec

__all__ = ['CELL', 'FIT_H', 'LOAD', 'PIECE', 'Problem', 'SIGNALS', 'steps']


SIGNALS = ('z_dot', 'z', 'p_CP', 'p_CT', 'p_L', 'load_cell')


#: the load pressure p_CP - p_CT: fitted where a rig records only that (not a state)
LOAD = 'p_L'
#: the load cell, the specimen's force ``k_L (z - z_L) + c_L z_dot``: fitted where recorded
#: (it makes the specimen's stiffness identifiable)
CELL = 'load_cell'


_FD_STEP = 1e-3


#: Integration step of the replay [s], per model. The full model's is seven substeps of a
#: 1 ms sample (143 us, 2.9x its plant's 50 us): on the identify bench's full-model rig the
#: cold fit took 3.0 s against 3.5 s at eight (125 us), every value within 0.55 % of the
#: truth at either (the closed-loop error at 125 us stays <= 1.6e-5 m, docs/model.md).
FIT_H = {'full': 1e-3 / 7, 'reduced': DEFAULT_H['reduced'],
         'simplified': DEFAULT_H['simplified']}


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
    cell: np.ndarray | None = None    # measured load cell [N]
    cell_sigma: float = 1.0
    cell_zv: np.ndarray | None = None   # the measured position and velocity it goes with
    derivative: np.ndarray | None = None   # the filter that derived the velocity (None: measured)
    per: int = 1                 # pieces each sample's input is held in (``u`` has N * per rows)
    nsub: int = 1                # integration steps a sample
    warmup: int = 0              # leading samples replayed, not compared (a segment of their own)

    def segments(self):
        """Yield (first, end) sample indices of each replay segment; the last ends at N+1."""
        return zip(self.edges[:-1], self.edges[1:])

    def derive_velocity(self, o: np.ndarray, iz: int, iv: int) -> None:
        """
        Put in ``o``'s velocity column the derivative of its position, as the data's was derived.

        A velocity derived from the position by a smoothing derivative is compared with the
        model's position through the same derivative, per segment (a replay's position jumps
        where a segment restarts from the measured one); within half the filter's width of a
        segment's ends the model's velocity is taken as measured (no residual there).
        Compared with the model's own velocity instead, the smoothing at each reversal read as
        friction: on simulated rigs recorded position-only at 250 Hz-4 kHz, the breakaway
        friction came out 10-30 % low in a fit in four.
        """
        c = self.derivative
        h = c.size // 2
        for a, b in self.segments():
            if b - a > c.size:
                o[a + h:b - h, iv] = np.convolve(o[a:b, iz], c, 'valid')
                o[a:a + h, iv] = self.y[a:a + h, iv]
                o[b - h:b, iv] = self.y[b - h:b, iv]
            else:
                o[a:b, iv] = self.y[a:b, iv]

    def offset_free(self, e: np.ndarray) -> np.ndarray:
        """Remove the mean of ``e`` (a position error) per segment, in place."""
        for a, b in self.segments():
            e[a:b] -= e[a:b].mean()
        return e


#: The longest piece of a sample the replay holds one value of the command over [s]. A
#: driver's command takes over at its cycle, which jitters (:func:`takeover_times
#: <ros_ehs.core.identify.experiment.takeover_times>`), so between two of the fit's samples
#: on their uniform grid; held as the sample's mean, a takeover 0.8 ms into a 4 ms sample
#: acts as if it were spread over it. Measured (benchmark ``verdict``, seeds 0-59 and
#: 140-199, the reduced model, states jittered by up to a fifth of a period, the 13 records
#: at 250 Hz without pressures): held whole, the breakaway friction F_cc came out 5.9 % low
#: (median; 1.2-1.4 % at 2-4 kHz), 4 fits were within 5 % on all five values and 4 more than
#: 10 % off, one of them called adequate; held in 0.5 ms pieces, 0.1 % low, 8 within 5 % and
#: 4 more than 10 % off, all four flagged. A sample of 0.5 ms or less (2 kHz and faster) is
#: held whole.
PIECE = 0.5e-3


def steps(dt: float, h: float, held: bool) -> tuple[int, int]:
    """
    Return the pieces a replay holds a sample of ``dt`` [s] in, and its steps of about ``h``.

    ``held``: the current comes from commands taken over between samples (a driver's), so
    is cut in pieces of at most :data:`PIECE`, each of whole steps no more than 1 % above
    ``h`` (a jittered driver's mean period is not exact), and at most one piece a step. Else
    one piece, of ``ceil(dt / h)`` steps.
    """
    nsub = max(1, int(math.ceil(dt / h - 1e-9)))
    per = min(nsub, max(1, int(math.ceil(dt / PIECE - 0.01)))) if held else 1
    if per == 1:
        return 1, nsub
    return per, per * max(1, int(math.ceil(dt / (per * h) - 0.01)))


#: the piston has moved once it is this many position-noise sigmas from where it started
MOVED = 10.0
#: a run's breakaway starts a replay segment only on a grid this fine or finer [s]
BREAKAWAY_DT = 1.0e-3


def _with_breakaway(edges: list, z: np.ndarray) -> list:
    """Add a segment edge where a run that starts at rest first moves (its breakaway)."""
    sz = noise_sigma(z)
    moved = np.flatnonzero(np.abs(z - z[0]) > MOVED * sz)
    if not moved.size:
        return edges
    k = int(moved[0])
    if k <= 1 or k >= edges[-1] - 2 or k in edges:
        return edges
    return sorted(edges + [k])


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
            # a warm-up is a segment of its own: the compared samples re-anchor where it ends
            w = int(getattr(e, 'warmup', 0))
            if w < 0:
                raise DataError(f'{e.name}: `warmup` = {w} samples must be >= 0')
            if w >= e.t.size - 1:
                raise DataError(f'{e.name}: a warm-up of {w} samples leaves fewer than 2 of '
                                f'{e.t.size} to compare')
            edges = [0] * (w > 0) + list(range(w, e.t.size - 1, seg)) + [e.t.size]
            if not getattr(e, 'after_gap', False) and e.dt <= 1.01 * BREAKAWAY_DT:
                edges = _with_breakaway(edges, e.z)
            cell = getattr(e, 'load_cell', None) if CELL in signals else None
            per, nsub = steps(e.dt, plant.h, getattr(e, 'commands', None) is not None)
            held = e.held(per) if per > 1 else e.i[:-1]
            self.exps.append(_Exp(name, np.column_stack([held, np.zeros(held.size)]),
                                  y, measured, sigma, edges, e.dt, x0, load,
                                  known.get(LOAD) or (noise_sigma(load) if load is not None
                                                      else 1.0), cell,
                                  self._cell_sigma(e, known) if cell is not None else 1.0,
                                  None if cell is None else np.column_stack([e.z, e.v]),
                                  derivative_coefficients(e.dt)
                                  if 'z_dot' in use and 'z_dot' in getattr(e, 'derived', ())
                                  else None, per, nsub, w))
        self.ipa, self.ipb = self.names.index('p_CP'), self.names.index('p_CT')
        self.iz, self.iv = self.names.index('z'), self.names.index('z_dot')
        self.nfev = 0
        self._last: tuple[np.ndarray, np.ndarray] | None = None

    def _cell_sigma(self, e: Experiment, known: dict) -> float:
        """
        Return the noise of the load cell's residual: the cell's own and the measured motion's.

        The model's load cell is ``k_L (z - z_L) + c_L z_dot`` on the *measured* position and
        velocity, so their noise reaches the residual through the specimen: ``sqrt(s_F^2 +
        (k_L s_z)^2 + (c_L s_v)^2)``. On a stiff specimen the position's term dominates (10
        MN/m and 5 um of encoder noise: 50 N, where the load cell's own was 20 N), and a
        residual judged against ``s_F`` alone called every fit of it not adequate.
        """
        def sig(name: str, x) -> float:
            return float(known[name]) if name in known else float(noise_sigma(x))

        s_f = sig(CELL, e.load_cell)
        k, c = abs(float(self.base['k_L'])), abs(float(self.base['c_L']))
        return math.sqrt(s_f ** 2 + (k * sig('z', e.z)) ** 2 + (c * sig('z_dot', e.v)) ** 2)

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
        c = coefficients(d)
        outs = []
        for ex in self.exps:
            n = ex.u.shape[0] // ex.per
            o = np.empty((n + 1, len(self.names)))
            x = ex.x0.copy()
            for k0, end in ex.segments():
                k1 = min(n, end)
                x[ex.measured] = ex.y[k0, ex.measured]
                if ex.load is not None:
                    self._split(x, float(ex.load[k0]))
                buf = o[k0:k1 + 1]
                ok = K.simulate_pieces(self.mid, x.copy(), ex.u[k0 * ex.per:k1 * ex.per], ex.per,
                                       c, ex.dt, ex.nsub, self.xscale, self.jac_every, buf)
                if ok <= k1 - k0:
                    buf[ok:] = np.nan
                x = buf[-1].copy()
                if not np.all(np.isfinite(x)):
                    x = ex.x0.copy()
            if ex.derivative is not None:
                ex.derive_velocity(o, self.iz, self.iv)
            outs.append(o)
        return outs

    def restarts_pressures(self) -> bool:
        """Return whether a segment restarts from measured pressures in some experiment."""
        return any(self.ipa in ex.measured or ex.load is not None for ex in self.exps)

    def cell_force(self, theta: np.ndarray, ex: _Exp) -> np.ndarray:
        """
        Return the load cell the model gives for an experiment: the specimen's force.

        On the measured position and velocity (the load cell sees the specimen, whose
        deflection is measured), not the replay's: a replay that drifts would bias the
        stiffness by its amplitude error.
        """
        d = dict(self.base)
        d.update(self.values(theta))
        z, v = ex.cell_zv[:, 0], ex.cell_zv[:, 1]
        return float(d['k_L']) * (z - float(d['z_L'])) + float(d['c_L']) * v

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
            if ex.cell is not None:
                r = np.column_stack([r, (self.cell_force(theta, ex) - ex.cell) / ex.cell_sigma])
            r = r[ex.warmup:]
            bad = ~np.isfinite(r)
            if bad.any():
                r[bad] = 1e3     # diverged: a large, finite penalty keeps TRF going
            parts.append(r)
        return parts

    def blocks(self, seconds: float) -> np.ndarray:
        """Label of each entry of :meth:`residual`: its experiment's ``seconds``-long block."""
        out, first = [], 0
        for ex in self.exps:
            n = ex.y.shape[0] - ex.warmup
            per = max(1, int(round(seconds / ex.dt)))
            b = np.arange(n) // per
            out.append(np.repeat(first + b, len(ex.measured) + (ex.load is not None) +
                                 (ex.cell is not None)))
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
