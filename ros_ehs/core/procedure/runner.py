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
The procedure node's rules: a test run step by step, its cycles counted, its failure decided.

:class:`ProcedureRunner` turns a checked :class:`~ros_ehs.core.procedure.spec.Procedure` into
the reference of every stamp (:meth:`~ProcedureRunner.sample`), takes the measured states
(:meth:`~ProcedureRunner.measure`), the controller's events (:meth:`~ProcedureRunner.event`) and
the operator's requests (start, hold, resume, stop), and leaves for the node what it should
publish and record: events, each cycle's extremes (:class:`~ros_ehs.core.procedure.
detectors.Cycle`), full cycles at log-spaced counts, and the checkpoint. The clock is the
states' stamps (sim or real time), passed in; each rule is tested in
``test/test_procedure.py`` without DDS, and the node only decodes, calls and publishes.

**The timeline.** The reference is a sequence of segments (a level held, a ramp, a step's
waveform), each from a stamp on. A step whose end is known (a ramp reaching its level, a
dwell's time, a count of cycles, a sweep, a drive's passes) hands over to the next exactly
at its end. A decision taken on a measured state stamped ``s`` (an end condition, a
failure, hold, stop, an interlock) changes the timeline from ``s + latency`` on: samples up to
``latency`` (the reference's ``preview``) may already have gone out, and none of them
changes.

**Cycles** are the step's waveform's (a cyclic step's periods, a sweep's turns of phase, a
drive's passes), counted exactly: cycle ``k`` of a step is complete when a state stamped at
or after its end has been measured, and counted once. Each complete cycle's extremes of the
command, the position and the load are a :class:`Cycle` record; a cycle a hold, an
interlock or a restart cut is not counted (its load was not completed), and the step goes on
at the same count.

**Transitions** (a waveform step's start, and its resume after a hold, an interlock, a
restart of any node or of all of them, from the checkpoint) move the axis in two moves, as
test controllers do (docs/procedures.md, "Starts and resumes"): the mean first, from where
the axis is (the measured value on a resume, the last command otherwise) to the midpoint of
the cycle's command, along the ramp-on's quintic at no more than the step's ``mean_rate``;
then the amplitude, from zero, its envelope growing along the same quintic over the step's
``taper`` cycles. Both wait for the controller's ramp-on to end (``ramp_time``): a cycle
it attenuates is not carried. The command stays within the hull of where the axis was and
the cycle's peak and valley. Tapered cycles count (they are carried) and are flagged
(:data:`~ros_ehs.core.procedure.detectors.TAPERED`); the compensation does not learn from
them and the failure detectors do not judge them (their settling and reference cycles come
after the taper). A resumed step goes on at the start of its next whole cycle; the
compensation's learnt corrections and the detectors' reference cycles come back with it
(:meth:`checkpoint`, :meth:`restore`).

**States**: ``idle`` (before start: the level measured is held), ``running``, ``switching``
(a step in the other control mode waits for the controller's switch), ``held`` (~/hold: the
command frozen, hydraulics on), ``interrupted`` (an interlock acted, or a restart: resume
when ready), ``stopping`` (ramping to ``stop_level``), ``finished`` (its ``result``:
``completed``, ``failed`` (a failure detector or the controller's specimen break),
``run_out``, ``stopped`` or ``interrupted``). The end of a test, failed, completed or run
out, ramps to ``stop_level`` as ``~/stop`` does. An interlock that acts during that ramp (a
hold, a stop or a power-off: the controller, not the ramp, has the axis now) ends the test
there, holding the measured level: a test that had completed its steps is then
``interrupted``, never ``completed``; any other result keeps its name, the interlock added
to its reason.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Mapping

import numpy as np
from ros_ehs.core.control.apc import AmplitudePhaseControl
from ros_ehs.core.control.levels import CycleLevels, FITTED
from ros_ehs.core.control.modes import MODES as CONTROLLER_MODES
from ros_ehs.core.control.pvc import Block, PeakValleyControl
from ros_ehs.core.control.safety import ramp_weight
from ros_ehs.core.control.waveforms import Samples
from ros_ehs.core.errors import InputError
from ros_ehs.core.procedure.detectors import Cycle, FailureDetector, TAPERED
from ros_ehs.core.procedure.envelope import check_envelope, RigEnvelope
from ros_ehs.core.procedure.spec import Procedure, Step
from ros_ehs_msgs_py import Reference

__all__ = ['ACTING', 'BACKOFF', 'CHECKPOINT_PERIOD', 'ProcedureRunner', 'STATES', 'capture_counts']

STATES = ('idle', 'running', 'switching', 'held', 'interrupted', 'stopping', 'finished')
#: the cycles before a step's end (and a run-out) that a jump never credits: they are simulated
JUMP_MARGIN = 3
#: the room of a jump in a step with no end
JUMP_UNBOUNDED = 10 ** 15
#: a controller trip with one of these actions interrupts the test
ACTING = ('hold', 'stop', 'power_off')
#: the checkpoint is due at every state change, every counted cycle, and at least this often
#: [s of the stamps]
CHECKPOINT_PERIOD = 10.0
#: the rate of a stop ramp when neither the procedure nor a ramp step gives one [m/s, N/s]
STOP_RATE = {'displacement': 1.0e-3, 'force': 1.0e3}
#: A frequency backing off (``frequency_min``) falls to this fraction of itself each time.
BACKOFF = 0.8
_NS = 1_000_000_000


def capture_counts(n: int) -> bool:
    """Return True when cycle ``n`` (the test's count) is one the full cycles are kept at."""
    if n < 1:
        return False
    e = 10 ** int(math.floor(math.log10(n) + 1e-12))
    return n in (e, 2 * e, 5 * e)


@dataclass
class _Segment:
    """A piece of the timeline from ``t0`` [ns] on (see the module docstring)."""

    kind: str                    # 'level', 'ramp', 'blend', 'wave'
    t0: int
    mode: str
    v0: float = 0.0              # level; a ramp's start
    v1: float = 0.0              # a ramp's end
    rate: float = 0.0            # a ramp's rate
    step: int = -1               # the step it plays (-1: none)
    c0: int = 0                  # a wave's first cycle (its count in the step)
    lead: float = 0.0            # a wave's taper [s]; a blend's duration
    lead_from: float = 0.0       # the midpoint the taper grows from
    end: int | None = None       # the stamp it ends at, when known [ns]
    n_end: int | None = None     # a wave's cycle at that end, when known
    nulls: int = 0               # a wave's cycles not counted (null pacing): n_end's excess
    wave: Any = None             # a wave's waveform (_Wave)
    cyc: dict | None = None      # the cycle being measured

    def ramp_end(self) -> int:
        return self.t0 + int(round(abs(self.v1 - self.v0) / self.rate * 1e9))


class _Wave:
    """A step's waveform in its own time ``tau`` [s] (cycle ``k`` from ``k`` periods on)."""

    def __init__(self, step: Step, latency: float, harmonics: int, c0: int, lead: float,
                 learnt: Mapping | None, frequency: float | None = None) -> None:
        self.step = step
        self.corr = None
        frozen = False
        if step.type == 'cyclic':
            blocks = step['blocks']
            f = frequency or step['frequency']      # (a backed-off frequency)
            self.period = 1.0 / f
            comp = step['compensation']
            sine = step['waveform'] == 'sine' and len(blocks) == 1
            frozen = comp == 'none'
            if frozen:
                latency = 0.0            # nothing learnt, nothing to bring in ahead of time
            peak, valley = blocks[0][0], blocks[0][1]
            # auto: peak/valley control, the loads a fatigue test is specified by (APC holds
            # the fundamental: the peaks of a 1-10 kN sine fell 0.3 % short with it)
            if comp == 'apc' or (comp == 'none' and sine):
                self.corr = AmplitudePhaseControl(0.5 * (peak - valley), f,
                                                  0.5 * (peak + valley), harmonics=harmonics,
                                                  latency=latency, learn_from=0.0,
                                                  gain=step['compensation_gain'])
            else:
                self.corr = PeakValleyControl([Block(*b) for b in blocks], f,
                                              step['waveform'], latency=latency,
                                              learn_from=0.0, gain=step['compensation_gain'])
            self.blocks = blocks
        elif step.type == 'sweep':
            self.period = 1.0 / step['f0']
            self.corr = AmplitudePhaseControl(step['amplitude'], step['f0'], step['mean'],
                                              sweep_to=step['f1'],
                                              sweep_time=step['duration'],
                                              latency=latency, learn_from=0.0,
                                              gain=step['compensation_gain'])
            frozen = step['compensation'] == 'none'
        else:      # drive: one pass a cycle
            self.drive = _drive_file(step['file'])
            self.period = float(self.drive.t[-1])
        self.t_off = c0 * self.period if step.type != 'sweep' else 0.0
        if step.type == 'sweep' and c0:
            self.t_off = self.corr.cycle_start(c0)
        if self.corr is not None:
            self.corr.limit = step['compensation_limit']
            # the tapered cycles are not learnt from
            self.corr.learn_from = self.t_off + lead
            if learnt:
                _restore(self.corr, learnt)
            if frozen:                   # the specified waveform, nothing learnt
                self.corr.freeze()

    def midpoint(self, k: int) -> float:
        """Return the midpoint of cycle ``k``'s command extremes (sampled, 256 a cycle)."""
        a = self.cycle_start(k)
        span = self.cycle_start(k + 1) - a
        vs = [self.value(a + span * j / 256.0)[0] for j in range(256)]
        return 0.5 * (max(vs) + min(vs))

    def value(self, tau: float) -> tuple[float, float]:
        """Return the command and its rate at the waveform's time ``tau`` [s]."""
        if self.corr is not None:
            return self.corr.reference(tau)
        x = tau % self.period
        z, v = self.drive(np.array([x]))
        return float(z[0]), float(v[0])

    def cycle_of(self, tau: float) -> int:
        """Return the cycle the waveform's time ``tau`` falls in."""
        if self.step.type == 'sweep':
            return self.corr.cycle_of(tau)
        return int(math.floor(tau / self.period + 1e-9))

    def cycle_start(self, k: int) -> float:
        """Return the waveform's time at which cycle ``k`` starts."""
        if self.step.type == 'sweep':
            return self.corr.cycle_start(k)
        return k * self.period

    def specified(self, k: int) -> tuple[float, float] | None:
        """Return the peak and valley specified for the controlled signal in cycle ``k``."""
        if self.step.type == 'cyclic':
            b = self.blocks[_block_of(self.blocks, k)]
            return b[0], b[1]
        if self.step.type == 'sweep':
            return (self.step['mean'] + self.step['amplitude'],
                    self.step['mean'] - self.step['amplitude'])
        return None

    def measure(self, tau: float, value: float) -> None:
        """Give the compensation the measured controlled signal at ``tau``."""
        if self.corr is not None:
            self.corr.measure(tau, value)

    def learnt(self) -> dict | None:
        """Return the compensation's learnt corrections (JSON values), or None."""
        return None if self.corr is None else _learnt(self.corr)


def _block_of(blocks, k: int) -> int:
    per = sum(b[2] for b in blocks)
    r = k % per
    for j, b in enumerate(blocks):
        if r < b[2]:
            return j
        r -= b[2]
    return len(blocks) - 1


def _drive_file(path: str) -> Samples:
    from ros_ehs.core.control.waveforms import CsvTrajectory
    return CsvTrajectory(path)


def _learnt(corr) -> dict:
    if isinstance(corr, AmplitudePhaseControl):
        c = corr._segments[-1][4]
        g = corr._gain_k
        return {'kind': 'apc', 'c': [[float(x.real), float(x.imag)] for x in c],
                'mean': float(corr._segments[-1][5]),
                'gain': [[float(x.real), float(x.imag)] for x in g],
                'converged_at': corr.converged_at}
    return {'kind': 'pvc', 'amp': [float(a) for a in corr.amp],
            'mean': [float(m) for m in corr.mean], 'converged_at': corr.converged_at}


def _restore(corr, d: Mapping) -> None:
    """Put learnt corrections back into a new compensation (a resumed step)."""
    if isinstance(corr, AmplitudePhaseControl) and d.get('kind') == 'apc':
        c = np.array([complex(*x) for x in d['c']])
        if c.size == corr.harmonics:
            m = float(d['mean'])
            corr._segments = [(-math.inf, corr.period, c, m, c, m)]
            corr._gain_k = np.array([complex(*x) for x in d['gain']])
            corr.converged_at = d.get('converged_at')
    elif isinstance(corr, PeakValleyControl) and d.get('kind') == 'pvc':
        if len(d['amp']) == len(corr.blocks):
            corr.amp = [float(a) for a in d['amp']]
            corr.mean = [float(m) for m in d['mean']]
            corr._planned = list(zip(corr.amp, corr.mean))
            corr._plans = {0: corr._make_plan(0, 0.0)}
            corr.converged_at = d.get('converged_at')


class ProcedureRunner:
    """
    The procedure node's rules (see the module docstring).

    ``procedure``: checked; ``latency``: the reference's preview [s] (decisions act that
    much after the state they were taken on); ``harmonics``: APC's; ``rate_hz``: the loop's;
    ``observe``: the failure detectors report when they trip and the test goes on (a virtual
    test that tells when each would trip); ``ramp_time``: the controller's ramp-on [s] (from
    its first state, and from each ``reset`` and ``enabled`` event): a waveform step waits
    for it to end, and the compensation does not learn from a cycle it attenuated;
    ``lockstep``: the samples go out in windows (:meth:`window`) to a loop that runs as fast
    as they come: the hold before the start is a level at the first state measured, so a
    window once sent never changes (a hold that follows the measurement, as in real time,
    would send each stamp again with another value, and which one the loop used would depend
    on when each arrived).
    """

    def __init__(self, procedure: Procedure, *, latency: float = 0.02, harmonics: int = 5,
                 rate_hz: float = 1000.0, observe: bool = False,
                 ramp_time: float = 0.0, lockstep: bool = False) -> None:
        if not isinstance(procedure, Procedure):
            raise InputError(f'`procedure` must be a Procedure, got {type(procedure).__name__}')
        if not (math.isfinite(latency) and latency >= 0):
            raise InputError(f'`latency` = {latency!r} s must be >= 0')
        if not (math.isfinite(ramp_time) and ramp_time >= 0):
            raise InputError(f'`ramp_time` = {ramp_time!r} s must be >= 0')
        for step in procedure.steps:
            # each step's compensation made once now: a step it refuses is named at load,
            # never when the test reaches it
            if step.type in ('cyclic', 'sweep'):
                try:
                    _Wave(step, latency, harmonics, 0, 0.0, None)
                except InputError as err:
                    raise InputError(
                        f'{procedure.name!r} {step.label}: its compensation cannot run with a '
                        f'preview of {latency:g} s ({err}): a correction must be in before the '
                        "next cycle: shorten the procedure node's `preview`") from None
        self.procedure = procedure
        self.steps = procedure.steps
        self.ramp_ns = int(round(ramp_time * 1e9))
        self._ramp_until = -1               # the controller ramps on until this stamp [ns]
        self._clipped = ''                  # why the controller clips its command ('': not)
        self.latency_ns = int(round(latency * 1e9))
        self.dt_ns = int(round(1e9 / rate_hz))
        self.harmonics = int(harmonics)
        self.observe = bool(observe)    # failure detectors report, the test goes on (virtual)
        self.lockstep = bool(lockstep)
        self.tripped: dict[str, int] = {}     #: each failure detector's trip cycle
        self.state = 'idle'
        self.result = ''
        self.reason = ''
        self.step_index = 0
        self.counts = [0] * len(self.steps)
        self.total = 0
        self.failed_at: int | None = None
        self.mode = self.steps[0].control_mode
        #: whether :attr:`mode` is the controller's (False: a node still asking the controller;
        #: a start or a resume waits for :meth:`controller_mode`)
        self.mode_known = True
        #: what the rig cannot follow of this procedure, one sentence a step and limit, by the
        #: controller's values in force (:meth:`rig_params`; empty: nothing, or not known)
        self.beyond_rig: list[str] = []
        self.request_mode: str | None = None   #: the node should switch the controller
        self.events: list[tuple[str, str, float, str]] = []   #: (kind, what, value, message)
        self.cycles: list[Cycle] = []          #: complete cycles, for the node to record
        self.captures: list[dict] = []         #: full cycles at log-spaced counts
        self.notes: list[tuple[str, str]] = []
        self.checkpoint_due = False
        self._segs: list[_Segment] = []
        self._waves: list[_Segment] = []     # the waveform segments whose cycles are counted
        self._memo: tuple = (None, (0.0, 0.0))
        self._learnt: dict[int, dict] = {}
        self._freq: dict[int, float] = {}     # each step's frequency backed off to [Hz]
        self._null_cycles: dict[int, int] = {}  # each step's cycles not counted (null pacing)
        self._null_s: dict[int, float] = {}     # ... and their time [s]
        self._null_run = 0                      # cycles in a row not counted
        self._level_run = 0                     # cycles in a row off their levels
        self.jumped = 0                          #: cycles credited by jumps (a virtual test)
        self._detectors: dict[int, list[FailureDetector]] = {}
        self._det_state: dict[int, list[dict]] = {}
        self._last_ns = -1
        self._last_meas = (math.nan, math.nan)
        self._park = -1                        # switching: the window's last stamp [ns]
        self._floor = -1                       # the oldest stamp still asked for [ns]
        self._last_checkpoint = -1
        self._step_t0 = 0                      # the step's start stamp (its time)
        self._time_in_step = 0.0

    # -- the timeline ----------------------------------------------------------------------
    def _push(self, seg: _Segment) -> None:
        # from seg.t0 on the timeline is seg's; a segment is dropped once the next one began
        # at or before the oldest stamp still asked for (a window asks again from its start:
        # the one in force there must stay, or those stamps would change when sent again)
        segs = [s for s in self._segs if s.t0 < seg.t0] + [seg]
        k = 0
        while k + 1 < len(segs) and segs[k + 1].t0 <= self._floor:
            k += 1
        self._segs = segs[k:]

    def _seg_at(self, stamp: int) -> _Segment | None:
        for s in reversed(self._segs):       # in t0's order: the newest begun is in force
            if s.t0 <= stamp:
                return s
        return None

    def _value(self, seg: _Segment, stamp: int) -> tuple[float, float]:
        key = (id(seg), stamp)
        if self._memo[0] == key:          # sample() and the measurement ask alike
            return self._memo[1]
        out = self._compute(seg, stamp)
        self._memo = (key, out)
        return out

    def _compute(self, seg: _Segment, stamp: int) -> tuple[float, float]:
        t = (stamp - seg.t0) * 1e-9
        if seg.kind == 'level':
            return seg.v0, 0.0
        if seg.kind == 'blend':
            if t >= seg.lead:
                return seg.v1, 0.0
            w, dw = ramp_weight(t / seg.lead)
            d = seg.v1 - seg.v0
            return seg.v0 + w * d, dw / seg.lead * d
        if seg.kind == 'ramp':
            d = seg.v1 - seg.v0
            span = abs(d) / seg.rate
            if t >= span:
                return seg.v1, 0.0
            return seg.v0 + math.copysign(seg.rate * t, d), math.copysign(seg.rate, d)
        wave = seg.wave
        tau = wave.t_off + t
        v, r = wave.value(tau)
        if seg.lead > 0 and t < seg.lead:          # the taper: the envelope grows from 0
            w, dw = ramp_weight(t / seg.lead)
            d = v - seg.lead_from
            return seg.lead_from + w * d, w * r + dw / seg.lead * d
        return v, r

    def sample(self, stamp_ns: int) -> Reference:
        """Return the reference at ``stamp_ns`` (advancing to a step whose start is due)."""
        self._floor = max(self._floor, stamp_ns)
        return self._sample(stamp_ns)

    def _sample(self, stamp_ns: int) -> Reference:
        self._advance(stamp_ns)
        seg = self._seg_at(stamp_ns)
        if seg is None:       # nothing to run yet: hold what was measured
            z, f = self._last_meas
            v = f if self.quantity == 'force' else z
            frozen = self.state in ('held', 'interrupted')
            if not self._segs and self._last_ns >= 0 and math.isfinite(v) and (
                    frozen and self.quantity == 'force' or
                    self.lockstep and self.state == 'idle'):
                # a restored or restarted force test holds the load it was first measured at:
                # a force reference that follows the load cell holds nothing, and a load
                # that crept 3 kN over the peak in 0.5 s was followed. (A position that
                # follows its measurement stays where the valve's integrator holds it; held
                # at a fixed value the friction's stick-slip hunts about it, 0.15 mm.)
                self._push(_Segment('level', stamp_ns, self.quantity, v0=v))
            return self._ref(stamp_ns, v, 0.0, self.quantity)
        v, r = self._value(seg, stamp_ns)
        return self._ref(stamp_ns, v, r, seg.mode)

    @staticmethod
    def _ref(stamp: int, v: float, r: float, mode: str) -> Reference:
        if mode == 'force':
            return Reference(stamp, math.nan, math.nan, v)
        return Reference(stamp, v, r)

    def _advance(self, stamp: int) -> None:
        """Hand over from segments whose known end has come, exactly at their end."""
        segs = self._segs          # the common case first (twice a period): no end has come
        if not segs:
            return
        end = segs[-1].end
        if (end is None and segs[-1].kind != 'ramp') or (end is not None and stamp < end):
            return
        for _ in range(len(self.steps) + 2):
            seg = self._segs[-1] if self._segs else None
            if seg is None or self.state not in ('running', 'stopping'):
                return
            end = seg.end
            if seg.kind == 'ramp' and end is None:
                end = seg.ramp_end()
            if end is None or stamp < end:
                return
            if self.state == 'stopping':
                # finished once at the stop level (or held where the controller's own switch
                # left it) and every cycle before the stop is counted
                if not self._waves:
                    if seg.kind == 'ramp':
                        self._push(_Segment('level', end, seg.mode, v0=seg.v1))
                    self._finish_stop(end)
                return
            if seg.step != self.step_index:
                return
            self._end_step(end, 'completed')

    # -- operator ------------------------------------------------------------------------------
    @property
    def quantity(self) -> str:
        """Return what the controller's mode tracks: ``force``, else ``displacement``."""
        return 'force' if self.mode == 'force' else 'displacement'

    def controller_mode(self, mode: str) -> None:
        """
        Take the controller's control mode as read from it, before a start or a resume.

        The first step (or the resumed one) in another mode then switches the controller
        first, as a step does between steps: a procedure never drives a force step's newtons
        into a controller that holds a position.
        """
        self.mode = mode
        self.mode_known = True

    def rig_params(self, params: Mapping[str, float]) -> None:
        """
        Take the rig's parameters in force (the controller's: nominal or identified).

        A start or a resume is refused while a step asks for more than the rig of these
        values can do (:func:`~ros_ehs.core.procedure.envelope.check_envelope`), naming the
        step and the limit: never an end stop to catch up.
        """
        self.beyond_rig = check_envelope(self.procedure, RigEnvelope.from_params(params))

    def _refused_by_rig(self) -> str:
        return ('the rig cannot follow this procedure:\n  ' + '\n  '.join(self.beyond_rig)
                if self.beyond_rig else '')

    def start(self, stamp_ns: int) -> tuple[bool, str]:
        """Start the test (idle) at ``stamp_ns`` + latency: (ok, why)."""
        if self.state != 'idle':
            return False, f'the test is {self.state}; start is for an idle test'
        if not self.mode_known:
            return False, "the controller's control mode is not known yet (asking it)"
        if self.beyond_rig:
            return False, self._refused_by_rig()
        z, f = self._last_meas
        if not math.isfinite(f if self.steps[0].control_mode == 'force' else z):
            return False, 'no measured state yet (or no load cell for a force step)'
        self._set('running', stamp_ns, 'started')
        self._begin_step(0, stamp_ns + self.latency_ns)
        return True, f'started: {self.steps[0].label}'

    def hold(self, stamp_ns: int) -> tuple[bool, str]:
        """Freeze the command where it is (the step's clock stops): (ok, why)."""
        if self.state not in ('running', 'switching'):
            return False, f'the test is {self.state}; nothing runs to hold'
        self._freeze(stamp_ns, 'held', 'held by the operator')
        return True, 'held: the command frozen, hydraulics on'

    def resume(self, stamp_ns: int) -> tuple[bool, str]:
        """Go on from a hold, an interlock or a restart at the same count: (ok, why)."""
        if self.state not in ('held', 'interrupted'):
            return False, f'the test is {self.state}; resume is for a held or interrupted test'
        if not self.mode_known:
            return False, "the controller's control mode is not known yet (asking it)"
        if self.beyond_rig:
            return False, self._refused_by_rig()
        z, f = self._last_meas
        step = self.steps[self.step_index]
        value = f if step.control_mode == 'force' else z
        if not math.isfinite(value):
            return False, 'no measured state to resume from'
        self._set('running', stamp_ns,
                  f'resumed {step.label} at cycle {self.counts[self.step_index]} of the step '
                  f'({self.total} in all)')
        self._begin_step(self.step_index, stamp_ns + self.latency_ns, resume=True)
        return True, self.events[-1][3]

    def stop(self, stamp_ns: int, why: str = 'stopped by the operator') -> tuple[bool, str]:
        """Ramp to ``stop_level``, then finish (result ``stopped``): (ok, why)."""
        if self.state in ('finished', 'stopping'):
            return False, f'the test is {self.state}'
        self.result = self.result or 'stopped'
        self.reason = self.reason or why
        self._to_stop(stamp_ns + self.latency_ns)
        return True, f'stopping: to {self.procedure.stop_level:g} then held'

    # -- controller -------------------------------------------------------------------------
    def event(self, kind: str, detector: str, action: str, stamp_ns: int) -> None:
        """
        Take a controller event: an acting trip interrupts; a specimen break fails the test.

        A ``mode`` event (the controller ended force control itself: a break, a lost load
        cell; or another node switched it: the campaign's specimen protect for a coupon's
        installation) holds the measured position in that mode from ``latency`` on, and a
        start or a resume then switches it to its step's mode. Between a
        ``clipped`` and an ``unclipped`` event (the controller did not apply its command as
        asked: the valve saturated, a limit) the compensation learns only what asks less of
        the rig (:meth:`~ros_ehs.core.control.cycles.CycleCorrection.clip`).
        """
        if kind == 'mode' and detector in CONTROLLER_MODES and detector != self.mode:
            self.mode = detector
            if self._segs and self.state != 'idle':
                t = stamp_ns + self.latency_ns
                q = self.quantity
                # a stop under way ends there: the axis holds where it is
                self._push(_Segment('level', t, q, v0=self._measured(q),
                                    end=t if self.state == 'stopping' else None))
            self.notes.append(('info', f'the controller switched to {detector} control'))
            return
        if kind in ('clipped', 'unclipped'):  # not learnt from until it is applied again
            self._clipped = detector if kind == 'clipped' else ''
            return
        if kind in ('reset', 'enabled'):      # the controller ramps on again from here
            self._ramp_until = max(self._ramp_until, stamp_ns + self.ramp_ns)
            return
        if kind != 'trip' or action not in ACTING:
            return
        if self.state in ('running', 'switching', 'stopping'):
            if detector == 'specimen_break':
                self.failed_at = self.total
                self.result, self.reason = 'failed', (f'the controller detected the specimen '
                                                      f'break at cycle {self.total}')
                self._note_event('failure', 'specimen_break', float(self.total), self.reason)
                self._to_stop(stamp_ns + self.latency_ns)
                return
            if self.state != 'stopping':
                self._freeze(stamp_ns, 'interrupted', f'interlock: {detector} ({action})')
                return
            # the stop cannot go on: the controller holds the axis or turned the hydraulics
            # off, and that is where the test ends. A test that had completed its steps did
            # not end as planned: interrupted, never completed
            why = f'interlock: {detector} ({action}) during the stop'
            if self.result in ('', 'completed'):
                self.result, self.reason = 'interrupted', why
            else:
                self.reason = f'{self.reason}; {why}'
            self._note_event('interlock', detector, float(self.total), why)
            t = stamp_ns + self.latency_ns
            self._push(_Segment('level', t, self.quantity, v0=self._measured(self.quantity),
                                end=t))
            self._finish_stop(t)

    def estimate(self, stamp_ns: int, k_L: float, stderr: float, adequate: bool) -> None:
        """
        Take a live fit's specimen stiffness ``k_L`` [N/m], its standard error and verdict.

        The running cyclic step's ``fitted_stiffness_drop`` detectors judge it (at the count
        now); a trip fails the test as a cycle's detector does, from the newest state on (an
        estimate's stamp is its window's end, seconds old: a stop ramp from there would have
        jumped the command to where that ramp is now). Outside a running step it is not
        judged.
        """
        if self.state != 'running':
            return
        now = max(stamp_ns, self._last_ns)
        for d in self._detectors.get(self.step_index, []):
            why = d.estimate(k_L, stderr, adequate, self.total)
            if why and self._failed(d, why, now):
                return

    def mode_switched(self, ok: bool, why: str, stamp_ns: int) -> None:
        """Take the controller's answer to :attr:`request_mode`."""
        if self.state != 'switching':
            return
        mode, self.request_mode = self._switch_to, None
        if not ok:
            self._freeze(stamp_ns, 'held', f'the controller refused {mode}: {why}')
            return
        self.mode = mode
        self._set('running', stamp_ns, f'control mode {mode}')
        # from the measured value of the new mode's signal (the controller holds it: its
        # switch is bumpless), not from the last command, which was in the other unit
        self._begin_step(self.step_index, stamp_ns + self.latency_ns, measured=True)

    # -- states ------------------------------------------------------------------------------
    @property
    def last_stamp(self) -> int:
        """Return the newest measured state's stamp [ns] (-1: none yet)."""
        return self._last_ns

    def window(self, t_ns: int, preview_ns: int) -> list[Reference]:
        """
        Return the samples at ``t_ns``, one period apart, up to ``t_ns + preview_ns``.

        While the step waits for the controller's switch (``switching``) the window ends at
        :attr:`park_ns`: a lock-step loop stops at the first state past it, and the switch
        lands there, at a state that does not depend on when the controller's answer comes
        (:attr:`parked`).
        """
        n = max(0, -(-preview_ns // self.dt_ns))
        self._floor = max(self._floor, t_ns)
        out = []
        for j in range(n + 1):
            t = t_ns + j * self.dt_ns
            r = self._sample(t)
            if self.state == 'switching' and t > self._park:
                break
            out.append(r)
        return out

    @property
    def park_ns(self) -> int | None:
        """Return the stamp the window ends at while ``switching`` [ns] (None: not)."""
        return self._park if self.state == 'switching' else None

    @property
    def parked(self) -> bool:
        """
        Return whether a state past :attr:`park_ns` was measured (the loop waits there).

        A lock-step node sends the switch then: the controller switches before it answers
        that state, whichever moment its answer takes.
        """
        return self.state == 'switching' and self._last_ns > self._park

    def state_measured(self) -> tuple[float, float]:
        """Return the newest measured (position [m], load [N])."""
        return self._last_meas

    def measure(self, stamp_ns: int, z: float, load: float) -> None:
        """Take a measured state: count cycles, judge them, check the end conditions."""
        if stamp_ns <= self._last_ns:
            return
        if self._last_ns < 0:               # a new run of states: the controller ramps on
            self._ramp_until = stamp_ns + self.ramp_ns
        self._last_ns = stamp_ns
        self._last_meas = (z, load)
        if self.state in ('running', 'stopping'):
            self._measure(stamp_ns, z, load)
        self._advance(stamp_ns)
        if self._last_checkpoint < 0 or \
                stamp_ns - self._last_checkpoint >= CHECKPOINT_PERIOD * _NS:
            self.checkpoint_due = True

    def new_run(self) -> None:
        """Take a new run of stamps (a restarted plant): interrupt, keep the counts."""
        if self.state in ('running', 'switching', 'stopping'):
            self._freeze(None, 'interrupted', 'the loop restarted (a new run of stamps)')
        self._last_ns = -1
        self._floor = -1
        self._segs = []

    # -- the steps -----------------------------------------------------------------------------
    def _begin_step(self, k: int, t0: int, resume: bool = False,
                    measured: bool = False) -> None:
        step = self.steps[k]
        self.step_index = k
        if step.control_mode != self.mode:
            self._switch_to = step.control_mode
            self.request_mode = step.control_mode
            self.state = 'switching'
            self._park = t0
            q = self.quantity
            v = self._value(self._segs[-1], t0)[0] if self._segs else self._measured(q)
            self._push(_Segment('level', t0, q, v0=v))
            self.notes.append(('info', f'{step.label}: switching the controller to '
                               f'{step.control_mode}'))
            return
        # from the last command, within its step's levels (a compensated command runs beyond
        # them), or from the measured value on a resume
        start = self._measured(step.control_mode) if (resume or measured or not self._segs) \
            else self._in_envelope(self._segs[-1], t0, self._value(self._segs[-1], t0)[0])
        if not math.isfinite(start):
            start = self._value(self._segs[-1], t0)[0] if self._segs else 0.0
        self._step_t0 = t0
        mode = step.control_mode
        if not resume:
            self._note_event('step', step.name, float(k), f'{step.label}: {step.type}')
        if step.type == 'ramp':
            rate = step['rate']
            self._push(_Segment('ramp', t0, mode, v0=start, v1=step['to'], rate=rate, step=k))
        elif step.type == 'dwell':
            self._push(_Segment('level', t0, mode, v0=start, step=k,
                                end=t0 + int(round(step['time'] * 1e9))))
        else:
            c0 = self.counts[k]
            if t0 < self._ramp_until:        # the controller still ramps on: wait for it
                self._push(_Segment('level', t0, mode, v0=start, step=-1))
                t0 = self._ramp_until + self.dt_ns
            probe = _Wave(step, self.latency_ns * 1e-9, self.harmonics, c0, 0.0,
                          self._learnt.get(k), self._freq.get(k))
            taper = step['taper'] * probe.period
            wave = _Wave(step, self.latency_ns * 1e-9, self.harmonics, c0, taper,
                         self._learnt.get(k), self._freq.get(k))
            mid = wave.midpoint(c0)
            # the mean first: the quintic's peak rate is 15/8 of its mean rate
            rate = step['mean_rate'] or self.procedure.stop_rate or STOP_RATE[mode]
            t_mean = 1.875 * abs(mid - start) / rate
            if t_mean >= 0.5 * self.dt_ns * 1e-9:
                self._push(_Segment('blend', t0, mode, v0=start, v1=mid, lead=t_mean, step=-1))
                t0 += int(round(t_mean * 1e9))
            end, n_end = self._wave_end(wave, step, c0, t0)
            self._null_run = self._level_run = 0
            seg = _Segment('wave', t0, mode, step=k, c0=c0, lead=taper, lead_from=mid,
                           end=end, n_end=n_end, wave=wave)
            self._push(seg)
            self._waves.append(seg)
            dets = [FailureDetector(e.kind, e.values, mode) for e in step.end if e.failure]
            for d, st in zip(dets, self._det_state.get(k, [])):
                d.restore(st)
            self._detectors[k] = dets
        self.checkpoint_due = True

    def _wave_end(self, w: '_Wave', step: Step, c0: int, t0: int
                  ) -> tuple[int | None, int | None]:
        """Return the stamp the step's waveform ends at and its count there, when known."""
        n = None
        if step.type == 'cyclic' and step['count']:
            n = step['count']
        elif step.type == 'drive':
            n = step['repeats']
        run_out = self.procedure.run_out
        if run_out:
            left = run_out - self.total
            n = left + c0 if n is None else min(n, left + c0)
        if step.type == 'sweep':
            end = t0 + int(round((step['duration'] - w.t_off) * 1e9))
            turns = w.corr.cycle_of(step['duration'] - 1e-9)
            return end, turns if n is None else min(n, turns)
        if n is None:
            return None, None
        if step.type == 'cyclic' and step['count_tolerance'] > 0:
            # null pacing: whether the last cycle counts is known only once it is measured;
            # the step ends then (_close_cycle), never one short
            return None, n
        return t0 + int(round((w.cycle_start(n) - w.t_off) * 1e9)), n

    def _measured(self, mode: str) -> float:
        z, f = self._last_meas
        return f if mode == 'force' else z

    def _measure(self, stamp: int, z: float, load: float) -> None:
        was = self.state
        for seg in list(self._waves):
            if stamp >= seg.t0:
                self._measure_wave(seg, stamp, z, load)
            if self.state != was:
                return
        if was == 'running':
            self._check_time_and_level(stamp, z, load)

    def _measure_wave(self, seg: _Segment, stamp: int, z: float, load: float) -> None:
        """Measure a counted waveform segment: close its cycles, track the one under way."""
        w = seg.wave
        step = self.steps[seg.step]
        tau = w.t_off + (stamp - seg.t0) * 1e-9
        ended = seg.end is not None and stamp >= seg.end
        if not ended:
            if stamp <= self._ramp_until and w.corr is not None:
                w.corr.spoil()                   # the controller's ramp-on attenuates it
            elif self._clipped and w.corr is not None:
                w.corr.clip()                    # the controller clips the command
            w.measure(tau, load if step.control_mode == 'force' else z)
        k = w.cycle_of(tau)
        cyc = seg.cyc
        if cyc is not None and k != cyc['k']:
            seg.cyc = None
            was = self.state
            self._close_cycle(seg, cyc, stamp, whole=k == cyc['k'] + 1)
            cyc = None
            if self.state != was:
                return
        if ended:
            self._waves.remove(seg)
            return
        cmd = self._value(seg, stamp)[0]
        if cyc is None:
            cap = self.total + 1
            fit = step.type == 'cyclic' and step['waveform'] in FITTED
            cyc = seg.cyc = {
                'k': k, 'taper': seg.lead > 0 and tau < w.t_off + seg.lead - 1e-9,
                'cmd': [cmd, cmd], 'z': [z, z], 'f': [load, load],
                # a sinusoid's levels: the extremes of a fit of its samples (noise does not
                # move them); the raw extremes otherwise
                'levels': (CycleLevels(True, w.cycle_start(k), w.period),
                           CycleLevels(True, w.cycle_start(k), w.period)) if fit else None,
                # begun within this segment (not cut by its start): a whole cycle, whether or
                # not a state came at its very start (a real-time loop loses one now and then)
                'begun_here': w.cycle_start(k) >= w.t_off - 0.5 * self.dt_ns * 1e-9,
                'capture': ({'count': cap, 't': [], 'cmd': [], 'z': [], 'f': []}
                            if step.capture == 'log' and capture_counts(cap) else None)}
        lv = cyc['levels']
        for ext, v in (((cyc['cmd'], cmd), (cyc['z'], z), (cyc['f'], load)) if lv is None
                       else ((cyc['cmd'], cmd),)):   # the levels keep the signals' own
            # [lo, hi] in place; a non-finite value makes both NaN, and NaN stays
            if v - v != 0.0:                    # NaN or infinite
                ext[0] = ext[1] = math.nan
            elif v < ext[0]:
                ext[0] = v
            elif v > ext[1]:
                ext[1] = v
        if lv is not None:
            lv[0].add(tau, z)
            lv[1].add(tau, load)
        cap = cyc['capture']
        if cap is not None:
            cap['t'].append(stamp)
            cap['cmd'].append(cmd)
            cap['z'].append(z)
            cap['f'].append(load)

    def _close_cycle(self, seg: _Segment, cyc: dict, stamp: int, whole: bool) -> None:
        """Count, record and judge a cycle a state has ended."""
        k = seg.step
        if not (whole and cyc['begun_here']):
            return                     # not a whole cycle (cut, or begun mid-way): not counted
        if cyc['levels'] is not None:
            # the controlled signal's levels as peak/valley control fitted them, if it did
            corr = seg.wave.corr
            last = corr.last_levels if corr is not None else None
            force = self.steps[k].control_mode == 'force'
            own = last[1:] if last is not None and last[0] == cyc['k'] and \
                math.isfinite(last[1]) and math.isfinite(last[2]) else None
            lz, lf = cyc['levels']
            z_hi, z_lo = own if own and not force else lz.levels()
            f_hi, f_lo = own if own and force else lf.levels()
        else:
            z_hi, z_lo, f_hi, f_lo = cyc['z'][1], cyc['z'][0], cyc['f'][1], cyc['f'][0]
        step_of = self.steps[k]
        own_levels = (f_hi, f_lo) if step_of.control_mode == 'force' else (z_hi, z_lo)
        cyclic = step_of.type == 'cyclic'
        if cyclic and step_of['level_error'] > 0 and not cyc['taper'] and \
                self._levels_off(seg, cyc, stamp, own_levels):
            return
        tol = step_of['count_tolerance'] if cyclic else 0.0
        if tol > 0 and self._null(seg, cyc, stamp, tol, own_levels):
            return
        self.counts[k] += 1
        self.total += 1
        self.checkpoint_due = True            # the count on disk is never a cycle behind
        c = Cycle(self.total, k, stamp, cyc['cmd'][1], cyc['cmd'][0], z_hi, z_lo, f_hi, f_lo,
                  TAPERED if cyc['taper'] else 0)
        self.cycles.append(c)
        cap = cyc['capture']
        if cap is not None and cap['count'] == self.total:
            self.captures.append(cap)
        corr = seg.wave.corr
        if corr is not None and corr.limited_cycles >= step_of['limit_cycles'] and \
                self.state == 'running':
            why = (f'levels not reached: the compensation met its limit '
                   f"(compensation_limit {step_of['compensation_limit']:g} of the amplitude) "
                   f'for {corr.limited_cycles} cycles in a row, at cycle {self.total}: the rig '
                   'cannot follow this step')
            self._note_event('levels', step_of.name, float(self.total), why)
            self._freeze(stamp, 'interrupted', why)
            return
        if not cyc['taper']:
            spec = seg.wave.specified(cyc['k'])
            for d in self._detectors.get(k, []):
                why = d.cycle(c, spec)
                if why and self._failed(d, why, stamp):
                    return
        run_out = self.procedure.run_out
        if run_out and self.total >= run_out and self.state == 'running':
            self.result, self.reason = 'run_out', (f'run-out: {self.total} cycles without a '
                                                   'failure')
            self._note_event('run_out', '', float(self.total), self.reason)
            self._to_stop(stamp + self.latency_ns)
            return
        if tol > 0 and seg.end is None and seg.n_end is not None and \
                self.counts[k] >= seg.n_end and self.state == 'running':
            self._end_step(stamp + self.latency_ns, 'completed')   # its last cycle counted

    def _off_by(self, seg: _Segment, cyc: dict, levels: tuple[float, float]
                ) -> tuple[float, tuple[float, float] | None]:
        """Return how far a cycle's levels are off the specified ones (of its range), and those."""
        spec = seg.wave.specified(cyc['k'])
        if spec is None:
            return 0.0, None
        hi, lo = levels
        return max(abs(hi - spec[0]), abs(lo - spec[1])) / (spec[0] - spec[1]), spec

    def _not_reached(self, step: Step, stamp: int, why: str) -> None:
        """Interrupt the test: its levels are not reached (a ``levels`` event names why)."""
        self._note_event('levels', step.name, float(self.total), why)
        self._freeze(stamp, 'interrupted', why)

    def _levels_off(self, seg: _Segment, cyc: dict, stamp: int,
                    levels: tuple[float, float]) -> bool:
        """
        Judge a cycle past its taper by the levels detector; True when it interrupted the test.

        A cycle whose peak or valley is further than ``level_error`` of the specified range
        from its level is off; ``level_cycles`` off in a row interrupt the test (``levels``),
        the cycle not counted.
        """
        step = self.steps[seg.step]
        err, spec = self._off_by(seg, cyc, levels)
        if spec is None or not err > step['level_error']:   # within, or NaN (not judged)
            self._level_run = 0
            return False
        self._level_run += 1
        if self._level_run < step['level_cycles'] or self.state != 'running':
            return False
        hi, lo = levels
        clip = (f' (the controller clips its command: {self._clipped}; no larger command '
                'was learnt from it)' if self._clipped else '')
        self._not_reached(step, stamp, f'levels not reached: {self._level_run} cycles in a row '
                          f"off by more than level_error ({step['level_error']:g} of the "
                          f'range; the last {hi:.6g}/{lo:.6g} against {spec[0]:.6g}/'
                          f'{spec[1]:.6g}), at cycle {self.total}: the rig does not carry '
                          f'this step{clip}')
        return True

    def _null(self, seg: _Segment, cyc: dict, stamp: int, tol: float,
              levels: tuple[float, float]) -> bool:
        """
        Judge a whole cycle against ``count_tolerance``; return True when it does not count.

        A cycle outside it is carried, not counted: the wave runs one cycle longer (its end
        and the count there move on), the step's null cycles and time grow, the first of a
        run and its end are events, and ``null_cycles`` of them in a row interrupt the test.
        """
        k, step = seg.step, self.steps[seg.step]
        err, spec = self._off_by(seg, cyc, levels)
        if spec is None:
            return False
        hi, lo = levels
        if err <= tol:                              # NaN levels: not within, not counted
            if self._null_run:
                self._note_event('pacing', step.name, float(self.total),
                                 f'levels within count_tolerance again after {self._null_run} '
                                 f'cycles not counted; {self._null_cycles[k]} in the step, '
                                 f'{self._null_s[k]:.6g} s')
                self._null_run = 0
            return False
        period = seg.wave.period
        self._null_cycles[k] = self._null_cycles.get(k, 0) + 1
        self._null_s[k] = self._null_s.get(k, 0.0) + period
        self._null_run += 1
        seg.nulls += 1
        if seg.n_end is not None and seg.end is not None:
            seg.n_end += 1
            seg.end += int(round(period * 1e9))
        if self._null_run == 1:
            self._note_event('pacing', step.name, float(self.total),
                             f'count waiting: cycle {cyc["k"] + 1} carried {hi:.6g}/{lo:.6g} '
                             f'against {spec[0]:.6g}/{spec[1]:.6g} (count_tolerance '
                             f'{tol:g} of the range)')
        if self._back_off(seg, stamp):
            return True
        if self._null_run >= step['null_cycles'] and self.state == 'running':
            self._not_reached(step, stamp, f'levels not reached: {self._null_run} cycles in '
                              f'a row outside count_tolerance ({tol:g} of the range), not '
                              f'counted, at cycle {self.total}: the rig does not carry this '
                              'step')
        return True

    def _back_off(self, seg: _Segment, stamp: int) -> bool:
        """
        Lower the step's frequency after ``backoff_cycles`` null cycles in a row; True if so.

        By :data:`BACKOFF` down to ``frequency_min``; the step goes on at the count it has,
        from where the axis is (the mean, then the taper, as a resume), its compensation
        learning afresh (what it learnt at the other frequency would not fit this one).
        """
        k, step = seg.step, self.steps[seg.step]
        f_min = step['frequency_min'] if step.type == 'cyclic' else 0.0
        f = self._freq.get(k, step['frequency'])
        if not (f_min > 0 and f > f_min and self._null_run >= step['backoff_cycles']
                and self.state == 'running'):
            return False
        f_new = max(f_min, BACKOFF * f)
        self._freq[k] = f_new
        self._note_event('pacing', step.name, float(self.total),
                         f'frequency backed off from {f:.6g} to {f_new:.6g} Hz after '
                         f'{self._null_run} cycles in a row outside count_tolerance')
        self._save_step_state()
        self._learnt.pop(k, None)
        self._waves = []                  # the cycle under way is not counted
        self._begin_step(k, stamp + self.latency_ns, resume=True)
        return True

    def _failed(self, d: FailureDetector, why: str, stamp: int) -> bool:
        """Note a failure detector's trip; end the test unless observing (True if it ended)."""
        self.tripped.setdefault(d.kind, self.total)
        if self.observe:
            self._note_event('detector', d.kind, float(self.total), why)
            return False
        self.failed_at = self.total
        self.result, self.reason = 'failed', why
        self._note_event('failure', d.kind, float(self.total), why)
        self._to_stop(stamp + self.latency_ns)
        return True

    def _check_time_and_level(self, stamp: int, z: float, load: float) -> None:
        step = self.steps[self.step_index]
        t = (stamp - self._step_t0) * 1e-9
        for e in step.end:
            if e.kind == 'time' and t >= e.values['time']:
                self._end_step(stamp + self.latency_ns, f'time {e.values["time"]:g} s')
                return
            if e.kind == 'level':
                x = load if e.values['signal'] == 'load' else z
                a, b = e.values['above'], e.values['below']
                if (math.isfinite(a) and x > a) or (math.isfinite(b) and x < b):
                    self._end_step(stamp + self.latency_ns, f'{e.values["signal"]} '
                                   f'{x:.6g} crossed its level')
                    return

    def _end_step(self, t_end: int, why: str) -> None:
        k = self.step_index
        step = self.steps[k]
        self._save_step_state()
        for seg in self._waves:
            if seg.step == k and (seg.end is None or seg.end > t_end):
                seg.end = t_end                 # a condition ended it: no cycle beyond
        # the cycles up to the end that the states after it will close
        pending = sum(max(0, s.n_end - s.nulls - self.counts[k]) for s in self._waves
                      if s.step == k and s.n_end is not None and s.end == t_end)
        n = self.counts[k] + pending
        nulls = self._null_cycles.get(k, 0)
        paced = (f'; {nulls} more carried outside count_tolerance, not counted '
                 f'({self._null_s[k]:.6g} s)') if nulls else ''
        self._note_event('step_end', step.name, float(n),
                         f'{step.label} ended ({why}): {n} cycles{paced}')
        run_out = self.procedure.run_out
        if k + 1 < len(self.steps) and not (run_out and self.total + pending >= run_out):
            self._begin_step(k + 1, t_end)
            return
        self.result, self.reason = 'completed', 'every step done'   # or run-out, once counted
        self._to_stop(t_end)

    def _save_step_state(self) -> None:
        for seg in self._waves:
            learnt = seg.wave.learnt()
            if learnt is not None:
                self._learnt[seg.step] = learnt
        k = self.step_index
        if k in self._detectors:
            self._det_state[k] = [d.state() for d in self._detectors[k]]

    def _freeze(self, stamp: int | None, state: str, why: str) -> None:
        """Hold the command at its value ``latency`` on; the cycle under way is not counted."""
        self._save_step_state()
        self._waves = []              # the cycles under way are not counted
        if self._segs and stamp is not None:
            t = stamp + self.latency_ns
            seg = self._seg_at(t) or self._segs[-1]
            v = self._in_envelope(seg, t, self._value(seg, t)[0])
            self._push(_Segment('level', t, seg.mode, v0=v))
        self._set(state, stamp, why)

    def _in_envelope(self, seg: _Segment, stamp: int, v: float) -> float:
        """
        Return the command ``v`` of ``seg`` at ``stamp`` clipped to its cycle's specified levels.

        A compensated command runs beyond the levels (it makes up for the loop's roll-off);
        held still, the axis would carry all of it: a hold or a stop starts within the levels.
        """
        if seg.kind != 'wave' or seg.wave is None:
            return v
        w = seg.wave
        spec = w.specified(w.cycle_of(w.t_off + (stamp - seg.t0) * 1e-9))
        return v if spec is None else min(max(v, spec[1]), spec[0])

    def _to_stop(self, t0: int) -> None:
        """Ramp to the stop level from the command at ``t0``, then finish."""
        self._save_step_state()
        for seg in self._waves:
            seg.end = min(seg.end or t0, t0)
        seg = self._seg_at(t0) or (self._segs[-1] if self._segs else None)
        q = self.quantity
        v = self._in_envelope(seg, t0, self._value(seg, t0)[0]) if seg is not None else \
            self._measured(q)
        rate = self.procedure.stop_rate or next(
            (s['rate'] for s in self.steps if s.type == 'ramp' and s.control_mode == q),
            STOP_RATE[q])
        self._push(_Segment('ramp', t0, q, v0=v, v1=self.procedure.stop_level,
                            rate=rate))
        self._set('stopping', t0, f'to {self.procedure.stop_level:g} at {rate:g}/s: '
                  f'{self.reason}')

    def _finish_stop(self, stamp: int) -> None:
        run_out = self.procedure.run_out
        if self.result == 'completed' and run_out and self.total >= run_out:
            self.result, self.reason = 'run_out', (f'run-out: {self.total} cycles without a '
                                                   'failure')
            self._note_event('run_out', '', float(self.total), self.reason)
        self.result = self.result or 'stopped'
        self._set('finished', stamp, f'{self.result}: {self.reason} ({self.total} cycles)')

    # -- bookkeeping -----------------------------------------------------------------------
    def _set(self, state: str, stamp: int | None, why: str) -> None:
        was, self.state = self.state, state
        self._note_event(state, self.steps[self.step_index].name, float(self.total), why)
        if was != state:
            self.checkpoint_due = True

    def _note_event(self, kind: str, what: str, value: float, message: str) -> None:
        self.events.append((kind, what, value, message))

    # -- cycle jumping (a virtual test) -------------------------------------------------------
    def jump_room(self) -> int:
        """
        Return how many cycles may be credited now without simulating them (0: none).

        Only while the test runs a cyclic or drive step's counted cycles past its taper (a
        sweep is simulated whole; a block program's jumps are whole sequences, the caller's
        to size), and never into the step's last
        :data:`JUMP_MARGIN` cycles (its end and a run-out are simulated). Unbounded steps give
        :data:`JUMP_UNBOUNDED`.
        """
        if self.state != 'running' or len(self._waves) != 1:
            return 0
        seg = self._waves[0]
        step = self.steps[seg.step]
        if seg.step != self.step_index or step.type not in ('cyclic', 'drive'):
            return 0
        cyc = seg.cyc
        if cyc is None or cyc['taper'] or not cyc['begun_here']:
            return 0
        if seg.n_end is None:
            return JUMP_UNBOUNDED
        return max(0, seg.n_end - cyc['k'] - 1 - JUMP_MARGIN)

    def step_period(self) -> float:
        """Return the running waveform step's cycle [s] (a drive's pass), NaN if none."""
        return self._waves[0].wave.period if len(self._waves) == 1 else math.nan

    def step_detectors(self) -> list:
        """Return the running step's failure detectors."""
        return list(self._detectors.get(self.step_index, []))

    def jump(self, n: int) -> None:
        """
        Credit ``n`` cycles of the running step as carried without simulating them.

        A virtual test's cycle jumping: the counts advance by ``n`` and the step's end comes
        ``n`` cycles sooner (the inverse of a cycle null pacing does not count); the caller
        has advanced the specimen. At most :meth:`jump_room`.
        """
        room = self.jump_room()
        if not 0 < n <= room:
            raise InputError(f'a jump of {n!r} cycles: {room} may be jumped now')
        seg = self._waves[0]
        self.counts[seg.step] += n
        self.total += n
        self.jumped += n
        if seg.n_end is not None:
            seg.n_end -= n
            seg.nulls -= n
            seg.end -= int(round(n * seg.wave.period * 1e9))
        self.checkpoint_due = True

    def time_to_go(self) -> float:
        """Return the seconds the steps still planned take, NaN where a condition decides."""
        total = 0.0
        level = self._measured(self.quantity)
        level = level if math.isfinite(level) else 0.0
        elapsed = max(0, self._last_ns - self._step_t0) * 1e-9
        for k in range(self.step_index, len(self.steps)):
            s = self.steps[k]
            now = k == self.step_index and self.state in ('running', 'switching')
            if s.type == 'ramp':
                d = abs(s['to'] - level) / s['rate']
                level = s['to']
            elif s.type == 'dwell':
                d = s['time'] - (elapsed if now else 0.0)
            elif s.type == 'cyclic':
                if not s['count']:
                    return math.nan
                d = (s['count'] - self.counts[k]) / self._freq.get(k, s['frequency'])
                level = 0.5 * (s['blocks'][0][0] + s['blocks'][0][1])
            elif s.type == 'sweep':
                d = s['duration'] - (elapsed if now else 0.0)
                level = s['mean']
            else:
                return math.nan
            total += max(d, 0.0)
        return total

    def status(self) -> dict[str, Any]:
        """
        Return the status values: state, step, counts, time to go, result.

        ``controller_mode``: the controller's control mode once known ('' while a node still
        asks it: a start or a resume is refused until then, so a client waits for it).

        And for each failure detector of the step, ``<kind>.value`` (its newest judged value:
        the drop, the move or the range's fraction) and ``<kind>.reference_at`` (the cycle
        its reference was complete at, -1 while it has none).
        """
        k = self.step_index
        out = {'state': self.state, 'step': self.steps[k].name, 'step_index': k,
               'step_cycles': self.counts[k], 'total_cycles': self.total,
               'time_to_go_s': self.time_to_go(), 'result': self.result,
               'reason': self.reason, 'failed_at': self.failed_at
               if self.failed_at is not None else -1, 'stamp_ns': self._last_ns,
               'controller_mode': self.mode if self.mode_known else ''}
        for d in self._detectors.get(k, []):
            out[f'{d.kind}.value'] = d.last_value
            out[f'{d.kind}.reference_at'] = d.reference['at'] if d.reference else -1
        return out

    # -- checkpoint ------------------------------------------------------------------------
    def checkpoint(self) -> dict[str, Any]:
        """Return the test's state as JSON values (what a restart resumes from)."""
        self._save_step_state()
        self.checkpoint_due = False
        self._last_checkpoint = self._last_ns
        return {'version': 1, 'procedure': self.procedure.name,
                'state': self.state, 'result': self.result, 'reason': self.reason,
                'step': self.step_index, 'counts': list(self.counts), 'total': self.total,
                'failed_at': self.failed_at, 'mode': self.mode,
                'learnt': {str(k): v for k, v in self._learnt.items()},
                'frequency': {str(k): v for k, v in self._freq.items()},
                'detectors': {str(k): v for k, v in self._det_state.items()},
                'stamp_ns': self._last_ns}

    def restore(self, cp: Mapping[str, Any], recovered_total: int | None = None) -> str:
        """
        Take a checkpoint back (a restarted node); the test waits ``interrupted`` for resume.

        ``recovered_total``: the test's count the bag shows (cycles recorded after the
        checkpoint), counted in the checkpoint's step; returns what was restored.
        """
        if cp.get('version') != 1 or cp.get('procedure') != self.procedure.name:
            raise InputError(f"the checkpoint is not this procedure's (it is "
                             f'{cp.get("procedure")!r}, version {cp.get("version")!r})')
        counts = [int(c) for c in cp['counts']]
        if len(counts) != len(self.steps):
            raise InputError(f'the checkpoint has {len(counts)} steps, the procedure '
                             f'{len(self.steps)}')
        self.counts, self.total = counts, int(cp['total'])
        self.step_index = int(cp['step'])
        self.mode = cp.get('mode', self.mode)
        self.failed_at = cp.get('failed_at')
        self._learnt = {int(k): v for k, v in cp.get('learnt', {}).items()}
        self._freq = {int(k): float(v) for k, v in cp.get('frequency', {}).items()}
        self._det_state = {int(k): v for k, v in cp.get('detectors', {}).items()}
        extra = 0
        if recovered_total is not None and recovered_total > self.total:
            extra = recovered_total - self.total
            self.counts[self.step_index] += extra
            self.total = recovered_total
        state = cp['state']
        if state == 'finished':
            self.state, self.result, self.reason = 'finished', cp['result'], cp['reason']
            return f'the test had finished: {self.result} ({self.total} cycles)'
        self.state = 'interrupted'
        self.result, self.reason = '', ''
        msg = (f'restored {self.steps[self.step_index].label} at cycle '
               f'{self.counts[self.step_index]} ({self.total} in all)')
        if extra:
            msg += f', {extra} of them recovered from the bag'
        self._note_event('restored', self.steps[self.step_index].name, float(self.total), msg)
        return msg
