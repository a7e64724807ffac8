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
The simulated axis without DDS: stamp policy, watchdog, start, catch-up, lock-step, faults.

Clocks are passed in, so each rule is checked at its exact period; the plant node's DDS tests
(test_nodes.py, test_stamps.py, test_safety_nodes.py) check the same rules end to end.
"""

import math

import numpy as np
import pytest
from ros_ehs.core.errors import InputError
from ros_ehs.core.model.plant import Plant
from ros_ehs.core.params import Params
from ros_ehs.core.sim.axis import MAX_CATCHUP, PACE_CREDIT, PACE_TICK, SimulatedAxis

MS = 1_000_000      # ns


def _running(**kw) -> SimulatedAxis:
    """Return a real-time axis at 1 kHz started at wall 0 ns, armed by a command at 1.2 ms."""
    a = SimulatedAxis(Params(), rate_hz=1000.0, wall0_ns=0, **kw)
    assert a.start(0, 1)
    assert a.tick(1 * MS) == 1
    a.step()
    assert a.command(a.stamp_ns(), 0.001, 1.2e-3) == 'applied'
    return a


def test_the_stamp_policy_takes_only_the_answer_to_a_published_state():
    a = SimulatedAxis(Params(), rate_hz=1000.0, wall0_ns=0)
    a.start(0, 1)
    # before the first state: an answer to another run must not arm the watchdog
    assert a.command(0, 0.001, 0.0) == 'stale' and not a.armed
    a.tick(1 * MS)
    a.step()
    st = a.stamp_ns()
    assert a.command(st + 1, 0.001, 1e-3) == 'future'          # after the latest state
    assert a.command(st, math.nan, 1e-3) == 'non_finite'
    assert a.command(st, math.inf, 1e-3) == 'non_finite'
    assert a.command(st, 1.0, 1e-3) == 'applied' and a.armed
    assert a.i_cmd == 2 * Params()['i_rated']                  # clamped to twice rated
    assert a.command(st, 0.0, 1e-3) == 'stale'                 # no newer than the last applied
    assert a.command(st - MS, 0.0, 1e-3) == 'stale'
    f = a.figures(0.0)
    assert (f['future_commands'], f['bad_commands'], f['stale_commands']) == (1, 2, 3)


def test_the_watchdog_zeroes_the_valve_from_the_tick_a_command_would_outlive_its_periods():
    a = _running(watchdog_periods=3)           # the command arrived at 1.2 ms
    assert a.tick(2 * MS) == 1                 # applied until 3 ms: 1.8 ms old, allowed
    a.step()
    assert a.applied == 0.001 and not a.tripped
    # the tick due at 3 ms runs at 3.3 ms: the coming period would end 3.1 ms (> 3 periods)
    # after the command; on time it would have ended 2.8 ms after: a late tick's trip
    assert a.tick(3 * MS + 300_000) == 1
    a.step()
    assert a.applied == 0.0 and a.tripped and a.trips == 1 and a.trips_late_tick == 1
    trip = a.trip_log[-1]
    assert trip.command_age_ms == pytest.approx(2.1) and trip.tick_late_ms == pytest.approx(0.3)
    assert trip.late_tick_only and a.figures(0.0)['watchdog'] == 'tripped'
    assert a.tick(4 * MS) == 1                 # on time, and 3.8 ms: the controller stopped
    a.step()
    assert a.applied == 0.0 and a.trips == 1   # one trip, counted once
    assert a.trips_late_tick == 0 and not a.trip_log[-1].late_tick_only
    assert a.command(a.stamp_ns(), 0.002, 4.1e-3) == 'applied'
    a.tick(5 * MS)
    a.step()
    assert a.applied == 0.002 and not a.tripped and a.figures(0.0)['watchdog'] == 'ok'


def test_a_stall_under_the_watchdog_rides_through_on_the_last_command_and_is_counted_late():
    a = _running()                       # the default watchdog: 20 periods
    assert a.watchdog_periods == 20
    a.tick(2 * MS)
    a.step()
    # the controller stalls 8 ms: the valve keeps its last command (as a DAC holds it); each
    # period from the one ending 3 ms after the command is late, one episode, counted
    for k in range(3, 11):
        assert a.tick(k * MS) == 1
        a.step()
        assert a.applied == 0.001 and not a.tripped
    f = a.figures(0.0)
    assert (f['late_commands'], f['watchdog_trips']) == (1, 0)
    # found at the tick due at 4 ms: its period ends 3.8 ms after the command came
    assert a.late.log[-1].command_age_ms == pytest.approx(2.8)
    assert a.command(a.stamp_ns(), 0.002, 10.1e-3) == 'applied'
    a.tick(11 * MS)
    a.step()
    assert a.applied == 0.002 and not a.late.on
    # a controller that died: late from 3 periods, the valve zero from 20
    for k in range(12, 40):
        a.tick(k * MS)
        a.step()
        assert (a.applied == 0.0) == (k >= 30) and a.late.on == (k >= 13), k
    f = a.figures(0.0)
    assert (f['late_commands'], f['watchdog_trips']) == (2, 1)
    # what the piston did, the model's own: the current's peak and its largest step (the
    # watchdog's 2 mA to 0), the hydraulic force's peak and the travel
    assert f['current_peak_a'] == 0.002 and f['current_step_a'] == pytest.approx(0.002)
    assert f['force_peak_n'] > 0.0 and f['z_range_m'] > 0.0


def test_a_late_tick_alone_is_counted_apart():
    a = _running(watchdog_periods=3)
    a.tick(2 * MS)
    a.step()
    # the machine held the axis: the tick due at 3 ms runs at 6 ms; fresh commands then
    # return, so it stays a trip of the late tick alone
    n = a.tick(6 * MS)
    assert n == 4
    assert a.tripped and a.trips_late_tick == 1 and a.trip_log[-1].late_tick_only
    for _ in range(n):
        a.step()
    assert a.command(a.stamp_ns(), 0.001, 6.1e-3) == 'applied'
    a.tick(7 * MS)
    a.step()
    assert not a.tripped and a.trips == 1 and a.trips_late_tick == 1


def test_time_starts_with_the_subscribers_on_whole_periods_of_the_wall_grid():
    a = SimulatedAxis(Params(), rate_hz=1000.0, t0_ns=10**12, wall0_ns=0, wait_subscribers=2)
    assert not a.start(7_400_000, 1) and a.figures(0.0)['watchdog'] == 'waiting'
    assert a.start(7_400_000, 2)
    assert a.t0_ns == 10**12 + 7 * MS          # the wall grid's whole periods
    assert a.tick(7_900_000) == 0 and a.tick(8 * MS) == 1
    a.step()
    assert a.stamp_ns() == 10**12 + 8 * MS and a.sample().state.stamp_ns == a.stamp_ns()


def test_a_late_tick_steps_every_missed_period_and_far_behind_moves_the_grid_on():
    a = _running()
    assert a.tick(11 * MS) == 10               # 10 periods due: stamps without a gap
    for _ in range(10):
        a.step()
    assert a.k == 11 and a.overruns == 0
    k, t0 = a.k, a.t0_ns
    assert a.tick((11 + MAX_CATCHUP + 5) * MS) == 1     # further behind: one step, a gap
    a.step()
    assert a.overruns == 1 and a.k == k + 1
    assert a.stamp_ns() == t0 + (11 + MAX_CATCHUP + 5) * MS


def test_lockstep_steps_once_per_answer_and_resends_after_silence():
    a = SimulatedAxis(Params(), rate_hz=1000.0, lockstep=True, t0_ns=5 * 10**9,
                      start_delay=0.5, resend_period=0.05, clock_period=0.003, duration=0.005)
    assert a.poll(10.0, 0) is None
    assert a.poll(10.0, 1) == 'matched'
    assert a.poll(10.4, 1) is None and a.poll(10.5, 1) == 'first'
    assert a.clock_due()                       # the first state carries /clock
    assert a.command(a.stamp_ns() - MS, 0.001, 10.51) == 'not_current'
    assert a.command(a.stamp_ns(), 0.001, 10.51) == 'applied' and a.k == 1
    assert a.command(a.stamp_ns() - MS, 0.001, 10.52) == 'stale'    # a repeated answer
    assert a.k == 1 and a.poll(10.55, 1) is None
    assert a.poll(10.561, 1) == 'resend' and a.resends == 1
    clocks = []
    while not a.finished:
        assert a.command(a.stamp_ns(), 0.001, 10.6) == 'applied'
        clocks.append(a.clock_due())
    assert a.k == 5 and clocks == [False, True, False, True]     # every 3rd, and the last
    assert a.command(a.stamp_ns(), 0.001, 10.7) == 'not_current'   # finished: no more steps
    assert a.poll(20.0, 1) is None                                 # nor resends
    assert a.figures(20.0)['steps_per_s'] == pytest.approx(4 / 0.09)


def test_lockstep_at_a_real_time_factor_holds_each_state_until_its_time():
    """At 0.5 (2 ms of wall per 1 ms period) from the first state; released by poll."""
    a = SimulatedAxis(Params(), rate_hz=1000.0, lockstep=True, start_delay=0.0,
                      resend_period=0.05, real_time_factor=0.5)
    assert a.poll_period == PACE_TICK
    assert a.poll(1.0, 1) == 'matched' and a.poll(1.0, 1) == 'first'
    assert a.command(a.stamp_ns(), 0.001, 1.0005) == 'applied' and a.k == 1
    assert a.held                                  # due at 1.002
    assert a.poll(1.0019, 1) is None and a.held
    assert a.command(a.stamp_ns(), 0.001, 1.0019) == 'future'   # an answer to an unsent state
    assert a.poll(1.002, 1) == 'release' and not a.held
    # a slow answer: behind the pace, so the next state goes at once
    assert a.command(a.stamp_ns(), 0.001, 1.0045) == 'applied' and a.k == 2 and not a.held
    assert a.command(a.stamp_ns(), 0.001, 1.0046) == 'applied' and a.k == 3 and a.held
    assert a.poll(1.0059, 1) is None and a.poll(1.006, 1) == 'release'
    # while held there is no resend, however long the wait
    b = SimulatedAxis(Params(), rate_hz=10.0, lockstep=True, start_delay=0.0,
                      resend_period=0.05, real_time_factor=1.0)
    assert b.poll(0.0, 1) == 'matched' and b.poll(0.0, 1) == 'first'
    assert b.command(b.stamp_ns(), 0.0, 0.001) == 'applied' and b.held
    assert [b.poll(t, 1) for t in (0.05, 0.09)] == [None, None] and b.resends == 0
    assert b.poll(0.1, 1) == 'release'
    assert b.poll(0.149, 1) is None and b.poll(0.151, 1) == 'resend'   # then the usual rule


def test_a_paced_lockstep_run_far_behind_restarts_its_pace_and_the_last_state_is_not_held():
    a = SimulatedAxis(Params(), rate_hz=1000.0, lockstep=True, start_delay=0.0,
                      real_time_factor=1.0, duration=0.005)
    assert a.poll(0.0, 1) == 'matched' and a.poll(0.0, 1) == 'first'
    # a stall: the first answer comes 1 s late; the run does not race through the next second
    assert a.command(a.stamp_ns(), 0.0, 1.0) == 'applied' and not a.held
    assert a.command(a.stamp_ns(), 0.0, 1.0) == 'applied' and a.held       # paced from 1 s
    assert a.poll(1.001, 1) == 'release'
    # behind by less than PACE_CREDIT: caught up at full speed
    t = 1.001 + PACE_CREDIT / 2
    assert a.command(a.stamp_ns(), 0.0, t) == 'applied' and not a.held
    assert a.command(a.stamp_ns(), 0.0, t) == 'applied' and a.k == 4 and not a.held
    assert a.command(a.stamp_ns(), 0.0, t) == 'applied' and a.finished and not a.held
    # unpaced (the default) and real time never hold
    for b in (SimulatedAxis(Params(), lockstep=True, start_delay=0.0),
              SimulatedAxis(Params(), real_time_factor=1.0)):
        assert b.poll_period == b.resend_period
    with pytest.raises(InputError, match='`real_time_factor` = -1'):
        SimulatedAxis(Params(), lockstep=True, real_time_factor=-1.0)


def test_a_paused_lockstep_axis_holds_the_next_state_until_the_pause_ends():
    a = SimulatedAxis(Params(), rate_hz=1000.0, lockstep=True, start_delay=0.0,
                      resend_period=0.05)
    assert a.poll(0.0, 1) == 'matched' and a.poll(0.0, 1) == 'first'
    a.pause(True, 0.001)
    # the answer to the state already sent steps once; the state after it is held
    assert a.command(a.stamp_ns(), 0.001, 0.002) == 'applied' and a.k == 1 and a.held
    assert a.command(a.stamp_ns(), 0.001, 0.003) == 'future' and a.k == 1
    assert [a.poll(t, 1) for t in (0.1, 10.0)] == [None, None] and a.resends == 0
    assert a.figures(10.0)['paused'] is True
    a.pause(True, 10.0)                          # again: nothing changes
    a.pause(False, 10.0)
    assert a.poll(10.0, 1) == 'release' and not a.held and not a.paused
    assert a.command(a.stamp_ns(), 0.001, 10.001) == 'applied' and a.k == 2 and not a.held
    # paused before the first state: it waits for the pause to end
    b = SimulatedAxis(Params(), lockstep=True, start_delay=0.0)
    b.pause(True, 0.0)
    assert b.poll(0.0, 1) == 'matched' and b.poll(1.0, 1) is None
    b.pause(False, 1.0)
    assert b.poll(1.0, 1) == 'first'
    # a paced run pauses too, and its pace counts from the end of the pause
    c = SimulatedAxis(Params(), rate_hz=1000.0, lockstep=True, start_delay=0.0,
                      real_time_factor=1.0)
    assert c.poll(0.0, 1) == 'matched' and c.poll(0.0, 1) == 'first'
    assert c.command(c.stamp_ns(), 0.0, 0.0001) == 'applied' and c.held      # due at 0.001
    c.pause(True, 0.0002)
    assert c.poll(0.5, 1) is None
    c.pause(False, 5.0)
    assert c.poll(5.0, 1) == 'release'
    assert c.command(c.stamp_ns(), 0.0, 5.0001) == 'applied' and c.held      # due at 5.001
    assert c.poll(5.0009, 1) is None and c.poll(5.001, 1) == 'release'
    # a real-time axis runs on the clock: it refuses, and going on is nothing to it
    with pytest.raises(InputError, match='only a lock-step axis holds still'):
        SimulatedAxis(Params()).pause(True, 0.0)
    SimulatedAxis(Params()).pause(False, 0.0)


def test_the_lockstep_axis_is_the_model_stepped_with_each_answer():
    p = Params()
    a = SimulatedAxis(p, rate_hz=1000.0, lockstep=True)
    ref = Plant(p, 'simplified')
    x = ref.equilibrium()
    for k, i in enumerate(np.linspace(-0.005, 0.005, 20)):
        a.command(a.stamp_ns(), float(i), k * 1e-3)
        x = ref.step(x, np.array([i, 0.0]), 1e-3)
    np.testing.assert_allclose(a.x, x, rtol=1e-12, atol=0)
    s = a.sample()
    assert s.state.z == x[ref.state_names.index('z')] and s.state.i == 0.005
    assert s.p_cp == x[ref.state_names.index('p_CP')]


@pytest.mark.parametrize('fault', ['frozen_sensor', 'nan_sensor', 'stuck_valve',
                                   'lost_pressure'])
def test_each_fault_starts_at_its_time_and_ends_when_set_to_none(fault):
    a = SimulatedAxis(Params(), rate_hz=1000.0, lockstep=True, fault=fault, fault_time=0.01)
    for k in range(30):
        a.command(a.stamp_ns(), 0.004 if k < 10 else -0.004, k * 1e-3)
        s = a.sample()
        if k == 9:
            before = s
    assert a.fault_active and a.figures(0.0)['fault'] == fault
    assert a.notes == [('warning', f'fault {fault} injected at 0.01 s')]
    if fault == 'frozen_sensor':
        assert (s.state.z, s.state.z_dot) == (before.state.z, before.state.z_dot)
        assert a.x[a.plant.state_names.index('z')] != before.state.z     # the model moves on
    elif fault == 'nan_sensor':
        assert math.isnan(s.state.z) and math.isnan(s.state.z_dot)
    elif fault == 'stuck_valve':
        assert s.state.i == 0.004                   # the current at the start stays
    else:
        assert a.plant.params['p_s'] == 1.0e6
    a.notes.clear()
    a.configure(fault='none')
    a.command(a.stamp_ns(), -0.004, 1.0)
    assert not a.fault_active and a.notes == [('warning', 'injected fault ended')]
    assert a.plant.params['p_s'] == Params()['p_s'] and a.sample().state.i == -0.004


def test_a_failed_model_step_holds_the_state_and_is_noted_once_per_run_of_failures():
    a = SimulatedAxis(Params(), rate_hz=1000.0, lockstep=True)
    x = a.x.copy()
    a.x[:] = math.nan                              # the state has left the model
    held = a.x.copy()
    for k in range(3):
        assert a.command(a.stamp_ns(), 0.001, k * 1e-3) == 'applied'
    assert a.model_faults == 3 and a.i_cmd == 0.0 and len(a.notes) == 1
    assert a.notes[0][0] == 'error' and 'model step failed' in a.notes[0][1]
    np.testing.assert_array_equal(np.isnan(a.x), np.isnan(held))
    a.x[:] = x
    a.command(a.stamp_ns(), 0.001, 1.0)
    a.x[:] = math.nan
    a.command(a.stamp_ns(), 0.001, 1.0)
    assert len(a.notes) == 2                       # a new run of failures, noted again


def test_sensor_noise_is_seeded_and_leaves_the_model_exact():
    def run(seed):
        a = SimulatedAxis(Params(), rate_hz=1000.0, lockstep=True, noise=(1e-5, 1e-3, 1e4),
                          seed=seed)
        iz, ip = a.plant.state_names.index('z'), a.plant.state_names.index('p_CP')
        out = []
        for k in range(50):
            a.command(a.stamp_ns(), 0.002, k * 1e-3)
            s = a.sample()
            out.append((s.state.z - a.x[iz], s.p_cp - a.x[ip]))
        return np.array(out)
    e = run(1)
    np.testing.assert_array_equal(e, run(1))
    assert not np.array_equal(e, run(2))
    assert 0.5e-5 < e[:, 0].std() < 2e-5 and 0.5e4 < e[:, 1].std() < 2e4


@pytest.mark.parametrize('kw, name', [
    ({'rate_hz': 0.0}, '`rate_hz`'), ({'rate_hz': math.nan}, '`rate_hz`'),
    ({'noise': (0.0, -1.0, 0.0)}, '`noise`'), ({'noise': (0.0, 0.0)}, '`noise`'),
    ({'watchdog_periods': 0}, '`watchdog_periods`'), ({'fault': 'fire'}, '`fault`'),
    ({'fault_time': -1.0}, '`fault_time`'), ({'start_delay': math.inf}, '`start_delay`'),
])
def test_bad_configuration_names_the_argument(kw, name):
    with pytest.raises(InputError, match=name):
        SimulatedAxis(Params(), **kw)
