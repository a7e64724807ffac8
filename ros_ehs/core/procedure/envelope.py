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
What a rig can do, and the steps of a procedure it cannot: checked when the procedure loads.

:class:`RigEnvelope` takes the rig's parameters (Table 1's names, identified or nominal) and
:func:`check_envelope` names every step that asks for more, with the limit it breaks, so that
a test the rig cannot follow is refused before anything moves rather than driven into an end
stop (a peak/valley compensation asked for the impossible winds its command up without
bound). The limits, each from the model's own parameters:

* **stroke**: every displacement level, with its amplitude, within the position limits and
  at least ``END_MARGIN`` from the end stops (``stroke``);
* **speed**: the piston speed a step needs (a sine's ``2 pi f A``, a triangle's ``4 f A``, a
  haversine's ``pi f (peak - valley)``, a ramp's rate; in force control the load's rate over
  the load train's stiffness, :func:`~ros_ehs.core.control.modes.load_train_compliance`)
  under the valve's, ``v_max sqrt(1 - |F| / F_stall)``: its flow at ``u_max`` with no load
  (``u_max K_q K_x / A_p``), less as the load takes the pressure drop across the valve;
* **force**: the largest force a step needs (its load level in force control; the specimen's
  ``k_L (z - z_L)`` in displacement) under ``F_stall / STALL_RESERVE``, the stall force
  ``(p_s - p_t) A_p`` less a reserve to accelerate with (Moog sizes valves 30 % above need);
* **frequency**: under the oil column's natural frequency at mid-stroke (times
  ``FREQUENCY_FRACTION``), ``sqrt(2 beta_e A_p / (l_iac m_p)) / 2 pi``, beyond which the loop
  cannot put the command through.

A drive step's file is not judged here (its levels come from iterating it on the rig).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Mapping

from ros_ehs.core.control.modes import load_train_compliance
from ros_ehs.core.errors import InputError
from ros_ehs.core.model.coefficients import flow_gain_kq
from ros_ehs.core.procedure.spec import Procedure, Step

__all__ = ['END_MARGIN', 'FREQUENCY_FRACTION', 'RIG_NAMES', 'RigEnvelope', 'STALL_RESERVE',
           'check_envelope', 'demands', 'require_envelope']

#: the closest a displacement level may come to an end stop [m]
END_MARGIN = 5.0e-3
#: the stall force is this many times the force a step may need
STALL_RESERVE = 1.3
#: a step's frequency stays under this fraction of the oil column's natural frequency
FREQUENCY_FRACTION = 1.0
#: the parameters the envelope is made of (the controller declares them, so that a procedure
#: node can check a test against the values in force, identified or nominal)
RIG_NAMES = ('stroke', 'limit_position_min', 'limit_position_max', 'u_max', 'K_x', 'A_p', 'C_d',
             'd_s', 'd_c', 'rho', 'p_s', 'p_t', 'beta_e', 'l_iac', 'm_p', 'k_L', 'z_L')


@dataclass(frozen=True)
class RigEnvelope:
    """What the rig can do (SI units); build with :meth:`from_params`."""

    z_min: float          #: the lowest displacement level [m]
    z_max: float          #: the highest [m]
    v_max: float          #: the valve's no-load piston speed at u_max [m/s]
    f_stall: float        #: the stall force (p_s - p_t) A_p [N]
    f_h: float            #: the oil column's natural frequency at mid-stroke [Hz]
    k_L: float            #: the specimen's stiffness [N/m] (0: none)
    z_L: float            #: where it carries no load [m]
    compliance: float     #: the load train's compliance at mid-stroke [m/N] (0: none)

    @classmethod
    def from_params(cls, params: Mapping[str, object]) -> 'RigEnvelope':
        """Return the envelope of a rig of these parameters."""
        p = {k: float(params[k]) for k in RIG_NAMES}
        stop = p['stroke'] - END_MARGIN
        return cls(z_min=max(-stop, p['limit_position_min']),
                   z_max=min(stop, p['limit_position_max']),
                   v_max=p['u_max'] * flow_gain_kq(params) * p['K_x'] / p['A_p'],
                   f_stall=(p['p_s'] - p['p_t']) * p['A_p'],
                   f_h=math.sqrt(2.0 * p['beta_e'] * p['A_p'] / (p['l_iac'] * p['m_p']))
                   / (2.0 * math.pi),
                   k_L=p['k_L'], z_L=p['z_L'], compliance=load_train_compliance(params))

    def speed_at(self, force: float) -> float:
        """Return the piston speed the valve gives against ``force`` [N] [m/s]."""
        return self.v_max * math.sqrt(max(0.0, 1.0 - abs(force) / self.f_stall))


def _wave(step: Step) -> tuple[float, float, float, float] | None:
    """Return a waveform step's (lowest, highest level, frequency, level speed), or None."""
    if step.type == 'cyclic':
        f = step['frequency']
        lo = min(b[1] for b in step['blocks'])
        hi = max(b[0] for b in step['blocks'])
        rng = max(b[0] - b[1] for b in step['blocks'])
        speed = {'sine': math.pi, 'triangle': 2.0, 'haversine': math.pi}[step['waveform']]
        return lo, hi, f, speed * f * rng
    if step.type == 'sweep':
        a, m, f = step['amplitude'], step['mean'], max(step['f0'], step['f1'])
        return m - a, m + a, f, 2.0 * math.pi * f * a
    return None


def demands(step: Step, rig: RigEnvelope) -> dict[str, float]:
    """
    Return what ``step`` asks of the rig: its levels, speed, force and frequency.

    Keys: ``z_lo``, ``z_hi`` [m] (displacement), ``speed`` [m/s] of the piston, ``force`` [N]
    (the largest magnitude), ``frequency`` [Hz] (NaN where a step has none).
    """
    out = {'z_lo': math.nan, 'z_hi': math.nan, 'speed': 0.0, 'force': 0.0,
           'frequency': math.nan}
    w = _wave(step)
    if w is not None:
        lo, hi, f, rate = w
        out['frequency'] = f
    elif step.type == 'ramp':
        lo = hi = step['to']
        rate = step['rate']
    else:
        return out
    if step.control_mode == 'displacement':
        out['z_lo'], out['z_hi'] = lo, hi
        out['speed'] = rate
        if rig.k_L > 0:
            out['force'] = rig.k_L * max(abs(lo - rig.z_L), abs(hi - rig.z_L))
    else:
        out['force'] = max(abs(lo), abs(hi))
        # the load's rate moves the piston through the load train's compliance
        out['speed'] = rate * rig.compliance if rig.compliance > 0 else 0.0
        if rig.k_L > 0:
            out['z_lo'] = rig.z_L + min(lo, hi) / rig.k_L
            out['z_hi'] = rig.z_L + max(lo, hi) / rig.k_L
    return out


def check_envelope(procedure: Procedure, rig: RigEnvelope) -> list[str]:
    """Return a sentence for each step and limit it breaks (empty: the rig can do it)."""
    bad = []
    for k, step in enumerate(procedure.steps):
        d = demands(step, rig)
        name = f'{procedure.name!r} {step.label}'
        if math.isfinite(d['z_lo']) and (d['z_lo'] < rig.z_min or d['z_hi'] > rig.z_max):
            bad.append(f'{name}: the piston at {d["z_lo"] * 1e3:.4g} to {d["z_hi"] * 1e3:.4g} mm '
                       f'leaves the stroke the rig may use, {rig.z_min * 1e3:.4g} to '
                       f'{rig.z_max * 1e3:.4g} mm (the position limits, {END_MARGIN * 1e3:g} mm '
                       'from the end stops)')
        f_max = rig.f_stall / STALL_RESERVE
        if d['force'] > f_max:
            bad.append(f'{name}: it needs {d["force"]:.4g} N, above the {f_max:.4g} N the rig '
                       f'has with a reserve to accelerate (stall {rig.f_stall:.4g} N / '
                       f'{STALL_RESERVE:g})')
        v = rig.speed_at(min(d['force'], rig.f_stall))
        if d['speed'] > v:
            bad.append(f'{name}: the piston must move at {d["speed"]:.4g} m/s, above the '
                       f'{v:.4g} m/s the valve gives against {d["force"]:.4g} N (its flow at '
                       f'u_max: {rig.v_max:.4g} m/s unloaded)')
        f_top = FREQUENCY_FRACTION * rig.f_h
        if d['frequency'] > f_top:
            bad.append(f'{name}: {d["frequency"]:.4g} Hz is above {f_top:.4g} Hz (the oil '
                       f"column's natural frequency, {rig.f_h:.4g} Hz, times "
                       f'{FREQUENCY_FRACTION:g}): the loop cannot put it through')
    return bad


def require_envelope(procedure: Procedure, params: Mapping[str, object]) -> None:
    """Raise InputError naming every step the rig of ``params`` cannot follow, and why."""
    bad = check_envelope(procedure, RigEnvelope.from_params(params))
    if bad:
        raise InputError('the rig cannot follow this procedure:\n  ' + '\n  '.join(bad))
