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
The reference node's rules without DDS (ros_ehs.core.control.reference), each at its period.

Time zero, the duration hold, lock-step previews and new runs, the corrections' readiness,
early states, freezing and resuming, live waveform changes and the corrections' refusals.
"""

import math

import numpy as np
import pytest
from ros_ehs.core.control.apc import AmplitudePhaseControl
from ros_ehs.core.control.loop import NOTE_PERIOD
from ros_ehs.core.control.reference import (correction_for, EARLY_STATES, ReferenceGenerator,
                                            STATES_LOST)
from ros_ehs.core.control.waveforms import Sine, WAVEFORM
from ros_ehs.core.errors import ParameterError
from ros_ehs.core.options import REFERENCE
from ros_ehs.core.params import Params
from ros_ehs.core.sim.closed_loop import run_closed_loop

MS = 1_000_000
T0 = 5 * 10**9


def _options(**kw):
    o = {s.name: s.default for s in REFERENCE}
    o.update(kw)
    return o


def _values(**kw):
    v = {s.name: s.default for s in WAVEFORM}
    v.update(kw)
    return v


def test_real_time_waits_for_its_subscribers_and_the_closed_loop_then_samples_each_tick():
    g = ReferenceGenerator(_values(), _options(wait_subscribers=2, wait_loop=True))
    assert not g.closed and g.tick(T0, 2) is None          # the loop is not closed yet
    g.loop_closed()
    assert g.tick(T0, 1) is None and not g.started         # one subscriber short
    r = g.tick(T0, 2)
    assert r[:3] == (T0, 0.0, pytest.approx(2 * math.pi * 0.04)) and g.started
    assert math.isnan(r.f_ref)                               # a displacement reference
    assert g.notes == [('info', 'time zero: 2 subscriber(s) on reference, the plant reports '
                        'its loop closed')]
    r = g.tick(T0 + 250 * MS, 0)                            # subscribers no longer matter
    assert r.z_ref == pytest.approx(0.04) and abs(r.v_ref) < 1e-12
    assert g.figures()['published'] == 2 and g.figures()['time_s'] == 0.25


def test_after_duration_the_last_position_is_held_still():
    g = ReferenceGenerator(_values(), _options(duration=0.25))
    g.tick(T0, 0)
    r = g.tick(T0 + 300 * MS, 0)
    assert r.z_ref == pytest.approx(0.04) and r.v_ref == 0.0


def test_sim_time_answers_each_clock_with_its_preview():
    g = ReferenceGenerator(_values(), _options(preview=0.02), sim_time=True)
    w = g.clock(T0)
    assert [r.stamp_ns for r in w] == [T0 + k * MS for k in range(21)]
    z, v = Sine()(np.arange(21) * 1e-3)
    np.testing.assert_allclose([r.z_ref for r in w], z, atol=1e-15)
    assert g.clock(T0) == w                    # a resend: the same preview again
    assert g.clock(T0 + 10 * MS)[0].stamp_ns == T0 + 10 * MS


def test_a_clock_further_back_than_epoch_periods_is_a_new_run_noted_once_a_second():
    g = ReferenceGenerator(_values(), _options(), sim_time=True)
    g.clock(T0, now=0.0)
    g.clock(T0 + 100 * MS, now=0.0)
    w = g.clock(T0 + 96 * MS, now=0.0)                        # reordering: the same run
    assert w[0].z_ref == pytest.approx(0.04 * math.sin(2 * math.pi * 0.096)) and g.runs == 1
    w = g.clock(T0, now=0.1)                                  # back: the waveform restarts
    assert w[0].z_ref == 0.0 and g.runs == 2
    g.clock(T0 + 100 * MS, now=0.2)
    g.clock(T0, now=0.3)                                      # within a second: not noted
    assert g.runs == 3 and sum('new run' in t for _, t in g.notes) == 1
    g.clock(T0 + 100 * MS, now=0.3 + NOTE_PERIOD)
    g.clock(T0, now=0.3 + NOTE_PERIOD)
    assert sum('new run' in t for _, t in g.notes) == 2


def test_a_malformed_clock_is_counted():
    g = ReferenceGenerator(_values(), _options(), sim_time=True)
    g.malformed_clock()
    assert g.figures()['bad_clocks'] == 1


def test_a_corrected_preview_waits_for_the_state_that_ends_the_cycle_it_learns_from():
    opt = _options(amplitude_phase_control=True, preview=0.02, ramp_time=0.0)
    g = ReferenceGenerator(_values(frequency=10.0, amplitude=0.002), opt, sim_time=True)
    assert g.clock(T0) is not None              # the first cycle needs no measurement
    for k in range(0, 100):                     # the first cycle's states, but its last
        assert g.state(T0 + k * MS, 0.0, 0.0) == []
    # the preview at 100 ms holds the second cycle's correction: it waits for state 100
    assert g.clock(T0 + 100 * MS) is None
    got = g.state(T0 + 100 * MS, 0.0, 0.0)
    assert len(got) == 1 and got[0][0].stamp_ns == T0 + 100 * MS


def test_states_before_time_zero_are_kept_and_taken_when_it_comes():
    opt = _options(amplitude_phase_control=True, ramp_time=0.0)
    g = ReferenceGenerator(_values(frequency=10.0, amplitude=0.002), opt, sim_time=True)
    for k in range(EARLY_STATES + 5):
        g.state(T0 + k * MS, 0.0, 0.0)
    assert len(g._early) == EARLY_STATES
    g.clock(T0)
    assert g._measured_ns == T0 + (EARLY_STATES - 1) * MS


def test_the_generator_in_lock_step_is_the_in_process_loop():
    # the previews the controller reads, fed the loop's measured positions in the order the
    # plant sends them, equal the in-process loop's references (what the DDS test checks
    # end to end, to 1e-9 m)
    opt = _options(amplitude_phase_control=True)
    vals = _values(frequency=5.0, amplitude=0.002)
    g = ReferenceGenerator(vals, opt, sim_time=True)
    corr = correction_for(vals, opt)
    run = run_closed_loop(Params(), corr, 2.0, model='simplified', dt=1e-3, supervised=True)
    sent = {}
    for k in range(0, 2000, 10):                       # a /clock every 10 periods
        for st in range(max(0, k - 9), k + 1):         # the states up to it
            for w in g.state(T0 + st * MS, float(run.z_meas[st]), 0.0):
                sent.update({r.stamp_ns: r.z_ref for r in w})
        w = g.clock(T0 + k * MS)
        if w is not None:
            sent.update({r.stamp_ns: r.z_ref for r in w})
    np.testing.assert_allclose([sent[T0 + k * MS] for k in range(2000)], run.z_ref[:2000],
                               rtol=0, atol=1e-9)


def test_a_trip_that_acts_freezes_the_corrections_until_a_reset():
    opt = _options(amplitude_phase_control=True, ramp_time=1.0)
    g = ReferenceGenerator(_values(), opt)
    g.tick(T0, 0)
    g.tick(T0 + 3000 * MS, 0)
    g.event('trip', 'indicate')
    assert not g.frozen_by
    g.event('trip', 'hold')
    assert g.frozen_by == {'safety trip'} and g.correction.frozen
    g.event('reset', 'off')
    assert not g.frozen_by and not g.correction.frozen
    # the ramp-on after the reset is not learnt from
    assert g.correction.learn_from == pytest.approx(3.0 + 1.0)
    assert [t for _, t in g.notes] == ['APC frozen: safety trip', 'APC resumed: safety trip']


def test_a_clipped_command_marks_the_cycles_the_corrections_learn_from_until_applied_again():
    g = ReferenceGenerator(_values(), _options(amplitude_phase_control=True))
    g.tick(T0, 0)
    g.event('clipped', 'off')
    g.state(T0 + MS, 0.0, 0.0)
    assert g.clipped and g.correction._clipped and not g.frozen_by
    g.event('unclipped', 'off')
    g.state(T0 + 2 * MS, 0.0, 0.0)
    assert not g.clipped


def test_real_time_states_lost_freeze_the_corrections_and_a_state_resumes_them():
    g = ReferenceGenerator(_values(), _options(amplitude_phase_control=True))
    g.tick(T0, 0)
    g.watch(1.0)                     # the lost time starts at the first look
    g.state(T0, 0.0, 1.0)
    g.watch(1.0 + STATES_LOST)
    assert not g.frozen_by
    g.watch(1.0 + STATES_LOST + 1e-6)
    assert g.frozen_by == {'states lost'}
    g.state(T0 + MS, 0.0, 1.5)
    assert not g.frozen_by


def test_a_waveform_change_is_checked_as_a_whole_and_restarts_the_corrections():
    g = ReferenceGenerator(_values(), _options(amplitude_phase_control=True))
    old = g.correction
    g.set_waveform({'amplitude': 0.01})
    assert g.values['amplitude'] == 0.01 and g.correction is not old
    with pytest.raises(ParameterError, match='amplitude_phase_control corrects a sine or chirp'):
        g.set_waveform({'kind': 'triangle'})
    assert g.values['kind'] == 'sine' and g.values['amplitude'] == 0.01


@pytest.mark.parametrize('values, options, match', [
    ({}, {'amplitude_phase_control': True, 'peak_valley_control': True}, 'choose one'),
    ({'kind': 'step'}, {'peak_valley_control': True}, 'corrects a triangle or haversine'),
    ({'frequency': 60.0}, {'amplitude_phase_control': True},
     r'`preview` = 0.02 s must be under the period \(0.0166667 s\)'),
    ({'kind': 'triangle', 'frequency': 30.0}, {'peak_valley_control': True},
     r'must be under half the period')])
def test_a_correction_it_cannot_make_is_refused_by_name(values, options, match):
    with pytest.raises(ParameterError, match=match):
        correction_for(_values(**values), _options(**options))


def test_without_a_correction_there_is_nothing_to_learn_or_freeze():
    g = ReferenceGenerator(_values(), _options())
    assert g.correction is None and correction_for(_values(), _options()) is None
    assert g.state(T0, 0.0, 0.0) == [] and g.describe() == 'sine reference'
    g.event('trip', 'power_off')
    assert not g.frozen_by
    assert isinstance(correction_for(_values(), _options(amplitude_phase_control=True)),
                      AmplitudePhaseControl)


# -- force control: the waveform is a force ----------------------------------------------------
def test_a_force_waveform_goes_out_as_each_references_force_with_no_position():
    g = ReferenceGenerator(_values(amplitude=4e3, offset=5e3, frequency=2.0),
                           _options(control_mode='force'), sim_time=True)
    refs = g.clock(T0)
    assert all(math.isnan(r.z_ref) and math.isnan(r.v_ref) for r in refs)
    assert refs[0].f_ref == pytest.approx(5e3)
    assert refs[5].f_ref == pytest.approx(5e3 + 4e3 * math.sin(2 * math.pi * 2 * 5e-3))
    # real time alike
    g = ReferenceGenerator(_values(amplitude=4e3, offset=5e3), _options(control_mode='force'))
    r = g.tick(T0, 0)
    assert math.isnan(r.z_ref) and r.f_ref == pytest.approx(5e3)


def test_a_position_waveform_beyond_2_m_is_refused_naming_force_control():
    with pytest.raises(ParameterError, match='control_mode force'):
        ReferenceGenerator(_values(amplitude=4e3), _options())
    g = ReferenceGenerator(_values(), _options())
    with pytest.raises(ParameterError, match='`offset`'):
        g.set_waveform({'offset': -2.5})


def test_apc_and_pvc_correct_the_force_from_the_load_cell():
    """APC of a force sine, and PVC of a force block sequence, on a specimen, in process."""
    from ros_ehs.core.control.pvc import parse_blocks, PeakValleyControl
    from ros_ehs.core.params import preset
    from ros_ehs.core.sim.specimen_runs import run_axis
    rig = preset('fatigue_actuator', k_L=5e6, specimen_life=1e12, control_mode='force',
                 force_kp=1.675e-7, force_ki=5.0e-7, ramp_time=0.2)
    apc = correction_for(_values(amplitude=4e3, offset=5e3, frequency=5.0),
                         _options(control_mode='force', amplitude_phase_control=True,
                                  ramp_time=0.2))
    run = run_axis(rig, 0.2 + 20 / 5.0, apc, signal='force')
    assert apc.converged_at is not None and apc.converged_at <= 15
    last = run.t > run.t[-1] - 0.2
    want = 5e3 + 4e3 * np.sin(2 * np.pi * 5.0 * run.t[last])
    assert np.sqrt(np.mean((run.load[last] - want) ** 2)) < 0.01 * 4e3
    blocks = parse_blocks('10000 1000 6; 6000 2000 6')        # N: a block-loading sequence
    pvc = PeakValleyControl(blocks, 2.0, 'haversine', latency=0.02, learn_from=0.2)
    run_axis(rig, 0.2 + 36 / 2.0, pvc, signal='force')
    assert pvc.converged_at is not None and pvc.converged_at <= 20
    assert max(pvc.errors) <= 0.005                  # every block's peak and valley: 0.5 %
