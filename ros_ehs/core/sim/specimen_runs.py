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
An axis with its specimen run in process: the plant node's and the controller node's cores.

:func:`run_axis` steps a lock-step :class:`~ros_ehs.core.sim.axis.SimulatedAxis` (the model,
its specimen and load cell) and a lock-step :class:`~ros_ehs.core.control.loop.ControlLoop`
(the controller node's rules, modes and detectors) period by period, the reference of each
stamp given before its state as the reference node's trajectory gives it: what the nodes do
over DDS in lock-step, without DDS. The benchmarks and ``ehs_sim tune`` run it; the tests use
it for the rules that need a closed loop.

A reference is a callable ``t -> (z_ref, v_ref, f_ref)`` (NaN for what it does not give), or
an object with ``measure(t, value)`` and ``reference(t) -> (value, rate)`` (amplitude/phase or
peak/valley control) with ``signal`` 'position' or 'force': it takes the measured position or
load each period, then gives that period's reference. ``actions`` are operator requests at
given times: ``(t, 'mode', name)``, ``(t, 'reset', None)``, ``(t, 'enable', bool)``; their
answers come back in ``answers`` as ``(t, kind, ok, why)``.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Callable, Sequence

import numpy as np
from ros_ehs.core.control.loop import ControlLoop
from ros_ehs.core.errors import InputError
from ros_ehs.core.params import Params
from ros_ehs.core.sim.axis import SimulatedAxis
from ros_ehs_msgs_py import Reference

__all__ = ['AxisRun', 'run_axis']


@dataclass(frozen=True)
class AxisRun:
    """What a run recorded, one row a period (SI units)."""

    t: np.ndarray          #: the state's time [s]
    z: np.ndarray          #: the measured position [m]
    z_dot: np.ndarray      #: the measured velocity [m/s]
    load: np.ndarray       #: the load cell [N]
    i: np.ndarray          #: the command answering the state [A]
    z_ref: np.ndarray      #: the reference given [m] (NaN: none)
    f_ref: np.ndarray      #: the force reference given [N] (NaN: none)
    p_a: np.ndarray        #: the chamber pressures [Pa]
    p_b: np.ndarray
    driving: tuple         #: the loop that drove the valve each period ('' for 0 A)
    events: tuple          #: the safety and mode events, in order
    answers: tuple         #: (t, kind, ok, why) of each action
    figures: dict          #: the axis's and the loop's figures at the end


def run_axis(params: Params, duration: float, reference, *, model: str = 'full',
             controller_params: Params | None = None, rate_hz: float = 1000.0,
             signal: str = 'position', actions: Sequence[tuple] = (),
             initial_z: float = 0.0, stop: Callable[[int, 'SimulatedAxis'], bool] | None = None,
             ) -> AxisRun:
    """
    Run the axis on ``reference`` for ``duration`` [s] (see the module docstring).

    ``params`` is the plant's (the specimen's too); ``controller_params`` the controller's
    (default the same). ``stop(k, axis)`` ends the run early when it returns True.
    """
    if signal not in ('position', 'force'):
        raise InputError(f'`signal` = {signal!r} is not position or force')
    n = int(round(duration * rate_hz))
    if n < 1:
        raise InputError(f'`duration` = {duration!r} s is shorter than one period')
    ax = SimulatedAxis(params, model, rate_hz=rate_hz, lockstep=True, initial_z=initial_z)
    loop = ControlLoop(controller_params or params, rate_hz=rate_hz, lockstep=True)
    online = hasattr(reference, 'measure')
    todo = sorted(actions, key=lambda a: a[0])
    rows = np.full((n, 9), math.nan)
    driving, events, answers = [], [], []
    k = 0
    for k in range(n):
        s = ax.sample()
        st = s.state
        t = (st.stamp_ns - ax.t0_ns) * 1e-9
        while todo and todo[0][0] <= t + 1e-12:
            _, kind, arg = todo.pop(0)
            if kind == 'mode':
                ok, why, ev = loop.set_mode(arg)
            elif kind == 'reset':
                ok, why, ev = loop.reset(t)
            elif kind == 'enable':
                ok, why, ev = loop.enable(bool(arg))
            else:
                raise InputError(f'unknown action {kind!r}: mode, reset or enable')
            answers.append((t, kind, ok, why))
            events.append(ev)
        if online:
            reference.measure(t, s.load if signal == 'force' else st.z)
            v, rate = reference.reference(t)
            ref = (math.nan, math.nan, v) if signal == 'force' else (v, rate, math.nan)
        else:
            ref = reference(t)
        loop.trajectory([Reference(st.stamp_ns, *ref)])
        reply = loop.state(st, t, st.stamp_ns)
        if reply is None:
            raise InputError(f'the loop did not answer the state at {t:.6g} s')
        ax.command(st.stamp_ns, reply.current, t)
        events.extend(reply.events)
        rows[k] = (t, st.z, st.z_dot, s.load, reply.current, ref[0], ref[2], s.p_cp, s.p_ct)
        driving.append(loop.axis.driving or '')
        if stop is not None and stop(k, ax):
            break
    rows = rows[:k + 1]
    figures = {**ax.figures(0.0), **loop.figures()}
    return AxisRun(*rows.T, tuple(driving), tuple(events), tuple(answers), figures)


def square_wave(params: Params, loop: str, amplitude: float, *, period: float = 1.0,
                cycles: int = 3, model: str = 'full', rate_hz: float = 1000.0,
                mean: float | None = None) -> tuple[float, AxisRun]:
    """
    Return the overshoot [%] of ``loop``'s response to a square wave, and the run.

    The square wave steps between ``mean -+ amplitude`` (default mean: 0 N, or the installed
    position ``z_L``) every half ``period``, after the ramp-on; ``loop`` is ``displacement``
    or ``force`` (the control mode); the feedforward is off (a square wave's rate is a spike:
    the feedback loop alone is judged, as its tuning predicts). The overshoot is the mean over
    the steps of the peak past the new level, in % of the step, the level being the mean of
    each half period's last tenth.
    """
    if loop not in ('displacement', 'force'):
        raise InputError(f'`loop` = {loop!r} is not displacement or force')
    if not (math.isfinite(amplitude) and amplitude > 0):
        raise InputError(f'`amplitude` = {amplitude!r} must be a positive number')
    p = params.replace(control_mode=loop, ff_enable=0.0, force_ff=0.0, ff_velocity=0.0)
    ramp = float(p['ramp_time'])
    centre = (0.0 if loop == 'force' else float(p['z_L'])) if mean is None else float(mean)
    half = 0.5 * period

    def level(t: float) -> float:
        k = int(math.floor((t - ramp) / half)) if t >= ramp else -1
        return centre + (amplitude if k % 2 == 0 else -amplitude) if k >= 0 else centre

    def ref(t: float) -> tuple[float, float, float]:
        v = level(t)
        return (math.nan, math.nan, v) if loop == 'force' else (v, 0.0, math.nan)

    run = run_axis(p, ramp + cycles * period + 1e-9, ref, model=model, rate_hz=rate_hz,
                   initial_z=float(p['z_L']))
    y = run.load if loop == 'force' else run.z
    over = []
    for k in range(1, 2 * cycles):       # each step but the first (from the centre)
        a, b = ramp + k * half, ramp + (k + 1) * half
        seg = (run.t >= a - 1e-9) & (run.t < b - 1e-9)
        ys = y[seg]
        if ys.size < 10:
            continue
        final = float(np.mean(ys[-max(1, ys.size // 10):]))
        before = level(a - 1e-6)
        step = final - before
        if step == 0:
            continue
        peak = float(np.max(ys) if step > 0 else np.min(ys))
        over.append(max(0.0, (peak - final) / step * 100.0))
    return (float(np.mean(over)) if over else math.nan), run
