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
"""Plant physics: each test checks a property that a wrong model would fail."""

import os
import subprocess
import sys

import numpy as np
import pytest

from ros_ehs.core.control.waveforms import Sine
from ros_ehs.core.errors import InputError, ParameterError
from ros_ehs.core.model import flow_gain_kq, Plant
from ros_ehs.core.model.kernels import edge_gap
from ros_ehs.core.params import preset
from ros_ehs.core.sim.closed_loop import run_closed_loop

EST = preset('table1_estimated', ff_enable=0.0)
FRICTIONLESS = EST.replace(F_cc=0.0, F_sc=0.0, c_c=0.0, K_C=0.0)


def _hold(plant, i, seconds, x0=None, f_load=0.0):
    n = int(round(seconds / 1e-3))
    return plant.simulate(1e-3, np.tile([i, f_load], (n, 1)), x0=x0)


def test_frictionless_linear_law_steady_speed_is_kq_kx_i_over_a():
    p = FRICTIONLESS.replace(flow_law='linear')
    i = 2e-3
    r = _hold(Plant(p, 'simplified'), i, 0.5)
    expected = flow_gain_kq(p) * p['K_x'] * i / p['A_p']
    assert r.z_dot[-1] == pytest.approx(expected, rel=1e-6)


def test_frictionless_orifice_law_steady_speed_matches_the_opening_law():
    p = FRICTIONLESS
    i = 2e-3
    r = _hold(Plant(p, 'simplified'), i, 0.5)
    xe = p['K_x'] * i + p['x_bias']
    gap = edge_gap(xe, p['d_c'] / 2, p['r_c']) - edge_gap(-xe, p['d_c'] / 2, p['r_c'])
    w = np.pi * (p['d_s'] + p['d_c'] / 2)
    exact = p['C_d'] * w * gap * np.sqrt((p['p_s'] - p['p_t']) / p['rho']) / p['A_p']
    assert r.z_dot[-1] == pytest.approx(exact, rel=2e-3)
    # wide open (x >> d_c, r_c) the orifice law tends to the linear law of eq. (7)
    i = 10e-3
    r = _hold(Plant(p, 'simplified'), i, 0.1)
    linear = flow_gain_kq(p) * p['K_x'] * i / p['A_p']
    assert r.z_dot[-1] == pytest.approx(linear, rel=0.02)


@pytest.mark.parametrize('model', ['full', 'reduced', 'simplified'])
def test_zero_current_keeps_pressures_balanced_and_the_piston_still(model):
    p = EST.replace(x_bias=0.0)
    plant = Plant(p, model)
    r = _hold(plant, 0.0, 1.0)
    assert abs(r.p_a[-1] - r.p_b[-1]) < 1.0
    assert r.p_a[-1] == pytest.approx(0.5 * p['p_s'], rel=1e-3)
    assert np.abs(r.z).max() < 1e-9
    # with the paper's null bias the pressures differ a little, and friction holds the piston
    r = _hold(Plant(EST, model), 0.0, 1.0)
    assert abs(EST['A_p'] * (r.p_a[-1] - r.p_b[-1])) < EST['F_sc']
    assert np.abs(r.z).max() < 1e-7


def test_piston_sticks_until_the_hydraulic_force_reaches_static_friction():
    p = EST.replace(c_c=0.0)
    plant = Plant(p, 'simplified', h=1e-4)
    r = _hold(plant, 0.1e-3, 0.6)   # a trickle of flow builds pressure in a stuck piston
    moving = np.flatnonzero(np.abs(r.z_dot) > 1e-4)
    assert moving.size, 'piston never broke away'
    k = moving[0]
    assert np.abs(r.z[: k - 20]).max() < 2e-6
    assert np.abs(r.force[: k - 20]).max() < p['F_sc']
    assert abs(r.force[k]) == pytest.approx(p['F_sc'], rel=0.05)


def test_papers_friction_form_creeps_at_rest_where_the_renormalised_form_sticks():
    f_load = 0.5 * EST['F_sc']
    stuck = _hold(Plant(EST, 'simplified', h=1e-4), 0.0, 0.3, f_load=f_load)
    creep = _hold(Plant(EST.replace(friction_law='paper'), 'simplified', h=1e-4), 0.0, 0.3,
                  f_load=f_load)
    # with the valve at null a load compresses the oil column by F/k_h ~ 43 um; the paper's
    # form (xi(0) = 0.119) lets the piston follow, the renormalised form holds it
    k_h = 2 * EST['beta_e'] * EST['A_p'] / EST['l_iac']
    assert abs(stuck.z[-1]) < 1e-6
    assert abs(creep.z[-1]) > 0.5 * f_load / k_h


@pytest.mark.parametrize('model', ['full', 'reduced', 'simplified'])
def test_pressures_stay_within_tank_and_supply_on_the_papers_test(model):
    r = run_closed_loop(EST, Sine(), 2.0, model=model)
    for name in ('p_CP', 'p_CT'):
        s = r.signal(name)
        assert s.min() > EST['p_t'] and s.max() < EST['p_s']


def test_full_and_simplified_models_agree_on_the_1hz_sine():
    full = run_closed_loop(EST, Sine(), 2.0, model='full')
    simp = run_closed_loop(EST, Sine(), 2.0, model='simplified')
    assert np.abs(full.z - simp.z).max() < 1e-3          # 2.5 % of the 0.04 m amplitude
    assert np.sqrt(np.mean((full.z - simp.z) ** 2)) < 4e-4


@pytest.mark.parametrize('model,tol', [('full', 1e-6), ('reduced', 1e-5), ('simplified', 1e-4)])
def test_fast_integrator_matches_the_radau_reference(model, tol):
    fast = run_closed_loop(EST, Sine(), 0.15, model=model)
    ref = run_closed_loop(EST, Sine(), 0.15, model=model, stepper='reference')
    assert np.abs(fast.z - ref.z).max() < tol
    assert np.abs(fast.z_dot - ref.z_dot).max() < 1e3 * tol


def _valve_alone(i, p_load):
    """Return the full model's six valve equations, chambers frozen at load ``p_load``."""
    from ros_ehs.core.model.kernels import coefficients
    from ros_ehs.core.model.kernels import rhs_full
    c = coefficients(EST)
    pm = 0.5 * (EST['p_s'] + EST['p_t'])
    x = np.array([0.0, 0.0, pm, pm, 0.0, 0.0, pm + p_load / 2, pm - p_load / 2, 0.0, 0.0])
    u = np.array([i, 0.0])

    def f(t, y):
        x[:6] = y
        out = np.empty(10)
        rhs_full(x, u, c, out)
        return out[:6]
    return f, x[:6].copy()


@pytest.mark.parametrize('p_load', [0.0, 10e6, -10e6])
def test_reduced_valve_gain_and_lag_match_the_full_valve(p_load):
    """
    The full valve alone (scipy's Radau, chambers frozen) against the reduced model's.

    A 5 mA step: the settled spool position (which grows under load: the flow force
    stiffens the spool less) and the step response, sampled every 0.5 ms. The reduced
    valve is a second-order lag, the full one sixth-order.
    """
    from scipy.integrate import solve_ivp
    from ros_ehs.core.model.coefficients import C_A2V, C_TAUV
    from ros_ehs.core.model.kernels import coefficients
    from ros_ehs.core.model.kernels import spool_reduced
    i = 5e-3
    f, y0 = _valve_alone(i, p_load)
    f0, _ = _valve_alone(0.0, p_load)
    y0 = solve_ivp(f0, (0, 0.1), y0, method='Radau', rtol=1e-9, atol=1e-12).y[:, -1]
    t = np.arange(0.0, 0.03, 5e-4)
    full = solve_ivp(f, (0, t[-1]), y0, method='Radau', t_eval=t, rtol=1e-9,
                     atol=1e-12).y[5]
    pm = 0.5 * (EST['p_s'] + EST['p_t'])
    c = coefficients(EST)
    x_ss = spool_reduced(i, pm + p_load / 2, pm - p_load / 2, c)
    x0 = spool_reduced(0.0, pm + p_load / 2, pm - p_load / 2, c)
    assert x_ss - x0 == pytest.approx(full[-1] - full[0], rel=5e-3)
    if p_load:
        assert (x_ss - x0) / i > 1.1 * EST['K_x']     # opens further under load

    def lag(t, y):
        return [(x_ss - y[1] - c[C_TAUV] * y[0]) / c[C_A2V], y[0]]
    red = solve_ivp(lag, (0, t[-1]), [0.0, x0], t_eval=t, rtol=1e-9, atol=1e-12).y[1]
    # moments matched at 0 Hz: the full valve starts faster (6 % of the step at 0.5 ms, 9 %
    # under 10 MPa load),
    # then the two agree (within 1.7 % of it at 5 ms)
    step = abs(full[-1] - full[0])
    assert np.abs(red - full).max() < 0.10 * step
    assert np.abs(red - full)[t >= 5e-3].max() < 0.02 * step


@pytest.mark.parametrize('case', ['sine', 'chirp'])
def test_reduced_model_follows_the_full_one_where_the_simplified_does_not(case):
    """
    Equal parameters, the default controller, 10 s: RMS differences from the full model.

    Targets (docs/model.md): velocity <= 1 %, load pressure <= 3 % of the full model's RMS.
    """
    from ros_ehs.core.sim.closed_loop import model_difference
    from ros_ehs.core.control.waveforms import Chirp
    ref = Sine(0.04, 1.0) if case == 'sine' else Chirp(0.02, 0.2, 5.0, 10.0)
    p = preset('table1_estimated')
    red = model_difference(p, ref, 10.0, 'reduced')
    simp = model_difference(p, ref, 10.0, 'simplified')
    assert red['velocity'] <= 0.01 and red['load_pressure'] <= 0.03, red
    assert simp['velocity'] > 0.02 and simp['load_pressure'] > 0.05, simp


def test_integrator_error_shrinks_as_h_squared():
    ref = run_closed_loop(EST, Sine(), 0.3, model='full', h=1.25e-5)
    errs = [np.abs(run_closed_loop(EST, Sine(), 0.3, model='full', h=h).z - ref.z).max()
            for h in (2e-4, 1e-4)]
    assert 3.0 < errs[0] / errs[1] < 5.0


def test_smoothing_leaves_the_response_unchanged():
    smooth = run_closed_loop(EST, Sine(), 1.0, model='simplified', h=1e-4)
    from ros_ehs.core.control import Controller
    plant = Plant(EST, 'simplified', h=1e-6, smooth=False)   # exact sign/sat/sqrt
    ctrl = Controller(EST)
    x = plant.equilibrium()
    z_ref, v_ref = Sine()(smooth.t)
    z = [x[3]]
    for k in range(smooth.t.size - 1):
        x = plant.step(x, [ctrl.step(z_ref[k], v_ref[k], x[3]), 0.0], 1e-3)
        z.append(x[3])
    assert np.abs(np.array(z) - smooth.z).max() < 5e-5     # 0.1 % of the amplitude


def _rates(plant, x, i):
    from ros_ehs.core.model import kernels as K
    f = np.empty(plant.n)
    K.rhs(plant._id, x, np.array([i, 0.0]), plant._c, f)
    return dict(zip(plant.state_names, f))


@pytest.mark.parametrize('model', ['full', 'reduced', 'simplified'])
def test_the_rest_state_is_newtons_and_hybrs_alike(model, monkeypatch):
    # Newton's method solves it (no scipy.optimize at a node's start); MINPACK's hybrid
    # method, where Newton does not converge, finds the same state where it converges
    from ros_ehs.core.model import plant as plant_module
    rng = np.random.default_rng(7)
    for k in range(6):
        p = EST.replace(**{n: float(EST[n] * rng.uniform(0.75, 1.25))
                           for n in ('d_c', 'F_cc', 'F_sc', 'l_iac', 'c_c', 'r_c')})
        pl = Plant(p, model)
        z, i = float(rng.uniform(-0.05, 0.05)), float(rng.uniform(-2e-4, 2e-4)) * (k % 2)
        x = pl.equilibrium(z, i)
        rates = _rates(pl, x, i)
        held = [s for s in ('p_CP', 'p_CT', 'x_dot', 'theta_dot', 'p_tL', 'p_tR')
                if s in rates]
        assert x[pl.state_names.index('z')] == z and x[pl.state_names.index('z_dot')] == 0.0
        # each solved rate vanishes: a pressure's to 1e-3 Pa/s (of 1e7 Pa), the others' to 1e-9
        assert all(abs(rates[s]) < (1e-3 if s.startswith('p') else 1e-9) for s in held), rates
        with monkeypatch.context() as m:
            m.setattr(plant_module, '_newton', lambda resid, y: None)     # hybr alone
            y = pl.equilibrium(z, i)
        assert np.allclose(x, y, rtol=1e-11, atol=1e-12), (x, y)


def test_a_plant_at_rest_does_not_import_scipy_optimize(python_lines):
    code = ('import sys\n'
            'from ros_ehs.core.params import Params\n'
            'from ros_ehs.core.sim.axis import SimulatedAxis\n'
            'for model in ("simplified", "reduced", "full"):\n'
            '    SimulatedAxis(Params(), model, initial_z=0.01)\n'
            'print("scipy.optimize" in sys.modules)')
    assert python_lines(code) == ['False']


def test_bad_inputs_give_clear_errors():
    plant = Plant(EST, 'simplified')
    x = plant.equilibrium()
    with pytest.raises(InputError, match=r'`u` = \[nan, 0.0\] is not finite'):
        plant.step(x, [np.nan, 0.0], 1e-3)
    with pytest.raises(InputError, match='`dt`'):
        plant.step(x, [0.0, 0.0], -1e-3)
    with pytest.raises(InputError, match=r"non-finite states: \['z_dot'\]"):
        plant.step(np.array([1e7, 1e7, np.inf, 0.0]), [0.0, 0.0], 1e-3)
    with pytest.raises(InputError, match='shape'):
        plant.dynamics(0.0, np.zeros(10), [0.0, 0.0])
    with pytest.raises(InputError, match='not finite at sample 2'):
        plant.simulate(1e-3, [0.0, 0.0, np.inf])
    with pytest.raises(ParameterError, match='`model`'):
        Plant(EST, 'quantum')
    assert np.array_equal(plant.step(x, [0.0, 0.0], 0.0), x)


def test_a_step_that_leaves_no_finite_state_says_so_in_both_paths():
    full = Plant(EST, 'full')
    x = full.equilibrium()
    x[full.state_names.index('p_CP')] = 1e300          # finite, and overflows in one step
    with pytest.raises(InputError, match=r'integration diverged within dt = 0.001 s at u'):
        full.step(x, [0.01, 0.0], 1e-3)
    with pytest.raises(InputError, match=r'integration diverged within dt = 0.001 s at u'):
        run_closed_loop(EST, Sine(0.01, 1.0), 0.01, model='full', x0=x)


@pytest.mark.parametrize('model', ['full', 'reduced', 'simplified'])
def test_the_unchecked_advance_is_step_to_the_bit_and_says_when_the_state_leaves(model):
    checked, fast = Plant(EST, model), Plant(EST, model)
    x = checked.equilibrium()
    y = x.copy()
    for i in np.random.default_rng(3).uniform(-0.01, 0.01, 200):
        u = np.array([i, 0.0])
        x = checked.step(x, u, 1e-3)
        assert fast.advance(y, u, 1e-3) == y.tolist()     # the new state, as floats
    assert np.array_equal(x, y)
    bad = y.copy()
    bad[0] = np.nan
    assert fast.advance(bad, np.zeros(2), 1e-3) is None
    out = y.copy()
    out[fast.state_names.index('z')] = 1.01 * EST['l_iac']     # past the cylinder's end
    assert fast.advance(out, np.zeros(2), 1e-3) is None


@pytest.mark.parametrize('model', ['simplified', 'reduced'])
@pytest.mark.parametrize('law,flow,smooth', [('renormalised', 'orifice', True),
                                             ('paper', 'orifice', True),
                                             ('renormalised', 'linear', True),
                                             ('renormalised', 'orifice', False)])
def test_the_exact_jacobians_match_central_differences(model, law, flow, smooth):
    """The integrator's W for the simplified and reduced models: exact, and the same rhs."""
    from ros_ehs.core.model import kernels as K
    from ros_ehs.core.model.kernels import coefficients
    c = coefficients(EST.replace(friction_law=law, flow_law=flow), smooth=smooth)
    rhs, both = ((K.rhs_simplified, K.rhs_jacobian_simplified) if model == 'simplified' else
                 (K.rhs_reduced, K.rhs_jacobian_reduced))
    rng = np.random.default_rng(3)
    n = 4 if model == 'simplified' else 6
    scale = np.array([1e5, 1e5, 1e-3, 1e-3])
    if n == 6:
        scale = np.concatenate([[1e-3, 1e-6], scale])
    worst = 0.0
    for _ in range(200):
        # chambers across the supply range, speeds from sticking to fast, in and beyond stroke
        x = np.array([rng.uniform(1e6, 2e7), rng.uniform(1e6, 2e7),
                      rng.normal(0.0, 0.05) * rng.choice([1.0, 1e-3, 1e-5]),
                      rng.uniform(-0.12, 0.12)])
        if n == 6:        # spool speed and opening, inside and at its stops
            x = np.concatenate([[rng.normal(0.0, 0.05), rng.normal(0.0, 2e-4)], x])
        u = np.array([rng.normal(0.0, 0.01), rng.normal(0.0, 1000.0)])
        f, jac = np.empty(n), np.empty((n, n))
        both(x, u, c, f, jac)
        ref = np.empty(n)
        rhs(x, u, c, ref)
        np.testing.assert_allclose(f, ref, rtol=1e-12, atol=0.0)
        fp, fm, num = np.empty(n), np.empty(n), np.empty((n, n))
        for j in range(n):
            d = 1e-6 * max(abs(x[j]), scale[j])
            xp, xm = x.copy(), x.copy()
            xp[j] += d
            xm[j] -= d
            rhs(xp, u, c, fp)
            rhs(xm, u, c, fm)
            num[:, j] = (fp - fm) / (2.0 * d)
        if not smooth and abs(x[n - 2]) < 1e-4:
            continue         # the exact sign's kink: differences straddle it
        # relative to each row's largest entry (entries near zero carry round-off)
        err = np.abs(jac - num) / (np.abs(num).max(axis=1, keepdims=True) + 1e-300)
        worst = max(worst, float(err.max()))
    assert worst < 1e-5, worst


def test_compile_kernels_leaves_every_entry_point_compiled_for_contiguous_arrays():
    """setup.sh compiles through this: it must reach what the plant and the fit call."""
    from ros_ehs.core.model import kernels as K
    from ros_ehs.core.model.plant import compile_kernels
    compile_kernels()
    for kernel in (K.rhs, K.advance_ws, K.simulate, K.simulate_pieces):
        arrays = [[a for a in sig if getattr(a, 'layout', None)] for sig in kernel.signatures]
        assert any(all(a.layout == 'C' and str(a.dtype) == 'float64'
                       for a in sig if str(a.dtype) != 'int64') for sig in arrays), \
            (kernel.__name__, kernel.signatures)


@pytest.mark.parametrize('model', ['full', 'reduced', 'simplified'])
def test_a_sample_held_in_pieces_is_the_same_to_the_bit_as_the_pieces_held_as_samples(model):
    """
    ``simulate_pieces`` holds piece j of sample k for its share of the substeps.

    It is ``simulate`` on the pieces' own grid with the Jacobian refreshed once a sample: the
    same bits at every sample; with each sample's pieces alike it is ``simulate`` itself, and
    a takeover within a sample ends elsewhere than the sample's mean held whole.
    """
    from ros_ehs.core.model import kernels as K
    plant = Plant(preset('table1_estimated'), model)
    x0 = plant.equilibrium()
    dt, nsub, n = 1e-3, 8, 300
    t = np.arange(n * 4) * dt / 4
    fine = np.column_stack([0.008 * np.sin(2 * np.pi * 2.0 * t) +
                            0.003 * np.sign(np.sin(2 * np.pi * 9.0 * t + 0.3)), np.zeros(t.size)])

    def pieces(u, per):
        out = np.empty((n + 1, plant.n))
        assert K.simulate_pieces(plant._id, x0.copy(), u, per, plant._c, dt, nsub,
                                 plant._xscale, 1, out) == n + 1
        return out

    for per in (2, 4):
        u = fine[::4 // per]
        grid = np.empty((n * per + 1, plant.n))
        K.simulate(plant._id, x0.copy(), u, plant._c, dt / per, nsub // per, plant._xscale, per,
                   grid)
        np.testing.assert_array_equal(pieces(u, per), grid[::per])
    whole = fine[::4]
    held = np.empty((n + 1, plant.n))
    K.simulate(plant._id, x0.copy(), whole, plant._c, dt, nsub, plant._xscale, 1, held)
    np.testing.assert_array_equal(pieces(np.repeat(whole, 4, axis=0), 4), held)
    mean = np.repeat(fine.reshape(n, 4, 2).mean(axis=1), 4, axis=0)
    iz = plant.state_names.index('z')
    assert np.max(np.abs(pieces(fine, 4)[:, iz] - pieces(mean, 4)[:, iz])) > 1e-6


#: each model's replay of a record, as a digest of its states' bits, in the order given
_REPLAY_DIGESTS = """
import hashlib, sys
import numpy as np
from ros_ehs.core.model import kernels as K, Plant
from ros_ehs.core.params import preset
t = np.arange(1500) * 1e-3
u = 0.008 * np.sin(2 * np.pi * 1.5 * t) + 0.002 * np.sign(np.sin(2 * np.pi * 7 * t))
for model in sys.argv[1:]:
    plant = Plant(preset('table1_estimated'), model)
    x = plant.simulate(1e-3, u).x
    # the fit's replay of a command held in two pieces of each 2 ms sample
    held = np.empty((751, plant.n))
    K.simulate_pieces(plant._id, x[0].copy(), np.column_stack([u, 0 * u]), 2, plant._c, 2e-3,
                      8, plant._xscale, 1, held)
    print(model, hashlib.sha256(x.tobytes() + held.tobytes()).hexdigest())
"""


def test_a_replay_is_the_same_to_the_bit_whatever_numba_built_first_and_for_which_cpu(tmp_path):
    """
    Two cold builds of the kernels replay a record to the same bits.

    One for this CPU with the models in one order, one for a generic CPU (no FMA, no AVX) in
    the other. A fit's path through its optimizer can fork on a replay's last bits, so the
    same record must replay the same from any build.
    """
    models = ['full', 'reduced', 'simplified']

    def digests(cache, order, cpu):
        env = {k: v for k, v in os.environ.items() if k != 'NUMBA_CPU_NAME'}
        env.update({'NUMBA_CACHE_DIR': str(tmp_path / cache), **cpu})
        out = subprocess.run([sys.executable, '-c', _REPLAY_DIGESTS, *order],
                             capture_output=True, text=True, timeout=600, env=env)
        assert out.returncode == 0, out.stderr[-2000:]
        got = dict(line.split() for line in out.stdout.strip().splitlines())
        assert list(got) == order
        return got

    here = digests('host', models, {})
    assert digests('generic', models[::-1], {'NUMBA_CPU_NAME': 'generic'}) == here


def test_the_kernels_cache_is_named_by_their_sources_options_and_numba():
    """Any change to a source file, to the options or to numba's version names another cache."""
    from ros_ehs.core.model import kernels as K
    tag = K.build_tag(K._SOURCES, K._JIT, '0.68.1')
    assert K.build_tag(K._SOURCES, K._JIT, '0.68.1') == tag
    assert K.build_tag(K._SOURCES, {**K._JIT, 'fastmath': True}, '0.68.1') != tag
    assert K.build_tag(K._SOURCES, K._JIT, '0.69.0') != tag
    assert K.build_tag(K._SOURCES[:-1], K._JIT, '0.68.1') != tag
    # every kernel, and the helper compiled from smooth.py, is cached under this build's name
    dispatchers = [v for v in vars(K).values() if hasattr(v, 'py_func')]
    assert len(dispatchers) > 20
    for disp in dispatchers:
        assert disp._cache._impl.locator.get_cache_path().startswith(K.CACHE_DIR + os.sep)


#: compile smooth_clip as a build with other options would have, into NUMBA_CACHE_DIR
_FOREIGN_BUILD = """
from numba import njit
from ros_ehs.core.model.smooth import smooth_clip
njit(cache=True, fastmath=True)(smooth_clip)(3.0, 1.0)
"""

#: the kernels' smooth_clip: did it load from the cache or compile?
_OWN_BUILD = """
from ros_ehs.core.model import kernels as K
K._smooth_clip(3.0, 1.0)
stats = K._smooth_clip.stats
print(sum(stats.cache_hits.values()), sum(stats.cache_misses.values()))
"""


def test_a_cached_kernel_built_with_other_options_is_not_loaded(tmp_path):
    """
    An entry of smooth.py's ``smooth_clip`` built with other options is compiled again.

    numba keys that entry on smooth.py alone; loading it for the kernels changed the last bits
    of every replay. The kernels' own build, cached, is loaded the second time.
    """
    env = {**os.environ, 'NUMBA_CACHE_DIR': str(tmp_path)}

    def run(script):
        out = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                             timeout=600, env=env)
        assert out.returncode == 0, out.stderr[-2000:]
        return out.stdout.split()

    assert run(_FOREIGN_BUILD) == []
    assert run(_OWN_BUILD) == ['0', '1']
    assert run(_OWN_BUILD) == ['1', '0']


def test_null_load_gain_is_the_slope_of_the_exact_null_of_the_flows():
    # the still piston under load F: the valve's flows feed the piston's leakage exactly
    from scipy.optimize import root
    from ros_ehs.core.model.coefficients import null_load_gain, pack
    from ros_ehs.core.model.kernels import main_stage_flows
    from ros_ehs.core.params import Params
    p = Params()
    c = pack(p)

    def null_current(force):
        dp = force / p['A_p']

        def eqs(v):
            qa, qb = main_stage_flows(v[0] * 1e-6, v[1] * 1e6, v[1] * 1e6 - dp, c)
            return [(qa - p['K_C'] * dp) * 1e6, (qb + p['K_C'] * dp) * 1e6]
        sol = root(eqs, [0.0, 0.5 * (p['p_s'] + p['p_t'] + dp) * 1e-6], tol=1e-12)
        assert np.max(np.abs(eqs(sol.x))) < 1e-9, sol.message
        return sol.x[0] * 1e-6 / p['K_x']

    g = null_load_gain(p)
    i0 = null_current(0.0)
    assert (null_current(100.0) - i0) / 100.0 == pytest.approx(g, rel=0.01)
    assert (null_current(9000.0) - i0) / 9000.0 == pytest.approx(g, rel=0.09)
    assert null_load_gain(p.replace(flow_law='linear')) > 0     # the piston's leakage alone
