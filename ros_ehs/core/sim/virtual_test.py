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
A virtual test: a procedure run in process on the model, faster than real time.

:func:`run_procedure` runs the procedure node's core
(:class:`~ros_ehs.core.procedure.runner.ProcedureRunner`) against the plant node's and the
controller node's cores (:class:`~ros_ehs.core.sim.axis.SimulatedAxis` with its specimen,
:class:`~ros_ehs.core.control.loop.ControlLoop` with its modes and detectors) in lock-step, as
the nodes run it over DDS: each period's reference first, then the state, the command, the
step. The controller's events go to the runner (an interlock interrupts the test; the
specimen's break fails it); a step in the other control mode switches the controller as the
node does. It tells what the rig would do: the cycles, the time, when each failure detector
would trip (``observe``: they report and the test goes on to the fracture, the run-out or its
end), and every cycle's extremes (memory: a fixed-size table, whatever the length).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import time
from typing import Any, Callable, Sequence

import numpy as np
from ros_ehs.core.control.loop import ControlLoop
from ros_ehs.core.errors import DataError, InputError
from ros_ehs.core.identify.live import LiveIdentifier, SampleWindow
from ros_ehs.core.model.specimen import Specimen
from ros_ehs.core.params import Params
from ros_ehs.core.procedure.detectors import CYCLE_COLUMNS, EXTRAPOLATED
from ros_ehs.core.procedure.envelope import require_envelope
from ros_ehs.core.procedure.runner import ProcedureRunner
from ros_ehs.core.procedure.spec import Procedure
from ros_ehs.core.sim.axis import SimulatedAxis
from ros_ehs.core.sim.jumps import CycleJumps, Jumper

__all__ = ['LiveFits', 'OPERATOR', 'VirtualTest', 'model_trip_cycle', 'run_procedure']

#: How often a virtual test looks at the wall clock for its ``progress`` [periods].
PROGRESS_PERIODS = 1000
#: The operator's requests a virtual test takes at given times (``actions``).
OPERATOR = ('hold', 'resume', 'stop', 'restart')


@dataclass
class VirtualTest:
    """What a virtual test did (SI units)."""

    result: str
    reason: str
    total_cycles: int
    sim_s: float
    wall_s: float
    tripped: dict                  #: each failure detector's trip cycle
    fractured_at: float | None     #: the specimen's fracture (its cycles), None if it held
    events: list = field(default_factory=list)      #: the runner's and the controller's
    cycles: np.ndarray | None = None   #: the last cycles' records (CYCLE_COLUMNS)
    checkpoints: int = 0
    checkpoint_s: float = 0.0          #: the time the checkpoints took in all [s]
    #: live refits (``live``): (stamp [ns], the ParameterEstimate or None, its verdict or error)
    estimates: list = field(default_factory=list)
    jumped: int = 0                    #: cycles credited by jumps, not simulated
    rig_s: float = math.nan            #: the test's time on the rig: simulated plus jumped [s]

    @property
    def speed(self) -> float:
        """Return simulated time over wall time."""
        return self.sim_s / self.wall_s if self.wall_s > 0 else math.inf

    @property
    def rig_speed(self) -> float:
        """Return the rig's time (jumps included) over wall time."""
        return self.rig_s / self.wall_s if self.wall_s > 0 else math.inf


@dataclass(frozen=True)
class LiveFits:
    """
    Live identification in a virtual test.

    ``identifier`` refits the last ``window`` seconds every ``period`` seconds of simulated
    time, as the identify node does on the rig.
    """

    identifier: LiveIdentifier
    window: float = 2.0
    period: float = 2.0


def run_procedure(procedure: Procedure, params: Params, *, model: str = 'simplified',
                  controller_params: Params | None = None, rate_hz: float = 1000.0,
                  max_seconds: float = 1.0e7, observe: bool = True, keep_cycles: int = 100_000,
                  latency: float = 0.002, checkpoint=None, live: LiveFits | None = None,
                  noise: tuple[float, float, float] = (0.0, 0.0, 0.0),
                  actions: Sequence[tuple[float, str]] = (), fault: str = 'none',
                  fault_time: float = 0.0, settle_after: float = 1.0, check: bool = True,
                  probe: Callable[[SimulatedAxis, ProcedureRunner, Any, Any], None] | None
                  = None,
                  progress: Callable[[float, int, str], None] | None = None,
                  progress_every: float = 10.0, jumps: CycleJumps | None = None
                  ) -> VirtualTest:
    """
    Run ``procedure`` on the model of ``params`` (its specimen too) until it finishes.

    ``controller_params``: the controller's (default: the same); ``max_seconds`` of simulated
    time at most; ``keep_cycles``: the newest cycle records kept (a ring: memory stays flat);
    ``checkpoint(dict)``: called with each checkpoint the runner makes (what the node writes);
    ``live``: refit the running loop (its sensors: position, velocity, current, pressures,
    load cell) and give each estimate's ``k_L`` to the runner, which is what a
    ``fitted_stiffness_drop`` detector judges (its estimates are in ``estimates``; each
    refit costs wall time the ``speed`` counts); ``noise``: the sensors' white noise (1
    sigma: position [m], velocity [m/s], pressures [Pa]; the load cell's is the parameter
    ``load_cell_noise``); ``actions``: the operator's requests at given simulated times
    [s], ``(t, 'hold' | 'resume' | 'stop' | 'restart')`` (``restart``: the procedure node
    restarted from its last checkpoint, the test ``interrupted`` until a ``resume``), their
    answers in ``events`` as ``('operator', kind, ok, why)``; ``fault``, ``fault_time``: the
    axis's injected fault (:data:`~ros_ehs.core.sim.faults.FAULTS`); ``probe(axis, runner,
    reply, reference)``: called each period after the command (a benchmark reads what the specimen
    carried: :meth:`SimulatedAxis.true_load`); ``settle_after``: a test interrupted or held
    with no action left to resume it ends the run this long after [s] (its ``result`` is
    then ``interrupted`` or ``held``, with the reason), rather than at ``max_seconds``;
    ``check``: refuse a procedure the rig of ``params`` cannot follow (InputError naming each
    step and limit, :func:`~ros_ehs.core.procedure.envelope.require_envelope`);
    ``progress(sim_s, cycles, state)``: called at most every ``progress_every`` seconds of
    wall time (judged every ``PROGRESS_PERIODS`` periods), for a long run's progress;
    ``jumps``: jump the cycles of a settled constant-amplitude step
    (:mod:`ros_ehs.core.sim.jumps`; None: every period simulated, the exact run). With jumps
    the cycle table's ends and ``rig_s`` are the rig's time (simulated plus jumped).
    """
    if not isinstance(procedure, Procedure):
        raise InputError(f'`procedure` must be a Procedure, got {type(procedure).__name__}')
    if check:
        require_envelope(procedure, params)
    if live is not None and not isinstance(live, LiveFits):
        raise InputError(f'`live` must be LiveFits, got {type(live).__name__}')
    cp = controller_params or params
    axis = SimulatedAxis(params, model, rate_hz=rate_hz, lockstep=True, noise=noise,
                         fault=fault, fault_time=fault_time)
    if not (math.isfinite(progress_every) and progress_every >= 0):
        raise InputError(f'`progress_every` = {progress_every!r} s must be finite and >= 0')
    if not (math.isfinite(settle_after) and settle_after >= 0):
        raise InputError(f'`settle_after` = {settle_after!r} s must be finite and >= 0')
    for t, kind in actions:
        if kind not in OPERATOR:
            raise InputError(f'unknown action {kind!r}: one of {", ".join(OPERATOR)}')
        if not (math.isfinite(t) and t >= 0):
            raise InputError(f'the {kind} action at {t!r} s: its time must be finite and >= 0')
    todo = sorted(actions, key=lambda a: a[0])
    last_cp: dict | None = None
    loop = ControlLoop(cp.replace(control_mode=procedure.steps[0].control_mode),
                       rate_hz=rate_hz, lockstep=True)
    ramp = float(cp['ramp_time'])
    runner = ProcedureRunner(procedure, latency=latency, rate_hz=rate_hz, observe=observe,
                             ramp_time=ramp)
    table = np.full((keep_cycles, len(CYCLE_COLUMNS)), np.nan)
    n_kept = 0
    jumper = Jumper(jumps) if jumps is not None else None
    jumped_s = 0.0                     # the time the jumps stood for [s]
    events: list = []
    fractured = None
    checkpoints, cp_s = 0, 0.0
    n = int(max_seconds * rate_hz)
    window, every, full = None, 1, 0.0
    estimates: list = []
    if live is not None:
        window = SampleWindow(live.window, int(live.window * rate_hz) + 10)
        every = max(1, int(round(live.period * rate_hz)))
        full = live.window - 1.5 / rate_hz        # the window's span once it is full [s]
    # the nodes' calls, bound once (a period is some 130 calls: each lookup counts)
    sample, reference, trajectory, answer = axis.sample, runner.sample, loop.trajectory, \
        loop.state
    command, measure = axis.command, runner.measure
    wall0 = last_progress = time.perf_counter()
    started = False
    stopped_at: int | None = None     # the period the test was interrupted or held at
    k = 0
    for k in range(n):
        s = sample()
        st = s.state
        stamp = st.stamp_ns
        if not started:
            measure(stamp, st.z, s.load)
            ok, why = runner.start(stamp)
            if not ok:
                raise InputError(f'the procedure did not start: {why}')
            started = True
        while todo and todo[0][0] <= k / rate_hz + 1e-12:
            kind = todo.pop(0)[1]
            if kind == 'restart':
                runner = ProcedureRunner(procedure, latency=latency, rate_hz=rate_hz,
                                         observe=observe, ramp_time=ramp)
                if jumper is not None:
                    jumper = Jumper(jumps)
                reference, measure = runner.sample, runner.measure
                if last_cp is not None:
                    runner.restore(last_cp)
                measure(stamp, st.z, s.load)
                ok, why = True, runner.state
            else:
                ok, why = getattr(runner, kind)(stamp)
            events.append(('operator', kind, ok, why))
        ref = reference(stamp)
        trajectory((ref,))
        reply = answer(st, 0.0, stamp)
        command(stamp, reply.current, 0.0)
        if probe is not None:
            probe(axis, runner, reply, ref)
        for e in reply.events:
            events.append(('controller', e.kind, e.detector, e.message))
            runner.event(e.kind, e.detector, e.action, stamp)
        measure(stamp, st.z, s.load)
        if window is not None:
            _live_step(live, window, every, full, k, s, reply.current, runner, estimates)
        if runner.request_mode is not None:
            ok, why, ev = loop.set_mode(runner.request_mode)
            events.append(('controller', ev.kind, ev.detector, ev.message))
            runner.mode_switched(ok, why, stamp)
        if runner.cycles:
            for c in runner.cycles:
                table[n_kept % keep_cycles] = c.row()
                table[n_kept % keep_cycles, 2] += jumped_s
                n_kept += 1
            if jumper is not None:
                jumper.saw(runner.cycles, axis.specimen.half_cycles)
                last = runner.cycles[-1]
                jn = jumper.size(runner, axis.specimen, procedure.steps[runner.step_index])
                if jn:
                    period = runner.step_period()
                    if axis.specimen.present and jumper.per_cycle > 0:
                        axis.specimen.advance(jn * jumper.per_cycle, jumper.force_range)
                        axis.plant.set_load(axis.specimen.stiffness, axis.specimen.damping)
                    runner.jump(jn)
                    jumper.jumped(jn)
                    n_kept = _jumped_rows(table, n_kept, last, jn, period, jumped_s)
                    jumped_s += jn * period
            runner.cycles.clear()
        if runner.captures:
            runner.captures.clear()
        if runner.events:
            events.extend(('procedure',) + e for e in runner.events)
            runner.events.clear()
        if runner.checkpoint_due:
            t0 = time.perf_counter()
            d = last_cp = runner.checkpoint()
            if checkpoint is not None:
                checkpoint(d)
            cp_s += time.perf_counter() - t0
            checkpoints += 1
        if fractured is None and axis.specimen.broken:
            fractured = axis.specimen.cycles
        if runner.state == 'finished':
            break
        if progress is not None and not k % PROGRESS_PERIODS:
            now = time.perf_counter()
            if now - last_progress >= progress_every:
                last_progress = now
                progress(k / rate_hz, runner.total, runner.state)
        if runner.state in ('interrupted', 'held') and not todo:
            if stopped_at is None:
                stopped_at = k
            elif (k - stopped_at) / rate_hz >= settle_after:
                break
        else:
            stopped_at = None
    wall = time.perf_counter() - wall0
    if n_kept > keep_cycles:
        start = n_kept % keep_cycles
        table = np.concatenate([table[start:], table[:start]])
    else:
        table = table[:n_kept]
    reason = runner.reason
    if not runner.result and runner.state in ('interrupted', 'held'):
        reason = next((e[4] for e in reversed(events) if e[0] == 'procedure' and
                       e[1] == runner.state), '')
    return VirtualTest(runner.result or runner.state, reason, runner.total,
                       (k + 1) / rate_hz, wall, dict(runner.tripped), fractured, events, table,
                       checkpoints, cp_s, estimates, runner.jumped,
                       (k + 1) / rate_hz + jumped_s)


def _live_step(live: LiveFits, window: SampleWindow, every: int, full: float, k: int, s,
               current: float, runner: ProcedureRunner, estimates: list) -> None:
    """Feed the window one period; refit it every ``every`` periods once it spans ``full`` s."""
    st = s.state
    window.add_state(st.stamp_ns, st.z, st.z_dot, st.i)
    window.add_command(st.stamp_ns, current)
    window.add_pressure(0, st.stamp_ns, s.p_cp)
    window.add_pressure(1, st.stamp_ns, s.p_ct)
    window.add_load(st.stamp_ns, s.load)
    if k % every or window.span() < full or runner.state != 'running':
        return
    try:
        est, _ = live.identifier.refit(window.experiments(), st.stamp_ns, live.window)
    except (DataError, InputError) as err:        # a window that cannot be fitted: the next
        estimates.append((st.stamp_ns, None, str(err)))
        return
    estimates.append((st.stamp_ns, est, est.verdict))
    if 'k_L' in est.values:
        runner.estimate(st.stamp_ns, est.values['k_L'], est.stderr.get('k_L', math.nan),
                        est.adequate)


def _jumped_rows(table: np.ndarray, n_kept: int, last, n: int, period: float,
                 jumped_s: float) -> int:
    """Write ``n`` jumped cycles after ``last`` into the ring ``table``; return the rows kept."""
    keep = table.shape[0]
    first = max(0, n - keep)                  # older ones would be overwritten at once
    j = np.arange(first + 1, n + 1)
    rows = np.tile(np.array(last.row(), dtype=float), (j.size, 1))
    rows[:, 0] = last.count + j
    rows[:, 2] += jumped_s + j * period
    rows[:, 9] = EXTRAPOLATED
    at = (n_kept + first + np.arange(j.size)) % keep
    table[at] = rows
    return n_kept + n


def model_trip_cycle(specimen: Specimen, kind: str, values: dict, peak: float, valley: float,
                     first: int = 0, taper: int = 0) -> float:
    """
    Return the cycle at which the specimen model meets a failure detector's criterion.

    A force-controlled constant-amplitude test between ``peak`` and ``valley`` [N], its
    cycles counted from ``first`` specimen cycles on (a preload's). The detector's reference
    is the model's stiffness averaged over the same cycles as the detector's (after
    ``settling``), a cycle's stiffness the one half-way through it; ``persist`` cycles beyond.
    ``stiffness_drop``: the stiffness under ``1 - drop`` of the reference;
    ``peak_valley_change``: the position's peak moves ``F_peak (1/k - 1/k_ref)``, so the
    criterion is ``k < k_ref / (1 + tolerance (peak - valley) / |peak|)`` (the peak the larger
    in magnitude). ``taper``: the step's tapered cycles, which the detectors do not judge
    (their settling counts from the first cycle after them). Returns inf when the specimen
    fractures first.
    """
    rng = peak - valley
    if kind not in ('stiffness_drop', 'peak_valley_change') or rng <= 0:
        raise InputError(f'no model criterion for {kind!r} between {valley!r} and {peak!r}')

    def k(n: float) -> float:
        return specimen.stiffness_after(first + n - 0.5, rng)

    s0, nr = int(values['settling']) + int(taper), int(values['reference'])
    k_ref = sum(k(n) for n in range(s0 + 1, s0 + nr + 1)) / nr
    if kind == 'stiffness_drop':
        k_trip = (1.0 - values['drop']) * k_ref
    else:
        f_peak = max(abs(peak), abs(valley))
        k_trip = k_ref / (1.0 + values['tolerance'] * rng / f_peak)
    life = specimen.cycles_to(1.0, rng) - first
    lo, hi = float(s0 + nr), life
    if k(hi) >= k_trip:
        return math.inf
    for _ in range(100):                 # the stiffness falls monotonically: bisect
        mid = 0.5 * (lo + hi)
        if k(mid) < k_trip:
            hi = mid
        else:
            lo = mid
    n = math.floor(hi) if k(math.floor(hi)) < k_trip else math.ceil(hi)
    return float(n + int(values['persist']) - 1)
