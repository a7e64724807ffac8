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
The control modes without DDS: the force loop, bumpless switches, refusals, protect, a break.

Closed loops run the plant node's and the controller node's cores in lock-step
(:func:`ros_ehs.core.sim.specimen_runs.run_axis`); the rules of one period are fed by hand.
"""

import math

import numpy as np
import pytest
from ros_ehs.core.control.modes import ForceLimit, ForceLoop, load_train_compliance
from ros_ehs.core.control.safety import break_travel
from ros_ehs.core.control.supervised import AxisController
from ros_ehs.core.model.coefficients import flow_gain_kq, null_load_gain
from ros_ehs.core.params import preset
from ros_ehs.core.sim.specimen_runs import run_axis

MS = 1_000_000
NAN = math.nan
#: a fatigue rig with a compliant specimen and gains tuned for it (the force benchmark's)
RIG = preset('fatigue_actuator', k_L=5e6, specimen_life=1e12, ramp_time=0.2,
             force_kp=1.675e-7, force_ki=5.0e-7)


def _force(t, f=NAN):
    return (NAN, NAN, f)


def test_the_force_loop_tracks_a_force_and_holds_it():
    run = run_axis(RIG.replace(control_mode='force'), 1.5,
                   lambda t: _force(t, 4e3 if t >= 0.5 else 0.0))
    assert set(run.driving) == {'force'}
    late = run.t > 1.2
    assert np.max(np.abs(run.load[late] - 4e3)) < 40.0          # 1 % of the step
    assert abs(run.load[-1] - 4e3) < 20.0
    # no specimen stiffness in the controller: no feedforward, the loop alone still holds it
    run = run_axis(RIG.replace(control_mode='force'), 1.5,
                   lambda t: _force(t, 4e3 if t >= 0.5 else 0.0),
                   controller_params=RIG.replace(control_mode='force', k_L=0.0))
    assert abs(run.load[-1] - 4e3) < 40.0


def test_the_force_feedforward_is_the_flow_of_the_load_trains_compliance():
    c = load_train_compliance(RIG)
    k_h = 2 * RIG['beta_e'] * RIG['A_p'] / RIG['l_iac']
    assert c == pytest.approx(1 / 5e6 + 1 / k_h)
    assert load_train_compliance(RIG.replace(k_L=0.0)) == 0.0
    loop = ForceLoop(RIG, 1e-3)
    loop.start(0, 0.0, 0.0, blend_time=0.0)
    loop.step(0, 0.0, 0.0)                       # the first target: no rate yet
    u = loop.step(MS, 0.0, 10.0)                 # 10 N in 1 ms: 1e4 N/s
    v = 1e4 * c
    ff = RIG['force_ff'] * RIG['A_p'] / (flow_gain_kq(RIG) * RIG['K_x']) * v
    assert loop.last_ff == pytest.approx(ff)
    assert u == pytest.approx(ff + RIG['force_kp'] * 10.0 + RIG['force_ki'] * 1e-3 * 0.0)


def test_a_force_loop_takes_over_at_the_command_it_finds():
    loop = ForceLoop(RIG, 1e-3)
    loop.start(5 * MS, 1234.0, 0.004)
    # at the handover the reference is the measured load: error 0, no feedforward yet
    assert loop.step(5 * MS, 1234.0, 5000.0) == pytest.approx(0.004)
    assert loop.target == 1234.0
    # and it blends to the reference over mode_blend_time
    half = 5 * MS + int(RIG['mode_blend_time'] / 2 * 1e9)
    assert loop.reference(half, 5000.0) == pytest.approx(1234.0 + 0.5 * (5000.0 - 1234.0))
    assert loop.reference(half * 10, 5000.0) == 5000.0
    # a reference without a force holds the load of the handover
    assert loop.reference(half * 10, NAN) == 1234.0


@pytest.mark.parametrize('kind', ['stiff', 'compliant'])
def test_switches_between_displacement_and_force_are_bumpless(kind):
    k = 5e7 if kind == 'stiff' else 5e6
    p = RIG.replace(k_L=k, force_kp=6.9e-8 if kind == 'stiff' else 1.675e-7)
    z0 = 5e3 / k
    run = run_axis(p, 2.5, lambda t: (z0, 0.0, NAN) if t < 1.5 else (NAN, NAN, 5e3),
                   actions=((1.0, 'mode', 'force'), (1.5, 'mode', 'displacement')))
    assert [a[1:3] for a in run.answers] == [('mode', True), ('mode', True)]
    k1, k2 = (int(np.searchsorted(run.t, t - 1e-9)) for t in (1.0, 1.5))
    assert run.driving[k1 - 1] == 'displacement' and run.driving[k1] == 'force'
    assert run.driving[k2 - 1] == 'force' and run.driving[k2] == 'displacement'
    for kk in (k1, k2):
        f0 = run.load[kk - 1]
        assert np.max(np.abs(run.load[kk:kk + 400] - f0)) < 0.01 * 1e4      # 1 % of 10 kN
        assert np.max(np.abs(np.diff(run.i[kk - 10:kk + 10]))) < 0.01 * p['i_rated']
    kinds = [(e.kind, e.detector) for e in run.events]
    assert kinds == [('mode', 'force'), ('mode', 'displacement')]


def _axis(**kw) -> AxisController:
    return AxisController(RIG.replace(ramp_time=0.0, **kw), 1e-3)


def _step(ax, k, z=0.0, load=1000.0, z_traj=0.0, f_traj=NAN):
    return ax.step(k * MS, z, 0.0, NAN, z_traj, 0.0, load, f_traj)


def test_a_switch_to_force_is_refused_without_a_valid_load_or_with_an_interlock():
    ax = _axis()
    _step(ax, 0)
    ok, why, ev = ax.set_mode('force', 0, load_ok=False)
    assert not ok and 'load cell' in why and ev.kind == 'mode_refused' and ax.mode == \
        'displacement'
    ok, why, ev = ax.set_mode('sideways', 0, load_ok=True)
    assert not ok and 'unknown control mode' in why
    # an interlock latched: reset first
    ax = _axis(limit_position_max=0.01, limit_position_max_action='hold')
    _step(ax, 0, z=0.02)
    ok, why, _ = ax.set_mode('force', 1, load_ok=True)
    assert not ok and 'reset first' in why and 'limit_position_max' in why
    # protect while the load is beyond the protect force
    ax = _axis(protect_force=500.0)
    _step(ax, 0, load=600.0)
    ok, why, _ = ax.set_mode('displacement_force_limited', 1, load_ok=True)
    assert not ok and 'beyond protect_force' in why
    _step(ax, 1, load=500.0)                     # exactly at it: allowed
    assert ax.set_mode('displacement_force_limited', 2, load_ok=True)[0]
    # back to displacement is never refused
    assert ax.set_mode('displacement', 3, load_ok=False)[0]


def test_force_control_without_a_valid_load_trips_load_feedback_and_holds_in_displacement():
    ax = _axis(control_mode='force')
    _step(ax, 0, load=1000.0, f_traj=1000.0)
    assert ax.driving == 'force'
    _step(ax, 1, z=1e-4, load=NAN, f_traj=1000.0)
    trips = [(e.kind, e.detector, e.action) for e in ax.events]
    assert ('trip', 'load_feedback', 'hold') in trips
    assert ('mode', 'displacement') in [(e.kind, e.detector) for e in ax.events]
    assert ax.mode == 'displacement' and ax.driving == 'displacement'
    assert ax.demand.mode == 'hold' and ax.demand.z_ref == 1e-4
    # the displacement loop took the command over where the force loop left it
    assert ax.output == pytest.approx(ax.ctrl.pid.i_term, abs=1e-12)


def test_a_hold_in_displacement_closes_the_valve_to_its_null_under_the_hydraulic_force():
    """
    The load cell lost, the hold starts at the valve's null under the load the oil holds.

    Its hydraulic force, not the load cell (which tripped), times ``null_load_gain``: with 0 A
    the displacement loop's P alone found that current, 12 um (120 N) off the held position on
    the fatigue rig; without a hydraulic force in the state, 0 A.
    """
    for force, want in ((9000.0, null_load_gain(RIG) * 9000.0), (NAN, 0.0)):
        ax = _axis(control_mode='force', command_rate=0.0)
        ax.step(0, 1e-4, 0.0, force, 0.0, 0.0, 9000.0, 9000.0)
        i = ax.step(MS, 1e-4, 0.0, force, 0.0, 0.0, NAN, 9000.0)     # lost: held at 0.1 mm
        assert ax.supervisor.tripped() == ['load_feedback'] and ax.driving == 'displacement'
        assert ax.demand.z_ref == 1e-4 and i == pytest.approx(want, rel=1e-9, abs=1e-15)
    assert null_load_gain(RIG) * 9000.0 == pytest.approx(1.1e-4, rel=0.1)   # docs/safety.md


def test_a_non_finite_load_in_displacement_is_no_fault():
    ax = _axis()
    for k in range(3):
        _step(ax, k, load=NAN)
    assert ax.events == [] and not ax.fault and ax.supervisor.tripped() == []


def test_an_interlocks_hold_in_force_control_holds_the_load_it_tripped_at_in_force():
    ax = _axis(control_mode='force', limit_load_max=2000.0, limit_load_max_action='hold')
    _step(ax, 0, load=1500.0, f_traj=1500.0)
    _step(ax, 1, z=2e-4, load=2100.0, f_traj=2500.0)
    assert [(e.kind, e.detector) for e in ax.events] == [('trip', 'limit_load_max')]
    # the load cell is sound: the force loop holds the load of the trip, not the reference
    assert ax.driving == 'force' and ax.demand.mode == 'hold'
    assert ax.force.target == 2100.0 and ax.force.last_ff == 0.0     # no rate fed
    _step(ax, 2, z=2e-4, load=2080.0, f_traj=2600.0)
    assert ax.force.target == 2100.0
    assert ax.mode == 'force'                       # an ordinary trip keeps the mode
    ok, why, _ = ax.supervisor.reset(2 * MS, 2e-4, load=1950.0)     # hysteresis: 5 %
    assert not ok and 'limit_load_max (load = 1950 N' in why
    ok, why, _ = ax.supervisor.reset(2 * MS, 2e-4, load=1900.0)
    assert ok, why
    _step(ax, 3, z=2e-4, load=1500.0, f_traj=1500.0)
    assert ax.driving == 'force' and ax.force.target == 1500.0


def test_a_load_limit_tripped_ahead_of_the_load_holds_the_limit_with_a_share_of_the_brake():
    """The load ahead passed the limit before the reading: the force loop holds the limit."""
    ax = _axis(control_mode='force', limit_load_max=2025.0, limit_load_max_action='hold',
               limit_load_lead=0.002)
    for k in range(40):                          # 50 N a period, the reference 100 N ahead
        ff = ax.force.last_ff
        _step(ax, k, load=50.0 * k, f_traj=50.0 * k + 100.0)
        if ax.events:
            break
    # the load ahead is 100 N on (2 ms at 50 N a period): 1900 N is 2000 N ahead, 1950 N
    # 2050 N, half a period's change beyond the limit: it trips half a period late
    assert k == 39 and [(e.kind, e.detector) for e in ax.events] == [('trip', 'limit_load_max')]
    assert ax.force.target == 2025.0 and ax.demand.mode == 'hold'
    assert ff > 0 and ax.force.last_ff == pytest.approx(-0.5 * RIG['hold_brake'] * ff)


def test_a_hold_the_axis_does_not_obey_turns_the_hydraulics_off():
    """
    A stuck valve: the load runs on from the one held.

    Past hold_error_force for longer than hold_error_time, hold_error latches power off (0 A).
    """
    ax = _axis(control_mode='force', limit_load_max=2000.0, limit_load_max_action='hold',
               hold_error_force=500.0, hold_error_time=0.005)
    _step(ax, 0, load=1500.0, f_traj=1500.0)
    _step(ax, 1, z=2e-4, load=2100.0, f_traj=2500.0)            # held at 2100 N
    # 100 N more each period: beyond 500 N from k = 7 on, for more than 5 ms at k = 12
    for k in range(2, 12):
        assert _step(ax, k, z=2e-4, load=2100.0 + 100.0 * (k - 1), f_traj=2500.0) != 0.0
        assert ax.supervisor.tripped() == ['limit_load_max'], k
    assert _step(ax, 12, z=2e-4, load=3200.0, f_traj=2500.0) == 0.0
    assert ax.supervisor.tripped() == ['limit_load_max', 'hold_error']
    assert ax.supervisor.action == 'power_off' and 'does not hold' in ax.events[0].message


def test_a_hold_in_force_whose_piston_runs_away_turns_the_hydraulics_off():
    """
    The load path lost while held in force (the break detector off): the piston runs.

    The load cell reads the held load; past hold_error_position + hold_error_force / k_L
    (1 mm + 0.1 mm on 1e7 N/m) for longer than hold_error_time, hold_error powers off.
    """
    ax = _axis(control_mode='force', k_L=1.0e7, limit_load_max=2000.0,
               limit_load_max_action='hold', hold_error_time=0.005)
    _step(ax, 0, load=1500.0, f_traj=1500.0)
    _step(ax, 1, z=2e-4, load=2100.0, f_traj=2500.0)            # held at 2100 N
    said = []
    for k in range(2, 20):                   # 0.1 mm a period, the load as held
        _step(ax, k, z=2e-4 + 1e-4 * (k - 1), load=2100.0, f_traj=2500.0)
        said += [e.message for e in ax.events if e.detector == 'hold_error']
        if k <= 12 + 5:                      # beyond 1.1 mm from k = 13, latched after 5 ms
            assert 'hold_error' not in ax.supervisor.tripped(), k
    assert ax.supervisor.tripped() == ['limit_load_max', 'hold_error']
    assert len(said) == 1 and 'the load path is lost' in said[0]
    assert ax.supervisor.action == 'power_off'


def test_a_frozen_load_cell_under_force_control_holds_where_it_last_read_true():
    ax = _axis(control_mode='force', k_L=1.0e7, load_frozen_force=200.0)
    _step(ax, 0, z=1.0e-4, load=1000.0, f_traj=1000.0)
    for k in range(1, 4):          # the reading repeats while the piston moves 10 um a period
        _step(ax, k, z=1.0e-4 + 1.0e-5 * k, load=1000.0, f_traj=1500.0)
    # k_L times 30 um is 300 N > 200 N (20 um: 200 N, not above): tripped on the third
    assert ax.supervisor.tripped() == ['load_feedback']
    assert 'frozen' in ax.events[0].message and ax.mode == 'displacement'
    assert ax.demand.mode == 'hold' and ax.demand.z_ref == pytest.approx(1.0e-4)
    # exactly 0 N (a simulated broken specimen's cell) is left to the break detector
    ax = _axis(control_mode='force', k_L=1.0e7)
    for k in range(6):
        _step(ax, k, z=1.0e-4 * k, load=0.0, f_traj=0.0)
    assert ax.supervisor.tripped() == []


def test_specimen_protect_keeps_a_move_into_a_stiff_specimen_under_its_limit():
    p = RIG.replace(k_L=5e7, force_kp=6.9e-8, control_mode='displacement_force_limited',
                    protect_force=2e3)

    def ref(t):
        s = min(max(t - 0.5, 0.0) * 0.01, 0.005)
        return s, (0.01 if 0.0 < s < 0.005 else 0.0), NAN

    run = run_axis(p, 1.5, ref)
    assert np.max(np.abs(run.load)) <= 2e3 * 1.05
    assert run.figures['protect_limiting']
    # and the tracking error detector does not take the limit for a fault
    assert run.figures['trips_limit_error'] == 0
    # without protect the same move loads it far beyond
    run = run_axis(p.replace(control_mode='displacement'), 0.7, ref)
    assert np.max(run.load) > 2e4


def test_the_limit_pulls_back_towards_its_force_and_undoes_the_integration():
    lim = ForceLimit(RIG.replace(protect_force=1000.0, force_kd=0.0), 1e-3)
    assert lim.apply(0.01, 0.0) == pytest.approx(RIG['force_kp'] * 1000.0) and lim.active
    assert lim.apply(-0.01, 0.0) == pytest.approx(-RIG['force_kp'] * 1000.0)
    assert lim.apply(1e-6, 0.0) == 1e-6 and not lim.active
    assert lim.apply(0.01, NAN) == 0.01                           # no reading: no limit


@pytest.mark.parametrize('kind', ['stiff', 'compliant'])
def test_a_break_in_force_control_ends_held_in_displacement_within_its_bound(kind):
    k = 5e7 if kind == 'stiff' else 5e6
    p = RIG.replace(k_L=k, force_kp=6.9e-8 if kind == 'stiff' else 1.675e-7,
                    control_mode='force', specimen_life=5.0, specimen_life_range=9e3,
                    specimen_compliance=0.0)
    run = run_axis(p, 3.0, lambda t: _force(t, 5.5e3 + 4.5e3 * math.sin(2 * math.pi * 5 * t)))
    kb = int(np.nonzero((run.load == 0.0) & (run.t > 0.2))[0][0])
    trips = [e for e in run.events if e.kind == 'trip']
    assert [e.detector for e in trips] == ['specimen_break']
    assert trips[0].action == 'hold' and trips[0].value > p['break_drop']
    assert run.figures['control_mode'] == 'displacement' and run.figures['mode'] == 'hold'
    peak = np.max(run.load[kb - 60:kb])
    travel = np.max(np.abs(run.z[kb:] - run.z[kb]))
    assert 0 < travel <= break_travel(p, peak, 1e-3)
    assert np.max(np.abs(run.z_dot[-200:])) < 1e-3            # held: the loop settles it
    # without the detector the force loop runs the piston away, towards its end stop
    # (and without the force error's and the hold's, which catch it too)
    run = run_axis(p.replace(specimen_break_action='off', load_feedback_action='off',
                             limit_force_error_action='off', hold_error_action='off'), 3.0,
                   lambda t: _force(t, 5.5e3 + 4.5e3 * math.sin(2 * math.pi * 5 * t)))
    assert np.max(np.abs(run.z)) > 0.05


def test_a_force_hold_reverses_the_rate_feedforward_for_one_period_then_holds_its_load():
    f = ForceLoop(RIG, 1e-3)
    f.start(0, 5000.0, 0.0, blend_time=0.0)
    for k in range(1, 4):                       # a load rising at 100 kN/s: a rate feedforward
        f.step(k * MS, 5000.0 + 100.0 * k, 5000.0 + 100.0 * k)
    rate_ff = f.last_ff
    assert rate_ff > 0
    f.hold(5300.0)
    f.step(4 * MS, 5300.0, 9e3)
    assert RIG['hold_brake'] == 2.0          # reversed twice over (docs/safety.md)
    assert f.target == 5300.0 and f.last_ff == pytest.approx(-2.0 * rate_ff)
    f.step(5 * MS, 5300.0, 9e3)                 # one period only
    assert f.last_ff == 0.0
    f.start(6 * MS, 5300.0, 0.0, blend_time=0.0)
    for k in range(7, 10):
        f.step(k * MS, 5300.0 + 100.0 * k, 5300.0 + 100.0 * k)
    f.hold(6300.0, brake=0.25)                  # a share of the brake: a quarter of it
    f.step(10 * MS, 6250.0, 9e3)
    assert f.last_ff == pytest.approx(-0.5 * rate_ff)
    f.release()
    assert f.reference(6 * MS, 9e3) == 9e3
    f.release()                                 # twice: nothing more
    assert f.reference(6 * MS, 8e3) == 8e3


def test_a_force_holds_brake_is_its_setting_and_zero_steps_the_valve_to_its_null():
    f = ForceLoop(RIG.replace(hold_brake=0.0), 1e-3)
    f.start(0, 5000.0, 0.0, blend_time=0.0)
    for k in range(1, 4):
        f.step(k * MS, 5000.0 + 100.0 * k, 5000.0 + 100.0 * k)
    assert f.last_ff > 0
    f.hold(5300.0)
    f.step(4 * MS, 5300.0, 9e3)
    assert f.last_ff == 0.0


def test_a_force_hold_damps_with_the_hydraulic_force_within_hold_dp_max():
    """
    A force hold damps the oil column with the hydraulic force, within ``hold_dp_max``.

    It takes ``hold_dp_gain`` times the hydraulic force, high-passed with ``dp_tau`` from the
    held load (here the reading beyond the limit, 2100 N), off its command (the PID's own
    state untouched), never more than ``hold_dp_max`` either way; without a hydraulic force
    in the state, nothing.
    """
    g, tau, dt = 4e-7, RIG['dp_tau'], 1e-3
    loads = [2100.0, 2150.0, 2180.0, 2120.0, 2060.0, 2050.0, 2050.0]
    forces = [2300.0, 2500.0, 2200.0, 1900.0, 2050.0, 6000.0, -3000.0]

    def run(gain, force=True):
        ax = _axis(control_mode='force', limit_load_max=2000.0, limit_load_max_action='hold',
                   command_rate=0.0, hold_dp_gain=gain)
        ax.step(0, 0.0, 0.0, 1500.0, 0.0, 0.0, 1500.0, 1500.0)
        out = [ax.step(k * MS, 2e-4, 0.0, f if force else NAN, NAN, NAN, load, 2500.0)
               for k, (load, f) in enumerate(zip(loads, forces), start=1)]
        assert ax.supervisor.tripped() == ['limit_load_max']
        return np.array(out)
    hp, prev, want = 0.0, loads[0], []
    for f in forces:                             # held from the first (the trip's) period
        hp, prev = tau / (tau + dt) * (hp + f - prev), f
        want.append(-min(max(g * hp, -1e-3), 1e-3))
    d = run(g) - run(0.0)
    assert d == pytest.approx(want, abs=1e-15) and min(d[:5]) < -5e-5
    assert list(d[5:]) == [-1e-3, 1e-3]          # hold_dp_max, both ways
    assert RIG['hold_dp_max'] == 1e-3
    assert list(run(g, force=False) - run(0.0, force=False)) == [0.0] * len(forces)
    with pytest.raises(ValueError, match='hold_dp_gain'):
        RIG.replace(hold_dp_gain=-1e-7)


def test_a_load_limit_tripped_ahead_damps_about_the_limit_not_the_force_at_the_trip():
    """
    Tripped ahead of its reading, a load limit's hold damps about the limit it holds.

    The delta-P's memory starts at the held load: a hydraulic force still short of the
    limit at the trip adds current toward it, and the term is zero where the force reaches
    the limit. Started at the force at the trip, it pulled the stopped load back there (the
    swing back of some 2 % of the range in the ``transitions`` benchmark).
    """
    def run(gain):
        ax = _axis(control_mode='force', limit_load_max=2000.0, limit_load_max_action='hold',
                   command_rate=0.0, hold_dp_gain=gain)
        out = []
        for k, load in enumerate((1000.0, 1400.0, 1800.0)):    # ahead: 1800 + 3.4 ms rate
            out.append(ax.step(k * MS, 2e-4, 0.0, load - 100.0, NAN, NAN, load, 2500.0))
        assert ax.supervisor.tripped() == ['limit_load_max']
        assert ax.supervisor.load_trip[0] == 2000.0             # the hold holds the limit
        out.append(ax.step(3 * MS, 2e-4, 0.0, 2000.0, NAN, NAN, 1950.0, 2500.0))
        return np.array(out)
    g, tau, dt = 4e-7, RIG['dp_tau'], 1e-3
    d = run(g) - run(0.0)
    assert d[:2] == pytest.approx([0.0, 0.0], abs=1e-15)       # before the trip: no term
    assert d[2] == pytest.approx(g * tau / (tau + dt) * (2000.0 - 1700.0), rel=1e-12)
    hp = tau / (tau + dt) * (-300.0 * tau / (tau + dt) + 2000.0 - 1700.0)
    assert d[3] == pytest.approx(-g * hp, rel=1e-12) and abs(d[3]) < 0.1 * d[2]


def test_a_force_hold_takes_the_valve_null_current_of_its_load_into_the_integrator():
    f = ForceLoop(RIG, 1e-3)
    assert f.i_per_load == pytest.approx(null_load_gain(RIG)) and f.i_per_load > 0
    f.start(0, 5500.0, 1e-3, blend_time=0.0)
    for k in range(1, 2000):                    # 1-10 kN at 10 Hz: its mean is 5.5 kN
        v = 5500.0 + 4500.0 * math.sin(2 * math.pi * 10 * k * 1e-3)
        f.step(k * MS, v, v)
    i0 = f.pid.i_term
    f.hold(9000.0)                              # at rest under 9 kN the null needs more current
    # the mean over the integrator's time constant (0.34 s) ripples +-214 N at 10 Hz
    assert f.pid.i_term - i0 == pytest.approx(f.i_per_load * 3500.0, abs=f.i_per_load * 250.0)
    assert ForceLoop(RIG.replace(force_ff=0.0), 1e-3).i_per_load == 0.0   # no feedforward


def test_a_clipped_command_is_an_episode_one_event_at_its_start_and_one_at_its_end():
    """The valve at its limit, then as asked for CLIP_QUIET: two events, not one a period."""
    from ros_ehs.core.control.supervised import CLIP_QUIET
    ax = _axis(command_rate=0.0)
    _step(ax, 0)
    kinds = []
    for k in range(1, 50):                    # 20 mm off: the PID at u_max every period
        _step(ax, k, z=0.0, z_traj=0.02)
        assert ax.saturated
        kinds += [(e.kind, e.detector) for e in ax.events]
    assert kinds == [('clipped', 'saturation')] and ax.clipping
    quiet = int(CLIP_QUIET / 1e-3)
    ends = []
    for k in range(50, 50 + quiet + 2):        # on its reference: applied as asked
        _step(ax, k, z=0.0, z_traj=0.0)
        assert not ax.saturated or k < 52
        ends += [(k, e.kind) for e in ax.events]
    assert [e for _, e in ends] == ['unclipped'] and not ax.clipping
    assert ends[0][0] >= 50 + quiet - 2
