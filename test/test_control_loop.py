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
The controller node's rules without DDS (ros_ehs.core.control.loop), each at its period.

Stamps, references, lost states, the operator's requests, notes and diagnosis.

The clocks are passed in: ``now`` the monotonic arrival [s], ``clock`` the node's clock [ns]
(in real time the states are stamped on it, so a state's age is ``clock - stamp``).
"""

import math

import pytest
from ros_ehs.core.control.loop import (ControlLoop, EPOCH_PERIODS, LOST_FACTOR, NOTE_PERIOD,
                                       REF_BUFFER)
from ros_ehs.core.errors import InputError
from ros_ehs.core.params import Params
from ros_ehs_msgs_py import AxisState, Load, Reference

MS = 1_000_000
T0 = 10**18          # a stamp on the system clock [ns]


def _st(k: int, z: float = 0.0, v: float = 0.0, f: float = 0.0,
        load: float = math.nan) -> AxisState:
    """State of period ``k`` (1 kHz) stamped on the node's clock."""
    return AxisState(T0 + k * MS, z, v, f, load=load)


def _loop(**kw) -> ControlLoop:
    kw.setdefault('params', Params())
    return ControlLoop(kw.pop('params'), **kw)


def _answer(loop, k, z=0.0, now=None, clock=None, **st):
    """Give state ``k`` arriving on time (1 ms periods); return the reply."""
    now = k * 1e-3 if now is None else now
    clock = T0 + k * MS if clock is None else clock
    return loop.state(_st(k, z, **st), now, clock)


def test_every_state_is_answered_once_with_its_own_stamp():
    loop = _loop()
    for k in range(5):
        r = _answer(loop, k)
        assert r.stamp_ns == T0 + k * MS and math.isfinite(r.current)
    assert loop.counts['answered'] == 5


def test_a_state_stamped_ahead_of_the_clock_is_dropped_counted_and_noted_once_a_second():
    loop = _loop(future_tolerance=0.05)
    assert _answer(loop, 0) is not None
    # 60 ms ahead of the node's clock: dropped, never adopted as the newest stamp
    assert loop.state(_st(60), 0.001, T0) is None
    assert loop.state(_st(61), 0.002, T0) is None
    assert loop.counts['future'] == 2 and loop.last_stamp == T0
    assert [n for n in loop.notes if 'ahead of this clock' in n[1]] == [
        ('warning', 'dropped a state stamped 0.06 s ahead of this clock')]
    loop.notes.clear()
    loop.state(_st(200), 0.002 + NOTE_PERIOD, T0)    # a second later: noted again
    assert len(loop.notes) == 1
    # exactly at the tolerance: taken
    assert loop.state(_st(50), 0.003, T0) is not None
    assert loop.diagnosis() == (1, 'dropped states stamped ahead of this clock')
    assert loop.diagnosis()[1] != 'dropped states stamped ahead of this clock'  # none since


def test_a_repeated_stamp_gets_the_same_command_without_a_pid_update():
    loop = _loop()
    loop.reference(Reference(T0, 0.01, 0.0), 0.0)
    r1 = _answer(loop, 0)
    before = loop.axis.ctrl.pid.i_term
    r2 = _answer(loop, 0, now=0.0005)
    assert r2 == (r1.stamp_ns, r1.current, ()) and loop.axis.ctrl.pid.i_term == before
    assert loop.counts['repeated'] == 1 and loop.counts['answered'] == 1


def test_an_older_stamp_is_reordering_up_to_epoch_periods_and_a_new_run_beyond():
    loop = _loop()
    for k in range(20):
        _answer(loop, k)
    assert _answer(loop, 19 - EPOCH_PERIODS, now=0.0201, clock=T0 + 20 * MS) is None
    assert loop.counts['out_of_order'] == 1
    # further back: a new run, answered at once; the ramp-on starts again
    r = _answer(loop, 19 - EPOCH_PERIODS - 1, now=0.0202, clock=T0 + 20 * MS)
    assert r is not None and loop.counts['epochs'] == 1
    assert loop.axis.demand.mode == 'ramp'
    assert any('new run: the state stamp jumped back' in t for _, t in loop.notes)


def test_a_state_older_than_stale_timeout_repeats_the_held_command():
    loop = _loop(params=Params().replace(stale_timeout=0.005))
    r0 = _answer(loop, 0)
    # arrives 6 ms after its stamp: not used, the held command again
    r = loop.state(_st(1, z=0.002), 0.007, T0 + 7 * MS)
    assert r == (T0 + MS, r0.current, ()) and loop.counts['stale'] == 1
    assert loop.last_stamp == T0 + MS and loop.counts['answered'] == 1
    # exactly at the timeout: used
    assert loop.state(_st(2), 0.007, T0 + 7 * MS) is not None
    assert loop.counts['answered'] == 2


def test_before_the_first_reference_the_first_measured_position_is_held():
    loop = _loop(params=Params().replace(ramp_time=0.0))
    _answer(loop, 0, z=0.003)
    _answer(loop, 1, z=0.004)
    assert loop.axis.demand.z_ref == 0.003 and loop.axis.demand.v_ref == 0.0


def test_a_reference_is_carried_to_the_states_instant_forward_and_back():
    loop = _loop(params=Params().replace(ramp_time=0.0), reference_timeout=0.1)
    loop.reference(Reference(T0, 0.01, 0.5), 0.0)
    _answer(loop, 4)                        # 4 ms after the reference: forward
    assert loop.axis.demand.z_ref == pytest.approx(0.01 + 0.5 * 0.004)
    loop.reference(Reference(T0 + 7 * MS, 0.02, 0.5), 0.005)
    _answer(loop, 5, now=0.0055)            # a reference stamped after the state: back
    assert loop.axis.demand.z_ref == pytest.approx(0.02 - 0.5 * 0.002)
    assert loop.axis.demand.v_ref == 0.5


def test_a_state_between_two_references_gets_the_velocity_at_its_instant():
    """
    Its velocity interpolated between theirs, not the newer one's.

    The newer reference's alone would lead the state by up to a reference period, by the
    phase of the two nodes' timers: a feedforward lead that changed from run to run.
    """
    loop = _loop(params=Params().replace(ramp_time=0.0), reference_timeout=0.1)
    loop.reference(Reference(T0 + 2 * MS, 0.010, 0.2), 0.0015)
    loop.reference(Reference(T0 + 6 * MS, 0.011, 0.6), 0.0055)
    _answer(loop, 5, now=0.0056)            # stamped 3/4 of the way from the first
    assert loop.axis.demand.v_ref == pytest.approx(0.5)
    assert loop.axis.demand.z_ref == pytest.approx(0.011 - 0.6 * 0.001)    # as before
    _answer(loop, 7, now=0.0075)            # after the newest: its own velocity
    assert loop.axis.demand.v_ref == 0.6
    loop.reference(Reference(T0 + 3 * MS, 0.012, 0.1), 0.0076)     # out of order: not used
    _answer(loop, 8, now=0.0082)            # for the velocity between
    assert loop.axis.demand.v_ref == 0.1


def test_a_stale_reference_is_held_still_and_the_axis_ramps_back_onto_it():
    p = Params().replace(ramp_time=0.05)
    loop = _loop(params=p, reference_timeout=0.1)
    loop.reference(Reference(T0, 0.01, 0.2), 0.0)
    _answer(loop, 0)
    assert loop.axis.demand.mode == 'ramp'     # the start's ramp-on, over by 50 ms
    z = 0.0
    for k in range(1, 100):                    # a piston that follows its demand
        _answer(loop, k, z=z, now=k * 1e-3 - 1e-4)
        z = loop.axis.demand.z_ref
    assert loop.axis.demand.mode == 'run' and loop.counts['reference_stale'] == 0
    # 0.1 s after it came, no new reference: held at its position, no velocity; once
    _answer(loop, 100, z=z, now=0.1001)
    assert loop.axis.demand.v_ref == 0.0 and loop.counts['reference_stale'] == 1
    _answer(loop, 101, z=z + 1e-6, now=0.1011)
    assert loop.counts['reference_stale'] == 1
    assert any('no reference for 0.1 s' in t for _, t in loop.notes)
    # back 60 mm on: the demand ramps from where it was held, no jump
    held = loop.axis.demand.z_ref
    loop.reference(Reference(T0 + 102 * MS, 0.07, 0.0), 0.102)
    _answer(loop, 102, z=z + 2e-6, now=0.102)
    assert loop.axis.demand.mode == 'ramp' and abs(loop.axis.demand.z_ref - held) < 1e-6
    assert any('ramping onto it' in t for _, t in loop.notes)


def test_lockstep_answers_a_state_only_with_the_reference_of_its_stamp():
    loop = _loop(lockstep=True)
    assert not loop.wall
    assert _answer(loop, 0) is None            # no reference yet: parked
    r = loop.trajectory([Reference(T0 + MS, 0.0, 0.0)])
    assert r is None                           # not its stamp
    r = loop.trajectory([Reference(T0, 0.0, 0.0), Reference(T0 + 2 * MS, 0.0, 0.0)])
    assert r is not None and r.stamp_ns == T0  # the parked state, answered now
    assert _answer(loop, 1) is not None        # its reference came before it
    assert T0 + MS not in loop._refs           # a used reference is dropped at once


def test_lockstep_keeps_at_most_ref_buffer_references_oldest_dropped_first():
    loop = _loop(lockstep=True)
    loop.trajectory([Reference(T0 + k * MS, 0.0, 0.0) for k in range(REF_BUFFER + 10)])
    assert len(loop._refs) == REF_BUFFER and T0 + 9 * MS not in loop._refs
    assert _answer(loop, 10) is not None


def test_lost_states_send_zero_once_and_the_pid_restarts_when_they_return():
    p = Params().replace(stale_timeout=0.005, ramp_time=0.0)
    loop = _loop(params=p)
    loop.reference(Reference(T0, 0.01, 0.0), 0.0)
    _answer(loop, 0)
    assert loop.axis.output > 0.0
    limit = LOST_FACTOR * 0.005
    assert loop.tick(limit - 1e-4, T0 + 49 * MS) == (None, ())
    reply, events = loop.tick(limit, T0 + 50 * MS)
    assert reply == (T0 + 50 * MS, 0.0, ()) and events == ()
    assert loop.lost and loop.counts['state_lost_events'] == 1 and loop.axis.output == 0.0
    assert loop.tick(limit + 0.01, T0 + 60 * MS) == (None, ())      # once
    assert loop.diagnosis() == (1, 'no state: command 0 A')
    r = _answer(loop, 70, now=0.07)
    assert not loop.lost and r is not None
    # the 0 A the tick sent is what the valve had: not a late loop's held command
    assert 'loop_timing' not in [e.detector for e in r.events]
    assert not loop.axis.supervisor.latches['loop_timing'].tripped
    assert ('info', 'states are back; PID restarted from rest') in loop.notes


def test_no_state_for_feedback_timeout_trips_the_feedback_detector_and_powers_off():
    p = Params().replace(feedback_timeout=0.2, stale_timeout=0.1)
    loop = _loop(params=p)
    _answer(loop, 0)
    reply, events = loop.tick(0.2, T0 + 200 * MS)      # exactly at the timeout: not yet
    assert events == ()
    reply, events = loop.tick(0.2001, T0 + 200 * MS)
    assert [e.detector for e in events] == ['feedback'] and events[0].action == 'power_off'
    assert reply == (T0 + 200 * MS, 0.0, ())
    assert loop.diagnosis()[0] == 2 and 'interlock power_off' in loop.diagnosis()[1]
    # reset is refused while the feedback is still lost
    ok, why, ev = loop.reset(0.3)
    assert not ok and 'no feedback for' in why and ev.kind == 'reset_refused'


def test_without_the_wall_clock_nothing_is_future_stale_or_lost():
    loop = _loop(wall=False, params=Params().replace(stale_timeout=0.005))
    assert loop.state(_st(0), 0.0, T0 - 10**12) is not None       # an hour "ahead"
    assert loop.state(_st(1), 100.0, T0 + 10**12) is not None     # "old"
    assert loop.tick(1000.0, T0) == (None, ())
    assert loop.counts['future'] == loop.counts['stale'] == 0


def test_non_finite_input_is_zero_current_counted_and_noted():
    loop = _loop()
    loop.reference(Reference(T0, math.nan, 0.0), 0.0)
    r = _answer(loop, 0, z=0.0)
    assert r.current == 0.0 and loop.counts['nonfinite'] == 1
    assert ('warning', 'non-finite state or reference: command 0 A') in loop.notes
    assert loop.diagnosis() == (2, 'non-finite input: command 0 A')


def test_delta_p_without_the_force_in_the_state_is_one_error_until_it_returns():
    loop = _loop(params=Params().replace(dp_gain=1e-7))
    r = _answer(loop, 0, f=math.nan)
    assert r.current == 0.0 and loop.no_force
    _answer(loop, 1, f=math.nan)
    errors = [t for lv, t in loop.notes if lv == 'error']
    assert len(errors) == 1 and 'dp_gain > 0 needs the hydraulic force' in errors[0]
    assert loop.diagnosis() == (2, 'no hydraulic force in the state for dp_gain: command 0 A')
    _answer(loop, 2, f=100.0)
    assert not loop.no_force and ('info', 'the hydraulic force is back in the state: delta-P '
                                  'on') in loop.notes


def test_an_interlock_says_the_input_fault_behind_it():
    """0 A for want of the force: the piston falls behind, the tracking error holds it."""
    loop = _loop(params=Params().replace(dp_gain=1e-7, ramp_time=0.0))
    loop.reference(Reference(T0, 0.01, 0.0), 0.0)
    for k in range(60):                       # 10 mm behind for 60 ms: above 5 mm for 50
        _answer(loop, k, f=math.nan)
    level, msg = loop.diagnosis()
    assert level == 2 and msg == ('interlock hold: limit_error (~/reset); no hydraulic force '
                                  'in the state for dp_gain: command 0 A')


def test_a_trip_comes_back_in_the_reply_and_reset_and_enable_are_the_supervisors():
    p = Params().replace(limit_position_max=0.01, limit_position_max_action='hold')
    loop = _loop(params=p)
    r = _answer(loop, 0, z=0.02)
    assert [e.detector for e in r.events] == ['limit_position_max']
    assert loop.counts['events'] == 1 and loop.diagnosis()[0] == 2
    ok, why, ev = loop.reset(0.01)            # still beyond the limit
    assert not ok and 'limit_position_max' in why
    back = _answer(loop, 1, z=0.0)
    # the hold's command 20 mm off is at the valve's limit: a clipping episode begins
    assert [(e.kind, e.detector) for e in back.events] == [('clipped', 'saturation')]
    ok, why, ev = loop.reset(0.01)
    assert ok and why == 'cleared limit_position_max' and loop.counts['events'] == 4
    ok, why, ev = loop.enable(False)
    assert ok and loop.diagnosis() == (1, 'hydraulics off: 0 A (~/enable)')
    assert _answer(loop, 2).current == 0.0


def test_the_figures_report_tracking_and_the_safety_state():
    loop = _loop(params=Params().replace(ramp_time=0.0))
    loop.reference(Reference(T0, 0.001, 0.0), 0.0)
    _answer(loop, 0, z=0.0)
    f = loop.figures()
    assert f['tracking_rms_m'] == pytest.approx(0.001) and f['answered'] == 1
    assert f['mode'] == 'run' and f['interlock'] == 'off' and 'trips_feedback' in f


@pytest.mark.parametrize('kw, match', [
    ({'rate_hz': 0.0}, '`rate_hz` = 0.0 must be a positive number'),
    ({'rate_hz': math.nan}, '`rate_hz` = nan'),
    ({'reference_timeout': 0.0}, '`reference_timeout` = 0.0 s must be a positive number'),
    ({'future_tolerance': math.inf}, '`future_tolerance` = inf s')])
def test_bad_options_are_named(kw, match):
    with pytest.raises(InputError, match=match):
        _loop(**kw)


# -- the load cell and the control modes -------------------------------------------------------
def test_a_load_topic_in_real_time_gives_each_state_the_newest_fresh_reading():
    loop = _loop(load_source='topic')
    loop.load(Load(T0, 1500.0))
    _answer(loop, 0)
    assert loop.measured.load == 1500.0 and loop.load_ok()
    loop.load(Load(T0 - MS, 99.0))                 # an older reading does not replace it
    _answer(loop, 1)
    assert loop.measured.load == 1500.0
    # stale: older than stale_timeout (5 ms) before the state
    _answer(loop, 6)
    assert math.isnan(loop.measured.load) and not loop.load_ok()
    ok, why, ev = loop.set_mode('force')
    assert not ok and 'load cell' in why and ev.kind == 'mode_refused'
    loop.load(Load(T0 + 7 * MS, 1600.0))
    _answer(loop, 7)
    assert loop.load_ok() and loop.set_mode('force')[0]


def test_lockstep_with_a_load_topic_waits_for_the_reading_of_the_states_stamp():
    loop = _loop(lockstep=True, load_source='topic')
    loop.trajectory([Reference(T0, 0.0, 0.0, 500.0)])
    assert _answer(loop, 0) is None                         # its load has not come
    assert loop.load(Load(T0 + MS, 1.0)) is None            # another stamp's
    r = loop.load(Load(T0, 480.0))
    assert r is not None and r.stamp_ns == T0 and loop.measured.load == 480.0
    # the load first, then the reference
    loop.load(Load(T0 + 2 * MS, 490.0))
    assert _answer(loop, 2) is None
    assert loop.trajectory([Reference(T0 + 2 * MS, 0.0, 0.0, 500.0)]) is not None


def test_a_force_reference_is_carried_to_the_states_instant_with_its_rate():
    loop = _loop(params=Params().replace(control_mode='force', ramp_time=0.0,
                                         mode_blend_time=0.0, k_L=5e6))
    loop.reference(Reference(T0, math.nan, math.nan, 1000.0), 0.0)
    loop.reference(Reference(T0 + MS, math.nan, math.nan, 1010.0), 0.0)    # 1e4 N/s
    for k in range(3):
        _answer(loop, k, load=1000.0)
    r = loop.state(AxisState(T0 + 3 * MS, 0.0, 0.0, math.nan, load=1020.0), 0.003, T0 + 3 * MS)
    assert r is not None and loop.axis.force.target == pytest.approx(1030.0)


def test_a_mode_switch_is_an_event_and_its_figures_say_which_loop_drives():
    loop = _loop(params=Params().replace(ramp_time=0.0, k_L=5e6))
    _answer(loop, 0, load=200.0)
    assert loop.figures()['control_mode'] == 'displacement'
    ok, why, ev = loop.set_mode('force')
    assert ok and (ev.kind, ev.detector) == ('mode', 'force') and 'from displacement' in why
    _answer(loop, 1, load=200.0)
    f = loop.figures()
    assert (f['control_mode'], f['driving'], f['load_n']) == ('force', 'force', 200.0)
    assert f['force_ref_n'] == 200.0 and f['force_error_n'] == 0.0
    # an interlock latched: the switch back to force is refused until the reset
    loop.set_mode('displacement')
    loop.set_params(loop.params.replace(limit_load_max=100.0, limit_load_max_action='hold'))
    r = _answer(loop, 2, load=200.0)
    assert [e.detector for e in r.events] == ['limit_load_max']
    ok, why, _ = loop.set_mode('force')
    assert not ok and 'reset first' in why


def test_a_state_answered_later_than_loop_timing_late_trips_loop_timing_once():
    loop = _loop(params=Params().replace(loop_timing_late=0.02, stale_timeout=0.005))
    _answer(loop, 0)
    # 20 ms late exactly: not yet (stale: the held command, judged all the same)
    r = loop.state(_st(1), 0.021, T0 + 21 * MS)
    assert r.events == () and loop.counts['stale'] == 1
    r = loop.state(_st(2), 0.0221, T0 + 22 * MS + 100)
    assert [(e.kind, e.detector, e.action) for e in r.events] == [('trip', 'loop_timing',
                                                                  'hold')]
    assert 'too busy' in r.events[0].message and r.events[0].value == pytest.approx(0.0200001)
    assert r.events[0].limit == 0.02 and r.events[0].unit == 's'
    r = loop.state(_st(3), 0.04, T0 + 40 * MS)          # latched: reported once
    assert r.events == ()
    assert loop.axis.supervisor.latches['loop_timing'].tripped
    r = _answer(loop, 41)                                # on time again: held by the latch
    assert loop.axis.demand.mode == 'hold'
    ok, why, _ = loop.reset(0.05)                        # nothing left to judge: clears
    assert ok, why


def test_a_stall_the_newest_state_hides_trips_loop_timing_by_the_command_it_held():
    # the loop topics keep one state: a loop that stalled 25 ms wakes to a fresh state (age
    # 0.2 ms), and the valve held the answer to state 5 for the 24 states in between
    loop = _loop(params=Params().replace(loop_timing_late=0.02, stale_timeout=0.005))
    for k in range(6):
        assert _answer(loop, k).events == ()
    r = loop.state(_st(30), 0.0302, T0 + 30 * MS + 200_000)
    assert [(e.kind, e.detector, e.action) for e in r.events] == [('trip', 'loop_timing',
                                                                  'hold')]
    assert r.events[0].value == pytest.approx(0.0242)
    assert '24 states in between never answered' in r.events[0].message
    assert 'too busy' in r.events[0].message and loop.counts['stale'] == 0


def test_states_skipped_within_loop_timing_late_are_not_a_late_loop():
    loop = _loop(params=Params().replace(loop_timing_late=0.02, stale_timeout=0.005))
    _answer(loop, 0)
    # 19 states never answered, the 20th answered 0.9 ms after its stamp: 19.9 ms held
    r = loop.state(_st(20), 0.0209, T0 + 20 * MS + 900_000)
    assert r.events == () and not loop.axis.supervisor.latches['loop_timing'].tripped
    # a plant that starts again (its stamps jump back) is a new run, not a stall
    _answer(loop, 100)
    r = loop.state(_st(10), 0.2, T0 + 10 * MS + 100_000)
    assert loop.counts['epochs'] == 1 and r.events == ()


def test_without_the_wall_clock_lateness_is_not_judged():
    loop = _loop(wall=False, params=Params().replace(loop_timing_late=0.002))
    _answer(loop, 0)
    r = loop.state(_st(1), 10.0, T0 + 10**10)
    assert r.events == () and not loop.axis.supervisor.latches['loop_timing'].tripped


def test_a_command_after_the_valve_was_zeroed_starts_from_zero_at_the_command_rate():
    p = Params().replace(ramp_time=0.0, command_rate=3.0)
    off = _loop(params=p.replace(command_rate=0.0))
    off.reference(Reference(T0, 0.01, 0.0), 0.0)
    want = off.state(AxisState(T0, 0.0, 0.0, i=0.0), 0.0, T0).current   # what 10 mm asks
    assert want > 0.006
    loop = _loop(params=p)
    loop.reference(Reference(T0, 0.01, 0.0), 0.0)
    i, steps, i_terms = 0.0, [], []
    for k in range(3):                       # 3 mA a period at most, from the valve's 0 A
        r = loop.state(AxisState(T0 + k * MS, 0.0, 0.0, i=i), k * 1e-3, T0 + k * MS)
        steps.append(r.current - i)
        i = r.current
        i_terms.append(loop.axis.ctrl.pid.i_term)
    assert max(abs(x) for x in steps) <= 0.003 + 1e-12
    assert steps[0] == pytest.approx(0.003) and loop.axis.rate_limited >= 2
    assert i_terms[1] == i_terms[0]          # no integration into the limit
    # a stall: the plant's watchdog zeroed the valve, and the state says so
    r = loop.state(AxisState(T0 + 20 * MS, 0.0, 0.0, i=0.0), 0.02, T0 + 20 * MS)
    assert r.current == pytest.approx(0.003)
