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
The simulated axis a controller closes its loop on: what the plant node runs (no ROS import).

:class:`SimulatedAxis` steps the model on a grid of periods and decides everything the plant
node does between a message and the next: which command counts (the stamp policy), what the
valve gets (the watchdog), when time starts, how lock-step proceeds, the injected faults and
the sensor noise. The node converts messages, calls it and publishes; the clocks are passed
in (``now`` [s] or ``now_ns``, ``time.monotonic``'s), so every rule is tested without DDS.

**Stamp policy** (the controller stamps each command with the state it answers): a command
stamped after the latest state sent answers none (a stray publisher, another clock): ``future``;
one no newer than the last applied, or any before a real-time axis's first state: ``stale``;
in lock-step only the answer to the current state counts (``not_current``); a non-finite
current is ``non_finite``. A restarted controller therefore needs nothing: its first answer is
newer than the last applied. The current is clamped to twice the rated current.

**Real time**: :meth:`start` once the state has its subscribers (time restarts there, on
whole periods of the wall grid); each :meth:`tick` says how many periods are due (a late tick
steps every period it missed, up to ``MAX_CATCHUP``; further behind, the grid is moved on and
counted in ``overruns``). **Watchdog**: a command is never applied over a period that ends
more than ``watchdog_periods`` periods after it arrived; from the tick where that would
happen the valve current is zero until fresh commands return. A trip at a tick so late that
an on-time one would have applied the command is counted apart (``trips_late_tick``), unless
a later on-time tick finds the command too old as well (a controller that stopped). A command
older than ``LATE_PERIODS`` (3) at a period's end is counted as late the same way
(``late_commands``), and nothing else: the loop benchmarks' measure of its timing.

**Lock-step**: :meth:`poll` (every ``resend_period``) waits for the subscribers, then
``start_delay``, then says to send the first state, and to send it again after
``resend_period`` of silence; the answer to the current state steps exactly one period
(:meth:`command`). :meth:`clock_due` says which states carry ``/clock``. With a
``real_time_factor`` > 0 the run advances at most that much sim time per wall second, counted
from the first state: a state due later is held (:attr:`held`) and released by the first
:meth:`poll` at or after its time (poll every ``PACE_TICK`` then). A run that falls more than
``PACE_CREDIT`` behind its pace (a stalled machine) does not race to catch up: the pace
restarts from there. :meth:`pause` holds the loop still: the answer to the state already
sent steps the axis, and the state after it is held until the pause ends (a test calls a
service on a still loop so; no process is stopped, which the middleware can take for a
crash, docs/recording.md).

**The specimen** (:class:`~ros_ehs.core.model.specimen.Specimen`, when ``k_L`` > 0): each
step its force is taken from the new state, its crack grows at each reversal (the model's load
string follows), and it fractures at its life. The load cell reads its force with
``load_cell_noise`` (drawn from its own stream of ``seed``): in the state (joint
``load_cell``) while a specimen is installed, and for :meth:`load` always (an empty load
train reads 0 N). A change of a specimen's parameters installs a new one.

**Faults** (``fault`` from ``fault_time`` of sim time): ``frozen_sensor`` (position and
velocity of the fault's start from then on), ``nan_sensor``, ``stuck_valve`` (the current at
the start stays applied), ``lost_pressure`` (supply to ``LOST_SUPPLY``),
``frozen_load_cell`` (the load cell repeats its reading at the fault's start),
``nan_load_cell``, ``drifting_load_cell`` (its reading drifts from the truth at
``LOAD_DRIFT``). :meth:`true_load` is the specimen's own force, whatever its load cell
reads: what the specimen carried.

What the node should log is left in :attr:`SimulatedAxis.notes` as (level, text), once per
occurrence: a fault starting or ending, the first model step failure of a run of them.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
from typing import NamedTuple

import numpy as np
from ros_ehs.core.errors import InputError
from ros_ehs.core.model.plant import Plant
from ros_ehs.core.model.specimen import Specimen
from ros_ehs.core.params import Params
from ros_ehs.core.sim.faults import FAULTS, LOAD_DRIFT, LOST_SUPPLY
from ros_ehs_msgs_py import AxisState, Load

__all__ = ['Episodes', 'FAULTS', 'LATE_PERIODS', 'LOST_SUPPLY', 'MAX_CATCHUP', 'PACE_CREDIT',
           'PACE_TICK', 'SPECIMEN_PARAMS', 'Sample', 'SimulatedAxis', 'TRIP_LOG', 'WatchdogTrip']

#: Periods a late tick may step before the grid is moved on.
MAX_CATCHUP = 50
#: Watchdog trips kept (the newest), and late-command episodes.
TRIP_LOG = 100
#: A command older than this many periods at a period's end is late: counted
#: (``late_commands``), never acted on (the watchdog acts, after ``watchdog_periods``). The
#: loop benchmarks' measure of the loop's timing, as the bare ping-pong counts it.
LATE_PERIODS = 3
#: Lock-step at a real-time factor: the node polls at least this often [s] (the longest burst).
PACE_TICK = 0.005
#: Lock-step at a real-time factor: the most wall time a run may catch up at full speed [s].
PACE_CREDIT = 0.05
_ZEROS = (0.0, 0.0, 0.0, 0.0)


@dataclass
class WatchdogTrip:
    """One watchdog trip: when, how late its tick was, how old the command was."""

    time_s: float          #: monotonic time of the tick [s]
    tick_late_ms: float    #: that tick's lateness [ms]
    command_age_ms: float  #: age of the last fresh command at the tick [ms]
    late_tick_only: bool   #: an on-time tick would have applied the command

    def as_list(self) -> list:
        """Return ``[time_s, tick_late_ms, command_age_ms, late_tick_only]``, rounded."""
        return [round(self.time_s, 6), round(self.tick_late_ms, 4),
                round(self.command_age_ms, 4), self.late_tick_only]


class Episodes:
    """
    Episodes of a command older than a limit at a period's end, each counted once.

    ``on`` while it lasts; ``count`` episodes; ``late_tick`` of them, those an on-time tick
    would not have had (the axis's own lateness), until a tick finds the command too old on
    time as well; ``log`` the newest :data:`TRIP_LOG`.
    """

    def __init__(self) -> None:
        self.on = False
        self.count = 0
        self.late_tick = 0
        self._late_only = False
        self.log: deque[WatchdogTrip] = deque(maxlen=TRIP_LOG)

    def judge(self, age: float, on_time_age: float, limit: float, now: float,
              tick_late_ms: float, command_age_ms: float) -> bool:
        """Judge a period whose command is ``age`` old at its end [s]; say if it is over."""
        if not age > limit:
            self.on = False
            return False
        late_only = on_time_age <= limit
        if not self.on:
            self.on = True
            self.count += 1
            self._late_only = late_only
            self.late_tick += late_only
            self.log.append(WatchdogTrip(now, tick_late_ms, command_age_ms, late_only))
        elif self._late_only and not late_only:
            self._late_only = False
            self.late_tick -= 1
            self.log[-1].late_tick_only = False
        return True


class Sample(NamedTuple):
    """What the sensors read at a period's stamp: the state, the chamber pressures [Pa], load."""

    state: AxisState
    p_cp: float
    p_ct: float
    load: float = 0.0      #: the load cell's reading [N] (0 N without a specimen, plus noise)


#: the parameters of the specimen: a change installs a new one
SPECIMEN_PARAMS = ('k_L', 'c_L', 'z_L', 'specimen_life', 'specimen_life_range',
                   'specimen_paris_m', 'specimen_crack0', 'specimen_compliance',
                   'specimen_scatter', 'specimen_seed', 'specimen_fatigue_limit',
                   'specimen_limit_scatter')


class SimulatedAxis:
    """
    The model behind the contract topics, with its stamp policy, watchdog and lock-step.

    ``params`` the plant (Table 1 names), ``model`` full, reduced or simplified, ``rate_hz``
    the period's rate. ``t0_ns`` is the stamp of period 0 and ``wall0_ns`` the monotonic time
    it stands for (real time). ``noise`` the standard deviations of the sensors (z [m],
    z_dot [m/s], pressures [Pa]), drawn from ``seed``. See the module docstring.
    """

    def __init__(self, params: Params, model: str = 'simplified', rate_hz: float = 1000.0, *,
                 lockstep: bool = False, watchdog_periods: int = 20, initial_z: float = 0.0,
                 t0_ns: int = 0, wall0_ns: int = 0, duration: float = 0.0,
                 wait_subscribers: int = 1, start_delay: float = 0.5,
                 clock_period: float = 0.01, resend_period: float = 0.05,
                 noise: tuple[float, float, float] = (0.0, 0.0, 0.0), seed: int = 0,
                 fault: str = 'none', fault_time: float = 0.0,
                 real_time_factor: float = 0.0) -> None:
        if not isinstance(params, Params):
            raise InputError(f'`params` must be a Params, got {type(params).__name__}')
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise InputError(f'`rate_hz` = {rate_hz!r} must be a positive number of Hz')
        if len(noise) != 3 or not all(math.isfinite(s) and s >= 0 for s in noise):
            raise InputError(f'`noise` = {noise!r} must be three standard deviations >= 0')
        for name, v in (('duration', duration), ('start_delay', start_delay),
                        ('clock_period', clock_period), ('resend_period', resend_period)):
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f'`{name}` = {v!r} s must be finite and >= 0')
        if not (math.isfinite(real_time_factor) and real_time_factor >= 0):
            raise InputError(f'`real_time_factor` = {real_time_factor!r} must be finite and >= 0 '
                             '(0: as fast as the loop runs)')
        self.params = params
        self.model = model
        self.plant = Plant(params, model)
        self.x = self.plant.equilibrium(z=float(initial_z))
        self._x_next = self.x.copy()
        names = self.plant.state_names
        self._iz, self._iv = names.index('z'), names.index('z_dot')
        self._ipa, self._ipb = names.index('p_CP'), names.index('p_CT')
        self._ixv = names.index('x') if 'x' in names else -1
        self.dt = 1.0 / float(rate_hz)
        self.dt_ns = int(round(self.dt * 1e9))
        self.lockstep = bool(lockstep)
        self.t0_ns = int(t0_ns)
        self._wall0_ns = int(wall0_ns)
        self.duration = float(duration) if self.lockstep else 0.0
        self.wait_subscribers = int(wait_subscribers)
        self.start_delay = float(start_delay)
        self.resend_period = float(resend_period)
        self._clock_every = max(1, int(round(float(clock_period) / self.dt)))
        self._A_p = float(params['A_p'])
        self.i_limit = 2.0 * float(params['i_rated'])
        self._rng = np.random.default_rng(int(seed))
        self._rng_load = np.random.default_rng([int(seed), 1])     # the load cell's own
        self._noise = tuple(float(s) for s in noise)
        self.specimen = Specimen(params)
        self.plant.set_load(self.specimen.stiffness, self.specimen.damping)
        self._load_noise = float(params['load_cell_noise'])
        self.watchdog_periods = 1
        self.fault = 'none'
        self.fault_time = 0.0
        self.configure(watchdog_periods=watchdog_periods, fault=fault, fault_time=fault_time)
        self.u = np.zeros(2)
        self.i_cmd = 0.0         # the latest accepted command, clamped [A]
        self.applied = 0.0       # current applied over the last period [A]
        self.k = 0
        self.started = self.lockstep     # real time: once the state has its subscribers
        self.armed = False       # a first command has come
        self.watchdog = Episodes()     # over watchdog_periods: the valve zeroed
        # real time: the piston's extremes from the first command on (figures): |F|, |i|, the
        # largest step of i from one period to the next [N, A, A], z's least and most [m]
        # (not in lock-step: a microsecond a step is 4 % of a virtual test's period)
        self._peaks = [0.0, 0.0, 0.0, math.inf, -math.inf]
        self._i_prev = 0.0
        self.late = Episodes()         # over LATE_PERIODS: counted
        self.counts = dict.fromkeys(('non_finite', 'future', 'stale', 'not_current'), 0)
        self.model_faults = 0
        self._failing = False
        self.overruns = 0
        self.resends = 0
        self.finished = False
        self.tick_fresh = False  # real time: a fresh command came before the latest tick
        self._i_tick = 0.0       # real time: the current the latest tick allows [A]
        self._fresh = False
        self._last_cmd_stamp = -1
        self._last_rx = 0.0
        self._first_rx = self._last_step = math.nan
        self._fault_on = False
        self._fault_hold = (0.0, 0.0, 0.0, 0.0)   # frozen z, z_dot; stuck current; load
        self._last_load = 0.0    # the load cell's last reading [N]
        self._first_due: float | None = None  # lock-step: when the first state goes out
        self._sent_first = False
        self._last_progress = 0.0
        # lock-step pace: wall seconds per period (0: none); the wall time and period it
        # counts from; the wall time the held state is due at (None: none held)
        self._pace = self.dt / real_time_factor if self.lockstep and real_time_factor else 0.0
        self._pace_wall = 0.0
        self._pace_k = 0
        self._held_until: float | None = None
        self.paused = False
        self.notes: list[tuple[str, str]] = []

    # -- configuration -----------------------------------------------------------------------
    def configure(self, *, watchdog_periods: int | None = None, fault: str | None = None,
                  fault_time: float | None = None) -> None:
        """Change what may change while running (checked): the watchdog and the fault."""
        if watchdog_periods is not None:
            if int(watchdog_periods) != watchdog_periods or watchdog_periods < 1:
                raise InputError(f'`watchdog_periods` = {watchdog_periods!r} must be a whole '
                                 'number >= 1')
            self.watchdog_periods = int(watchdog_periods)
        if fault is not None:
            if fault not in FAULTS:
                raise InputError(f'`fault` = {fault!r} is not one of {list(FAULTS)}')
            self.fault = fault
        if fault_time is not None:
            if not (math.isfinite(fault_time) and fault_time >= 0):
                raise InputError(f'`fault_time` = {fault_time!r} s must be finite and >= 0')
            self.fault_time = float(fault_time)

    def set_params(self, params: Params) -> None:
        """
        Rebuild the model with ``params``, keeping the state (a live parameter change).

        A change of the specimen's parameters installs a new specimen; otherwise the one in
        the load string stays, its crack and stiffness as they are.
        """
        new_specimen = any(params[n] != self.params[n] for n in SPECIMEN_PARAMS)
        self.params = params
        self.plant = Plant(params, self.model)
        self._A_p = float(params['A_p'])
        self.i_limit = 2.0 * float(params['i_rated'])
        self._load_noise = float(params['load_cell_noise'])
        if new_specimen:
            self.specimen = Specimen(params)
        self.plant.set_load(self.specimen.stiffness, self.specimen.damping)

    # -- time --------------------------------------------------------------------------------
    def stamp_ns(self, k: int | None = None) -> int:
        """Return the stamp of period ``k`` (default: the current one) [ns]."""
        return self.t0_ns + (self.k if k is None else k) * self.dt_ns

    # -- commands ----------------------------------------------------------------------------
    def command(self, stamp_ns: int, i: float, now: float) -> str:
        """
        Take a command stamped ``stamp_ns`` of ``i`` A that arrived at ``now`` [s].

        Returns what became of it: ``applied``, or the rule that refused it (``non_finite``,
        ``future``, ``stale``, ``not_current``; each counted). In lock-step an applied command
        steps one period.
        """
        current = self.stamp_ns()
        if not math.isfinite(i):
            verdict = 'non_finite'
        elif stamp_ns > current or (stamp_ns == current and self.held):
            # adopting a command from after the latest state would make every true command
            # look stale until the watchdog zeroes the valve for good (a held state is not
            # sent yet)
            verdict = 'future'
        elif stamp_ns <= self._last_cmd_stamp or (self.k == 0 and not self.lockstep):
            # a real-time answer to another run must not arm the watchdog
            verdict = 'stale'
        elif self.lockstep and (stamp_ns != current or self.finished):
            verdict = 'not_current'
        else:
            verdict = 'applied'
        if verdict != 'applied':
            self.counts[verdict] += 1
            return verdict
        self._last_cmd_stamp = stamp_ns
        self.i_cmd = min(max(i, -self.i_limit), self.i_limit)
        self._last_rx = now     # before arming: a loop thread may tick in between
        self._fresh = True
        if not self.armed:
            self.armed = True
            self._first_rx = now
        if self.lockstep:
            self._last_progress = now
            self.step(self.i_cmd)
            self._last_step = now
            if self.paused:
                self._held_until = math.inf
            elif self._pace and not self.finished:
                self._hold(now)
        return verdict

    # -- real time ---------------------------------------------------------------------------
    def start(self, now_ns: int, subscribers: int) -> bool:
        """
        Start once the state has ``wait_subscribers`` subscribers; say if started.

        Time restarts there on the wall grid's whole periods (a grid started at this tick's
        wake-up would put the next on-time wake-ups a little before their period's end).
        """
        if self.started or subscribers < self.wait_subscribers:
            return self.started
        self.started = True
        periods = (now_ns - self._wall0_ns) // self.dt_ns
        self._wall0_ns += periods * self.dt_ns
        self.t0_ns += periods * self.dt_ns
        return True

    def tick(self, now_ns: int) -> int:
        """
        Real time: return how many periods are due at ``now_ns``; decide their current.

        Step them with :meth:`step` (no argument: the current the watchdog allows), each
        followed by its :meth:`sample`. A new trip is the newest of :attr:`trip_log`.
        """
        n = (now_ns - self._wall0_ns) // self.dt_ns - self.k
        if n <= 0:
            return 0
        due_ns = self._wall0_ns + (self.k + 1) * self.dt_ns     # before any resync below
        if n > MAX_CATCHUP:      # far behind: move the grid on (a gap in the stamps)
            self.overruns += 1
            self._wall0_ns += (n - 1) * self.dt_ns
            self.t0_ns += (n - 1) * self.dt_ns
            n = 1
        now = now_ns * 1e-9
        self.tick_fresh, self._fresh = self._fresh, False
        age = now + self.dt - self._last_rx   # the command's age at the coming period's end
        if not self.armed:
            self._i_tick = 0.0
            return int(n)
        # an on-time tick's age: when only this tick's lateness (the machine) makes the
        # command too old, it is counted apart, until a tick finds it too old on time as well
        # (a controller that has stopped)
        on_time = due_ns * 1e-9 + self.dt - self._last_rx
        said = (now, (now_ns - due_ns) * 1e-6, (now - self._last_rx) * 1e3)
        self.late.judge(age, on_time, LATE_PERIODS * self.dt, *said)
        zero = self.watchdog.judge(age, on_time, self.watchdog_periods * self.dt, *said)
        self._i_tick = 0.0 if zero else self.i_cmd
        return int(n)

    @property
    def tripped(self) -> bool:
        """Say whether the watchdog holds the valve at zero now."""
        return self.watchdog.on

    @property
    def trips(self) -> int:
        """Return the watchdog trips so far."""
        return self.watchdog.count

    @property
    def trips_late_tick(self) -> int:
        """Return how many of those the axis's own late tick made (see :class:`Episodes`)."""
        return self.watchdog.late_tick

    @property
    def trip_log(self) -> deque:
        """Return the newest watchdog trips (:attr:`Episodes.log` of the watchdog)."""
        return self.watchdog.log

    # -- lock-step ---------------------------------------------------------------------------
    def poll(self, now: float, subscribers: int) -> str | None:
        """
        Lock-step housekeeping at ``now`` [s]; return what to do.

        ``matched`` (the subscribers are there: the first state goes out in ``start_delay``),
        ``first`` (send the first state now), ``release`` (the held state's time has come:
        send it), ``resend`` (no answer for ``resend_period``: send the state again) or None.
        """
        if self._first_due is None:
            if subscribers >= self.wait_subscribers:
                self._first_due = now + self.start_delay
                return 'matched'
        elif not self._sent_first:
            if now >= self._first_due and not self.paused:
                self._sent_first = True
                self._last_progress = self._pace_wall = now
                self._pace_k = self.k
                return 'first'
        elif self._held_until is not None:
            if now >= self._held_until:
                self._held_until = None
                self._last_progress = now
                return 'release'
        elif now - self._last_progress >= self.resend_period and not self.finished:
            self.resends += 1
            return 'resend'
        return None

    def pause(self, on: bool, now: float) -> None:
        """
        Lock-step: hold the loop still from the next state on (``on``), or go on at ``now``.

        A held state goes at the next :meth:`poll`; a pace counts from there. Raises
        :class:`InputError` for a real-time axis, which runs on the clock.
        """
        if on and not self.lockstep:
            raise InputError('`paused`: only a lock-step axis holds still (a real-time one '
                             'runs on the clock)')
        on = bool(on)
        if on == self.paused:
            return
        self.paused = on
        if self._held_until is not None:
            self._held_until = math.inf if on else now
        if not on and self._sent_first:
            self._pace_wall, self._pace_k = now, self.k

    @property
    def poll_period(self) -> float:
        """Lock-step: how often the node calls :meth:`poll` [s] (more often at a pace)."""
        return min(self.resend_period, PACE_TICK) if self._pace else self.resend_period

    @property
    def held(self) -> bool:
        """Lock-step at a real-time factor: say if the current state waits for its time."""
        return self._held_until is not None

    def _hold(self, now: float) -> None:
        """Hold the new state until its time on the pace (restarting a pace far behind)."""
        due = self._pace_wall + (self.k - self._pace_k) * self._pace
        if now - due > PACE_CREDIT:       # far behind (a stall): no race to catch up
            self._pace_wall, self._pace_k = now, self.k
        elif due > now:
            self._held_until = due

    def clock_due(self) -> bool:
        """Lock-step: say if the current state carries ``/clock`` (each clock period, the last)."""
        return self.finished or self.k % self._clock_every == 0

    # -- stepping ----------------------------------------------------------------------------
    def step(self, i: float | None = None) -> bool:
        """
        Step one period with ``i`` A (default: what the latest :meth:`tick` allows).

        False if the model step failed (the state left the model: non-finite, or the piston
        outside the cylinder): the state is held, the command zeroed, and it is counted.
        """
        if i is None:
            i = self._i_tick
        if self.fault != 'none' or self._fault_on:
            self._fault_check()
            if self._fault_on and self.fault == 'stuck_valve':
                i = self._fault_hold[2]
        self.u[0] = self.applied = i
        nxt = self._x_next
        nxt[:] = self.x
        xs = self.plant.advance(nxt, self.u, self.dt)      # the unchecked fast path
        ok = xs is not None
        if ok:
            self.x, self._x_next = nxt, self.x
            self._failing = False
            if self.armed and not self.lockstep:    # the model's own extremes (real time)
                pk, zt = self._peaks, float(nxt[self._iz])
                pk[0] = max(pk[0], abs(self._A_p * float(nxt[self._ipa] - nxt[self._ipb])))
                pk[1] = max(pk[1], abs(i))
                pk[2] = max(pk[2], abs(i - self._i_prev))
                pk[3] = min(pk[3], zt)
                pk[4] = max(pk[4], zt)
            self._i_prev = i
            sp = self.specimen
            if not sp.broken and sp.present:
                if sp.update(sp.force(xs[self._iz], xs[self._iv])):
                    self.plant.set_load(sp.stiffness, sp.damping)
                    if sp.broken:
                        self.notes.append(('warning', f'the specimen fractured after '
                                           f'{sp.cycles:g} cycles, at {self.k * self.dt:.6g} s'))
        else:
            self.model_faults += 1
            self.i_cmd = 0.0
            if not self._failing:
                self._failing = True
                self.notes.append(('error', f'model step failed at i = {i!r} A (the state '
                                   'left the model: non-finite, or the piston outside the '
                                   'cylinder), state held'))
        self.k += 1
        if self.duration > 0:      # lock-step only
            self.finished = self.k * self.dt >= self.duration - 1e-12
        return ok

    def _fault_check(self) -> None:
        """Start or end the injected fault at this period."""
        want = self.fault != 'none' and self.k * self.dt >= self.fault_time
        if want == self._fault_on:
            return
        self._fault_on = want
        xs = self.x.tolist()
        self._fault_hold = (xs[self._iz], xs[self._iv], self.applied, self._last_load)
        p = self.params
        if self.fault == 'lost_pressure' or self.plant.params['p_s'] != p['p_s']:
            sup = LOST_SUPPLY if want and self.fault == 'lost_pressure' else p['p_s']
            self.plant = Plant(p.replace(p_s=sup, p_t=min(p['p_t'], 0.5 * sup)), self.model)
        self.notes.append(('warning', f'fault {self.fault} injected at {self.k * self.dt:.6g} s'
                           if want else 'injected fault ended'))

    # -- sensors -----------------------------------------------------------------------------
    def sample(self) -> Sample:
        """Return what the sensors read now: noise and faults on, the model's state exact."""
        xs = self.x.tolist()
        nz, nv, npr = self._noise
        e = self._rng.standard_normal(4).tolist() if (nz or nv or npr) else _ZEROS
        z, v = xs[self._iz] + nz * e[0], xs[self._iv] + nv * e[1]
        if self._fault_on:
            if self.fault == 'frozen_sensor':
                z, v = self._fault_hold[0], self._fault_hold[1]
            elif self.fault == 'nan_sensor':
                z = v = math.nan
        sp = self.specimen
        load = sp.force(xs[self._iz], xs[self._iv])
        if self._load_noise:
            load += self._load_noise * float(self._rng_load.standard_normal())
        if self._fault_on and self.fault in ('frozen_load_cell', 'nan_load_cell',
                                             'drifting_load_cell'):
            if self.fault == 'drifting_load_cell':
                load += LOAD_DRIFT * (self.k * self.dt - self.fault_time)
            else:
                load = self._fault_hold[3] if self.fault == 'frozen_load_cell' else math.nan
        self._last_load = load
        state = AxisState(self.stamp_ns(), z, v, self._A_p * (xs[self._ipa] - xs[self._ipb]),
                          xs[self._ixv] if self._ixv >= 0 else math.nan, self.applied,
                          load if sp.present else math.nan)
        return Sample(state, xs[self._ipa] + npr * e[2], xs[self._ipb] + npr * e[3], load)

    def true_load(self) -> float:
        """Return the force the specimen carries now [N] (the model's, not the load cell's)."""
        xs = self.x
        return self.specimen.force(float(xs[self._iz]), float(xs[self._iv]))

    def load(self, sample: Sample) -> Load:
        """Return the load cell's message of a sample (stamped as its state)."""
        return Load(sample.state.stamp_ns, sample.load)

    @property
    def fault_active(self) -> bool:
        """Say if the injected fault acts now."""
        return self._fault_on

    # -- figures -----------------------------------------------------------------------------
    def figures(self, now: float) -> dict:
        """
        Return the axis's figures at ``now`` [s] (the node adds its loop timing).

        In real time with the piston's extremes from the first command on, the model's own (not
        the sensors'): ``force_peak_n`` (|A_p p_L|), ``current_peak_a`` and ``current_step_a``
        (the current the valve had, and its largest step from one period to the next),
        ``z_range_m`` (the travel).
        """
        last = self.trip_log[-1] if self.trip_log else None
        f = {'steps': self.k, 'sim_time_s': self.k * self.dt,
             'watchdog': 'tripped' if self.tripped else 'ok' if self.armed else 'waiting',
             'watchdog_trips': self.trips, 'watchdog_trips_late_tick': self.trips_late_tick,
             'watchdog_latency_ms': last.command_age_ms if last else math.nan,
             'watchdog_tick_late_ms': last.tick_late_ms if last else math.nan,
             'late_commands': self.late.count, 'late_commands_late_tick': self.late.late_tick,
             'force_peak_n': self._peaks[0], 'current_peak_a': self._peaks[1],
             'current_step_a': self._peaks[2],
             'z_range_m': max(0.0, self._peaks[4] - self._peaks[3]),
             'current_a': float(self.u[0]), 'bad_commands': self.counts['non_finite'],
             'stale_commands': self.counts['stale'] + self.counts['not_current'],
             'future_commands': self.counts['future'], 'model_faults': self.model_faults,
             'overruns': self.overruns, 'resends': self.resends, 'finished': self.finished,
             'paused': self.paused,
             'fault': self.fault if self._fault_on else 'none'}
        if self.specimen.present:
            f.update(self.specimen.figures())
        if self.lockstep:
            end = self._last_step if self.finished else now
            span = end - self._first_rx
            f['steps_per_s'] = (self.k - 1) / span if self.k > 1 and span > 0 else math.nan
        return f
