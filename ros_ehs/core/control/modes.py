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
r"""
The control modes beside the displacement loop: the force loop and specimen protect.

* ``displacement``: the position loop of :mod:`ros_ehs.core.control.controller`.
* ``force``: :class:`ForceLoop`, a PIDF on the load cell. ``force_kp``, ``force_ki``,
  ``force_kd`` act on the force error ``F_ref - F`` [N] (the derivative filter, the output
  limit and the anti-windup are the displacement loop's). Its feedforward is the flow the force
  rate needs: a force that changes at :math:`\dot F` compresses the load train and the oil
  column, so the piston must move at

  .. math:: v_{eq} = \dot F_{ref} \left(\frac{1}{k_L} + \frac{l_{iac} + z}{2 \beta_e A_p}\right)

  (the specimen's stiffness, its load train included, in series with the two chambers' oil at
  the piston's position); the feedforward is ``force_ff`` times the current of that flow,
  ``A_p v_eq / (K_q K_x)``. It leaves out the friction terms of eq. (20): their estimate of
  the pressure force (eq. 11, the current integrated while the piston is still) is the
  friction's only on a free piston; on a specimen the specimen holds that force, and the
  terms turned a held load into a 3 % transient at a switch (measured). (It leaves out the
  valve's flow factor at the load pressure too: the odd harmonics a
  compensation of it puts into the command meet the loop's resonance at a 20 Hz test's third
  harmonic, and cost more than they correct; amplitude control takes the rest.) Without a
  specimen stiffness (``k_L`` = 0) there is no model: no feedforward.
* ``displacement_force_limited`` (specimen protect): the displacement loop, its command
  limited by :class:`ForceLimit` to what two proportional force loops towards
  ``+-protect_force`` allow: ``i_lo <= i <= i_hi`` with
  ``i_hi = force_kp (P - F) - force_kd dF/dt``, ``i_lo = force_kp (-P - F) - force_kd dF/dt``
  (a min/max override selector, as test controllers build their limit loops): far from the
  limit the displacement loop drives; near it the force loop takes over and, the valve being
  an integrator of flow, settles the force at the limit.

**Blends.** The loop that takes the valve over starts from the measured value of its own
signal and blends to its reference with the ramp-on's quintic, over ``mode_blend_time`` at a
mode switch and over ``ramp_time`` when force control comes on with the ramp-on (start,
hydraulics on, a reset); its integrator
takes the command it takes over (:meth:`ros_ehs.core.control.pid.Pid.handover`), so the valve
command is continuous. A reference without a force (NaN: a displacement reference) holds the
force measured when the loop took over.
"""

from __future__ import annotations

import math
from typing import Mapping

from ros_ehs.core.control.pid import Pid, PidGains
from ros_ehs.core.control.safety import ramp_weight
from ros_ehs.core.model.coefficients import flow_gain_kq, null_load_gain

__all__ = ['ForceLimit', 'ForceLoop', 'LOAD_MODES', 'MODES',
           'SPECIMEN_IN_CONTROLLER', 'load_train_compliance']

#: The control modes, in the order of ``control_mode``'s choices.
MODES = ('displacement', 'force', 'displacement_force_limited')
#: The modes that need the load cell.
LOAD_MODES = ('force', 'displacement_force_limited')
#: The specimen's values the controller reads (the controller node declares them too): its
#: stiffness and damping (the force loop's feedforward) and installed position (its limits);
#: the plant's specimen takes more (:data:`ros_ehs.core.sim.axis.SPECIMEN_PARAMS`).
SPECIMEN_IN_CONTROLLER = ('k_L', 'c_L', 'z_L')


def load_train_compliance(params: Mapping[str, object], z: float = 0.0) -> float:
    """
    Return the compliance a force change meets at piston position ``z`` [m/N].

    The specimen's ``1 / k_L`` in series with the chambers' oil, ``(l_iac + z) / (2 beta_e
    A_p)`` (both chambers, at mid-stroke the softest); 0 without a specimen (``k_L`` = 0).
    """
    k = float(params['k_L'])
    if not k > 0:
        return 0.0
    l_iac, beta, a_p = (float(params[n]) for n in ('l_iac', 'beta_e', 'A_p'))
    return 1.0 / k + (l_iac + abs(z)) / (2.0 * beta * a_p)


class ForceLoop:
    """The force loop: PIDF on the load cell, blended in at a handover (module docstring)."""

    def __init__(self, params: Mapping[str, object], dt: float) -> None:
        self.dt = float(dt)
        self.pid = Pid(PidGains.from_params(params, 'force_'))
        self._configure(params)
        self.target = math.nan      # the force the loop tracked last [N]
        self.error = math.nan       # its error [N]
        self.last_ff = 0.0
        self._t0 = 0
        self._blend = 0.0
        self._from = self._hold = math.nan
        self._holding = False      # a fault's hold (hold() to release())
        self._brake = 0.0          # the hold's one-period reversal of the rate's feedforward
        self._mean = 0.0           # the target's mean over the integrator's time constant [N]
        self._prev: float | None = None

    def _configure(self, params: Mapping[str, object]) -> None:
        self.params = params
        self.ff_weight = float(params['force_ff'])
        self.i_per_speed = float(params['A_p']) / (flow_gain_kq(params) * float(params['K_x']))
        self.i_per_load = null_load_gain(params) if self.ff_weight > 0 else 0.0
        # load_train_compliance's terms, for the hot path: 1/k_L, l_iac, 1/(2 beta_e A_p)
        k = float(params['k_L'])
        self._c_spec = 1.0 / k if k > 0 else 0.0
        self._l_iac = float(params['l_iac'])
        self._c_oil = 1.0 / (2.0 * float(params['beta_e']) * float(params['A_p']))
        self.blend_time = float(params['mode_blend_time'])
        self.hold_brake = float(params['hold_brake'])
        g = self.pid.gains
        tau = g.kp / g.ki if g.ki > 0 and g.kp > 0 else 1.0
        self._mean_a = self.dt / (tau + self.dt)

    @property
    def output(self) -> float:
        """Return the last command [A]."""
        return self.pid.last_u

    def set_params(self, params: Mapping[str, object]) -> None:
        """Take new gains bumplessly and the feedforward's values."""
        self.pid.set_gains(PidGains.from_params(params, 'force_'))
        self._configure(params)

    def start(self, stamp_ns: int, load: float, u: float,
              blend_time: float | None = None) -> None:
        """
        Take the valve over at ``stamp_ns`` from command ``u`` [A], the load at ``load``.

        The reference blends in over ``blend_time`` [s] (default ``mode_blend_time``).
        """
        self.release()
        self._brake = 0.0
        self.pid.handover(u)
        self._mean = float(load) if math.isfinite(load) else 0.0
        self._blend = self.blend_time if blend_time is None else float(blend_time)
        self._t0 = int(stamp_ns)
        self._from = self._hold = float(load)
        self._prev = None
        self.target = float(load)

    def hold(self, load: float, brake: float = 1.0) -> None:
        """
        Hold ``load`` [N] from now on (a fault's hold), until :meth:`release`.

        The target steps to ``load`` and no rate is fed forward. For one period the rate's
        feedforward is reversed ``brake`` times ``hold_brake`` over, which closes the spool
        within its lag rather than after it (the oil column the stop excites is damped by the
        axis's delta-P term, ``hold_dp_gain``). ``brake`` is 1 for a hold of the reading; a
        load limit tripped ahead of the load gives the share of a period it came late.
        The integrator takes the valve's null current under ``load`` at once
        (:func:`~ros_ehs.core.model.coefficients.null_load_gain` times the load less the
        target's mean over the integrator's time constant ``force_kp / force_ki``: at rest
        the load pressure unbalances the metering edges' leakage, and the integrator held
        the null of the cycle's mean load). Without the two, the fatigue rig's load sank
        3.5 % of its range under a 9 kN limit's trip while the integrator found that current
        (0.17 s). The null is taken at the hold only: fed forward all the time, it doubled a
        step's overshoot, the integrator winding up on the rise by about the same current.
        """
        self._blend = 0.0
        self._hold = float(load)
        self._brake = -self.hold_brake * brake * self.last_ff
        if math.isfinite(load):
            self.pid.i_term += self.i_per_load * (float(load) - self._mean)
        self._holding = True
        self._prev = None

    def release(self) -> None:
        """End a hold: the reference is the trajectory's again."""
        self._holding = False

    def reference(self, stamp_ns: int, f_traj: float) -> float:
        """Return the force to track at ``stamp_ns``: the blend into ``f_traj`` [N]."""
        if self._holding:                         # a fault's hold: its load, whatever comes
            return self._hold
        f_ref = f_traj if math.isfinite(f_traj) else self._hold
        t = (stamp_ns - self._t0) * 1e-9
        if self._blend > 0 and t < self._blend:
            w = ramp_weight(t / self._blend)[0]
            return self._from + w * (f_ref - self._from)
        return f_ref

    def step(self, stamp_ns: int, load: float, f_traj: float, z: float = 0.0,
             dt: float | None = None) -> float:
        """Return the command [A] for load cell reading ``load`` [N] (the PID's NaN policy)."""
        dt = self.dt if dt is None else dt
        target = self.reference(stamp_ns, f_traj)
        ff = 0.0
        if math.isfinite(target):
            self._mean += self._mean_a * (target - self._mean)
        c = (self._c_spec + (self._l_iac + abs(z)) * self._c_oil) if self._c_spec > 0 and \
            math.isfinite(z) else self._c_spec + self._l_iac * self._c_oil if self._c_spec > 0 \
            else 0.0
        if c > 0.0 and dt > 0 and self._prev is not None:
            v = (target - self._prev) / dt * c
            ff += self.ff_weight * self.i_per_speed * v
        ff += self._brake
        self._brake = 0.0
        if dt > 0:
            self._prev = target
        self.target = target
        self.error = target - load
        self.last_ff = ff
        return self.pid.update(self.error, dt, ff)


class ForceLimit:
    """Specimen protect: the limits two proportional force loops put on a command."""

    def __init__(self, params: Mapping[str, object], dt: float) -> None:
        self.dt = float(dt)
        self.set_params(params)
        self.reset()

    def set_params(self, params: Mapping[str, object]) -> None:
        """Take ``protect_force``, ``force_kp``, ``force_kd`` and ``d_filter_tau``."""
        self.limit = float(params['protect_force'])
        self.kp = float(params['force_kp'])
        self.kd = float(params['force_kd'])
        self.tau = float(params['d_filter_tau'])

    def reset(self) -> None:
        """Forget the rate's memory."""
        self._prev: float | None = None
        self._rate = 0.0
        self.active = False

    def apply(self, u: float, load: float, dt: float | None = None) -> float:
        """Return ``u`` [A] limited for load ``load`` [N]; ``active`` says if it was."""
        dt = self.dt if dt is None else dt
        if not math.isfinite(load):
            self.active = False
            return u
        if self._prev is not None and dt > 0:
            raw = (load - self._prev) / dt
            a = dt / (self.tau + dt) if self.tau > 0 else 1.0
            self._rate += a * (raw - self._rate)
        self._prev = load
        damp = self.kd * self._rate
        hi = self.kp * (self.limit - load) - damp
        lo = self.kp * (-self.limit - load) - damp
        out = min(max(u, lo), hi)
        self.active = out != u
        return out
