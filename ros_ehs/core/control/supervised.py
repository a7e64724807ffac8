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
The supervised axis controller: the safety supervisor in front of the control modes.

:class:`~ros_ehs.core.control.safety.Supervisor` in front of the displacement loop
(:class:`~ros_ehs.core.control.controller.Controller`) and the force loop and specimen protect
(:mod:`ros_ehs.core.control.modes`), one call per control period. This is what the controller
node runs and what :func:`ros_ehs.core.sim.closed_loop.run_closed_loop` runs with
``supervised=True``: the same arithmetic in process and over DDS. While the supervisor
demands no power (power off, hydraulics off, waiting for a finite position) the command is 0
A and the loops stay at rest, so power returns without a kick.

**Which loop drives the valve.** The force loop when ``control_mode`` is ``force`` and the
supervisor runs (or ramps on); the displacement loop otherwise: always in a hold or a stop
(an interlock's actions are in displacement), and with specimen protect's limit on its
command when ``control_mode`` is ``displacement_force_limited``. Each change of the driving
loop is a handover: the new loop takes the last command over and blends from its measured
value (:mod:`ros_ehs.core.control.modes`); the displacement loop after the force loop blends
from the measured position over ``mode_blend_time`` (:meth:`Supervisor.blend_from`).

**Mode switches** (:meth:`AxisController.set_mode`): refused, with the reason, to a mode
that needs the load cell while it has no valid reading (``load_ok``), or while an interlock
(hold, stop, power off) is latched; to specimen protect also while the load is beyond
``protect_force`` (the limit would pull the piston back at once). Each switch, accepted or
refused, is an event (kind ``mode`` or ``mode_refused``). A trip of ``specimen_break`` or
``load_feedback`` whose action holds or more ends force control: the mode becomes
``displacement`` (an event), and force control comes back only by a switch.

**A fault's hold keeps the load where it was.** A detector whose action holds, tripping in
force control while the load cell is sound (a load limit, a force error), holds the load
measured at the trip with the force loop; one that ends force control (the load cell lost or
frozen, a break) holds the piston where it was, in displacement, the displacement loop
starting from rest (no command carried over from the force loop, which would drive the piston
on: the valve closes). A hold the axis does not obey (a stuck valve; in force control also
a piston that runs from where the hold began: a load path lost) trips ``hold_error``
(:meth:`~ros_ehs.core.control.safety.Supervisor.judge_hold`), power off by default.

A displacement loop whose reference carries a force but no position (NaN: a force reference)
holds the position measured when that began; a reference with neither is bad input (the
PID's policy: 0 A and ``fault``).

**A command not applied as the loop asked** (the driving loop's output at ``u_max``, or
specimen protect's limit) begins a clipping episode: an event of kind ``clipped``
(``detector`` says which: ``saturation``, ``specimen_protect``), and ``unclipped`` once no
command has been clipped for ``CLIP_QUIET`` s. From the cycles between the two a procedure's
compensation learns only what asks less of the rig (a larger command learnt from levels the
valve could not give would wind it further into the limit); the episode, not each period, is
an event, so a rig clipped at every peak sends two. The command's rate limit is not counted:
it is a rail for a late loop (whose own detector is ``loop_timing``), and it trims a
triangle's corner for a period every cycle on the default rig (the velocity feedforward's
step there), which peak/valley control corrects as it should.
"""

from __future__ import annotations

import math

from ros_ehs.core.control.controller import Controller, DeltaP
from ros_ehs.core.control.modes import ForceLimit, ForceLoop, LOAD_MODES, MODES
from ros_ehs.core.control.safety import Demand, Event, SafetyConfig, Supervisor
from ros_ehs.core.model.coefficients import null_load_gain
from ros_ehs.core.params import Params

__all__ = ['AxisController', 'CLIP_QUIET']

#: A clipping episode ends when no command has been clipped for this long [s].
CLIP_QUIET = 0.5

#: Trips that end force control when their action holds or more.
_ENDS_FORCE = ('specimen_break', 'load_feedback')
_ACTING = ('hold', 'stop', 'power_off')


class AxisController:
    """Detectors, actions and ramp-on around the control modes (see the module docstring)."""

    def __init__(self, params: Params, dt: float = 1e-3, enabled: bool = True) -> None:
        self.ctrl = Controller(params, dt)
        self.force = ForceLoop(params, dt)
        self.protect = ForceLimit(params, dt)
        self.supervisor = Supervisor(SafetyConfig.from_params(params), dt, enabled)
        self.demand = Demand('waiting', math.nan, 0.0, False)
        self.events: list[Event] = []     # the newest step's events
        self.mode = str(params['control_mode'])
        self.driving: str | None = None   # the loop that drove the valve last, None: 0 A
        self.limited = False              # specimen protect limited the last command
        self.blend_time = float(params['mode_blend_time'])
        # a force hold's delta-P damping (its filter from the hold's first state on)
        self.hold_dp = DeltaP(params['hold_dp_gain'], params['dp_tau'])
        self.hold_dp_max = float(params['hold_dp_max'])
        self.i_null_per_n = null_load_gain(params)   # the valve's null under load [A/N]
        self.command_rate = float(params['command_rate'])
        self.rate_limited = 0             # commands the rate limit changed
        self._sent = math.nan             # the last command returned [A]
        self._z_hold = math.nan           # the position held without a position reference
        self._measured = (math.nan, math.nan)    # the newest (z, load)
        self._f_hold = math.nan           # the load a hold in force control holds [N]
        self._z_fhold = math.nan          # ... and where the piston was then [m]
        self.clipping = False             #: a clipping episode is under way
        self._clip_at = 0                 # the stamp of its last clipped command [ns]

    @property
    def output(self) -> float:
        """Return the last command [A]."""
        return self.force.output if self.driving == 'force' else self.ctrl.output

    @property
    def fault(self) -> bool:
        """Return True after a non-finite input to the driving loop, until a finite one."""
        return (self.force.pid.fault if self.driving == 'force' else self.ctrl.fault)

    @property
    def saturated(self) -> bool:
        """Return True when the driving loop's last command was at its limit."""
        return (self.force.pid.saturated if self.driving == 'force' else
                self.ctrl.pid.saturated)

    def set_params(self, params: Params) -> None:
        """Apply new gains, feedforward values, limits and actions (latches stay)."""
        self.ctrl.set_params(params)
        self.force.set_params(params)
        self.protect.set_params(params)
        self.supervisor.set_config(SafetyConfig.from_params(params))
        self.blend_time = float(params['mode_blend_time'])
        self.hold_dp.set_gains(params['hold_dp_gain'], params['dp_tau'])
        self.hold_dp_max = float(params['hold_dp_max'])
        self.i_null_per_n = null_load_gain(params)
        self.command_rate = float(params['command_rate'])

    def restart(self) -> None:
        """Start a new run (epoch): the loops from rest, ramp on again; latches stay."""
        self._rest()
        self.supervisor.restart()

    def restart_loops(self) -> None:
        """Put the loops at rest (0 A): the next powered state hands the valve over again."""
        self._rest()

    def _rest(self) -> None:
        self.ctrl.reset()
        self.force.release()
        self.force.pid.reset()
        self.protect.reset()
        self.driving = None
        self.limited = False
        self._z_hold = math.nan
        self._f_hold = math.nan

    # -- modes -------------------------------------------------------------------------------
    def check_mode(self, mode: str, load_ok: bool) -> str:
        """Return why a switch to ``mode`` is refused now ('' when it is not)."""
        if mode not in MODES:
            return f'unknown control mode {mode!r}; known: {", ".join(MODES)}'
        if mode == self.mode:
            return ''
        sup = self.supervisor
        if mode in LOAD_MODES:
            if not load_ok:
                return (f'{mode} needs the load cell, and it has no valid reading (missing, '
                        'stale or non-finite)')
            if sup.action in _ACTING:
                return f'interlock latched ({", ".join(sup.tripped())}: {sup.action}): reset first'
            load = self._measured[1]
            if mode == 'displacement_force_limited' and \
                    abs(load) > self.protect.limit:
                return (f'the load {load:.6g} N is beyond protect_force '
                        f'{self.protect.limit:g} N')
        return ''

    def set_mode(self, mode: str, stamp_ns: int, load_ok: bool) -> tuple[bool, str, Event]:
        """Switch the control mode (bumpless, at the next state): (ok, why, event)."""
        why = self.check_mode(mode, load_ok)
        if why:
            return False, why, Event(stamp_ns, 'mode_refused', mode, math.nan, math.nan, '',
                                     self.supervisor.action, f'to {mode} refused: {why}')
        was, self.mode = self.mode, mode
        what = (f'control mode {mode} (from {was}): blending over {self.blend_time:g} s'
                if mode != was else f'control mode {mode} already')
        return True, what, Event(stamp_ns, 'mode', mode, math.nan, math.nan, '',
                                 self.supervisor.action, what)

    # -- per period ----------------------------------------------------------------------------
    def step(self, stamp_ns: int, z: float, z_dot: float, force: float, z_traj: float,
             v_traj: float, load: float = math.nan, f_traj: float = math.nan,
             applied: float = math.nan) -> float:
        """
        Return the servo current [A] for one state; ``events`` holds what happened.

        ``load``: the load cell [N] (NaN: none, or not valid); ``f_traj``: the force
        reference [N] (NaN: none); ``applied``: the current the state says the valve had
        over the period that ended here (NaN: not known), for the command's rate limit.
        """
        i = self._step(stamp_ns, z, z_dot, force, z_traj, v_traj, load, f_traj)
        self._sent = i = self._rate_limit(i, applied)
        self._judge_clip(stamp_ns, i)
        return i

    def _judge_clip(self, stamp_ns: int, i: float) -> None:
        """Begin or end a clipping episode (module docstring)."""
        why = '' if not self.demand.power or self.driving is None else (
            'saturation' if self.saturated else 'specimen_protect' if self.limited else '')
        if why:
            self._clip_at = stamp_ns
            if not self.clipping:
                self.clipping = True
                self.events.append(Event(
                    stamp_ns, 'clipped', why, float(i), math.nan, 'A', self.supervisor.action,
                    f'the command is not what the {self.driving} loop asked ({why}): '
                    f'{i * 1e3:.4g} mA; no compensation raises its command meanwhile'))
        elif self.clipping and stamp_ns - self._clip_at > CLIP_QUIET * 1e9:
            self.clipping = False
            self.events.append(Event(
                stamp_ns, 'unclipped', '', float(i), math.nan, 'A', self.supervisor.action,
                f'every command applied as asked for {CLIP_QUIET:g} s'))

    def _rate_limit(self, i: float, applied: float) -> float:
        """
        Return ``i`` [A] within ``command_rate`` times the period of the valve's current.

        The valve's current is the last command, or ``applied`` when that differs from it
        by more than the period's step (the valve does not have the last command: a plant's
        watchdog zeroed it while the loop stalled). 0 A (hydraulics off, a power-off) is not
        limited, nor a command with nothing to start from. A limited command is the driving
        loop's (its PID does not integrate further into the limit).
        """
        r = self.command_rate
        if not (r > 0) or i == 0.0 or self.driving is None or not self.demand.power or \
                not math.isfinite(i):
            return i
        base, step = self._sent, r * self.supervisor.dt
        if math.isfinite(applied) and not abs(applied - base) <= step:
            base = applied
        if not math.isfinite(base):
            return i
        u = min(max(i, base - step), base + step)
        if u != i:
            self.rate_limited += 1
            (self.force.pid if self.driving == 'force' else self.ctrl.pid).limited(u)
        return u

    def _step(self, stamp_ns: int, z: float, z_dot: float, force: float, z_traj: float,
              v_traj: float, load: float, f_traj: float) -> float:
        """Return the command of one state before the rate limit (:meth:`step`)."""
        sup = self.supervisor
        self._measured = (z, load)
        if self.driving == 'force' and self.mode != 'force':   # switched away: blend in z
            sup.blend_from(z, self.blend_time)
        d, events = sup.update(stamp_ns, z, z_dot, force, z_traj, v_traj, self.output,
                               self.saturated, load=load, needs_load=self.mode in LOAD_MODES,
                               track_position=self.mode != 'force', limited=self.limited)
        self.events = events
        for e in events:
            if e.kind == 'trip' and e.detector in _ENDS_FORCE and e.action in _ACTING and \
                    self.mode != 'displacement':
                what = (f'control mode displacement (from {self.mode}): {e.detector} '
                        f'tripped')
                self.mode = 'displacement'
                events.append(Event(stamp_ns, 'mode', 'displacement', math.nan, math.nan,
                                    '', e.action, what))
        self.demand = d
        if not d.power:
            if self.driving is not None or self.ctrl.pid.prev_error is not None:
                self._rest()
            return 0.0
        if d.mode == 'hold' and self.mode == 'force' and math.isfinite(load):
            if not math.isfinite(self._f_hold):     # the trip's period: hold its load
                # (a load limit tripped ahead of the reading: the limit, braked less)
                held, brake = sup.load_trip or (load, 1.0)
                self._f_hold, self._z_fhold = held, z
                self.force.hold(held, brake)
                # the delta-P's memory starts at the held load (at rest, the hydraulic
                # force that holds it): the term damps the stop about the load held, not
                # about the hydraulic force at the trip, which a trip ahead of the load
                # leaves some 400 N short of the limit and which pulled the load back there
                self.hold_dp.reset(memory=held)
            f_traj = math.nan                       # the loop holds what hold() gave it
            want = 'force'
        else:
            if math.isfinite(self._f_hold):
                self.force.release()
            self._f_hold = math.nan
            want = 'force' if (self.mode == 'force' and d.mode in ('run', 'ramp')) else \
                'displacement'
        if want != self.driving:
            self._handover(want, stamp_ns, z, load, d.mode == 'ramp',
                           rest=d.mode in ('hold', 'stop'), force=force)
        if d.mode == 'hold':
            force_hold = want == 'force'
            e = (self._f_hold - load) if force_hold else (d.z_ref - z)
            new = sup.judge_hold(stamp_ns, e, force_hold,
                                 travel=z - self._z_fhold if force_hold else 0.0)
            if new:
                events.extend(new)
                d = self.demand = sup.demand_for(stamp_ns, z, z_traj, v_traj)
                if not d.power:
                    self._rest()
                    return 0.0
        if want == 'force':
            i = self.force.step(stamp_ns, load, f_traj, z)
            if d.mode == 'hold':
                # delta-P damping of the oil column the stop rings: the hydraulic force is
                # collocated with the valve's flow (the load cell, past the piston's mass, is
                # not: fed back as fast, it rang up). Within hold_dp_max: a gain too high for
                # the rig's valve (twice the default on the full model) rings the hold within
                # that current instead of ringing it up
                if not math.isfinite(force):
                    return i
                cap = self.hold_dp_max
                return i - min(max(self.hold_dp.update(force, sup.dt), -cap), cap)
            new = sup.judge_force_error(stamp_ns, self.force.error)
            events.extend(new)
            if new and any(e.action in _ACTING for e in new):   # held from the next state on
                self.demand = sup.demand_for(stamp_ns, z, z_traj, v_traj)
            return i
        return self._displacement(d, z, force, load, f_traj)

    def _handover(self, loop: str, stamp_ns: int, z: float, load: float, ramp: bool,
                  rest: bool = False, force: float = math.nan) -> None:
        u = self.output if self.driving is not None else 0.0
        if rest and loop == 'displacement':     # a hold or a stop: the valve closes first,
            # to its null under the load the oil holds (the hydraulic force: the load cell
            # may be what tripped): without it the displacement loop's P alone found that
            # current, 12 um (120 N) off the held position on the fatigue rig
            u = self.i_null_per_n * force if math.isfinite(force) else 0.0
        if loop == 'force':     # coming on (a ramp-on) over ramp_time, a switch over the blend
            self.force.start(stamp_ns, load, u, self.supervisor.config.ramp_time if ramp
                             else self.blend_time)
            self.ctrl.reset()
        elif self.driving == 'force' or rest:
            self.ctrl.reset()
            self.ctrl.pid.handover(u)
        self.protect.reset()
        self.limited = False
        self._z_hold = math.nan
        self.driving = loop

    def _displacement(self, d: Demand, z: float, force: float, load: float,
                      f_traj: float) -> float:
        z_ref, v_ref = d.z_ref, d.v_ref
        if not math.isfinite(z_ref) and math.isfinite(f_traj) and d.mode in ('run', 'ramp'):
            # a reference without a position (a force reference): hold where it took over
            if not math.isfinite(self._z_hold):
                self._z_hold = z
            z_ref, v_ref = self._z_hold, 0.0
        else:
            self._z_hold = math.nan
        i = self.ctrl.step(z_ref, v_ref, z, force=force)
        self.limited = False
        if self.mode == 'displacement_force_limited':
            u = self.protect.apply(i, load)
            if u != i:
                self.ctrl.pid.limited(u)
                self.limited = True
                i = u
        return i
