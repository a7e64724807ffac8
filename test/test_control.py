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
"""Controller core: PID edge-case policy branch by branch, feedforward terms, experiments."""

import math

import numpy as np
import pytest

from ros_ehs.core.control import (Controller, DelayLine, DeltaP, Feedforward, Pid, PidGains,
                                  psc_force, stribeck_estimate, xi_blend)
from ros_ehs.core.errors import InputError, ParameterError
from ros_ehs.core.metrics import tracking_metrics
from ros_ehs.core.model import ff_force_gain
from ros_ehs.core.params import Params, preset
from ros_ehs.core.sim.paper_runs import paper_runs


def test_p_i_d_terms_match_eq_19():
    pid = Pid(PidGains(kp=2.0, ki=0.0, kd=0.0, d_filter_tau=0.0))
    assert pid.update(0.003, 1e-3) == pytest.approx(0.006)
    pid = Pid(PidGains(kp=0.0, ki=4.0, kd=0.0, d_filter_tau=0.0))
    for _ in range(10):
        u = pid.update(0.001, 1e-3)
    assert u == pytest.approx(9 * 4.0 * 0.001 * 1e-3)   # integral of previous samples
    pid = Pid(PidGains(kp=0.0, ki=0.0, kd=0.05, d_filter_tau=0.0, u_max=0.1))
    pid.update(0.0, 1e-3)
    assert pid.update(0.001, 1e-3) == pytest.approx(0.05 * 1.0)


def test_dt_zero_returns_previous_command_without_changing_state():
    pid = Pid()
    u = pid.update(0.01, 1e-3)
    i_term = pid.i_term
    assert pid.update(0.02, 0.0) == u
    assert pid.i_term == i_term


@pytest.mark.parametrize('dt', [-1e-3, math.nan, math.inf])
def test_negative_or_non_finite_dt_raises(dt):
    with pytest.raises(InputError, match='`dt`'):
        Pid().update(0.01, dt)


@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf])
def test_non_finite_error_gives_zero_current_and_fault_then_recovers(bad):
    pid = Pid()
    pid.update(0.01, 1e-3)
    i_term = pid.i_term
    assert pid.update(bad, 1e-3) == 0.0 and pid.fault
    assert pid.i_term == i_term
    assert pid.update(0.01, 1e-3) != 0.0 and not pid.fault


@pytest.mark.parametrize('antiwindup', ['conditional_integration', 'back_calculation'])
def test_output_limit_and_antiwindup_stop_windup(antiwindup):
    g = PidGains(kp=1.0, ki=100.0, kd=0.0, u_max=0.01, antiwindup=antiwindup)
    pid, none = Pid(g), Pid(PidGains(kp=1.0, ki=100.0, kd=0.0, u_max=0.01, antiwindup='none'))
    for _ in range(2000):                       # 2 s saturated by a large error
        u = pid.update(0.05, 1e-3)
        none.update(0.05, 1e-3)
    assert u == 0.01 and pid.saturated
    assert none.i_term == pytest.approx(2.0 * 100.0 * 0.05)     # plain integration winds up
    assert pid.i_term < 0.02                    # the limited integrator did not wind up
    steps = 0                                   # and it leaves saturation at once on reversal
    while pid.update(-0.005, 1e-3) >= 0.0:
        steps += 1
    assert steps < 50


def test_conditional_integration_integrates_out_of_the_limit_only():
    pid = Pid(PidGains(kp=1.0, ki=100.0, kd=0.0, d_filter_tau=0.0, u_max=0.01))
    pid.update(0.05, 1e-3)
    assert pid.saturated and pid.i_term == 0.0      # pushing into the limit: frozen
    pid.reset(i_term=0.02)
    pid.update(-0.001, 1e-3)                        # limited, but the error unwinds it
    assert pid.saturated and pid.i_term == pytest.approx(0.02 - 1e-4)
    pid.reset()
    pid.update(0.001, 1e-3)                         # not limited: plain integration
    assert not pid.saturated and pid.i_term == pytest.approx(1e-4)


def test_a_start_mid_stroke_leaves_no_offset_with_the_default_antiwindup():
    """
    The bench starts the plant at rest while the 0.04 m sine is at its peak (a 40 mm error).

    The paper's gains saturate the valve on P alone; back-calculation then drives the
    integrator to several mA of the wrong sign, which ki = 0.051 A/(m s) unwinds over ~15 s.
    Conditional integration (the default) is back on the sine within the first second.
    """
    from ros_ehs.core.sim.closed_loop import run_closed_loop
    from ros_ehs.core.params import Params
    from ros_ehs.core.control.waveforms import Sine
    sine = Sine(0.04, 1.0)

    def peak_first(t):
        return sine(np.asarray(t) + 0.25)

    err = {}
    for aw in ('conditional_integration', 'back_calculation'):
        p = Params().replace(antiwindup=aw)
        r = run_closed_loop(p, peak_first, 3.0, model='simplified', dt=1e-3)
        late = r.t >= 1.0
        err[aw] = abs(np.mean(peak_first(r.t[late])[0] - r.z[late]))
    assert Params()['antiwindup'] == 'conditional_integration'
    assert err['conditional_integration'] < 2e-4 and err['back_calculation'] > 1e-3, err


def test_derivative_filter_limits_the_kick_of_a_step():
    raw = Pid(PidGains(kp=0.0, ki=0.0, kd=0.01, d_filter_tau=0.0, u_max=0.1))
    filt = Pid(PidGains(kp=0.0, ki=0.0, kd=0.01, d_filter_tau=5e-3, u_max=0.1))
    raw.update(0.0, 1e-3)
    filt.update(0.0, 1e-3)
    assert filt.update(0.001, 1e-3) < 0.25 * raw.update(0.001, 1e-3)


def test_bumpless_gain_change():
    pid = Pid()
    for _ in range(100):
        u = pid.update(0.004, 1e-3)
    pid.set_gains(pid.with_gains(kp=3.0))
    assert pid.update(0.004, 1e-3) == pytest.approx(u, abs=2e-6)


def test_gains_are_validated():
    with pytest.raises(ParameterError, match='`kp`'):
        PidGains(kp=-1.0)
    with pytest.raises(ParameterError, match='`u_max`'):
        PidGains(u_max=math.nan)


def test_feedforward_terms():
    assert xi_blend(0.0, 0.01) == pytest.approx(0.0)
    assert xi_blend(0.0, 0.01, renormalised=False) == pytest.approx(0.1192, abs=1e-4)
    assert xi_blend(0.05, 0.01) > 0.99
    # sliding: friction opposes motion with F_cc; stuck: it balances the applied force
    assert stribeck_estimate(0.1, 0.0, 1000.0, 2000.0, 0.01, 1e-3) == pytest.approx(-1000.0)
    assert stribeck_estimate(0.0, 500.0, 1000.0, 2000.0, 0.01, 1e-3) == pytest.approx(-500, 0.01)
    assert psc_force(0.1, 0.0, 1000.0, 2000.0, 0.01, 1e-3, 1e4) == pytest.approx(2000.0)
    d = DelayLine(0.003, 1e-3)
    assert [d.push(v) for v in (1.0, 2.0, 3.0, 4.0)] == [0.0, 0.0, 0.0, 1.0]
    p = preset('table1_estimated')
    assert ff_force_gain(p) == pytest.approx(2 * p['beta_e'] * 2.38 * p['K_x'] / p['l_iac'],
                                             rel=0.01)


def test_feedforward_derivative_stays_bounded_through_velocity_reversal():
    p = preset('table1_estimated', ff_velocity=0.0, ff_max=0.1)
    ff = Feedforward(p, 1e-3)
    t = np.arange(0, 2, 1e-3)
    i = [ff.update(v, 0.0) for v in 0.25 * np.cos(2 * np.pi * t)]
    assert np.all(np.isfinite(i))
    # the Coulomb jump of 2 F_cc is spread over the tanh width: a finite pulse
    assert 0 < np.abs(i).max() < 2 * p['F_cc'] / (ff_force_gain(p) * 1e-3)


def test_controller_nan_state_gives_zero_and_hold_freezes_output():
    c = Controller(preset('table1_estimated'))
    assert c.step(0.01, 0.0, 0.0) != 0.0
    assert c.step(0.01, 0.0, math.nan) == 0.0 and c.fault
    u = c.step(0.01, 0.0, 0.0)
    c.hold()
    assert c.step(-0.03, 0.0, 0.0) == u
    c.hold(False)
    assert c.step(-0.03, 0.0, 0.0) != u
    assert abs(c.step(10.0, 0.0, 0.0)) <= c.params['u_max']


def test_delta_p_high_pass_starts_at_zero_and_lets_a_held_load_pass():
    dp = DeltaP(2e-7, 0.05)
    assert dp.update(5000.0, 1e-3) == 0.0           # the first force is the filter's memory
    step = dp.update(6000.0, 1e-3)                  # a 1 kN step: its high-passed share
    assert step == pytest.approx(2e-7 * 1000.0 * 0.05 / 0.051)
    for _ in range(1000):                           # held for 20 time constants
        held = dp.update(6000.0, 1e-3)
    assert 0.0 < held < 1e-8 * step
    dp.reset()
    assert dp.update(-3000.0, 1e-3) == 0.0


def test_delta_p_needs_the_force_only_when_on():
    off, on = (Controller(preset('table1_estimated', dp_gain=g)) for g in (0.0, 2e-7))
    assert off.step(0.01, 0.0, 0.0) != 0.0 and not off.fault     # no force: not needed
    assert on.step(0.01, 0.0, 0.0) == 0.0 and on.fault           # no force: bad input
    assert on.step(0.01, 0.0, 0.0, force=100.0) != 0.0 and not on.fault
    # a rising force takes current off the command: the loop gives way to the load
    a, b = (Controller(preset('table1_estimated', dp_gain=g)) for g in (0.0, 2e-7))
    for k in range(5):
        ua, ub = (c.step(0.001, 0.0, 0.0, force=1000.0 * k) for c in (a, b))
    assert ub < ua
    assert a.dp.last == 0.0 and b.dp.last > 0.0


def test_delta_p_gain_changes_are_bumpless():
    c = Controller(preset('table1_estimated', dp_gain=2e-7))
    f = 0.0
    for k in range(200):                   # a rising force keeps the high-pass away from 0
        f = 20.0 * k
        u = c.step(0.002, 0.0, 0.001, force=f)
    assert c.dp.last > 2e-5          # 40 uA: a bump would show
    c.set_params(preset('table1_estimated', dp_gain=0.0))
    # the same error, the force still rising by one period: the command moves by the
    # PID's and feedforward's share of a period, not by the delta-P current it dropped
    off = c.step(0.002, 0.0, 0.001, force=f + 20.0)
    assert off == pytest.approx(u, abs=1e-6)
    c.set_params(preset('table1_estimated', dp_gain=2e-7))
    assert c.step(0.002, 0.0, 0.001, force=f + 40.0) == pytest.approx(off, abs=1e-6)


def test_delta_p_follows_the_load_through_a_hold_so_release_has_no_kick():
    c = Controller(preset('table1_estimated', dp_gain=2e-7, dp_tau=0.05))
    for _ in range(200):
        u = c.step(0.002, 0.0, 0.001, force=1000.0)
    c.hold()
    for k in range(1000):       # the load rises 5 kN in 0.5 s, then stays for 10 dp_tau
        assert c.step(0.002, 0.0, 0.001, force=1000.0 + 10.0 * min(k, 500)) == u
    c.hold(False)
    # a filter left at the hold's first force would give 2e-7 * 5000 N = 1 mA at once
    assert c.step(0.002, 0.0, 0.001, force=6000.0) == pytest.approx(u, abs=5e-5)


def test_the_supervised_loop_gives_delta_p_the_force_of_each_state():
    from ros_ehs.core.control.waveforms import Sine
    from ros_ehs.core.sim.closed_loop import run_closed_loop
    p = preset('table1_estimated')
    off, on = (run_closed_loop(p, Sine(0.004, 10.0), 1.0, model='simplified', supervised=True,
                               controller_params=p.replace(dp_gain=g)) for g in (0.0, 2e-7))
    assert np.abs(on.i - off.i).max() > 1e-4
    blind = run_closed_loop(p, Sine(0.004, 10.0), 1.0, model='simplified', supervised=True,
                            controller_params=p.replace(dp_gain=2e-7),
                            fault=lambda k, z, v, f: (z, v, math.nan))
    assert np.all(blind.i == 0.0)         # no force to stabilise with: the valve at null


def test_delta_p_damps_the_oil_column_of_a_rig_the_controller_does_not_know():
    """The loop's ringing (40-80 Hz) on a road-like target falls with delta-P on."""
    from ros_ehs.benchmarks.tracking import MISMATCH
    from ros_ehs.core.control.drive import multisine
    from ros_ehs.core.control.waveforms import Samples
    from ros_ehs.core.sim.closed_loop import run_closed_loop
    est = preset('table1_estimated')
    rig = est.replace(**{n: est[n] * k for n, k in MISMATCH.items()})
    t, r = multisine(5.0, 1000.0, 0.5, 20.0, 0.08, seed=1)
    ring = []
    for g in (0.0, 1.5e-7):
        run = run_closed_loop(rig, Samples(t, r), 5.0, model='full',
                              controller_params=est.replace(dp_gain=g, dp_tau=0.05))
        e = np.fft.rfft(r - run.z[:-1])
        f = np.fft.rfftfreq(r.size, 1e-3)
        ring.append(np.sqrt(np.sum(np.abs(e[(f > 40) & (f < 80)]) ** 2)))
    assert ring[1] < 0.6 * ring[0], ring


def test_metrics_on_a_perfect_and_a_delayed_track():
    t = np.arange(0, 3, 1e-3)
    z, v = 0.04 * np.sin(2 * np.pi * t), 0.04 * 2 * np.pi * np.cos(2 * np.pi * t)
    m = tracking_metrics(t, z, v, z, v)
    assert m.rms_err_m == 0 and m.deadzone_s == 0 and m.lag_s == 0
    m = tracking_metrics(t, z, v, 0.04 * np.sin(2 * np.pi * (t - 0.02)),
                         0.04 * 2 * np.pi * np.cos(2 * np.pi * (t - 0.02)))
    assert m.lag_s == pytest.approx(0.02, abs=2e-4)


def test_paper_experiments_reproduce_dead_zone_and_feedforward_gain():
    runs = paper_runs('simplified', 3.0)
    m = {k: v[1] for k, v in runs.items()}
    # the estimated plant sticks clearly longer than the initial one
    assert m['pid'].deadzone_s > 1.4 * m['pid_initial'].deadzone_s
    assert m['pid'].peak_shortfall_m > m['pid_initial'].peak_shortfall_m
    # default feedforward: dead zone cut >= 50 %, RMS error cut >= 30 %
    assert m['ffpid'].deadzone_s <= 0.5 * m['pid'].deadzone_s
    assert m['ffpid'].rms_err_m <= 0.7 * m['pid'].rms_err_m
    # the printed law with the measured delay helps the dead zone, not the lag-bound RMS
    assert m['ffpid_paper_tau'].deadzone_s < m['pid'].deadzone_s
    assert m['ffpid_paper_tau'].rms_err_m > 0.95 * m['pid'].rms_err_m


def test_closed_loop_position_noise_reaches_the_controller_and_is_checked():
    from ros_ehs.core.sim.closed_loop import run_closed_loop
    from ros_ehs.core.control.waveforms import Sine
    p = preset('table1_estimated')
    noise = np.full(200, 1e-3)
    r = run_closed_loop(p, Sine(0.04, 1.0), 0.2, model='simplified', z_noise=noise)
    np.testing.assert_allclose(r.z_meas, r.z[:200] + 1e-3)
    clean = run_closed_loop(p, Sine(0.04, 1.0), 0.2, model='simplified')
    assert not np.allclose(r.i, clean.i)          # a 1 mm offset changes the command
    with pytest.raises(InputError, match='`z_noise`'):
        run_closed_loop(p, Sine(0.04, 1.0), 0.2, model='simplified', z_noise=noise[:10])
    with pytest.raises(InputError, match='`z_noise`'):
        run_closed_loop(p, Sine(0.04, 1.0), 0.2, model='simplified',
                        z_noise=np.full(200, np.nan))


def test_closed_loop_command_delay_holds_each_command_one_period_late():
    from ros_ehs.core.sim.closed_loop import run_closed_loop
    from ros_ehs.core.control.waveforms import Sine
    p = preset('table1_estimated')
    now = run_closed_loop(p, Sine(0.04, 1.0), 2.0, model='simplified', dt=2e-3)
    late = run_closed_loop(p, Sine(0.04, 1.0), 2.0, model='simplified', dt=2e-3,
                           command_delay=1)
    assert late.i[0] == 0.0 and now.i[0] != 0.0     # the first command waits a period
    e_now, e_late = (np.sqrt(np.mean((r.z_ref - r.z)[500:] ** 2)) for r in (now, late))
    assert 1.2 * e_now < e_late < 3 * e_now, (e_now, e_late)
    for bad in (-1, 0.5):
        with pytest.raises(InputError, match='`command_delay`'):
            run_closed_loop(p, Sine(0.04, 1.0), 0.1, model='simplified', command_delay=bad)


def test_a_handover_starts_from_the_output_it_takes_over():
    pid = Pid(PidGains())
    pid.update(0.01, 1e-3)
    pid.handover(0.004)
    assert pid.prev_error is None and pid.d_state == 0.0 and pid.last_u == 0.004
    assert pid.update(0.0, 1e-3) == pytest.approx(0.004)          # zero error: no bump
    pid.handover(math.nan)                                         # nothing to take over
    assert pid.update(0.0, 1e-3) == 0.0


def test_an_output_limited_further_undoes_the_integration_pushing_into_it():
    pid = Pid(PidGains(kp=1.0, ki=10.0, kd=0.0))
    pid.update(0.001, 1e-3)
    i_before = pid.i_term
    pid.update(0.001, 1e-3)
    assert pid.i_term > i_before
    pid.limited(0.0)                                   # the error pushes up, limited down
    assert pid.i_term == pytest.approx(i_before) and pid.last_u == 0.0
    pid.update(-0.001, 1e-3)
    i_before = pid.i_term
    pid.update(0.001, 1e-3)
    pid.limited(0.5)                                   # limited the other way: keeps it
    assert pid.i_term > i_before


def test_gains_of_another_loop_come_by_their_prefix():
    p = Params().replace(force_kp=2e-7, force_ki=3e-6, force_kd=1e-9, u_max=0.01)
    g = PidGains.from_params(p, 'force_')
    assert (g.kp, g.ki, g.kd, g.u_max) == (2e-7, 3e-6, 1e-9, 0.01)
