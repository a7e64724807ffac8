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
Every parameter of ros_ehs, declared once.

Each :class:`ParamSpec` gives name, SI unit, default, valid range and meaning. Everything else
is derived from this table: validation (:func:`validate`), the presets, the ROS 2 parameter
declarations of the nodes, the estimator's bounds and scales (paper Table 1), the YAML files
and the parameter reference in ``docs/parameters.md``.

Provenance tags in ``source``: ``P`` the Li & Zhang paper, ``K`` textbook / catalogue
knowledge (Merritt 1967, Moog G761 catalogue), ``D`` derived for a consistent G761-class
baseline (catalogue values made consistent with each other), ``I`` an assumption for the
test rig.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path
from typing import Iterable, Mapping

from ros_ehs.core.errors import ParameterError
from ros_ehs.core.settings import Setting

__all__ = [
    'ACTIONS',
    'ALL_SPECS',
    'CONTROL_SPECS',
    'ESTIMATED',
    'PLANT_SPECS',
    'ParamSpec',
    'Params',
    'PRESETS',
    'SAFETY_SPECS',
    'load_yaml',
    'preset',
    'save_yaml',
    'spec',
    'validate',
]


@dataclass(frozen=True)
class ParamSpec(Setting):
    """
    Declaration of one model or controller parameter: a live :class:`Setting`.

    ``group`` and ``source`` say where it belongs and where its value comes from.

    For the seven parameters the paper estimates, ``est_lo``/``est_hi`` are Table 1's bounds,
    ``scale`` its scale gain and ``initial``/``estimated`` its two columns.
    """

    live: bool = True
    group: str = ''
    source: str = ''
    est_lo: float | None = None
    est_hi: float | None = None
    scale: float | None = None
    initial: float | None = None
    estimated: float | None = None


def _p(name, unit, default, lo, hi, meaning, group, source, **kw) -> ParamSpec:
    return ParamSpec(name, unit, default, lo, hi, meaning, group=group, source=source, **kw)


# --- plant: the G761-class valve, symmetric cylinder and oil -------------------------------
PLANT_SPECS: tuple[ParamSpec, ...] = (
    # supply and oil
    _p('p_s', 'Pa', 21.0e6, 1.0e6, 35.0e6, 'supply pressure', 'supply', 'K'),
    _p('p_t', 'Pa', 0.0, 0.0, 2.0e6, 'return (tank) pressure', 'supply', 'K'),
    _p('rho', 'kg/m^3', 860.0, 700.0, 1100.0, 'oil density', 'oil', 'K'),
    _p('beta_e', 'Pa', 1.2e9, 1.0e8, 2.5e9, 'effective bulk modulus, cylinder side', 'oil', 'K'),
    _p('beta_p', 'Pa', 1.4e9, 1.0e8, 2.5e9, 'bulk modulus, pilot chambers', 'oil', 'K'),
    _p('p_cr', 'Pa', 1.0e5, 1.0e2, 1.0e6,
       'laminar/turbulent transition pressure of the smoothed orifice root', 'numerics', 'D'),
    # torque motor and armature-flapper
    _p('i_rated', 'A', 0.015, 1.0e-3, 0.1, 'rated servo current (coil option)', 'torque_motor',
       'K'),
    _p('K_t', 'N*m/A', 0.84, 0.01, 10.0, 'torque-motor current gain (flow-force calibrated)',
       'torque_motor', 'D'),
    _p('K_a', 'N*m/rad', 6.0, 0.1, 100.0, 'flexure-tube stiffness', 'torque_motor', 'K'),
    _p('K_m', 'N*m/rad', 4.5, 0.0, 100.0, 'magnetic spring (destabilising)', 'torque_motor', 'K'),
    _p('J_a', 'kg*m^2', 1.0e-7, 1.0e-9, 1.0e-5, 'armature + flapper inertia', 'torque_motor', 'K'),
    _p('B_a', 'N*m*s/rad', 4.0e-4, 1.0e-6, 1.0e-1, 'armature damping', 'torque_motor', 'K'),
    # flapper-nozzle pilot
    _p('D_N', 'm', 0.40e-3, 0.1e-3, 1.0e-3, 'nozzle diameter', 'pilot', 'K'),
    _p('x_f0', 'm', 40.0e-6, 5.0e-6, 200.0e-6, 'flapper-nozzle gap at null', 'pilot', 'K'),
    _p('D_0', 'm', 0.219e-3, 0.05e-3, 1.0e-3, 'fixed inlet orifice diameter', 'pilot', 'D'),
    _p('C_d0', '1', 0.80, 0.3, 1.0, 'discharge coefficient, inlet orifice', 'pilot', 'K'),
    _p('C_df', '1', 0.60, 0.3, 1.0, 'discharge coefficient, nozzle curtain', 'pilot', 'K'),
    _p('r_f', 'm', 9.0e-3, 1.0e-3, 30.0e-3, 'armature pivot to nozzle axis', 'pilot', 'K'),
    _p('l_fb', 'm', 21.0e-3, 1.0e-3, 60.0e-3, 'pivot to feedback-wire ball', 'pilot', 'K'),
    _p('V_c', 'm^3', 2.0e-7, 1.0e-8, 1.0e-5, 'spool-end (pilot) chamber volume at null',
       'pilot', 'K'),
    _p('k_nozzle', 'N/m', 1.0e6, 1.0e3, 1.0e8, 'flapper-nozzle contact stiffness',
       'pilot', 'I'),
    # main stage spool
    _p('d_s', 'm', 7.94e-3, 2.0e-3, 30.0e-3, 'spool diameter', 'spool', 'K'),
    _p('m_s', 'kg', 8.0e-3, 1.0e-3, 0.2, 'spool mass', 'spool', 'K'),
    _p('B_s', 'N*s/m', 12.0, 0.0, 1.0e3, 'spool viscous + transient flow-force damping',
       'spool', 'D'),
    _p('K_w', 'N/m', 1000.0, 10.0, 1.0e5, 'feedback-wire stiffness', 'spool', 'D'),
    _p('k_ff', '1', 0.43, 0.0, 1.0, 'steady flow-force coefficient 2*C_d*C_v*cos(69 deg)',
       'spool', 'K'),
    _p('x_v_max', 'm', 0.55e-3, 0.05e-3, 5.0e-3, 'spool travel to its end stop', 'spool', 'D'),
    _p('k_stop_s', 'N/m', 1.0e6, 1.0e3, 1.0e8, 'spool end-stop stiffness', 'spool', 'I'),
    _p('C_d', '1', 0.61, 0.3, 1.0, 'discharge coefficient, spool metering edges', 'spool', 'K'),
    _p('K_x', 'm/A', 0.0307, 1.0e-4, 1.0, 'static spool gain x/i (simplified model)', 'spool',
       'D'),
    # valve opening law: the three hard-to-measure valve parameters of Table 1
    _p('d_c', 'm', 8.4918e-6, 0.0, 100.0e-6,
       'spool-sleeve diametral clearance (radial gap c = d_c/2)', 'opening', 'P',
       est_lo=1.0e-6, est_hi=math.inf, scale=5.0e-7, initial=1.0e-6, estimated=8.4918e-6),
    _p('r_c', 'm', 1.5238e-6, 0.0, 100.0e-6, 'spool metering-edge rounding radius', 'opening',
       'P', est_lo=1.0e-7, est_hi=math.inf, scale=2.0e-7, initial=1.0e-6,
       estimated=1.5238e-6),
    _p('x_bias', 'm', -3.6659e-8, -50.0e-6, 50.0e-6,
       'null offset of the metering edges (x_e = x_v + x_bias)', 'opening', 'P',
       est_lo=-6.0e-6, est_hi=6.0e-6, scale=1.0e-6, initial=1.0e-6, estimated=-3.6659e-8),
    # cylinder
    _p('A_p', 'm^2', 1.527e-3, 1.0e-5, 0.1, 'piston annulus area (both sides)', 'cylinder', 'D'),
    _p('l_iac', 'm', 0.14417, 0.0, 5.0,
       'inactive length: dead volume per side over A_p, lines included', 'cylinder', 'P',
       est_lo=0.105, est_hi=math.inf, scale=0.005, initial=0.15, estimated=0.14417),
    _p('stroke', 'm', 0.10, 1.0e-3, 2.0, 'half stroke: end stops at +/- stroke', 'cylinder', 'I'),
    _p('k_stop', 'N/m', 1.0e8, 1.0e4, 1.0e10, 'cylinder end-stop stiffness', 'cylinder', 'I'),
    _p('K_C', 'm^3/(s*Pa)', 2.0e-13, 0.0, 1.0e-10, 'internal leakage across the piston',
       'cylinder', 'K'),
    _p('m_p', 'kg', 200.0, 1.0, 1.0e5, 'moving mass (piston, rod, fixture)', 'cylinder', 'I'),
    # the specimen and its load cell (ros_ehs.core.model.specimen)
    _p('k_L', 'N/m', 0.0, 0.0, 1.0e9, 'specimen stiffness, its load train included (0: no '
       'specimen: the piston moves free)', 'specimen', 'I', est_lo=1.0e3, scale=1.0e6),
    _p('c_L', 'N*s/m', 0.0, 0.0, 1.0e7, 'specimen damping', 'specimen', 'I'),
    _p('z_L', 'm', 0.0, -2.0, 2.0, "specimen's installed position: the piston position at "
       'which it carries no load', 'specimen', 'I'),
    _p('specimen_life', '1', 1.0e6, 1.0, 1.0e12, 'cycles to fracture at the force range '
       '`specimen_life_range` (Paris crack growth from `specimen_crack0`)', 'specimen', 'I'),
    _p('specimen_life_range', 'N', 1.0e4, 1.0, 1.0e8, 'the force range (peak to valley) the '
       'life holds at', 'specimen', 'I'),
    _p('specimen_paris_m', '1', 3.0, 1.0, 10.0, "Paris exponent: a cycle's crack growth "
       'goes with the force range to this power', 'specimen', 'K'),
    _p('specimen_crack0', '1', 0.1, 1.0e-4, 0.99, 'initial crack, a fraction of the crack '
       'at fracture', 'specimen', 'I'),
    _p('specimen_compliance', '1', 1.0, 0.0, 100.0, 'compliance growth with the crack: the '
       'stiffness is k_L / (1 + this a^2) for a crack a (a fraction of the crack at '
       'fracture)', 'specimen', 'I'),
    _p('specimen_scatter', '1', 0.0, 0.0, 1.0, 'scatter of the life: the standard deviation '
       'of its log10, drawn from `specimen_seed` (0: the life as set)', 'specimen', 'I'),
    _p('specimen_seed', '1', 0.0, 0.0, 2.0**31 - 1, 'seed of the life scatter', 'specimen',
       'I'),
    _p('specimen_fatigue_limit', 'N', 0.0, 0.0, 1.0e8, 'fatigue limit: the force range below '
       'which the initial crack does not grow (a threshold of the stress intensity range, so '
       'it falls as the crack grows, times sqrt(specimen_crack0 / a)), times a scatter factor '
       '10^(specimen_limit_scatter xi); 0: none', 'specimen', 'I'),
    _p('specimen_limit_scatter', '1', 0.0, 0.0, 1.0, 'scatter of the fatigue limit: the '
       'standard deviation of its log10, drawn from `specimen_seed` after the life', 'specimen',
       'I'),
    _p('load_cell_noise', 'N', 0.0, 0.0, 1.0e5, 'white noise (1 sigma) on the load cell '
       'reading', 'specimen', 'I'),
    # friction and damping: the four actuator parameters of Table 1
    _p('F_cc', 'N', 1046.9, 0.0, 1.0e5, 'Coulomb friction force', 'friction', 'P',
       est_lo=50.0, est_hi=math.inf, scale=100.0, initial=200.0, estimated=1046.9),
    _p('F_sc', 'N', 2201.9, 0.0, 1.0e5, 'static (breakaway) friction force', 'friction', 'P',
       est_lo=100.0, est_hi=math.inf, scale=100.0, initial=300.0, estimated=2201.9),
    _p('c_c', 'N*s/m', 1.610e4, 0.0, 1.0e7, 'viscous damping of the actuator', 'friction', 'P',
       est_lo=2000.0, est_hi=math.inf, scale=1000.0, initial=8000.0, estimated=1.610e4),
    _p('v_c', 'm/s', 0.01, 1.0e-4, 1.0, 'Stribeck velocity of eq. (15)', 'friction', 'K'),
    _p('eps_v', 'm/s', 1.0e-3, 1.0e-6, 0.1, 'smoothing velocity of sign(z_dot) -> tanh',
       'numerics', 'D'),
    _p('tau_st', 's', 1.0e-3, 1.0e-5, 1.0, 'time constant with which sticking friction stops '
       'residual creep', 'friction', 'D'),
    # model choices
    ParamSpec('friction_law', '', 'renormalised', meaning='Stribeck law: renormalised xi '
              '(sticks below F_sc) or paper eq. (15) as printed (creeps at rest)',
              group='friction', source='D', choices=('renormalised', 'paper')),
    ParamSpec('flow_law', '', 'orifice', meaning='simplified model main-stage flow: orifice '
              '(opening law with d_c, r_c, x_bias) or linear eq. (7)', group='opening',
              source='D', choices=('orifice', 'linear')),
)

# --- controller: PID eq. (19) and feedforward eqs. (9)-(20) ---------------------------------
CONTROL_SPECS: tuple[ParamSpec, ...] = (
    _p('kp', 'A/m', 0.75, 0.0, 100.0, 'PID proportional gain, eq. (19)', 'pid', 'P'),
    _p('ki', 'A/(m*s)', 0.051, 0.0, 1.0e4, 'PID integral gain, eq. (19)', 'pid', 'P'),
    _p('kd', 'A*s/m', 0.00049, 0.0, 10.0, 'PID derivative gain, eq. (19)', 'pid', 'P'),
    _p('d_filter_tau', 's', 2.0e-3, 0.0, 1.0, 'time constant of the derivative low-pass',
       'pid', 'D'),
    _p('u_max', 'A', 0.015, 1.0e-4, 0.1, 'output limit |i| (the valve rated current)', 'pid',
       'K'),
    _p('command_rate', 'A/s', 3.0, 0.0, 1000.0, "limit of the valve command's rate: each "
       "period's command within command_rate times the period of the current the valve has "
       '(the last command, or the current the state says was applied when the valve does not '
       "have it: a plant's watchdog zeroed it in a stall), so that a late state or a stall is "
       'not a current spike; the integrator does not integrate against it; 0: off. Above the '
       "steps the paper's sine needs (1.2 mA in 1 ms) and a full-scale 20 Hz sine's slope "
       '(1.9 A/s)', 'pid', 'D'),
    _p('tracking_tau', 's', 0.0, 0.0, 100.0, 'time constant of antiwindup = '
       'back_calculation (0: sqrt(kd/ki), or kp/ki when kd = 0)', 'pid', 'D'),
    ParamSpec('antiwindup', '', 'conditional_integration', meaning='anti-windup strategy '
              '(control_toolbox names): conditional_integration stops integrating while the '
              'output is limited and the error pushes further into the limit; '
              'back_calculation bleeds the excess (u_sat - u)/tracking_tau into the '
              'integrator; none', group='pid', source='D',
              choices=('conditional_integration', 'back_calculation', 'none')),
    _p('ff_enable', '1', 1.0, 0.0, 1.0, 'feedforward on (1) or off (0)', 'feedforward', 'D'),
    _p('tau_delay', 's', 0.0, 0.0, 0.5, 'signal-to-response delay tau of eq. (17): the '
       'measured loop delay (paper: 0.016 s under PID; ~0 with velocity feedforward)',
       'feedforward', 'D'),
    _p('ff_leak_tau', 's', 0.5, 1.0e-3, 100.0, 'leak of the pressure-force estimate of '
       'eq. (11)', 'feedforward', 'D'),
    _p('ff_velocity', '1', 1.1, 0.0, 1.5, 'weight of the velocity (flow-inversion) '
       'feedforward A v_ref / (K_q K_x); 0 = the law of the paper as printed', 'feedforward', 'D'),
    _p('ff_max', 'A', 0.015, 0.0, 0.1, 'limit of the feedforward current alone',
       'feedforward', 'D'),
    _p('dp_gain', 'A/N', 0.0, 0.0, 1.0e-4, 'delta-P stabilisation: current per newton of '
       'the high-passed hydraulic force A_p (p_P - p_T) taken off the command, damping the oil '
       "column; 0: off (the paper's controller). Needs the force in the state", 'stabilisation',
       'D'),
    _p('dp_tau', 's', 0.05, 1.0e-4, 10.0, 'time constant of the delta-P high-pass: force '
       'held longer than this (the static load) is not opposed', 'stabilisation', 'D'),
    _p('stale_timeout', 's', 0.005, 1.0e-4, 10.0, 'state older than this is stale: hold, '
       'then zero the command', 'safety', 'D'),
    # the control modes (ros_ehs.core.control.modes)
    ParamSpec('control_mode', '', 'displacement', meaning='the loop that drives the valve: '
              'displacement (PID + feedforward on the position), force (PIDF on the load cell) '
              'or displacement_force_limited (specimen protect: the displacement loop, its '
              'output limited so that |load| stays within protect_force). A switch is bumpless '
              '(mode_blend_time); to force it is refused while the load cell is missing, stale '
              'or invalid or an interlock is latched', group='modes', source='D',
              choices=('displacement', 'force', 'displacement_force_limited')),
    _p('force_kp', 'A/N', 3.0e-7, 0.0, 1.0e-2, 'force loop proportional gain (scales with '
       '1/specimen stiffness: `ehs_sim tune`)', 'modes', 'D'),
    _p('force_ki', 'A/(N*s)', 1.0e-5, 0.0, 1.0, 'force loop integral gain', 'modes', 'D'),
    _p('force_kd', 'A*s/N', 0.0, 0.0, 1.0e-3, 'force loop derivative gain (filtered with '
       'd_filter_tau)', 'modes', 'D'),
    _p('force_ff', '1', 1.1, 0.0, 1.5, "weight of the force loop's feedforward: the flow "
       'that the force rate needs through the load train and the oil column, '
       'dF_ref/dt (1/k_L + l_iac/(2 beta_e A_p)) (0: off)',
       'modes', 'D'),
    _p('hold_brake', '1', 2.0, 0.0, 10.0, "a force hold's first period: the rate's "
       'feedforward reversed this many times over, so the spool closes within its lag and the '
       'load stops near where the hold began (0: the valve steps to its null); a load limit '
       'tripped ahead of the load brakes by the share of a period it came late', 'modes', 'D'),
    _p('hold_dp_gain', 'A/N', 4.0e-7, 0.0, 1.0e-4, "a force hold's delta-P damping: current "
       'per newton of the hydraulic force A_p (p_P - p_T) less the held load, high-passed '
       "with dp_tau from the hold's start, taken off the command: damps the oil column the "
       'stop excites about the load held (needs the force in the state; 0: off)', 'modes',
       'D'),
    _p('hold_dp_max', 'A', 1.0e-3, 0.0, 0.1, "the most a force hold's delta-P damping takes "
       "off the command: a gain too high for the rig's valve rings the hold within this "
       'current instead of ringing it up', 'modes', 'D'),
    _p('mode_blend_time', 's', 0.2, 0.0, 60.0, 'a mode switch, and force control coming on: '
       "the new loop's reference blends from its measured value to the reference over this "
       'time (quintic)', 'modes', 'D'),
    _p('protect_force', 'N', 2.0e3, 1.0, 1.0e7, 'displacement_force_limited: the load cell '
       'magnitude the displacement loop may not push beyond', 'modes', 'I'),
)

#: What a detector does when it trips (``off``: the detector is disabled), least severe first.
ACTIONS: tuple[str, ...] = ('off', 'indicate', 'hold', 'stop', 'power_off')
_ACTION_MEANING = ('off: disabled; indicate: diagnostics WARN and an event; hold: the '
                   'reference freezes at the measured position; stop: the reference ramps to '
                   'safe_position at safe_velocity, then holds; power_off: valve current 0 A')


def _action(detector: str, default: str, what: str) -> ParamSpec:
    return ParamSpec(f'{detector}_action', '', default, meaning=f'action of the {what} '
                     f'detector ({_ACTION_MEANING}); latched until ~/reset', group='safety',
                     source='D', choices=ACTIONS)


# --- safety: limit and error detectors, their actions, ramp-on (ros_ehs.core.control.safety) -----
SAFETY_SPECS: tuple[ParamSpec, ...] = (
    _p('limit_position_max', 'm', 0.095, -2.0, 2.0, 'upper position limit: trips above it',
       'safety', 'I'),
    _action('limit_position_max', 'hold', 'upper position limit'),
    _p('limit_position_min', 'm', -0.095, -2.0, 2.0, 'lower position limit: trips below it',
       'safety', 'I'),
    _action('limit_position_min', 'hold', 'lower position limit'),
    _p('limit_velocity', 'm/s', 1.0, 1.0e-4, 10.0, 'speed limit: trips when |z_dot| is above '
       'it (z_dot measured, or differenced from the position)', 'safety', 'I'),
    _action('limit_velocity', 'off', 'speed limit'),
    _p('limit_force', 'N', 3.0e4, 1.0, 1.0e7, 'load force limit: trips when |(p_CP - p_CT) '
       'A_p| is above it (when the state carries the force)', 'safety', 'I'),
    _action('limit_force', 'off', 'load force limit'),
    _p('limit_error', 'm', 5.0e-3, 1.0e-6, 1.0, 'tracking error limit: trips when |z_ref - z| '
       'is above it for longer than limit_error_time', 'safety', 'I'),
    _p('limit_error_time', 's', 0.05, 0.0, 60.0, 'how long the tracking error must stay '
       'above limit_error', 'safety', 'I'),
    _action('limit_error', 'hold', 'tracking error'),
    _p('feedback_timeout', 's', 1.0, 1.0e-3, 60.0, 'real time: no state for this long '
       'latches the feedback detector (the controller sends 0 A, unlatched, after 10 '
       'stale_timeout already)', 'safety', 'D'),
    _p('frozen_periods', '1', 100.0, 2.0, 1.0e6, 'feedback frozen: the same position for '
       'this many periods with |i| >= frozen_current (periods with less neither count nor '
       'clear)', 'safety', 'D'),
    _p('frozen_current', 'A', 3.0e-4, 0.0, 0.1, 'the command above which a frozen position '
       'counts (a command this large moves a free piston)', 'safety', 'D'),
    _action('feedback', 'power_off', 'feedback validity (non-finite, lost, frozen)'),
    _p('limit_saturation_time', 's', 0.5, 0.0, 60.0, 'saturation: the command at its limit '
       'u_max for longer than this (control lost)', 'safety', 'I'),
    _action('saturation', 'off', 'command saturation'),
    _p('limit_hysteresis', '1', 0.05, 0.0, 0.5, 'a tripped limit clears (reset allowed) only '
       'this fraction of the limit inside it (of the position span for position limits)',
       'safety', 'D'),
    _p('safe_position', 'm', 0.0, -2.0, 2.0, 'where the stop action takes the piston',
       'safety', 'I'),
    _p('safe_velocity', 'm/s', 0.01, 1.0e-4, 1.0, 'speed of the stop action', 'safety', 'I'),
    _p('ramp_time', 's', 1.0, 0.0, 600.0, 'ramp-on: on start, enable and reset the reference '
       'blends from the measured position to the trajectory over this time (0: no ramp)',
       'safety', 'D'),
    # the specimen's detectors (the load cell, the displacement from its installed position z_L)
    _p('limit_load_max', 'N', 1.0e5, -1.0e7, 1.0e7, 'upper load limit: trips when the load '
       'cell reads above it', 'safety', 'I'),
    _action('limit_load_max', 'hold', 'upper load limit'),
    _p('limit_load_min', 'N', -1.0e5, -1.0e7, 1.0e7, 'lower load limit: trips when the load '
       'cell reads below it', 'safety', 'I'),
    _action('limit_load_min', 'hold', 'lower load limit'),
    _p('limit_load_lead', 's', 3.4e-3, 0.0, 0.05, 'the load limits also judge the load this '
       'far ahead at its rate (differenced, smoothed over as long): the time the axis takes to '
       "stop the load (a period, the valve's lag, the oil column); a trip ahead of the "
       'reading holds the limit; 0: the reading alone', 'safety', 'D'),
    _p('limit_specimen_max', 'm', 0.01, -2.0, 2.0, 'upper specimen limit: trips when the '
       'displacement from the installed position, z - z_L, is above it', 'safety', 'I'),
    _action('limit_specimen_max', 'off', 'upper specimen displacement limit'),
    _p('limit_specimen_min', 'm', -0.01, -2.0, 2.0, 'lower specimen limit: trips when z - z_L '
       'is below it', 'safety', 'I'),
    _action('limit_specimen_min', 'off', 'lower specimen displacement limit'),
    _p('limit_force_error', 'N', 2.0e3, 1.0e-3, 1.0e7, 'force control: trips when |F_ref - F| '
       'is above it for longer than limit_error_time', 'safety', 'I'),
    _action('limit_force_error', 'hold', 'force tracking error'),
    _p('break_drop', 'N', 1.0e3, 1.0, 1.0e7, 'specimen break: the load magnitude falls by more '
       'than this within break_window...', 'safety', 'I'),
    _p('break_travel', 'm', 1.0e-4, 1.0e-6, 0.1, '...while the piston moves more than this '
       'away from the installed position (the way that would load it more)', 'safety', 'I'),
    _p('break_window', 's', 0.02, 1.0e-3, 1.0, 'specimen break: the window the drop and the '
       'travel are judged over', 'safety', 'D'),
    _action('specimen_break', 'hold', 'specimen break (the force collapses while the piston '
            'runs away; with hold or more, force control ends: displacement from then on)'),
    _p('load_frozen_force', 'N', 200.0, 1.0, 1.0e7, 'load cell frozen: its reading repeats '
       'while the piston moves far enough to change the load by more than this (k_L times '
       'the travel; needs k_L)', 'safety', 'D'),
    _p('load_check_window', 's', 0.1, 0.01, 10.0, 'load cell against the motion: the window '
       'its readings are fitted over against the position (load = k z + b), when the motion '
       'swung k_L z by more than twice load_check_force; the fitted k under a quarter of k_L or '
       'above 4 k_L trips (a cell that does not follow the piston)', 'safety', 'D'),
    _p('load_check_force', 'N', 500.0, 1.0, 1.0e7, 'see load_check_window', 'safety', 'D'),
    _p('load_drift_force', 'N', 100.0, 1.0, 1.0e7, 'load cell drift: the fitted zero-load '
       'position (smoothed over 0.25 s) moved from its reference (its mean over the first 2 s '
       'of windows judged) by more than this over k_L (its zero drifted; a crack changes k, '
       'not where the load is zero)', 'safety', 'D'),
    _action('load_feedback', 'hold', 'load cell validity under force control and specimen '
            'protect (non-finite, missing, stale, frozen, not following the piston or '
            'drifted; with hold or more, displacement '
            'from then on, held where the reading was last true)'),
    _p('hold_error_position', 'm', 1.0e-3, 1.0e-6, 1.0, 'a hold not obeyed: the piston more '
       'than this from the position held...', 'safety', 'D'),
    _p('hold_error_force', 'N', 1.0e3, 1.0e-3, 1.0e7, '...or, held in force control, the load '
       'more than this from the load held...', 'safety', 'D'),
    _p('hold_error_time', 's', 0.02, 0.0, 10.0, '...for longer than this (a stuck valve)',
       'safety', 'D'),
    _action('hold_error', 'power_off', 'hold not obeyed'),
    _p('loop_timing_late', 's', 0.02, 1.0e-3, 10.0, 'real time: the valve holding one '
       'command longer than this trips loop_timing (a state answered this long after its '
       'stamp, or after the one answered before it: the machine too busy to run the loop on '
       'time)',
       'safety', 'D'),
    _action('loop_timing', 'hold', 'loop timing (real time)'),
)

ALL_SPECS: tuple[ParamSpec, ...] = PLANT_SPECS + CONTROL_SPECS + SAFETY_SPECS
_BY_NAME: dict[str, ParamSpec] = {s.name: s for s in ALL_SPECS}
assert len(_BY_NAME) == len(ALL_SPECS), 'duplicate parameter name'

#: The seven hard-to-measure parameters of the paper's Table 1, in its order.
ESTIMATED: tuple[str, ...] = ('d_c', 'r_c', 'x_bias', 'F_cc', 'F_sc', 'l_iac', 'c_c')


def spec(name: str) -> ParamSpec:
    """Return the declaration of parameter ``name``."""
    try:
        return _BY_NAME[name]
    except KeyError:
        raise ParameterError(f'unknown parameter `{name}`') from None


def validate(values: Mapping[str, object]) -> dict[str, float | str]:
    """Check every entry of ``values`` against its declaration; return converted values."""
    out: dict[str, float | str] = {}
    for name, value in values.items():
        out[name] = spec(name).check(value)
    _check_cross(out)
    return out


def _check_cross(v: Mapping[str, float | str]) -> None:
    """Relations between parameters that single ranges cannot express."""
    if 'p_s' in v and 'p_t' in v and not v['p_t'] < v['p_s']:
        raise ParameterError(f"parameter `p_t` = {v['p_t']!r} Pa must be below `p_s` = "
                             f"{v['p_s']!r} Pa")
    if 'F_cc' in v and 'F_sc' in v and v['F_cc'] > v['F_sc']:
        raise ParameterError(f"parameter `F_cc` = {v['F_cc']!r} N must not exceed `F_sc` = "
                             f"{v['F_sc']!r} N (Coulomb friction above breakaway)")
    if 'K_a' in v and 'K_m' in v and not v['K_m'] < v['K_a']:
        raise ParameterError(f"parameter `K_m` = {v['K_m']!r} must be below `K_a` = "
                             f"{v['K_a']!r} (net armature stiffness must be positive)")
    if 'limit_position_min' in v and 'limit_position_max' in v and \
            not v['limit_position_min'] < v['limit_position_max']:
        raise ParameterError(f"parameter `limit_position_min` = {v['limit_position_min']!r} m "
                             'must be below `limit_position_max` = '
                             f"{v['limit_position_max']!r} m")
    for lim in ('limit_position_min', 'limit_position_max'):
        if lim in v and 'stroke' in v and v.get(lim + '_action', 'off') != 'off' and \
                not abs(v[lim]) < v['stroke']:
            raise ParameterError(f'parameter `{lim}` = {v[lim]!r} m must be inside the stroke '
                                 f"(+-{v['stroke']!r} m) while it acts (its action "
                                 f"{v[lim + '_action']!r}): the end stop would come first")
    for lo, hi, unit in (('limit_load_min', 'limit_load_max', 'N'),
                         ('limit_specimen_min', 'limit_specimen_max', 'm')):
        if lo in v and hi in v and not v[lo] < v[hi]:
            raise ParameterError(f'parameter `{lo}` = {v[lo]!r} {unit} must be below `{hi}` = '
                                 f'{v[hi]!r} {unit}')
    if 'l_iac' in v and 'stroke' in v and not v['stroke'] < v['l_iac']:
        raise ParameterError(f"parameter `stroke` = {v['stroke']!r} m must be below `l_iac` = "
                             f"{v['l_iac']!r} m (a chamber volume would vanish)")


class Params(Mapping[str, float | str]):
    """
    An immutable, validated set of all parameters (plant and controller).

    Behaves as a read-only mapping. Build with :func:`preset` or :meth:`replace`.
    """

    __slots__ = ('_v',)

    def __init__(self, values: Mapping[str, object] | None = None) -> None:
        merged: dict[str, object] = {s.name: s.default for s in ALL_SPECS}
        if values:
            merged.update(values)
        self._v = validate(merged)

    def __getitem__(self, name: str) -> float | str:
        """Return the value of ``name``."""
        try:
            return self._v[name]
        except KeyError:
            raise ParameterError(f'unknown parameter `{name}`') from None

    def __getattr__(self, name: str) -> float | str:
        """Return the value of ``name`` as an attribute."""
        if name.startswith('_'):
            raise AttributeError(name)
        try:
            return self._v[name]
        except KeyError:
            raise AttributeError(name) from None

    def __iter__(self):
        """Iterate over parameter names in declaration order."""
        return iter(self._v)

    def __len__(self) -> int:
        """Return the number of parameters."""
        return len(self._v)

    def __repr__(self) -> str:
        """Show only values that differ from the defaults."""
        diff = {k: v for k, v in self._v.items() if v != _BY_NAME[k].default}
        return f'Params({diff!r})'

    def __eq__(self, other: object) -> bool:
        """Compare all values."""
        return isinstance(other, Params) and self._v == other._v

    def __hash__(self) -> int:
        """Hash all values."""
        return hash(tuple(self._v.items()))

    def replace(self, **changes: object) -> 'Params':
        """Return a copy with ``changes`` applied (validated)."""
        return Params({**self._v, **changes})

    def subset(self, names: Iterable[str]) -> dict[str, float | str]:
        """Return ``{name: value}`` for ``names``."""
        return {n: self[n] for n in names}


def _table1(column: str) -> dict[str, float]:
    return {n: getattr(spec(n), column) for n in ESTIMATED}


#: Named presets. ``g761_baseline`` is the default table (paper estimates in it);
#: ``table1_initial`` and ``table1_estimated`` set the seven parameters of Table 1;
#: ``fatigue_actuator`` is ``table1_estimated`` with a fatigue actuator's seals (hydrostatic
#: bearings: 50 N Coulomb, 100 N breakaway friction where the paper's cylinder has 1.0 and
#: 2.2 kN), the rig of the force benchmark (docs/controller.md says why).
PRESETS: dict[str, dict[str, float]] = {
    'g761_baseline': {},
    'table1_initial': _table1('initial'),
    'table1_estimated': _table1('estimated'),
    'fatigue_actuator': {**_table1('estimated'), 'F_cc': 50.0, 'F_sc': 100.0},
}


def preset(name: str = 'g761_baseline', **changes: object) -> Params:
    """Return preset ``name`` with ``changes`` applied."""
    if name not in PRESETS:
        raise ParameterError(f'unknown preset `{name}`; choose one of {sorted(PRESETS)}')
    return Params({**PRESETS[name], **changes})


def markdown_table() -> str:
    """Return the parameter reference (docs/parameters.md), derived from the table."""
    lines = ['# Parameters', '',
             'Generated from `ros_ehs/core/params.py` by `ehs_sim params-doc`; do not edit by '
             'hand.',
             'Source tags: P paper, K textbook/catalogue, D derived (for a consistent G761-class '
             'baseline, docs/model.md), '
             'I rig assumption.', '']
    for title, specs in (('Plant', PLANT_SPECS), ('Controller', CONTROL_SPECS),
                         ('Safety', SAFETY_SPECS)):
        lines += [f'## {title}', '', '| name | unit | default | range | meaning | source | '
                  'Table 1 initial / bounds / estimate / scale |', '|---|---|---|---|---|---|---|']
        for s in specs:
            rng = ', '.join(s.choices) if s.is_choice else f'[{s.lo:g}, {s.hi:g}]'
            t1 = ''
            if s.initial is not None:
                t1 = (f'{s.initial:g} / [{s.est_lo:g}, {s.est_hi:g}] / {s.estimated:g} / '
                      f'{s.scale:g}')
            elif s.est_lo is not None:       # fittable, not in Table 1: its fit bound, scale
                t1 = f'- / [{s.est_lo:g}, {s.hi:g}] / - / {s.scale or 1:g}'
            default = s.default if s.is_choice else f'{s.default:g}'
            lines.append(f'| `{s.name}` | {s.unit} | {default} | {rng} | {s.meaning} | '
                         f'{s.source} | {t1} |')
        lines.append('')
    return '\n'.join(lines)


def save_yaml(path: str | Path, params: Mapping[str, object], node_name: str = '/**',
              names: Iterable[str] | None = None) -> Path:
    """
    Write ``params`` as a ROS 2 parameters file (``node: ros__parameters: ...``).

    Numbers are written as doubles (``1.0``, never ``1``), as rclpy's double parameters
    reject integers. ``node_name='/**'`` applies the file to every node.
    """
    import yaml

    keys = list(names) if names is not None else list(params)
    body: dict[str, object] = {}
    for k in keys:
        s = spec(k)
        v = s.check(params[k])
        body[k] = v if s.is_choice else float(v)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump({node_name: {'ros__parameters': body}}, sort_keys=False)
    path.write_text(text)
    return path


def load_yaml(path: str | Path, base: Params | None = None) -> Params:
    """
    Read a ROS 2 parameters file and return ``base`` updated with the known parameters.

    Every node section is merged in file order; keys that are not ros_ehs parameters
    (``use_sim_time``, ``rate_hz``, ...) are ignored. Unknown values raise
    :class:`ParameterError` naming the file.
    """
    import yaml

    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise ParameterError(f'cannot read parameters file {path}: {err}') from err
    if not isinstance(doc, dict):
        raise ParameterError(f'{path}: not a ROS 2 parameters file (expected a mapping)')
    values: dict[str, object] = {}
    for node, section in doc.items():
        if not isinstance(section, dict) or 'ros__parameters' not in section:
            raise ParameterError(f'{path}: node `{node}` has no `ros__parameters` section')
        for k, v in (section['ros__parameters'] or {}).items():
            if k in _BY_NAME:
                values[k] = v
    base = base if base is not None else Params()
    try:
        return base.replace(**values)
    except ParameterError as err:
        raise ParameterError(f'{path}: {err}') from None
