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
The checked public plant: ``Plant(params, model)`` with ``dynamics``, ``step``, ``simulate``.

python-control's shape: ``dynamics(t, x, u)`` is the right-hand side ``rhs(t, x, u, params)``
bound to a parameter set, validated; :mod:`ros_ehs.core.model.kernels` is the unchecked fast path
that ``step`` (plant node) and ``simulate`` (identification) run.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from ros_ehs.core.errors import InputError, ParameterError
from ros_ehs.core.model import kernels as K
from ros_ehs.core.params import Params, preset

__all__ = ['FULL_STATES', 'MODELS', 'Plant', 'SIMPLIFIED_STATES', 'SimResult', 'StateSeries',
           'compile_kernels', 'rhs']

FULL_STATES = ('theta_dot', 'theta', 'p_tL', 'p_tR', 'x_dot', 'x', 'p_CP', 'p_CT', 'z_dot',
               'z')
SIMPLIFIED_STATES = ('p_CP', 'p_CT', 'z_dot', 'z')
REDUCED_STATES = ('x_dot', 'x', 'p_CP', 'p_CT', 'z_dot', 'z')
MODELS = {'full': (K.FULL, FULL_STATES), 'simplified': (K.SIMPLIFIED, SIMPLIFIED_STATES),
          'reduced': (K.REDUCED, REDUCED_STATES)}

# typical magnitude of each state, for the finite-difference Jacobian
_XSCALE = {'theta_dot': 1.0, 'theta': 1e-3, 'p_tL': 1e6, 'p_tR': 1e6, 'x_dot': 0.1,
           'x': 1e-4, 'p_CP': 1e6, 'p_CT': 1e6, 'z_dot': 1e-2, 'z': 1e-2}

#: Internal step of the fixed-step integrator [s], per model (chosen in docs/model.md).
#: Full: 50 us keeps the 1 Hz / 0.04 m closed loop within 1e-6 m of the Radau reference.
#: Simplified: one 1 ms step per control period (~4e-5 m), >= 1000x real time.
DEFAULT_H = {'full': 50e-6, 'simplified': 1e-3, 'reduced': 100e-6}
#: Jacobian refresh period, in calls of ``step`` (or samples of ``simulate``). ROS2 keeps
#: order 2 with a stale Jacobian, so reuse costs little accuracy (docs/model.md).
DEFAULT_JAC_EVERY = {'full': 4, 'simplified': 1, 'reduced': 1}


class StateSeries:
    """Named state signals of a result with ``x`` (N, n) and ``state_names``, in SI units."""

    x: np.ndarray
    state_names: tuple[str, ...]

    def signal(self, name: str) -> np.ndarray:
        """Return state ``name`` at every sample."""
        return self.x[:, self.state_names.index(name)]

    @property
    def z(self) -> np.ndarray:
        """Piston position [m]."""
        return self.signal('z')

    @property
    def z_dot(self) -> np.ndarray:
        """Piston velocity [m/s]."""
        return self.signal('z_dot')

    @property
    def p_a(self) -> np.ndarray:
        """Pressure in chamber P [Pa]."""
        return self.signal('p_CP')

    @property
    def p_b(self) -> np.ndarray:
        """Pressure in chamber T [Pa]."""
        return self.signal('p_CT')


@dataclass(frozen=True)
class SimResult(StateSeries):
    """
    A simulated run: time ``t`` (N+1,) [s], states ``x`` (N+1, n), inputs ``u`` (N, 2).

    ``u[k]`` is held over ``[t[k], t[k+1])``. Named signals are properties in SI units.
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    state_names: tuple[str, ...]
    params: Params

    @property
    def force(self) -> np.ndarray:
        """Hydraulic force A_p (p_P - p_T) on the piston [N]."""
        return self.params['A_p'] * (self.p_a - self.p_b)


def rhs(t: float, x: np.ndarray, u: np.ndarray, params: Params, model: str = 'full'):
    """Return dx/dt of ``model`` at state ``x`` and input ``u = [i, F_L]`` (checked)."""
    return Plant(params, model).dynamics(t, x, u)


#: Newton's method for the rest state: steps at most, and the step [scaled units] it ends at
NEWTON_STEPS, NEWTON_XTOL = 30, 1e-12


def compile_kernels(params: Params | None = None) -> None:
    """
    Compile every kernel the package calls, for each model, into numba's cache.

    numba compiles a kernel at its first call (seconds for the set) and caches it in
    ``NUMBA_CACHE_DIR`` (``scripts/env.sh``); ``scripts/setup.sh`` calls this at each set-up,
    so that neither the first node nor parallel test workers compile the same kernels again. With a
    warm cache it only loads them (well under a second).
    """
    params = params or preset()
    u = np.array([1e-3, 0.0])
    for model in MODELS:
        plant = Plant(params, model)
        x = plant.equilibrium()
        plant.dynamics(0.0, x, u)
        plant.step(x, u, 1e-3)
        plant.simulate(1e-3, np.tile(u, (3, 1)), x)
        # the fit's replay of a command held in pieces of a sample (identify.problem)
        K.simulate_pieces(plant._id, x, np.tile(u, (6, 1)), 2, plant._c, 1e-3, 2,
                          plant._xscale, plant.jac_every, np.empty((4, plant.n)))


def _newton(resid, y: np.ndarray) -> np.ndarray | None:
    """
    Return ``y`` with ``resid(y)`` = 0 by Newton's method, or None if it does not converge.

    A forward-difference Jacobian, a step halved until the residual falls (at most 30 times);
    converged when the Newton step moves no unknown by more than :data:`NEWTON_XTOL`
    (relative, as MINPACK's ``xtol``).
    """
    n = y.size
    jac = np.empty((n, n))
    r = resid(y)                    # a new array each call (f[eqs] is a copy)
    for _ in range(NEWTON_STEPS):
        for k in range(n):
            h = 1e-7 * max(1.0, abs(y[k]))
            yk = y[k]
            y[k] = yk + h
            jac[:, k] = (resid(y) - r) / h
            y[k] = yk
        try:
            step = np.linalg.solve(jac, -r)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(step)):
            return None
        if np.all(np.abs(step) <= NEWTON_XTOL * np.maximum(np.abs(y), 1.0)):
            return y + step             # converged (to the residual's rounding: no search)
        norm = float(np.sum(r * r))
        a = 1.0
        for _ in range(30):
            trial = y + a * step
            rt = resid(trial)
            if np.all(np.isfinite(rt)) and float(np.sum(rt * rt)) <= norm:
                break
            a *= 0.5
        else:
            return None
        y, r = trial, rt
    return None


class Plant:
    """
    The servo-valve and cylinder model with a fixed parameter set.

    Parameters
    ----------
    params : Params
        Validated parameter set (plant entries are used).
    model : {'full', 'simplified'}
        The 10-state model of eq. (3) or the 4-state model of eqs. (6)-(8).
    h : float, optional
        Internal integration step [s]; default ``DEFAULT_H[model]``.
    smooth : bool
        Smoothed sign/saturation/root (default). ``False`` uses the exact forms, for
        comparison only: the fixed-step integrator then needs a far smaller ``h``.

    """

    def __init__(self, params: Params, model: str = 'full', h: float | None = None,
                 smooth: bool = True) -> None:
        if not isinstance(params, Params):
            raise ParameterError(f'`params` must be a Params, got {type(params).__name__}')
        if model not in MODELS:
            raise ParameterError(f'`model` = {model!r} is not one of {sorted(MODELS)}')
        self.params = params
        self.model = model
        self._id, self.state_names = MODELS[model]
        self.n = len(self.state_names)
        h = DEFAULT_H[model] if h is None else h
        if not (isinstance(h, (int, float)) and math.isfinite(h) and 0 < h <= 0.01):
            raise ParameterError(f'`h` = {h!r} s must be in (0, 0.01]')
        self.h = float(h)
        self._c = K.coefficients(params, smooth=smooth)
        self._xscale = np.array([_XSCALE[s] for s in self.state_names])
        self.jac_every = DEFAULT_JAC_EVERY[model]
        self._w = np.empty((self.n, self.n))
        self._piv = np.empty(self.n, dtype=np.int64)
        self._calls = 0
        self._last_dt = -1.0
        self._nsub, self._nsub_dt = 1, -1.0
        self._iz = self.state_names.index('z')
        self._l_iac = float(params['l_iac'])

    def set_params(self, params: Params) -> None:
        """Take a new parameter set from the next step on (a rig that drifts; the state stays)."""
        if not isinstance(params, Params):
            raise ParameterError(f'`params` must be a Params, got {type(params).__name__}')
        smooth = bool(self._c[K.C_SMOOTH] > 0.5)
        self._c = K.coefficients(params, smooth=smooth)
        self.params = params
        self._l_iac = float(params['l_iac'])
        self._calls = 0          # the integrator's W from the new set at once

    def set_load(self, stiffness: float, damping: float) -> None:
        """
        Take the load string's stiffness [N/m] and damping [N s/m] from the next step on.

        The specimen's, as its crack grows (:class:`ros_ehs.core.model.specimen.Specimen`); its
        installed position stays ``z_L``. Unchecked (a fast path): finite values >= 0.
        """
        self._c[K.C_KL] = stiffness
        self._c[K.C_CL] = damping
        self._calls = 0          # the integrator's W from the new load at once

    # -- checks ------------------------------------------------------------------------
    def _check_x(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n,):
            raise InputError(f'`x` must have shape ({self.n},) for the {self.model} model, '
                             f'got {x.shape}')
        if not np.all(np.isfinite(x)):
            bad = [self.state_names[k] for k in np.flatnonzero(~np.isfinite(x))]
            raise InputError(f'`x` has non-finite states: {bad}')
        z = x[self.state_names.index('z')]
        if not abs(z) < self.params['l_iac']:
            raise InputError(f'`x`: piston position z = {z!r} m is outside the cylinder '
                             f'(|z| < l_iac = {self.params["l_iac"]!r} m)')
        return x

    @staticmethod
    def _check_u(u) -> np.ndarray:
        u = np.asarray(u, dtype=float)
        if u.shape != (2,):
            raise InputError(f'`u` must be [i, F_L] with shape (2,), got {u.shape}')
        if not np.all(np.isfinite(u)):
            raise InputError(f'`u` = {u.tolist()} is not finite (servo current [A], load [N])')
        return u

    # -- public API --------------------------------------------------------------------
    def dynamics(self, t: float, x, u) -> np.ndarray:
        """Right-hand side dx/dt [SI units per second] at ``x``, ``u`` (checked)."""
        out = np.empty(self.n)
        K.rhs(self._id, self._check_x(x), self._check_u(u), self._c, out)
        return out

    def rhs_unchecked(self, t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Right-hand side without checks, for solve_ivp references."""
        out = np.empty(self.n)
        K.rhs(self._id, x, u, self._c, out)
        return out

    def step(self, x, u, dt: float) -> np.ndarray:
        """
        Return the state ``dt`` seconds after ``x`` with input ``u`` held (zero-order hold).

        Internal substeps of at most ``self.h``. ``dt == 0`` returns a copy of ``x``.
        """
        x = self._check_x(x).copy()
        u = self._check_u(u)
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt >= 0):
            raise InputError(f'`dt` = {dt!r} s must be finite and >= 0')
        if dt == 0:
            return x
        self._advance(x, u, dt)
        if not np.all(np.isfinite(x)):
            raise self.diverged(dt, u)
        return x

    @staticmethod
    def diverged(dt: float, u: np.ndarray) -> InputError:
        """Return the error of a step over ``dt`` with input ``u`` that left no finite state."""
        return InputError(f'integration diverged within dt = {dt!r} s at u = {u.tolist()}')

    def advance(self, x: np.ndarray, u: np.ndarray, dt: float) -> list[float] | None:
        """
        Unchecked fast path of :meth:`step`, for the plant node's period: ``x`` in place.

        ``x`` (float64, this model's length), ``u`` (2,) and ``dt`` > 0 are trusted. Returns
        the new state as Python floats (``x.tolist()``), or None when the state left the
        model (a non-finite value, or the piston outside the cylinder): ``x`` is then garbage
        and the caller keeps its last good state. It costs 3-6 us less per call than
        :meth:`step` (no conversion, checks or copy; measured 2.8 us against 9.0 us for the
        simplified model).
        """
        self._advance(x, u, dt)
        xs = x.tolist()      # Python floats: no numpy scalar per element
        for v in xs:
            if not math.isfinite(v):
                return None
        return xs if abs(xs[self._iz]) < self._l_iac else None

    def _advance(self, x: np.ndarray, u: np.ndarray, dt: float) -> None:
        """Integrate ``x`` in place over ``dt`` (substeps, Jacobian refresh): no checks."""
        if dt != self._nsub_dt:
            self._nsub, self._nsub_dt = max(1, int(math.ceil(dt / self.h - 1e-9))), dt
        refresh = self._calls % self.jac_every == 0 or dt != self._last_dt
        self._calls += 1
        self._last_dt = dt
        K.advance_ws(self._id, x, u, self._c, dt / self._nsub, self._nsub, self._xscale,
                     self._w, self._piv, refresh)

    def simulate(self, dt: float, u, x0=None) -> SimResult:
        """
        Simulate a whole input record: ``u`` (N, 2) or (N,) currents, each held for ``dt``.

        ``x0`` defaults to :meth:`equilibrium` at z = 0.
        """
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise InputError(f'`dt` = {dt!r} s must be finite and > 0')
        u = np.asarray(u, dtype=float)
        if u.ndim == 1:
            u = np.column_stack([u, np.zeros_like(u)])
        if u.ndim != 2 or u.shape[1] != 2 or u.shape[0] < 1:
            raise InputError(f'`u` must have shape (N, 2) or (N,), got {u.shape}')
        if not np.all(np.isfinite(u)):
            k = int(np.flatnonzero(~np.all(np.isfinite(u), axis=1))[0])
            raise InputError(f'`u` is not finite at sample {k}: {u[k].tolist()}')
        x0 = self.equilibrium() if x0 is None else self._check_x(x0)
        nsub = max(1, int(math.ceil(dt / self.h - 1e-9)))
        out = np.empty((u.shape[0] + 1, self.n))
        ok = K.simulate(self._id, np.ascontiguousarray(x0, dtype=float), np.ascontiguousarray(u),
                        self._c, float(dt), nsub, self._xscale, self.jac_every, out)
        if ok <= u.shape[0]:
            raise InputError(f'simulation diverged at sample {ok} (t = {ok * dt:.6g} s)')
        t = np.arange(u.shape[0] + 1) * dt
        return SimResult(t, out, u, self.state_names, self.params)

    #: each state solved for rest, and the state whose rate must then vanish
    _RATE_OF = {'theta': 'theta_dot', 'x': 'x_dot'}

    def _at_rest(self, x: np.ndarray, i: float, solved: tuple[str, ...]) -> np.ndarray:
        """
        Solve the states named ``solved`` in ``x`` (in place) for zero rate at ``i``.

        Newton's method first (its few unknowns, a smooth model: it converges in a handful of
        steps, and a node's start does not pay scipy.optimize's import, about 0.15 CPU-s);
        MINPACK's hybrid method (``scipy.optimize.root``) where Newton does not converge.
        """
        names = self.state_names
        free = [k for k, s in enumerate(names) if s in solved]
        if not free:
            return x
        rate_of = self._RATE_OF
        eqs = [names.index(rate_of[names[k]]) if rate_of.get(names[k]) in names
               else k for k in free]
        scale = self._xscale[free]
        u = np.array([i, 0.0])
        f = np.empty(self.n)

        def resid(y):
            x[free] = y * scale
            K.rhs(self._id, x, u, self._c, f)
            return f[eqs] / np.maximum(np.abs(scale), 1.0) * 1e-3

        y0 = x[free] / scale
        y = _newton(resid, y0.copy())
        if y is None:
            from scipy.optimize import root
            y = root(resid, y0, method='hybr', options={'xtol': 1e-12}).x
        x[free] = y * scale
        return x

    def settle_valve(self, x, i: float = 0.0) -> np.ndarray:
        """
        Return ``x`` with the valve's states at rest for current ``i`` [A], the rest held.

        The state a record starts in when it starts mid-motion: position, velocity and
        chamber pressures as measured, the valve (armature, pilot pressures, spool) settled for
        the current and those pressures (its rates zero). The simplified model has no valve
        states: ``x`` comes back unchanged.
        """
        x = np.array(x, dtype=float)
        names = self.state_names
        for s, rate in self._RATE_OF.items():
            if s in names and rate in names:
                x[names.index(rate)] = 0.0
        return self._at_rest(x, float(i), ('theta', 'p_tL', 'p_tR', 'x'))

    def equilibrium(self, z: float = 0.0, i: float = 0.0) -> np.ndarray:
        """
        Return the rest state at piston position ``z`` [m] with current ``i`` [A] held.

        The piston is held still (friction permitting); pressures and, for the full model,
        the valve states are solved for zero rate with a Newton iteration.
        """
        p = self.params
        pm = 0.5 * (p['p_s'] + p['p_t'])
        x = np.zeros(self.n)
        names = self.state_names
        for s in ('p_CP', 'p_CT', 'p_tL', 'p_tR'):
            if s in names:
                x[names.index(s)] = pm
        x[names.index('z')] = z
        solved = ('theta', 'p_tL', 'p_tR', 'x', 'p_CP', 'p_CT')
        return self._at_rest(x, float(i), solved).copy()
