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
The control loop the controller node runs: every rule between a message and a command.

:class:`ControlLoop` takes the states, references and operator requests as plain records and
decides everything the controller node does with them; the node converts messages, calls it
and publishes what it returns. The clocks are passed in: ``now`` [s] is the node's monotonic
clock (when a message arrived, when a timer ran) and ``clock_ns`` its ROS clock, the one
the states are stamped on in real time. Each rule is tested in ``test/test_control_loop.py``
at its exact period, without DDS.

**Stamp policy** (any publisher on the bench network can send a ``state``: a bag player, a
rig driver with another clock, a restarted plant). The controller answers every state with
one command stamped with that state's stamp.

* real time: a state stamped more than ``future_tolerance`` ahead of ``clock_ns`` is dropped
  and counted (``future``), never adopted: one stray stamp an hour ahead must not make every
  true state look out of order;
* a repeated stamp (a lock-step resend): the same command again, no PID update
  (``repeated``);
* an older stamp than the last answered, by at most ``EPOCH_PERIODS`` periods (reordering):
  ignored and counted (``out_of_order``);
* older by more (a restarted plant, a replayed bag, a lock-step plant started again): a new
  run (``epochs``). The PID and feedforward restart from rest, the ramp-on starts again, the
  lock-step references are forgotten, and the stamp is answered at once;
* real time: a state older than ``stale_timeout`` on arrival is not used: the held command
  is repeated (``stale``);
* real time: every state taken is judged by the ``loop_timing`` detector
  (:meth:`ros_ehs.core.control.safety.Supervisor.judge_timing`) by how long the valve held
  one command: the state's age when answered, plus the periods of the states between it and
  the one answered before, which were never answered (the loop topics keep the newest state
  only, so a loop that stalled wakes to a fresh one). Beyond ``loop_timing_late`` the machine
  is too busy to run the loop on time.

**References.** Before the first reference, the first measured position is held. In real
time the newest reference is carried with its velocity to each state's stamp (a first-order
hold, forward or back by at most ``reference_timeout``), and a state stamped between the two
newest references gets the velocity interpolated between theirs (so neither the position nor
the velocity feedforward depends on the phase of the reference's timer against the
plant's); a reference older than
``reference_timeout`` on the monotonic clock is held at its position with zero velocity
(``reference_stale``), and when references come back the axis ramps onto them from the held
position over ``ramp_time``. In lock-step the references come as trajectories into a buffer
keyed by stamp (at most ``REF_BUFFER``, oldest dropped first; a used one dropped at once); a
state is answered only with the reference of its own stamp, and waits for it if it has not
come yet (:meth:`ControlLoop.trajectory` then answers it).

**Lost states** (real time, :meth:`ControlLoop.tick` every 10 ms or so): no state for
``LOST_FACTOR * stale_timeout``: 0 A once (``state_lost_events``), and the PID restarts from
rest when states return (a plain late state is only held: a kernel's 5-20 ms hiccups must not
reset the PID); no state for ``feedback_timeout``: the feedback detector trips
(:meth:`ros_ehs.core.control.safety.Supervisor.feedback_lost`), and a power-off or a disabled
axis sends 0 A at once.

**The load cell** comes with each state (its ``load``: the state's joint ``load_cell``), or
from a topic of its own (``load_source='topic'``, :meth:`ControlLoop.load`): in real time a
state takes the newest reading stamped at most ``stale_timeout`` before it (an older one is
stale: no reading); in lock-step a state waits for the reading of its own stamp as it waits
for its reference (at most ``REF_BUFFER`` kept). The force reference is the reference's
``f_ref``; in real time it is carried to the state's instant with the rate of the last two
references (a first-order hold, as the position).

**Control modes** (``control_mode``): :meth:`ControlLoop.set_mode` switches, refused with the
reason when the load cell has no valid reading (:meth:`ControlLoop.load_ok`) or an interlock
is latched (:mod:`ros_ehs.core.control.supervised`).

**Safety and the controller** are :class:`~ros_ehs.core.control.supervised.AxisController`
(limit and error detectors, latched actions, ramp-on, the control modes, delta-P): each
state's command comes from it, and its events come back in the :class:`Reply`.

What the node should log is left in :attr:`ControlLoop.notes` as ``(level, text)``: each
condition once when it starts (a dropped future state, a non-finite input, a missing force)
and, for those that repeat, at most once per ``NOTE_PERIOD`` of the monotonic clock.
"""

from __future__ import annotations

from collections import deque
import math
from typing import NamedTuple, Sequence

import numpy as np
from ros_ehs.core.control.safety import DETECTORS, Event
from ros_ehs.core.control.supervised import AxisController
from ros_ehs.core.control.waveforms import first_order_hold
from ros_ehs.core.errors import InputError
from ros_ehs.core.params import Params
from ros_ehs_msgs_py import AxisState, Load, Reference

__all__ = ['ControlLoop', 'EPOCH_PERIODS', 'LOST_FACTOR', 'NOTE_PERIOD', 'REF_BUFFER', 'Reply']

#: A stamp further back than this many periods than the last one starts a new run.
EPOCH_PERIODS = 5
#: States missing for this many ``stale_timeout`` mean the plant is gone.
LOST_FACTOR = 10
#: Lock-step references kept ahead of the states (stamps; 4 s at 1 kHz).
REF_BUFFER = 4096
#: A note that repeats is left at most once per this many seconds [s].
NOTE_PERIOD = 1.0
#: Tracking errors and compute times kept for the figures (2 s at 1 kHz).
WINDOW = 2000
#: What the loop counts (in the diagnostics).
COUNTS = ('answered', 'bad', 'nonfinite', 'stale', 'out_of_order', 'future', 'epochs',
          'repeated', 'state_lost_events', 'param_rejects', 'events', 'reference_stale')


class Reply(NamedTuple):
    """A command to publish, stamped ``stamp_ns``, of ``current`` [A], and what happened."""

    stamp_ns: int
    current: float
    events: tuple[Event, ...] = ()


class ControlLoop:
    """
    The controller node's rules (see the module docstring).

    ``params``: gains, feedforward values, limits and actions (a
    :class:`~ros_ehs.core.params.Params`); ``rate_hz`` the loop's rate; ``lockstep``: answer
    each state with the reference of its own stamp; ``wall``: staleness and lost states are
    judged on the clocks passed in (off under sim time and in lock-step, where the plant waits
    for the controller); ``start_enabled``: hydraulics on at start.
    """

    def __init__(self, params: Params, *, rate_hz: float = 1000.0, lockstep: bool = False,
                 wall: bool = True, start_enabled: bool = True,
                 reference_timeout: float = 0.1, future_tolerance: float = 0.05,
                 load_source: str = 'state') -> None:
        if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and rate_hz > 0):
            raise InputError(f'`rate_hz` = {rate_hz!r} must be a positive number of Hz')
        if load_source not in ('state', 'topic'):
            raise InputError(f'`load_source` = {load_source!r} is not one of [state, topic]')
        self.load_source = load_source
        self.dt = 1.0 / float(rate_hz)
        self.dt_ns = int(round(self.dt * 1e9))
        self.params = params
        self.axis = AxisController(params, self.dt, bool(start_enabled))
        self.lockstep = bool(lockstep)
        self.wall = bool(wall) and not self.lockstep
        self.counts = dict.fromkeys(COUNTS, 0)
        self.notes: list[tuple[str, str]] = []
        self.lost = False                 # no state for LOST_FACTOR stale_timeout: 0 A
        self.no_force = False             # dp_gain > 0 and the states carry no force
        self.last_stamp = -1
        self.last_rx = math.nan           # when the newest state arrived [s, monotonic]
        self.measured = AxisState(-1, math.nan, math.nan)    # the newest answered state
        self._refs: dict[int, tuple[float, float, float]] = {}   # lock-step: z, v, f
        self._loads: dict[int, float] = {}                       # lock-step, a load topic
        self._load: Load | None = None            # real time, a load topic: the newest
        self._ref: tuple[float, float, float, int] | None = None   # z, v, arrival, stamp
        self._v_prev: tuple[float, int] | None = None     # the reference before: v, stamp
        self._f: tuple[float, float, int] = (math.nan, 0.0, -1)   # real time: f, rate, stamp
        self._ref_stale = False
        self._late: list[Event] = []      # loop_timing's events for the next reply
        self._hold_z: float | None = None
        self._waiting: AxisState | None = None    # lock-step: parked until its reference
        self._noted: dict[str, float] = {}
        self._future_seen = 0              # future drops the last diagnosis saw
        self.errors: deque[float] = deque(maxlen=WINDOW)
        self.configure(reference_timeout=reference_timeout, future_tolerance=future_tolerance)

    # -- configuration -----------------------------------------------------------------------
    def configure(self, *, reference_timeout: float | None = None,
                  future_tolerance: float | None = None) -> None:
        """Change the live options (checked): the reference timeout, the future tolerance [s]."""
        for name, v in (('reference_timeout', reference_timeout),
                        ('future_tolerance', future_tolerance)):
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v)
                                      and v > 0):
                raise InputError(f'`{name}` = {v!r} s must be a positive number')
        if reference_timeout is not None:
            self.reference_timeout = float(reference_timeout)
        if future_tolerance is not None:
            self.future_tolerance = float(future_tolerance)

    def set_params(self, params: Params) -> None:
        """Apply new gains, feedforward values, limits and actions (latches stay)."""
        self.params = params
        self.axis.set_params(params)

    @property
    def stale_timeout(self) -> float:
        """Return how old a state may be on arrival [s]."""
        return float(self.params['stale_timeout'])

    # -- references --------------------------------------------------------------------------
    def reference(self, r: Reference, now: float) -> None:
        """Take a real-time reference that arrived at ``now`` [s]."""
        f0, _, st0 = self._f
        rate = 0.0
        if math.isfinite(r.f_ref) and math.isfinite(f0) and r.stamp_ns > st0 >= 0:
            rate = (r.f_ref - f0) / ((r.stamp_ns - st0) * 1e-9)
        self._f = (r.f_ref, rate, r.stamp_ns)
        if self._ref is not None:
            self._v_prev = (self._ref[1], self._ref[3])
        self._ref = (r.z_ref, r.v_ref, now, r.stamp_ns)

    def trajectory(self, refs: Sequence[Reference]) -> Reply | None:
        """Take lock-step references; answer the state that waited for one of them."""
        buf = self._refs
        for r in refs:
            buf[r.stamp_ns] = (r.z_ref, r.v_ref, r.f_ref)
        while len(buf) > REF_BUFFER:
            del buf[next(iter(buf))]
        return self._try_waiting()

    def load(self, reading: Load, now: float = math.nan) -> Reply | None:
        """Take a load cell reading from its own topic; answer a state that waited for it."""
        if self.lockstep:
            self._loads[reading.stamp_ns] = reading.force
            while len(self._loads) > REF_BUFFER:
                del self._loads[next(iter(self._loads))]
            return self._try_waiting()
        if self._load is None or reading.stamp_ns >= self._load.stamp_ns:
            self._load = reading
        return None

    def _try_waiting(self) -> Reply | None:
        w = self._waiting
        if w is None or w.stamp_ns not in self._refs:
            return None
        if self.load_source == 'topic':
            if w.stamp_ns not in self._loads:
                return None
            w = w._replace(load=self._loads.pop(w.stamp_ns))
        self._waiting = None
        return self._answer(w, *self._refs.pop(w.stamp_ns))

    def _load_for(self, s: AxisState) -> AxisState:
        """Return ``s`` with its load from the topic (real time): the newest, if fresh."""
        if self.load_source == 'state':
            return s
        r = self._load
        fresh = r is not None and r.stamp_ns >= s.stamp_ns - self.stale_timeout * 1e9
        return s._replace(load=r.force if fresh else math.nan)

    def _reference_for(self, s: AxisState, now: float) -> tuple[float, float, float]:
        """Return the real-time reference at the state's instant: z, v, f."""
        if self._ref is None:
            if self._hold_z is None and math.isfinite(s.z):
                self._hold_z = s.z
            return (self._hold_z if self._hold_z is not None else math.nan), 0.0, math.nan
        z, v, rx, stamp = self._ref
        f, rate, _ = self._f
        if now - rx > self.reference_timeout:
            if not self._ref_stale:
                self._ref_stale = True
                self.counts['reference_stale'] += 1
                self._note('warning', f'no reference for {self.reference_timeout:g} s: '
                           'holding its last position')
            return z, 0.0, f
        if self._ref_stale:        # back, and moved on meanwhile: ramp onto it, no step
            self._ref_stale = False
            self.axis.supervisor.ramp_again()
            self._note('info', 'the reference is back: ramping onto it from the held position')
        # to the state's instant, forward or back (carried only forward, the demand led the
        # state by up to a reference period, by the random phase of the two nodes' timers)
        if math.isfinite(f):
            f = first_order_hold(f, rate, stamp, s.stamp_ns, self.reference_timeout)
        z_at = first_order_hold(z, v, stamp, s.stamp_ns, self.reference_timeout) \
            if math.isfinite(z) else z
        # the velocity at the instant too: between the reference before and the newest,
        # interpolated. (The newest's own led the state by up to a reference period: a
        # velocity feedforward lead that changed with the timers' phase, and tracked the
        # paper's sine 0.88x as far off as the same loop in process.)
        v_at = v
        if self._v_prev is not None:
            v0, st0 = self._v_prev
            if st0 <= s.stamp_ns < stamp and math.isfinite(v0):
                v_at = v0 + (v - v0) * ((s.stamp_ns - st0) / (stamp - st0))
        return z_at, v_at, f

    # -- states ------------------------------------------------------------------------------
    def malformed(self, now: float = math.nan) -> None:
        """Count a message that did not decode (the node logs it); a state's ``now`` [s]."""
        if math.isfinite(now):
            self.last_rx = now
        self.counts['bad'] += 1

    def state(self, s: AxisState, now: float, clock_ns: int) -> Reply | None:
        """
        Take a state that arrived at ``now`` [s] (``clock_ns``: the node's clock then).

        Returns the command to publish, or None: dropped, or (lock-step) parked until its
        reference comes.
        """
        self.last_rx = now
        age = clock_ns - s.stamp_ns
        if self.wall and age < -self.future_tolerance * 1e9:
            self.counts['future'] += 1
            self._note('warning', f'dropped a state stamped {-age * 1e-9:.6g} s ahead of this '
                       'clock', now, key='future')
            return None
        if s.stamp_ns == self.last_stamp:
            self.counts['repeated'] += 1
            return Reply(s.stamp_ns, self.axis.output)
        if s.stamp_ns < self.last_stamp:
            if self.last_stamp - s.stamp_ns <= EPOCH_PERIODS * self.dt_ns:
                self.counts['out_of_order'] += 1
                return None
            self._new_run(s.stamp_ns, now)
        if self.wall:
            late, unanswered = self._late_by(s, age)
            self._late.extend(self.axis.supervisor.judge_timing(late, s.stamp_ns, unanswered))
        if self.wall and age > self.stale_timeout * 1e9:
            self.counts['stale'] += 1
            self.last_stamp = s.stamp_ns
            events, self._late = tuple(self._late), []
            self.counts['events'] += len(events)
            return Reply(s.stamp_ns, self.axis.output, events)
        if self.lockstep:
            self._waiting = s
            return self._try_waiting()
        ref = self._reference_for(s, now)
        return self._answer(self._load_for(s), *ref, now=now)

    def _late_by(self, s: AxisState, age: int) -> tuple[float, int]:
        """
        Return how long the valve held one command when ``s`` (``age`` [ns] old) is answered.

        [s], and how many states came between it and the one answered before, never answered:
        the loop topics keep only the newest state, so a loop that stalled wakes to a fresh
        one, and the valve held the earlier answer for those periods as well. Not across a
        new run or lost states (0 A went out; the tick said so).
        """
        last = self.last_stamp
        if last < 0 or self.lost or s.stamp_ns <= last:
            return age * 1e-9, 0
        gap = s.stamp_ns - last
        return max(age, age + gap - self.dt_ns) * 1e-9, max(0, round(gap / self.dt_ns) - 1)

    def _new_run(self, stamp_ns: int, now: float) -> None:
        """Start a new run at ``stamp_ns``: PID from rest, lock-step references forgotten."""
        back = (self.last_stamp - stamp_ns) * 1e-9
        self.counts['epochs'] += 1
        self.axis.restart()
        self.last_stamp = -1
        self._refs.clear()
        self._loads.clear()
        self._waiting = None
        self._note('info', f'new run: the state stamp jumped back {back:.6g} s; PID restarted '
                   f'from rest (run {self.counts["epochs"] + 1})', now, key='new_run')

    def _answer(self, s: AxisState, z_ref: float, v_ref: float, f_ref: float = math.nan,
                now: float = math.nan) -> Reply:
        if self.lost:
            self.lost = False
            self.axis.restart_loops()
            self._note('info', 'states are back; PID restarted from rest')
        axis, z = self.axis, s.z
        i = axis.step(s.stamp_ns, z, s.z_dot, s.force, z_ref, v_ref, s.load, f_ref, s.i)
        z_ok = math.isfinite(z)
        has_ref = math.isfinite(z_ref) and math.isfinite(v_ref) or math.isfinite(f_ref)
        if not (z_ok and has_ref):
            self.counts['nonfinite'] += 1
            if not axis.supervisor.latches['feedback'].tripped:   # else reported once
                self._note('warning', 'non-finite state or reference: command 0 A', now,
                           key='nonfinite')
        elif axis.ctrl.force_missing(s.force):
            self.counts['nonfinite'] += 1
            if not self.no_force:
                self.no_force = True
                self._note('error', 'dp_gain > 0 needs the hydraulic force in each state '
                           '(effort[0]) and this one has none: command 0 A')
        elif self.no_force and math.isfinite(s.force):
            self.no_force = False
            self._note('info', 'the hydraulic force is back in the state: delta-P on')
        self.measured = s
        self.last_stamp = s.stamp_ns
        self.counts['answered'] += 1
        if z_ok and math.isfinite(z_ref):
            self.errors.append(z_ref - z)
        events = tuple(self._late) + tuple(axis.events)
        self._late = []
        if events:
            self.counts['events'] += len(events)
        return Reply(s.stamp_ns, i, events)

    # -- lost states (real time: a timer) ----------------------------------------------------
    def feedback_age(self, now: float) -> float:
        """Return the age of the newest state at ``now`` [s] (0 when staleness is off)."""
        return now - self.last_rx if self.wall and math.isfinite(self.last_rx) else 0.0

    def tick(self, now: float, clock_ns: int) -> tuple[Reply | None, tuple[Event, ...]]:
        """
        Check for lost states at ``now`` [s]: return a 0 A command if one is due, and events.

        The command is stamped ``clock_ns``; the events are a feedback trip's. 0 A goes out
        when the states are lost, and at a feedback trip when the axis is off or the trip's
        action powers it off.
        """
        if not self.wall or self.last_stamp < 0:
            return None, ()
        sup = self.axis.supervisor
        events = tuple(sup.feedback_lost(self.feedback_age(now), self.measured.stamp_ns))
        self.counts['events'] += len(events)
        zero = bool(events) and (not sup.enabled or sup.action == 'power_off')
        if zero:
            self.axis.restart_loops()
        limit = LOST_FACTOR * self.stale_timeout
        if not self.lost and now - self.last_rx >= limit:
            self.lost = True
            self.counts['state_lost_events'] += 1
            self.axis.restart_loops()   # the held command is 0 A until states return
            self._note('warning', f'no state for {limit * 1e3:g} ms: command 0 A')
            zero = True
        return (Reply(clock_ns, 0.0) if zero else None), events

    # -- operator ----------------------------------------------------------------------------
    def reset(self, now: float) -> tuple[bool, str, Event]:
        """Clear the latches unless a latched condition still holds: (ok, why, event)."""
        m = self.measured
        ok, why, ev = self.axis.supervisor.reset(m.stamp_ns, m.z, m.z_dot, m.force,
                                                 self.feedback_age(now), m.load)
        if ok:
            self.axis.restart_loops()
        self.counts['events'] += 1
        return ok, why, ev

    def enable(self, on: bool) -> tuple[bool, str, Event]:
        """Turn the hydraulics on (ramp-on from the measured position) or off: (ok, why, event)."""
        ok, why, ev = self.axis.supervisor.enable(bool(on), self.measured.stamp_ns)
        if ok:
            self.axis.restart_loops()
        self.counts['events'] += 1
        return ok, why, ev

    def load_ok(self) -> bool:
        """
        Return True when the load cell has a valid reading now.

        The newest answered state's load is finite and states are coming (real time: not
        lost); from a load topic in real time, the newest reading is also at most
        ``stale_timeout`` older than that state.
        """
        m = self.measured
        if self.lost or m.stamp_ns < 0:
            return False
        if self.load_source == 'topic' and not self.lockstep:
            r = self._load
            return r is not None and math.isfinite(r.force) and \
                r.stamp_ns >= m.stamp_ns - self.stale_timeout * 1e9
        return math.isfinite(m.load)

    def check_mode(self, mode: str) -> str:
        """Return why a switch to ``mode`` would be refused now ('' when it would not)."""
        return self.axis.check_mode(mode, self.load_ok())

    def set_mode(self, mode: str) -> tuple[bool, str, Event]:
        """Switch the control mode at the next state (bumpless): (ok, why, event)."""
        ok, why, ev = self.axis.set_mode(mode, self.measured.stamp_ns, self.load_ok())
        self.counts['events'] += 1
        return ok, why, ev

    # -- notes, figures, diagnosis -----------------------------------------------------------
    def _note(self, level: str, text: str, now: float = math.nan, key: str = '') -> None:
        """Leave a note for the node's log; one with a ``key`` at most once per NOTE_PERIOD."""
        if key:
            last = self._noted.get(key, -math.inf)
            if math.isfinite(now) and now - last < NOTE_PERIOD:
                return
            self._noted[key] = now
        self.notes.append((level, text))

    def figures(self) -> dict:
        """Return the figures the diagnostics report."""
        e = np.fromiter(self.errors, float, len(self.errors))
        ax = self.axis
        c = ax.ctrl
        f = dict(self.counts)
        f.update(tracking_rms_m=float(np.sqrt((e * e).mean())) if e.size else math.nan,
                 tracking_max_m=float(np.abs(e).max()) if e.size else math.nan,
                 command_a=float(ax.output), fault=ax.fault, saturated=ax.saturated,
                 feedforward_a=float(ax.force.last_ff if ax.driving == 'force' else c.last_ff),
                 delta_p_a=float(c.dp.last), state_lost=self.lost,
                 control_mode=ax.mode, driving=ax.driving or 'none',
                 load_n=float(self.measured.load), force_ref_n=float(ax.force.target),
                 force_error_n=float(ax.force.error) if ax.driving == 'force' else math.nan,
                 protect_limiting=ax.limited)
        sup = self.axis.supervisor
        f.update(mode=sup.mode, interlock=sup.action, tripped=','.join(sup.tripped()),
                 enabled=sup.enabled, ramp=float(sup.ramp),
                 **{f'trips_{d}': n for d, n in sup.counts.items()})
        cfg = sup.config
        for d in DETECTORS:           # the detector table an operator's station shows
            f[f'{d}.limit'] = float(cfg.limit(d))
            f[f'{d}.action'] = cfg.action(d)
        return f

    def diagnosis(self) -> tuple[int, str]:
        """
        Return the diagnostics' level (0 OK, 1 WARN, 2 ERROR) and message now.

        An interlock comes first, with the input fault behind it where there is one (a
        controller that commands 0 A for want of the hydraulic force lets the piston fall
        behind its reference until the tracking error holds it: the hold is the news, the
        missing force its cause).
        """
        level, msg = 0, 'running'
        sup = self.axis.supervisor
        act = sup.action
        fault = '' if not self.axis.fault else (
            'no hydraulic force in the state for dp_gain: command 0 A'
            if self.axis.ctrl.force_missing(self.measured.force) else
            'non-finite input: command 0 A')
        if act in ('hold', 'stop', 'power_off'):
            level, msg = 2, f'interlock {act}: {", ".join(sup.tripped())} (~/reset)' + (
                f'; {fault}' if fault else '')
        elif not sup.enabled:
            level, msg = 1, 'hydraulics off: 0 A (~/enable)'
        elif act == 'indicate':
            level, msg = 1, f'limit indicated: {", ".join(sup.tripped())} (~/reset)'
        elif fault:
            level, msg = 2, fault
        elif self.lost:
            level, msg = 1, 'no state: command 0 A'
        elif self.counts['future'] > self._future_seen:
            level, msg = 1, 'dropped states stamped ahead of this clock'
        elif self.counts['answered'] == 0:
            level, msg = 1, 'waiting for states'
        self._future_seen = self.counts['future']
        return level, msg
