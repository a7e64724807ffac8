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
Packing of :class:`~ros_ehs.core.params.Params` into the flat coefficient vector the kernels read.

The numba kernels take one ``float64`` array instead of a mapping. Derived quantities
(areas, the corrected flow gain K_q of eq. (8), the Stribeck offset xi(0), the reduced
model's valve gain, compliance and lag) are computed here once, so the inner loop does no
repeated work.
"""

from __future__ import annotations

import math

import numpy as np

from ros_ehs.core.params import Params

__all__ = ['N_COEF', 'pack', 'flow_gain_kq', 'ff_force_gain', 'null_load_gain']

(C_PS, C_PT, C_RHO, C_BETA_E, C_BETA_P, C_PCR,
 C_KT, C_KA, C_KM, C_JA, C_BA,
 C_AN, C_XF0, C_A0, C_CD0, C_CDF, C_RF, C_LFB, C_VC, C_KNOZ,
 C_AS, C_MS, C_BS, C_KW, C_KFF, C_XVMAX, C_KSTOPS, C_CD, C_KX,
 C_W, C_CLR, C_RC, C_XBIAS,
 C_AP, C_LIAC, C_STROKE, C_KSTOP, C_KC, C_MP, C_KL,
 C_FCC, C_FSC, C_CC, C_VCS, C_EPSV, C_TAUST,
 C_RENORM, C_XI0, C_LINEAR, C_KQ, C_SMOOTH,
 C_GV0, C_CSV, C_TAUV, C_A2V, C_ZL, C_CL, N_COEF) = range(58)


def flow_gain_kq(p: Params) -> float:
    """
    Linearised flow gain K_q of eq. (8), corrected [m^2/s].

    ``K_q = C_d * pi * (d_s + d_c/2) * sqrt((p_s - p_t) / rho)``: the paper prints
    ``sqrt(rho * (p_P - p_T))``, which is not m^2/s (docs/model.md). This is the
    flow per metre of spool travel into a chamber at half supply pressure.
    """
    w = math.pi * (p['d_s'] + p['d_c'] / 2.0)
    return p['C_d'] * w * math.sqrt((p['p_s'] - p['p_t']) / p['rho'])


def ff_force_gain(p: Params) -> float:
    """
    Steady-state force gain of eq. (10), ``2 TF52 C46 K_q K_x`` [N/(A*s)].

    With TF52 = A_p and C46 = beta_e / V0, V0 = A_p * l_iac, this is
    ``2 beta_e K_q K_x / l_iac``: the rate of piston force per ampere while the piston is
    still (eq. 9). Named apart from the PID gain ``kp``.
    """
    return 2.0 * p['beta_e'] * flow_gain_kq(p) * p['K_x'] / p['l_iac']


def null_load_gain(p: Params) -> float:
    """
    Return the current per newton of load that holds a still piston at the valve's null [A/N].

    A load ``F`` on a still piston needs the load pressure ``P_L = F / A_p``, and the valve
    at null must then feed the leakage that pressure drives: its own (the metering edges'
    clearance flows, which ``P_L`` unbalances) and the piston's (``K_C P_L``). The load flow
    ``Q_L = (q_a - q_b) / 2`` of the orifice law
    (:func:`~ros_ehs.core.model.kernels.main_stage_flows`) linearised at null, both edges
    open by ``h0 = sqrt(r_c^2 + (c + r_c)^2) - r_c`` (``c = d_c / 2``) with the slope
    ``e0 = r_c / (h0 + r_c)``, both chambers at ``p0 = (p_s + p_t) / 2``, ``D = p_s - p0``,
    ``k = C_d w sqrt(2 / rho)``::

        dQ_L/dP_L = -k h0 / (2 sqrt(D)),   dQ_L/dx_v = 2 k e0 sqrt(D)
        gain = (K_C - dQ_L/dP_L) / (dQ_L/dx_v) / (A_p K_x)

    (the linear law, eq. (7): ``K_C / (K_q A_p K_x)``). For Table 1 this is 1.24e-8 A/N:
    0.11 mA holds 9 kN, 8 % under the exact null of the nonlinear flows (the linearisation
    underestimates it as the load grows). Pure Python: the controller starts without numba.
    """
    a_p, k_x, k_c = float(p['A_p']), float(p['K_x']), float(p['K_C'])
    if p['flow_law'] == 'linear':
        return k_c / (flow_gain_kq(p) * a_p * k_x)
    clr, rc = float(p['d_c']) / 2.0, float(p['r_c'])
    h0 = math.hypot(rc, clr + rc) - rc
    e0 = rc / (h0 + rc) if h0 + rc > 0 else 1.0
    k = float(p['C_d']) * math.pi * (float(p['d_s']) + clr) * math.sqrt(2.0 / float(p['rho']))
    root = math.sqrt(0.5 * (float(p['p_s']) - float(p['p_t'])))
    dql_dpl = -k * h0 / (2.0 * root)
    dql_dx = 2.0 * k * e0 * root
    if not dql_dx > 0:
        return 0.0
    return (k_c - dql_dpl) / dql_dx / (a_p * k_x)


def pack(p: Params, smooth: bool = True) -> np.ndarray:
    """
    Return the coefficient vector of ``p`` (``smooth=False``: exact sign), reduced valve unset.

    :func:`ros_ehs.core.model.kernels.coefficients` fills the reduced model's valve too (it is
    derived from the full model's, by the kernels): what the models take.
    """
    c = np.zeros(N_COEF)
    c[C_PS], c[C_PT], c[C_RHO] = p['p_s'], p['p_t'], p['rho']
    c[C_BETA_E], c[C_BETA_P], c[C_PCR] = p['beta_e'], p['beta_p'], p['p_cr']
    c[C_KT], c[C_KA], c[C_KM], c[C_JA], c[C_BA] = (p['K_t'], p['K_a'], p['K_m'], p['J_a'],
                                                   p['B_a'])
    c[C_AN] = math.pi * p['D_N'] ** 2 / 4.0
    c[C_XF0] = p['x_f0']
    c[C_A0] = math.pi * p['D_0'] ** 2 / 4.0
    c[C_CD0], c[C_CDF], c[C_RF], c[C_LFB] = p['C_d0'], p['C_df'], p['r_f'], p['l_fb']
    c[C_VC], c[C_KNOZ] = p['V_c'], p['k_nozzle']
    c[C_AS] = math.pi * p['d_s'] ** 2 / 4.0
    c[C_MS], c[C_BS], c[C_KW], c[C_KFF] = p['m_s'], p['B_s'], p['K_w'], p['k_ff']
    c[C_XVMAX], c[C_KSTOPS], c[C_CD], c[C_KX] = p['x_v_max'], p['k_stop_s'], p['C_d'], p['K_x']
    c[C_W] = math.pi * (p['d_s'] + p['d_c'] / 2.0)
    c[C_CLR] = p['d_c'] / 2.0
    c[C_RC], c[C_XBIAS] = p['r_c'], p['x_bias']
    c[C_AP], c[C_LIAC], c[C_STROKE], c[C_KSTOP] = p['A_p'], p['l_iac'], p['stroke'], p['k_stop']
    c[C_KC], c[C_MP], c[C_KL] = p['K_C'], p['m_p'], p['k_L']
    c[C_ZL], c[C_CL] = p['z_L'], p['c_L']
    c[C_FCC], c[C_FSC], c[C_CC] = p['F_cc'], p['F_sc'], p['c_c']
    c[C_VCS], c[C_EPSV], c[C_TAUST] = p['v_c'], p['eps_v'], p['tau_st']
    c[C_RENORM] = 1.0 if p['friction_law'] == 'renormalised' else 0.0
    c[C_XI0] = 0.5 * (math.tanh(-1.0) + 1.0)
    c[C_LINEAR] = 1.0 if p['flow_law'] == 'linear' else 0.0
    c[C_KQ] = flow_gain_kq(p)
    c[C_SMOOTH] = 1.0 if smooth else 0.0
    return c
