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
Unchecked numba kernels: opening law, friction, right-hand sides, Rosenbrock integrator.

Nothing here validates its input: :mod:`ros_ehs.core.model.plant` is the checked public layer.
Equations are documented in ``docs/model.md``; the comments below name them.

State vectors (paper order, eqs. (2) and (5)):

* full, 10 states: ``[theta_dot, theta, p_tL, p_tR, x_dot, x, p_CP, p_CT, z_dot, z]``
* simplified, 4 states: ``[p_CP, p_CT, z_dot, z]``
* reduced, 6 states: ``[x_dot, x, p_CP, p_CT, z_dot, z]`` (the simplified model with the
  valve's dynamics and its load-dependent gain, derived from the full model:
  :func:`valve_reduction`)

Input ``u = [i, F_L]``: servo current [A] and external load force on the piston [N]. The
load string is a spring and damper: the specimen's stiffness ``k_L`` and damping ``c_L``,
carrying no load at the piston position ``z_L`` (its installed position).
"""

import hashlib
import math
import os

import numba
from numba import njit
import numpy as np

from ros_ehs.core.model import coefficients as _coefficients_module
from ros_ehs.core.model import smooth as _smooth_module
from ros_ehs.core.model.coefficients import (C_A0, C_A2V, C_AN, C_AP, C_AS, C_BA, C_BETA_E,
                                             C_BETA_P, C_BS, C_CC, C_CD, C_CD0, C_CDF, C_CL, C_CLR,
                                             C_CSV, C_EPSV, C_FCC, C_FSC, C_GV0, C_JA, C_KA, C_KC,
                                             C_KFF, C_KL, C_KM, C_KNOZ, C_KQ, C_KSTOP, C_KSTOPS,
                                             C_KT, C_KW, C_KX, C_LFB, C_LIAC, C_LINEAR, C_MP, C_MS,
                                             C_PCR, C_PS, C_PT, C_RC, C_RENORM, C_RF, C_RHO,
                                             C_SMOOTH, C_STROKE, C_TAUST, C_TAUV, C_VC, C_VCS, C_W,
                                             C_XBIAS, C_XF0, C_XI0, C_XVMAX, C_ZL, pack)
from ros_ehs.core.model.smooth import smooth_clip

FULL = 0
SIMPLIFIED = 1
REDUCED = 2
N_FULL = 10
N_SIMPLIFIED = 4
N_REDUCED = 6

#: numba's options for every kernel. Without ``fastmath``: with it, LLVM may reassociate and
#: fuse floating-point operations as the surrounding code allows, so a replay's last bits
#: depended on which kernels were compiled first into numba's cache (the same bag, the same
#: machine: the verdict benchmark's rig 140 ended with F_cc 3.6 % or 9.1 % off) and on the
#: CPU they were built for. Without it a replay is the same to the bit in either case, at a
#: speed the ``model`` benchmark does not tell apart; and a check for a non-finite state is
#: not at the compiler's mercy (``fastmath`` lets it assume there is none).
_JIT = {'cache': True, 'nogil': True, 'fastmath': False, 'error_model': 'numpy'}

#: the source files the kernels' machine code is built from: this one, the helper it compiles
#: (:mod:`~ros_ehs.core.model.smooth`) and the coefficient indices it freezes in as
#: constants (:mod:`~ros_ehs.core.model.coefficients`)
_SOURCES = (__file__, _smooth_module.__file__, _coefficients_module.__file__)


def build_tag(sources, jit_options, numba_version) -> str:
    """
    Return a digest of everything a cached kernel's machine code depends on.

    numba invalidates a cache entry only when the source file of that very function changes;
    not when the options it is compiled with change, nor when a function it calls (in
    another file) or a constant it freezes in does. ``smooth_clip`` lives in ``smooth.py``
    and is compiled here with :data:`_JIT`, so a cache entry built with other options was
    loaded for a new build and changed the last bits of every replay (a fit's path through
    its optimizer can fork on them). Every kernel is therefore cached in a directory named by
    this digest of the files ``sources``, ``jit_options`` and ``numba_version``: a change to
    any of them compiles into a new, empty directory.
    """
    digest = hashlib.sha256(repr((sorted(jit_options.items()), numba_version)).encode())
    for path in sources:
        with open(path, 'rb') as f:
            digest.update(hashlib.sha256(f.read()).digest())
    return digest.hexdigest()[:16]


#: where this build's kernels are cached: a directory named by :func:`build_tag` in
#: ``NUMBA_CACHE_DIR`` (``scripts/env.sh``), else in this package's ``__pycache__`` (where
#: numba would put them); where neither is writable, numba falls back to its own locations
_CACHE_BASE = numba.config.CACHE_DIR or os.path.join(os.path.dirname(__file__), '__pycache__')
CACHE_DIR = os.path.join(_CACHE_BASE, 'kernels-' + build_tag(_SOURCES, _JIT, numba.__version__))


def _kernel(func):
    """Return ``func`` compiled with :data:`_JIT`, cached in :data:`CACHE_DIR`."""
    # numba's cache locator reads its directory from numba.config when the function is
    # decorated (njit(cache=True) creates the cache there), not later
    base = numba.config.CACHE_DIR
    numba.config.CACHE_DIR = CACHE_DIR
    try:
        return njit(**_JIT)(func)
    finally:
        numba.config.CACHE_DIR = base


#: :func:`ros_ehs.core.model.smooth.smooth_clip`, compiled
_smooth_clip = _kernel(smooth_clip)


# --- valve opening law --------------------------------------------------------------------
@_kernel
def edge_gap(x, clr, rc):
    """
    Minimum gap [m] of one metering edge opened by ``x`` [m] (x < 0: overlapped).

    The sleeve edge is sharp, the spool edge rounded with radius ``rc``, and the land
    clears the sleeve by the radial gap ``clr`` = d_c / 2::

        h(x) = clr                                    x <= -rc
        h(x) = sqrt((x + rc)^2 + (clr + rc)^2) - rc   x >  -rc

    h is C1, equals the leakage gap ``clr`` when overlapped and tends to ``x`` when wide open.
    """
    if x <= -rc:
        return clr
    s = x + rc
    q = clr + rc
    return math.sqrt(s * s + q * q) - rc


@_kernel
def sroot(dp, p_cr, smooth):
    """Signed square root of a pressure drop, smoothed near zero: dp / (dp^2 + p_cr^2)^(1/4)."""
    if smooth > 0.5:
        return dp / math.sqrt(math.sqrt(dp * dp + p_cr * p_cr))
    if dp >= 0.0:
        return math.sqrt(dp)
    return -math.sqrt(-dp)


@_kernel
def _sabs(v, eps, smooth):
    if smooth > 0.5:
        return math.sqrt(v * v + eps * eps) - eps
    return abs(v)


@_kernel
def soft_clip(f, lim, smooth):
    """Clip ``f`` to +-``lim``; smooth (see :func:`smooth_clip`) when ``smooth`` > 0.5."""
    if smooth > 0.5:
        return _smooth_clip(f, lim)
    return min(max(f, -lim), lim)


@_kernel
def _sign(v, eps, smooth):
    if smooth > 0.5:
        return math.tanh(v / eps)
    if v > 0.0:
        return 1.0
    if v < 0.0:
        return -1.0
    return 0.0


@_kernel
def main_stage_flows(xv, pA, pB, c):
    """Flows [m^3/s] into chambers P and T for spool position ``xv`` (4 edges, eq. (3))."""
    k = c[C_CD] * c[C_W] * math.sqrt(2.0 / c[C_RHO])
    xe = xv + c[C_XBIAS]
    h_pa = edge_gap(xe, c[C_CLR], c[C_RC])     # P->A and B->T edges
    h_pb = edge_gap(-xe, c[C_CLR], c[C_RC])    # P->B and A->T edges
    ps, pt, pcr, sm = c[C_PS], c[C_PT], c[C_PCR], c[C_SMOOTH]
    qa = k * (h_pa * sroot(ps - pA, pcr, sm) - h_pb * sroot(pA - pt, pcr, sm))
    qb = k * (h_pb * sroot(ps - pB, pcr, sm) - h_pa * sroot(pB - pt, pcr, sm))
    return qa, qb


# --- Stribeck friction, eqs. (14)-(15) ----------------------------------------------------
@_kernel
def friction(v, f_oc, c):
    """
    Friction force [N] on the piston at speed ``v`` with other forces ``f_oc``.

    Paper eq. (14)-(15): ``F_c = -[(1 - xi) sat(F_hold, +-F_sc) + xi sign(v) F_cc]``,
    ``xi = [tanh(|v|/v_c - 1) + 1] / 2``. With ``friction_law = renormalised`` (default)
    xi is rescaled to ``(xi - xi(0)) / (1 - xi(0))`` so that it is 0 at rest, and the static
    branch acts on ``F_hold = F_oc + m v / tau_st``, the force that stops residual motion
    within ``tau_st``: the piston then sticks while ``|F_oc| < F_sc``. With the paper's form
    (``xi(0) = 0.119``) it creeps.
    """
    sm = c[C_SMOOTH]
    eps = c[C_EPSV]
    xi = 0.5 * (math.tanh(_sabs(v, eps, sm) / c[C_VCS] - 1.0) + 1.0)
    f_hold = f_oc
    if c[C_RENORM] > 0.5:
        xi0 = c[C_XI0]
        xi = (xi - xi0) / (1.0 - xi0)
        f_hold = f_oc + c[C_MP] * v / c[C_TAUST]
    return -((1.0 - xi) * soft_clip(f_hold, c[C_FSC], sm) + xi * _sign(v, eps, sm) * c[C_FCC])


@_kernel
def _stop(pos, vel, limit, k, m):
    """Force of a stiff, damped end stop at +-limit (zero inside)."""
    if pos > limit:
        pen = pos - limit
    elif pos < -limit:
        pen = pos + limit
    else:
        return 0.0
    return -k * pen - 1.4 * math.sqrt(k * m) * vel


@_kernel
def _cylinder(pA, pB, zd, z, qa, qb, f_load, c, out, o):
    """Chamber pressures and piston (last four equations of eq. (3)), into out[o:o+4]."""
    ap = c[C_AP]
    leak = c[C_KC] * (pA - pB)
    va = ap * (c[C_LIAC] + z)
    vb = ap * (c[C_LIAC] - z)
    out[o] = c[C_BETA_E] / va * (qa - ap * zd - leak)
    out[o + 1] = c[C_BETA_E] / vb * (qb + ap * zd + leak)
    f_oc = ap * (pA - pB) - (c[C_CC] + c[C_CL]) * zd - c[C_KL] * (z - c[C_ZL]) + f_load
    f_c = friction(zd, f_oc, c)
    f_stop = _stop(z, zd, c[C_STROKE], c[C_KSTOP], c[C_MP])
    out[o + 2] = (f_oc + f_c + f_stop) / c[C_MP]
    out[o + 3] = zd


@_kernel
def rhs_full(x, u, c, out):
    """Full 10-state model, eq. (3), into ``out``."""
    thd, th, p1, p2, xvd, xv, pA, pB, zd, z = (x[0], x[1], x[2], x[3], x[4], x[5], x[6],
                                               x[7], x[8], x[9])
    i, f_load = u[0], u[1]
    sm = c[C_SMOOTH]
    pt, pcr, rho = c[C_PT], c[C_PCR], c[C_RHO]
    k2r = math.sqrt(2.0 / rho)
    # flapper-nozzle pilot: gaps, orifice flows, spool-end chambers
    rf, xf0 = c[C_RF], c[C_XF0]
    g1 = xf0 - rf * th
    g2 = xf0 + rf * th
    d = 0.05e-6
    g1p = 0.5 * (g1 + math.sqrt(g1 * g1 + d * d))
    g2p = 0.5 * (g2 + math.sqrt(g2 * g2 + d * d))
    k0 = c[C_CD0] * c[C_A0] * k2r
    kn = c[C_CDF] * math.pi * math.sqrt(4.0 * c[C_AN] / math.pi) * k2r
    q01 = k0 * sroot(c[C_PS] - p1, pcr, sm)
    q02 = k0 * sroot(c[C_PS] - p2, pcr, sm)
    qn1 = kn * g1p * sroot(p1 - pt, pcr, sm)
    qn2 = kn * g2p * sroot(p2 - pt, pcr, sm)
    a_s = c[C_AS]
    v1 = c[C_VC] + a_s * xv
    v2 = c[C_VC] - a_s * xv
    out[2] = c[C_BETA_P] / v1 * (q01 - qn1 - a_s * xvd)
    out[3] = c[C_BETA_P] / v2 * (q02 - qn2 + a_s * xvd)
    # armature: motor torque, magnetic spring, nozzle forces (pressure + jet), feedback wire
    an = c[C_AN]
    fn1 = (p1 - pt) * an + rho * qn1 * qn1 / an
    fn2 = (p2 - pt) * an + rho * qn2 * qn2 / an
    lfb, kw = c[C_LFB], c[C_KW]
    wire = kw * (lfb * th + xv)
    contact = 0.0
    if g1 < 0.0:
        contact += rf * c[C_KNOZ] * g1
    if g2 < 0.0:
        contact -= rf * c[C_KNOZ] * g2
    torque = (c[C_KT] * i + (c[C_KM] - c[C_KA]) * th - c[C_BA] * thd - rf * (fn1 - fn2)
              - lfb * wire + contact)
    out[0] = torque / c[C_JA]
    out[1] = thd
    # spool: pilot pressure, damping, wire, steady flow force, end stops
    dpv = c[C_PS] - pt - _sabs(pA - pB, 1e4, sm)
    f_ss = c[C_KFF] * c[C_W] * dpv * xv
    f_stop = _stop(xv, xvd, c[C_XVMAX], c[C_KSTOPS], c[C_MS])
    out[4] = (a_s * (p1 - p2) - c[C_BS] * xvd - wire - f_ss + f_stop) / c[C_MS]
    out[5] = xvd
    qa, qb = main_stage_flows(xv, pA, pB, c)
    _cylinder(pA, pB, zd, z, qa, qb, f_load, c, out, 6)


@_kernel
def spool_static(i, c):
    """Spool position of the simplified model, x = K_x i, held inside its end stops."""
    xv = c[C_KX] * i
    return min(max(xv, -c[C_XVMAX]), c[C_XVMAX])


@_kernel
def rhs_simplified(x, u, c, out):
    """Simplified 4-state model, eqs. (6)-(8) with the valve opening law, into ``out``."""
    pA, pB, zd, z = x[0], x[1], x[2], x[3]
    xv = spool_static(u[0], c)
    if c[C_LINEAR] > 0.5:
        qa = c[C_KQ] * xv      # eq. (7), K_q of eq. (8) corrected
        qb = -qa
    else:
        qa, qb = main_stage_flows(xv, pA, pB, c)
    _cylinder(pA, pB, zd, z, qa, qb, u[1], c, out, 0)


@_kernel
def spool_reduced(i, pA, pB, c):
    """
    Steady spool position [m] of the full model at current ``i`` and load ``pA - pB``.

    ``x = g0 i / (1 + C_s dk)``: ``g0`` and ``C_s`` are the full valve's gain and spool
    compliance at null (:func:`valve_reduction`); ``dk = -k_ff w |p_CP - p_CT|`` is the change of
    the steady flow-force stiffness from null, which makes the valve open further under load.
    Held inside the end stops.
    """
    dk = -c[C_KFF] * c[C_W] * _sabs(pA - pB, 1e4, c[C_SMOOTH])
    xv = c[C_GV0] * i / (1.0 + c[C_CSV] * dk)
    return min(max(xv, -c[C_XVMAX]), c[C_XVMAX])


@_kernel
def rhs_reduced(x, u, c, out):
    """
    Reduced 6-state model: the valve as a second-order lag on :func:`spool_reduced`.

    ``a2 x'' + tau_v x' + x = x_ss(i, p_CP - p_CT)``, chambers and piston as the others.
    """
    xvd, xv, pA, pB, zd, z = x[0], x[1], x[2], x[3], x[4], x[5]
    out[0] = (spool_reduced(u[0], pA, pB, c) - xv - c[C_TAUV] * xvd) / c[C_A2V]
    out[1] = xvd
    qa, qb = main_stage_flows(xv, pA, pB, c)
    _cylinder(pA, pB, zd, z, qa, qb, u[1], c, out, 2)


@_kernel
def rhs(model, x, u, c, out):
    """Dispatch to the full (0), simplified (1) or reduced (2) right-hand side."""
    if model == FULL:
        rhs_full(x, u, c, out)
    elif model == SIMPLIFIED:
        rhs_simplified(x, u, c, out)
    else:
        rhs_reduced(x, u, c, out)


@_kernel
def _null_pilot_pressure(c):
    """Pilot chamber pressure [Pa] at null: inlet orifice flow = nozzle flow (bisection)."""
    pcr, sm = c[C_PCR], c[C_SMOOTH]
    k2r = math.sqrt(2.0 / c[C_RHO])
    k0 = c[C_CD0] * c[C_A0] * k2r
    kn = c[C_CDF] * math.pi * math.sqrt(4.0 * c[C_AN] / math.pi) * k2r
    d = 0.05e-6
    gap = 0.5 * (c[C_XF0] + math.sqrt(c[C_XF0] * c[C_XF0] + d * d))
    lo, hi = c[C_PT], c[C_PS]
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if k0 * sroot(c[C_PS] - mid, pcr, sm) > kn * gap * sroot(mid - c[C_PT], pcr, sm):
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def coefficients(p, smooth: bool = True) -> np.ndarray:
    """
    Return the kernels' coefficient vector of :class:`~ros_ehs.core.params.Params` ``p``.

    :func:`~ros_ehs.core.model.coefficients.pack`, then the reduced model's valve derived from
    the full model's (:func:`valve_reduction`).
    """
    c = pack(p, smooth)
    valve_reduction(c)
    return c


@_kernel
def valve_reduction(c):
    """
    Fill the reduced model's valve coefficients of ``c`` from the full model's valve.

    The six valve states of eq. (3) are linearised at null (no current, no load; central
    differences of :func:`rhs_full`), ``A y' = ...``, with the current ``B`` and a force on
    the spool ``E`` as inputs. Then, with ``H(s) = e_x (sI - A)^-1 B``:

    * ``g0 = H(0)`` [m/A], the static spool gain (0.0306 m/A for Table 1);
    * ``C_s = e_x (-A)^-1 E`` [m/N], the spool's static compliance to a force on it, so a
      stiffness change ``dk`` makes the gain ``g0 / (1 + C_s dk)``;
    * ``1 / (1 + tau_v s + a2 s^2)``, the second-order lag whose first three moments match
      ``H(s) / H(0)`` at s = 0 (``H = H(0) (1 - tau_v s + (tau_v^2 - a2) s^2 + ...)``):
      ``tau_v = -H'(0) / H(0)``, the group delay at 0 Hz, and ``a2 = tau_v^2 - H''(0) /
      (2 H(0))``. For Table 1: 1.25 ms and (0.84 ms)^2, 190 Hz with damping 0.75; its gain
      is within 0.2 % of the full valve's to 50 Hz and 3 % at 100 Hz (a first-order lag:
      7 % and 18 %).
    """
    n = 6
    x = np.zeros(N_FULL)
    p0 = _null_pilot_pressure(c)
    x[2] = p0
    x[3] = p0
    x[6] = 0.5 * (c[C_PS] + c[C_PT])
    x[7] = x[6]
    u = np.zeros(2)
    fp = np.empty(N_FULL)
    fm = np.empty(N_FULL)
    a = np.empty((n, n))
    scale = (1.0, 1e-3, 1e6, 1e6, 0.1, 1e-4)
    for j in range(n):
        dx = 1e-6 * scale[j]
        x[j] += dx
        rhs_full(x, u, c, fp)
        x[j] -= 2.0 * dx
        rhs_full(x, u, c, fm)
        x[j] += dx
        for r in range(n):
            a[r, j] = -(fp[r] - fm[r]) / (2.0 * dx)     # -A
    di = 1e-6
    u[0] = di
    rhs_full(x, u, c, fp)
    u[0] = -di
    rhs_full(x, u, c, fm)
    b = np.empty(n)
    for r in range(n):
        b[r] = (fp[r] - fm[r]) / (2.0 * di)
    e = np.zeros(n)
    e[4] = 1.0 / c[C_MS]
    piv = np.empty(n, dtype=np.int64)
    _lu_factor(a, piv)
    _lu_solve(a, piv, b)       # (-A)^-1 B = H(0)
    _lu_solve(a, piv, e)
    g0 = b[5]
    _lu_solve(a, piv, b)       # (-A)^-2 B = -H'(0)
    tau = b[5] / g0
    _lu_solve(a, piv, b)       # (-A)^-3 B = H''(0) / 2
    c[C_GV0] = g0
    c[C_CSV] = e[5]
    c[C_TAUV] = tau
    c[C_A2V] = max(tau * tau - b[5] / g0, 1e-3 * tau * tau)   # > 0: a proper lag


# --- the simplified model's exact state Jacobian ------------------------------------------
@_kernel
def _dsroot(dp, p_cr, smooth):
    """Return the derivative of :func:`sroot` by the pressure drop."""
    if smooth > 0.5:
        q = dp * dp + p_cr * p_cr
        return (1.0 - 0.5 * dp * dp / q) / math.sqrt(math.sqrt(q))
    return 0.5 / math.sqrt(max(abs(dp), 1e-300))


@_kernel
def _dsoft_clip(f, lim, smooth):
    """Return the derivative of :func:`soft_clip` by ``f``."""
    if smooth > 0.5:
        d = 0.01 * lim + 1e-9
        a, b = f + lim, f - lim
        return 0.5 * (a / math.sqrt(a * a + d * d) - b / math.sqrt(b * b + d * d))
    return 1.0 if -lim < f < lim else 0.0


@_kernel
def _flows_jacobian(xv, pA, pB, c, linear):
    """
    Main-stage flows and their derivatives: ``qa, qb, dqa/dpA, dqb/dpB, dqa/dxv, dqb/dxv``.

    :func:`main_stage_flows` differentiated, or with ``linear`` the law ``K_q x`` (which
    only the simplified model offers).
    """
    if linear:
        qa = c[C_KQ] * xv
        return qa, -qa, 0.0, 0.0, c[C_KQ], -c[C_KQ]
    sm = c[C_SMOOTH]
    k = c[C_CD] * c[C_W] * math.sqrt(2.0 / c[C_RHO])
    xe = xv + c[C_XBIAS]
    clr, rc = c[C_CLR], c[C_RC]
    h_pa = edge_gap(xe, clr, rc)
    h_pb = edge_gap(-xe, clr, rc)
    ps, pt, pcr = c[C_PS], c[C_PT], c[C_PCR]
    sa1, sa2 = sroot(ps - pA, pcr, sm), sroot(pA - pt, pcr, sm)
    sb1, sb2 = sroot(ps - pB, pcr, sm), sroot(pB - pt, pcr, sm)
    qa = k * (h_pa * sa1 - h_pb * sa2)
    qb = k * (h_pb * sb1 - h_pa * sb2)
    dqa = -k * (h_pa * _dsroot(ps - pA, pcr, sm) + h_pb * _dsroot(pA - pt, pcr, sm))
    dqb = -k * (h_pb * _dsroot(ps - pB, pcr, sm) + h_pa * _dsroot(pB - pt, pcr, sm))
    ea = _dedge(xe, clr, rc)          # d h_pa / d xv
    eb = -_dedge(-xe, clr, rc)        # d h_pb / d xv
    return qa, qb, dqa, dqb, k * (ea * sa1 - eb * sa2), k * (eb * sb1 - ea * sb2)


@_kernel
def _dedge(x, clr, rc):
    """Return the derivative of :func:`edge_gap` by the opening ``x``."""
    if x <= -rc:
        return 0.0
    s = x + rc
    q = clr + rc
    return s / math.sqrt(s * s + q * q)


@_kernel
def _cylinder_jacobian(pA, pB, zd, z, qa, qb, dqa, dqb, f_load, c, out, jac, o):
    """
    Write :func:`_cylinder` into ``out[o:o+4]`` and its derivatives into ``jac``.

    The derivatives by its own four states go to ``jac[o:o+4, o:o+4]``; ``dqa``/``dqb`` are
    the flows' derivatives by their own chamber's pressure.
    """
    sm = c[C_SMOOTH]
    ap, beta, kc = c[C_AP], c[C_BETA_E], c[C_KC]
    leak = kc * (pA - pB)
    va = ap * (c[C_LIAC] + z)
    vb = ap * (c[C_LIAC] - z)
    ga, gb = beta / va, beta / vb
    fa = ga * (qa - ap * zd - leak)
    fb = gb * (qb + ap * zd + leak)
    jac[o, o + 0] = ga * (dqa - kc)
    jac[o, o + 1] = ga * kc
    jac[o, o + 2] = -ga * ap
    jac[o, o + 3] = -fa * ap / va
    jac[o + 1, o + 0] = gb * kc
    jac[o + 1, o + 1] = gb * (dqb - kc)
    jac[o + 1, o + 2] = gb * ap
    jac[o + 1, o + 3] = fb * ap / vb
    # piston: f_oc, the friction of eqs. (14)-(15) (see :func:`friction`), the end stop
    mp = c[C_MP]
    f_oc = ap * (pA - pB) - (c[C_CC] + c[C_CL]) * zd - c[C_KL] * (z - c[C_ZL]) + f_load
    eps = c[C_EPSV]
    vcs = c[C_VCS]
    if sm > 0.5:
        r = math.sqrt(zd * zd + eps * eps)
        sabs, dsabs = r - eps, zd / r
        th_s = math.tanh(zd / eps)
        sgn, dsgn = th_s, (1.0 - th_s * th_s) / eps
    else:
        sabs, dsabs = abs(zd), (1.0 if zd > 0.0 else (-1.0 if zd < 0.0 else 0.0))
        sgn, dsgn = dsabs, 0.0
    th = math.tanh(sabs / vcs - 1.0)
    xi = 0.5 * (th + 1.0)
    dxi = 0.5 * (1.0 - th * th) * dsabs / vcs
    f_hold = f_oc
    dhold_dv = 0.0
    if c[C_RENORM] > 0.5:
        xi0 = c[C_XI0]
        xi = (xi - xi0) / (1.0 - xi0)
        dxi = dxi / (1.0 - xi0)
        f_hold = f_oc + mp * zd / c[C_TAUST]
        dhold_dv = mp / c[C_TAUST]
    fsc, fcc = c[C_FSC], c[C_FCC]
    dclip = _dsoft_clip(f_hold, fsc, sm)
    df_doc = 1.0 - (1.0 - xi) * dclip            # d (f_oc + f_c) / d f_oc
    df_dv = -(-dxi * soft_clip(f_hold, fsc, sm) + (1.0 - xi) * dclip * dhold_dv
              + dxi * sgn * fcc + xi * dsgn * fcc)
    stroke = c[C_STROKE]
    dstop_z = 0.0
    dstop_v = 0.0
    if z > stroke or z < -stroke:
        dstop_z = -c[C_KSTOP]
        dstop_v = -1.4 * math.sqrt(c[C_KSTOP] * mp)
    jac[o + 2, o + 0] = df_doc * ap / mp
    jac[o + 2, o + 1] = -df_doc * ap / mp
    jac[o + 2, o + 2] = (-df_doc * (c[C_CC] + c[C_CL]) + df_dv + dstop_v) / mp
    jac[o + 2, o + 3] = (-df_doc * c[C_KL] + dstop_z) / mp
    jac[o + 3, o + 0] = 0.0
    jac[o + 3, o + 1] = 0.0
    jac[o + 3, o + 2] = 1.0
    jac[o + 3, o + 3] = 0.0
    f_c = -((1.0 - xi) * soft_clip(f_hold, fsc, sm) + xi * sgn * fcc)
    out[o] = fa
    out[o + 1] = fb
    out[o + 2] = (f_oc + f_c + _stop(z, zd, stroke, c[C_KSTOP], mp)) / mp
    out[o + 3] = zd


@_kernel
def rhs_jacobian_simplified(x, u, c, out, jac):
    """
    :func:`rhs_simplified` into ``out`` and its exact ``d/dx`` into ``jac`` (4, 4), at once.

    The integrator's W at the cost of about one more right-hand side, where forward
    differences cost four (and their round-off). Differentiated case by case as
    :func:`rhs_simplified` computes (smooth or exact forms); tested against differences.
    """
    qa, qb, dqa, dqb, _, _ = _flows_jacobian(spool_static(u[0], c), x[0], x[1], c,
                                             c[C_LINEAR] > 0.5)
    _cylinder_jacobian(x[0], x[1], x[2], x[3], qa, qb, dqa, dqb, u[1], c, out, jac, 0)


@_kernel
def rhs_jacobian_reduced(x, u, c, out, jac):
    """:func:`rhs_reduced` and its exact ``d/dx`` (6, 6), as :func:`rhs_jacobian_simplified`."""
    xvd, xv, pA, pB, zd, z = x[0], x[1], x[2], x[3], x[4], x[5]
    for r in range(6):
        for j in range(6):
            jac[r, j] = 0.0
    # the valve's lag on its steady, load-dependent opening (:func:`spool_reduced`)
    sm = c[C_SMOOTH]
    d = pA - pB
    dk = -c[C_KFF] * c[C_W] * _sabs(d, 1e4, sm)
    den = 1.0 + c[C_CSV] * dk
    ss = c[C_GV0] * u[0] / den
    lim = c[C_XVMAX]
    a2 = c[C_A2V]
    dss = 0.0                          # d ss / d (pA - pB), zero where the stop holds it
    if -lim < ss < lim:
        dsabs = d / math.sqrt(d * d + 1e8) if sm > 0.5 else (1.0 if d > 0.0 else -1.0)
        dss = c[C_GV0] * u[0] * c[C_CSV] * c[C_KFF] * c[C_W] * dsabs / (den * den)
    out[0] = (min(max(ss, -lim), lim) - xv - c[C_TAUV] * xvd) / a2
    out[1] = xvd
    jac[0, 0] = -c[C_TAUV] / a2
    jac[0, 1] = -1.0 / a2
    jac[0, 2] = dss / a2
    jac[0, 3] = -dss / a2
    jac[1, 0] = 1.0
    qa, qb, dqa, dqb, dqa_x, dqb_x = _flows_jacobian(xv, pA, pB, c, False)
    _cylinder_jacobian(pA, pB, zd, z, qa, qb, dqa, dqb, u[1], c, out, jac, 2)
    jac[2, 1] = c[C_BETA_E] / (c[C_AP] * (c[C_LIAC] + z)) * dqa_x
    jac[3, 1] = c[C_BETA_E] / (c[C_AP] * (c[C_LIAC] - z)) * dqb_x


# --- fixed-step linearly implicit integrator ---------------------------------------------
@_kernel
def _jacobian(model, x, u, c, f0, xscale, jac, xt, ft):
    n = x.shape[0]
    for j in range(n):
        xt[:] = x
        dx = 1.5e-8 * max(abs(x[j]), xscale[j])
        xt[j] = x[j] + dx
        rhs(model, xt, u, c, ft)
        for r in range(n):
            jac[r, j] = (ft[r] - f0[r]) / dx


@_kernel
def _lu_factor(a, piv):
    """In-place LU with partial pivoting (small dense matrices)."""
    n = a.shape[0]
    for k in range(n):
        p = k
        m = abs(a[k, k])
        for r in range(k + 1, n):
            if abs(a[r, k]) > m:
                m = abs(a[r, k])
                p = r
        piv[k] = p
        if p != k:
            for j in range(n):
                t = a[k, j]
                a[k, j] = a[p, j]
                a[p, j] = t
        inv = 1.0 / a[k, k]
        for r in range(k + 1, n):
            a[r, k] *= inv
            f = a[r, k]
            for j in range(k + 1, n):
                a[r, j] -= f * a[k, j]


@_kernel
def _lu_solve(a, piv, b):
    n = a.shape[0]
    for k in range(n):
        p = piv[k]
        if p != k:
            t = b[k]
            b[k] = b[p]
            b[p] = t
    for r in range(1, n):
        s = b[r]
        for j in range(r):
            s -= a[r, j] * b[j]
        b[r] = s
    for r in range(n - 1, -1, -1):
        s = b[r]
        for j in range(r + 1, n):
            s -= a[r, j] * b[j]
        b[r] = s / a[r, r]


GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


@_kernel
def advance_ws(model, x, u, c, h, nsub, xscale, w, piv, refresh):
    """
    Advance ``x`` in place by ``nsub`` steps of ``h`` seconds with input ``u`` held.

    Two-stage Rosenbrock method ROS2 (Verwer et al. 1999), L-stable and of order 2 for
    *any* matrix W = I - gamma h J, so a finite-difference Jacobian taken every few calls
    (``refresh``) serves all substeps in between::

        W k1 = f(x_n)
        W k2 = f(x_n + h k1) - 2 k1
        x_n+1 = x_n + 3/2 h k1 + 1/2 h k2

    ``w`` (n, n) and ``piv`` (n,) hold the factorised W between calls.
    """
    n = x.shape[0]
    f0 = np.empty(n)
    xt = np.empty(n)
    ft = np.empty(n)
    k1 = np.empty(n)
    k2 = np.empty(n)
    if refresh and model == SIMPLIFIED:
        rhs_jacobian_simplified(x, u, c, f0, w)
    elif refresh and model == REDUCED:
        rhs_jacobian_reduced(x, u, c, f0, w)
    else:
        rhs(model, x, u, c, f0)
    if refresh:
        if model == FULL:
            _jacobian(model, x, u, c, f0, xscale, w, xt, ft)
        for r in range(n):
            for j in range(n):
                w[r, j] = -GAMMA * h * w[r, j]
            w[r, r] += 1.0
        _lu_factor(w, piv)
    for s in range(nsub):
        if s > 0:
            rhs(model, x, u, c, f0)
        k1[:] = f0
        _lu_solve(w, piv, k1)
        for r in range(n):
            xt[r] = x[r] + h * k1[r]
        rhs(model, xt, u, c, ft)
        for r in range(n):
            k2[r] = ft[r] - 2.0 * k1[r]
        _lu_solve(w, piv, k2)
        for r in range(n):
            x[r] += h * (1.5 * k1[r] + 0.5 * k2[r])


@_kernel
def simulate(model, x0, u, c, dt, nsub, xscale, jac_every, out):
    """
    Batch simulation: ``u`` (N, 2) held for ``dt`` each; ``out`` (N+1, n) gets the states.

    The Jacobian is refreshed every ``jac_every`` samples. Returns the index of the first
    non-finite state (N+1 when all are finite).
    """
    return simulate_pieces(model, x0, u, 1, c, dt, nsub, xscale, jac_every, out)


@_kernel
def simulate_pieces(model, x0, u, per, c, dt, nsub, xscale, jac_every, out):
    """
    :func:`simulate` with each sample's input held in ``per`` pieces (``per`` divides ``nsub``).

    ``u`` (N * per, 2): piece j of sample k, ``u[k * per + j]``, is held for ``nsub // per``
    substeps; ``out`` (N+1, n) gets the states at the samples. A command that takes over
    between two samples (a jittered driver's) then acts from its piece rather than spread
    over the sample. The Jacobian is refreshed at the first piece of every ``jac_every``-th
    sample, as :func:`simulate` does.
    """
    n = x0.shape[0]
    x = x0.copy()
    w = np.empty((n, n))
    piv = np.empty(n, dtype=np.int64)
    out[0, :] = x
    h = dt / nsub
    sub = nsub // per
    samples = u.shape[0] // per
    for k in range(samples):
        for j in range(per):
            advance_ws(model, x, u[k * per + j], c, h, sub, xscale, w, piv,
                       j == 0 and k % jac_every == 0)
        for r in range(n):
            if not math.isfinite(x[r]):
                return k + 1
        out[k + 1, :] = x
    return samples + 1
