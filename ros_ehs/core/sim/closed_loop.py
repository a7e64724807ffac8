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
In-process closed loop: controller at a fixed period, plant stepped with the command held.

This is exactly what the plant and controller nodes do in lock-step mode, without DDS. The
plant is stepped either by the fast fixed-step integrator (``stepper='fast'``) or, as the
accuracy reference, by ``scipy.integrate.solve_ivp`` restarted every period
(``stepper='reference'``, Radau with tight tolerances).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ros_ehs.core.control.controller import Controller
from ros_ehs.core.control.supervised import AxisController
from ros_ehs.core.errors import InputError
from ros_ehs.core.model.plant import Plant, StateSeries
from ros_ehs.core.params import Params

__all__ = ['ClosedLoopResult', 'model_difference', 'reference_step', 'run_closed_loop']


@dataclass(frozen=True)
class ClosedLoopResult(StateSeries):
    """Time [s], reference z/v, plant states, current applied to the valve [A] per period."""

    t: np.ndarray
    z_ref: np.ndarray
    v_ref: np.ndarray
    x: np.ndarray
    i: np.ndarray
    state_names: tuple[str, ...]
    z_meas: np.ndarray | None = None   #: the position the controller saw (with z_noise)
    events: tuple = ()                 #: supervised: the safety events, in order


def reference_step(plant: Plant, x, u, dt: float, rtol: float = 1e-10,
                   method: str = 'Radau', atol_scale: float = 1e-9) -> np.ndarray:
    """
    Advance ``x`` by ``dt`` with ``solve_ivp`` restarted from ``x``.

    The defaults (Radau, tight tolerances) make it the accuracy reference; the model
    benchmark also times it with LSODA at everyday tolerances.
    """
    from scipy.integrate import solve_ivp

    sol = solve_ivp(lambda t, y: plant.rhs_unchecked(t, y, u), (0.0, dt), x, method=method,
                    rtol=rtol, atol=plant._xscale * atol_scale)
    if not sol.success:
        raise InputError(f'reference solver failed: {sol.message}')
    return sol.y[:, -1]


def run_closed_loop(plant_params: Params, reference, duration: float, *,
                    model: str = 'full', controller_params: Params | None = None,
                    dt: float = 1e-3, stepper: str = 'fast', h: float | None = None,
                    x0=None, z_noise=None, supervised: bool = False,
                    fault=None, command_delay: int = 0) -> ClosedLoopResult:
    """
    Simulate the position loop for ``duration`` s: ``reference(t) -> (z_ref, v_ref)``.

    A ``reference`` with ``measure(t, z)`` and ``reference(t)`` methods (amplitude/phase
    control, :class:`ros_ehs.core.control.apc.AmplitudePhaseControl`) is run online: each period it
    takes the measured position, then gives the period's reference.

    ``plant_params`` sets the plant (e.g. Table 1 estimated); ``controller_params`` the
    controller (defaults to the same set). The controller samples the position at the start
    of each period and its command is held for the period (zero-order hold), as on the bench.
    ``z_noise`` (one value [m] per period) is added to the sampled position: sensor noise the
    controller sees; the result's ``z_meas`` is that measured position.

    ``supervised``: the controller node's computation, :class:`~ros_ehs.core.control.supervised.
    AxisController` (limit detectors, actions, ramp-on; the limits and actions from
    ``controller_params``), fed with each period's stamp ``k dt`` in ns, the measured
    position, velocity and hydraulic force; ``events`` lists what it reported.
    ``fault(k, z, z_dot, force) -> (z, z_dot, force)`` (supervised only) changes what the
    controller sees in period ``k``: a sensor fault.

    ``command_delay``: periods between the controller's command and the plant applying it. 0
    is our plant node (it applies a command on arrival); 1 is a ros2_control driver, whose
    hardware interface writes at its next cycle the command that answered this cycle's state.
    """
    if stepper not in ('fast', 'reference'):
        raise InputError(f'`stepper` = {stepper!r} is not one of [fast, reference]')
    n = int(round(duration / dt))
    if n < 1:
        raise InputError(f'`duration` = {duration!r} s is shorter than one period {dt} s')
    if z_noise is not None:
        z_noise = np.asarray(z_noise, dtype=float)
        if z_noise.shape != (n,) or not np.all(np.isfinite(z_noise)):
            raise InputError(f'`z_noise` must be {n} finite values [m], got shape '
                             f'{z_noise.shape}')
    if not isinstance(command_delay, int) or command_delay < 0:
        raise InputError(f'`command_delay` = {command_delay!r} must be a whole number of '
                         'periods >= 0')
    if fault is not None and not supervised:
        raise InputError('`fault` needs `supervised=True`')
    plant = Plant(plant_params, model, h=h)
    cp = controller_params or plant_params
    axis = AxisController(cp, dt) if supervised else None
    ctrl = Controller(cp, dt) if not supervised else None
    dt_ns = int(round(dt * 1e9))
    iv = plant.state_names.index('z_dot')
    ipa, ipb = plant.state_names.index('p_CP'), plant.state_names.index('p_CT')
    a_p = float(plant_params['A_p'])
    events = []
    t = np.arange(n + 1) * dt
    online = hasattr(reference, 'measure')      # corrected from the response (APC)
    if online:
        z_ref, v_ref = np.empty(n + 1), np.empty(n + 1)
    else:
        z_ref, v_ref = reference(t)
    x = plant.equilibrium() if x0 is None else np.array(x0, dtype=float)      # a copy
    xs = np.empty((n + 1, plant.n))
    cur = np.zeros(n + 1)
    iz = plant.state_names.index('z')
    xs[0] = x
    u = np.zeros(2)
    z_meas = np.empty(n)
    late = [0.0] * command_delay                 # commands on their way to the plant
    for k in range(n):
        z_meas[k] = x[iz] + (z_noise[k] if z_noise is not None else 0.0)
        if online:      # time as a node has it: from a stamp in ns (bit for bit)
            tk = (k * dt_ns) * 1e-9
            reference.measure(tk, float(z_meas[k]))
            z_ref[k], v_ref[k] = reference.reference(tk)
        fm = a_p * float(x[ipa] - x[ipb])          # the hydraulic force the state carries
        if axis is None:
            u[0] = ctrl.step(float(z_ref[k]), float(v_ref[k]), float(z_meas[k]), force=fm)
        else:
            zm, vm = float(z_meas[k]), float(x[iv])
            if fault is not None:
                zm, vm, fm = fault(k, zm, vm, fm)
                z_meas[k] = zm
            u[0] = axis.step(k * dt_ns, zm, vm, fm, float(z_ref[k]), float(v_ref[k]))
            events.extend(axis.events)
        if late:
            late.append(u[0])
            u[0] = late.pop(0)
        cur[k] = u[0]
        if stepper != 'fast':
            x = reference_step(plant, x, u, dt)
        elif not plant.advance(x, u, dt) and not np.all(np.isfinite(x)):   # x in place
            raise plant.diverged(dt, u)
        xs[k + 1] = x
    cur[n] = cur[n - 1]
    if online:
        z_ref[n], v_ref[n] = reference.reference((n * dt_ns) * 1e-9)
    return ClosedLoopResult(t, z_ref, v_ref, xs, cur, plant.state_names, z_meas,
                            tuple(events))


def model_difference(params: Params, reference, duration: float, model: str, *,
                     against: str = 'full', against_params: Params | None = None,
                     h: float | None = None) -> dict[str, float]:
    """
    How far ``model`` is from ``against`` in closed loop.

    ``model`` runs with ``params`` and integration step ``h``; ``against`` with
    ``against_params`` (default: the same ``params``) and its default step, both through
    :func:`run_closed_loop` on ``reference``. Returns the RMS of the difference over the RMS
    of ``against``'s signal, for the piston velocity (``velocity``), the load pressure
    ``p_CP - p_CT`` (``load_pressure``) and the current (``current``).
    """
    ref = run_closed_loop(against_params or params, reference, duration, model=against)
    run = run_closed_loop(params, reference, duration, model=model, h=h)

    def rel(a, b):
        return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b ** 2)))

    return {'velocity': rel(run.z_dot, ref.z_dot),
            'load_pressure': rel(run.p_a - run.p_b, ref.p_a - ref.p_b),
            'current': rel(run.i, ref.i)}
