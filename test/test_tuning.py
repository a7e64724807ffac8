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
"""Tuning from the model: the linear loop against hand physics, the rule, and the rig's step."""

import math

import numpy as np
import pytest
from ros_ehs.core.control.pid import PidGains
from ros_ehs.core.control.tuning import linear_loop, loop_gain, margins, tune
from ros_ehs.core.errors import InputError
from ros_ehs.core.model.coefficients import flow_gain_kq
from ros_ehs.core.params import preset
from ros_ehs.core.sim.specimen_runs import square_wave

RIG = preset('fatigue_actuator', specimen_life=1e12)


def test_the_linear_loop_is_an_integrator_of_flow_at_low_frequency():
    g = flow_gain_kq(RIG) * RIG['K_x'] / RIG['A_p']       # [m/s per A], the nominal flow gain
    p = PidGains(kp=1.0, ki=0.0, kd=0.0)

    def gain(lin, f=0.5):
        return abs(loop_gain(lin, p, np.array([f]))[0]) * 2 * np.pi * f

    # at null the rounded edges and the clearance halve the valve's gain; over a 5 mA opening
    # the secant is the nominal gain within 5 %
    assert gain(linear_loop(RIG, 'displacement')) == pytest.approx(0.5 * g, rel=0.05)
    assert gain(linear_loop(RIG, 'displacement', current=5e-3)) == pytest.approx(g, rel=0.05)
    # a force loop on a specimen: the flow compresses the specimen and the oil in series (at
    # 5 Hz: below about 1 Hz the valve's flow-pressure coefficient bleeds the force)
    k = 5e6
    k_h = 2 * RIG['beta_e'] * RIG['A_p'] / RIG['l_iac']
    loaded = linear_loop(RIG.replace(k_L=k), 'force', current=5e-3)
    assert gain(loaded, 5.0) == pytest.approx(g / (1 / k + 1 / k_h), rel=0.05)
    assert gain(loaded, 0.1) < 0.5 * g / (1 / k + 1 / k_h)


def test_tuning_meets_the_bandwidth_asked_for_when_the_margins_allow_it():
    r = tune(RIG, 'displacement', bandwidth_hz=3.0, gain_margin_db=6.0, phase_margin_deg=45.0)
    assert r.bandwidth_hz == pytest.approx(3.0, rel=0.02) and r.note == ''
    assert r.phase_margin_deg >= 45.0 and r.gain_margin_db >= 6.0
    # the I zero a decade under the crossover (the crossover of P alone)
    assert r.gains.ki == pytest.approx(r.gains.kp * 2 * math.pi * r.crossover_hz / 10,
                                       rel=0.02)
    assert r.values() == {'kp': r.gains.kp, 'ki': r.gains.ki, 'kd': 0.0}
    # the prediction is the loop's: the margins recomputed from the gains agree
    fc, pm, gm, bw = margins(linear_loop(RIG, 'displacement'), r.gains)
    assert (fc, pm) == (pytest.approx(r.crossover_hz, rel=1e-3),
                        pytest.approx(r.phase_margin_deg, abs=0.1))
    assert r.step[-1] == pytest.approx(1.0, abs=0.01)


def test_a_bandwidth_beyond_the_margins_is_lowered_and_said():
    r = tune(RIG.replace(k_L=5e7), 'force', bandwidth_hz=40.0, gain_margin_db=10.0)
    assert r.gain_margin_db == pytest.approx(10.0, abs=0.05) and r.bandwidth_hz < 40.0
    assert 'margins asked for hold only up to' in r.note
    assert set(r.values()) == {'force_kp', 'force_ki', 'force_kd'}


@pytest.mark.parametrize('k, loop, step', [(0.0, 'displacement', 0.004),
                                           (5e6, 'force', 4e3)])
def test_the_rigs_square_wave_overshoots_as_predicted_within_3_points(k, loop, step):
    p = RIG.replace(k_L=k)
    r = tune(p, loop, bandwidth_hz=5.0 if loop == 'displacement' else 20.0,
             gain_margin_db=10.0, step=step)
    measured, run = square_wave(p.replace(**r.values()), loop, step / 2,
                                period=2 * max(0.5, 4 * r.settling_s), cycles=2)
    assert measured <= 10.0 and abs(measured - r.overshoot_pct) <= 3.0
    assert set(run.driving[300:]) == {loop}


@pytest.mark.parametrize('kw, match', [
    ({'loop': 'torque'}, '`loop`'), ({'bandwidth_hz': 0.0}, '`bandwidth_hz`'),
    ({'bandwidth_hz': 300.0}, 'quarter of the loop rate'),
    ({'phase_margin_deg': math.nan}, '`phase_margin_deg`'), ({'step': -1.0}, '`step`'),
])
def test_bad_tuning_requests_are_named(kw, match):
    with pytest.raises(InputError, match=match):
        tune(RIG.replace(k_L=5e6), **{'loop': 'force', **kw})


def test_a_force_loop_needs_a_specimen():
    with pytest.raises(InputError, match='k_L'):
        tune(RIG, 'force')


def test_ehs_sim_tune_prints_checks_and_writes_gains_the_controller_reads(tmp_path, capsys):
    from ros_ehs.core.params import load_yaml
    from ros_ehs.tools.cli import main
    out = tmp_path / 'gains.yaml'
    assert main(['tune', '--preset', 'fatigue_actuator', '--set', 'k_L=5e6', '--loop', 'force',
                 '--bandwidth', '20', '--out', str(out)]) == 0
    text = capsys.readouterr().out
    assert 'phase margin' in text and 'square wave +-2000 N' in text and 'points from' in text
    assert 'margins asked for hold only up to' in text        # 20 Hz is beyond this specimen
    p = load_yaml(out)
    r = tune(RIG.replace(k_L=5e6), 'force', bandwidth_hz=20.0, gain_margin_db=10.0, step=4e3)
    assert p['force_kp'] == pytest.approx(r.gains.kp) and p['force_ki'] == pytest.approx(
        r.gains.ki)
    # no specimen: a force loop cannot be tuned, said by name
    assert main(['tune', '--loop', 'force', '--no-check']) == 2
    assert 'set k_L' in capsys.readouterr().err
