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
"""Live re-identification without ROS: the window, the push policy, drift, the estimate record."""

import math
import queue
import threading

import numpy as np
import pytest
from ros_ehs.benchmarks.drift import run
from ros_ehs.core.errors import DataError, InputError, ParameterError
from ros_ehs.core.identify.live import (LiveIdentifier, ReceiveClock, RefitSchedule,
                                        RefitThread, SampleWindow)
from ros_ehs.core.model import Plant
from ros_ehs.core.model.drift import Drift, DriftStage, smoothstep
from ros_ehs.core.params import ESTIMATED, preset
from ros_ehs.data.experiments import load_experiment
from ros_ehs.data.synthetic_bag import record_synthetic_bag
import ros_ehs_msgs_py as c
from waits import BOUND

TRUE = preset('table1_estimated')
PUSHABLE = ('d_c', 'F_cc', 'F_sc', 'l_iac', 'c_c')


def _fill(win, seconds, t0_ns=0, rate=1000.0):
    """Add a 1 Hz, 0.04 m motion with a current that drives it."""
    for k in range(int(seconds * rate)):
        t = k / rate
        win.add_state(t0_ns + int(round(t * 1e9)), 0.04 * math.sin(2 * math.pi * t),
                      0.08 * math.pi * math.cos(2 * math.pi * t),
                      0.01 * math.cos(2 * math.pi * t))


def test_the_window_is_bounded_and_keeps_only_its_last_seconds():
    win = SampleWindow(2.0, capacity=3000)
    _fill(win, 5.0)
    assert len(win._states) == 3000                      # never more than its capacity
    (exp,) = win.experiments()
    assert exp.t[-1] == pytest.approx(2.0) and exp.t.size == 2001     # the last 2 s only
    assert exp.z[-1] == pytest.approx(0.04 * math.sin(2 * math.pi * 4.999))


def test_the_window_drops_non_finite_states_and_restarts_on_a_stamp_jumping_back():
    win = SampleWindow(2.0, capacity=5000)
    _fill(win, 3.0, t0_ns=10_000_000_000)
    win.add_state(13_000_000_000, math.nan, 0.0, 0.0)
    win.add_state(13_001_000_000, math.inf, 0.0, 0.0)
    assert win.dropped == 2
    _fill(win, 1.0)           # a restarted plant: stamps from zero again
    assert win.runs == 2 and win.span() == pytest.approx(0.999)


def test_a_lockstep_resend_counts_once_in_every_signal_of_the_window():
    """
    A state resent with its sensors, stamped as before, counts once in every signal.

    Each signal's noise is what it is without the resends (a repeated sample time made the
    noise of the pressures NaN, and a NaN passed every residual check).
    """
    def run(resends):
        win = SampleWindow(2.0, capacity=5000)
        rng = np.random.default_rng(1)
        noise = rng.normal(0.0, 2e4, (2, 2000))
        for k in range(2000):
            t = k * 1e-3
            for _ in range(1 + (k in resends) * 3):
                ns = k * 1_000_000
                win.add_state(ns, 0.04 * math.sin(2 * math.pi * t),
                              0.08 * math.pi * math.cos(2 * math.pi * t))
                win.add_command(ns, 0.01 * math.cos(2 * math.pi * t))
                win.add_pressure(0, ns, 1e7 + 1e6 * math.sin(2 * math.pi * t) + noise[0, k])
                win.add_pressure(1, ns, 1e7 - 1e6 * math.sin(2 * math.pi * t) + noise[1, k])
                win.add_load(ns, 5e3 * math.sin(2 * math.pi * t) + 0.5 * noise[0, k])
        (exp,) = win.experiments()
        return exp
    once, resent = run(()), run((500, 900, 901, 1500))
    assert resent.t.size == once.t.size == 2000
    for key in ('z', 'p_CP', 'p_CT', 'load_cell'):
        assert math.isfinite(resent.noise[key]) and resent.noise[key] == once.noise[key], key
    assert once.noise['p_CP'] == pytest.approx(2e4, rel=0.1)


def test_the_window_names_what_is_missing():
    win = SampleWindow(2.0, capacity=5000)
    with pytest.raises(DataError, match='no state received'):
        win.experiments()
    for k in range(2000):       # a piston that does not move
        win.add_state(k * 1_000_000, 0.01, 0.0, 0.0)
    with pytest.raises(DataError, match='no excitation'):
        win.experiments()
    with pytest.raises(InputError, match='seconds'):
        SampleWindow(0.0, 10)
    with pytest.raises(InputError, match='capacity'):
        SampleWindow(1.0, 1)


@pytest.fixture(scope='module')
def exps(tmp_path_factory):
    d = tmp_path_factory.mktemp('live')
    record_synthetic_bag(d / 'rig', seed=7)
    record_synthetic_bag(d / 'full', seed=7, model='full')
    return load_experiment(d / 'rig'), load_experiment(d / 'full')


def _identifier(**kw):
    args = {'free': ESTIMATED, 'pushable': PUSHABLE, 'model': 'simplified', 'sigmas': 3.0,
            'rel_change': 0.02, 'push_period': 10.0}
    args.update(kw)
    return LiveIdentifier(preset('table1_initial'), **args)


def test_a_refit_is_due_after_the_first_window_then_every_period_one_at_a_time():
    s = RefitSchedule(10.0, 5.0)
    sec = 10**9
    assert not s.state(100 * sec)                 # the window starts filling
    assert not s.state(110 * sec - 1)
    assert s.state(110 * sec) and s.busy          # one window of the state clock later
    assert not s.state(116 * sec)                 # busy: no second refit queued
    s.done()
    assert s.state(116 * sec)                     # due since 115 s: now
    s.done()
    assert not s.state(120 * sec) and s.state(121 * sec)
    s.done()
    # a new run (the window started again): a whole window first
    assert not s.state(5 * sec, new_run=True) and s.state(15 * sec)
    with pytest.raises(InputError, match='`period_s` = 0.0 must be a positive number'):
        RefitSchedule(10.0, 0.0)


def test_the_refit_thread_runs_a_job_per_wake_up_and_goes_on_after_a_failed_one():
    ran, failed, finished, setup, jobs = queue.Queue(), [], queue.Queue(), [], []

    def job():
        jobs.append(1)
        ran.put(len(setup))
        if len(jobs) == 1:
            raise ValueError('singular Jacobian')

    t = RefitThread(job, failed.append, lambda: finished.put(1), lambda: setup.append(1))
    t.wake()
    assert ran.get(timeout=BOUND) == 1                # the setup ran first, on the thread
    finished.get(timeout=BOUND)                        # also after the failed job
    assert [str(e) for e in failed] == ['singular Jacobian']
    t.wake()
    assert ran.get(timeout=BOUND) == 1 and finished.get(timeout=BOUND) == 1 and t.alive
    assert t.stop(BOUND) and not t.alive and ran.empty()


def test_a_stop_starts_no_refit_and_says_if_one_under_way_kept_the_thread():
    # the stop's own wake-up once started a refit: numba compiled it in LLVM while the
    # interpreter exited, and LLVM aborted the process
    ran = []
    t = RefitThread(lambda: ran.append(1), pytest.fail)
    assert t.stop(BOUND) and ran == [] and t.stopping
    t.wake()
    assert ran == [] and not t.alive

    inside, release = threading.Event(), threading.Event()

    def job():
        inside.set()
        assert release.wait(BOUND)

    t = RefitThread(job, pytest.fail)
    t.wake()
    assert inside.wait(BOUND)
    assert not t.stop(0.0) and t.alive and t.stopping       # a refit under way keeps it
    t.wake()
    release.set()
    assert t.stop(BOUND) and not t.alive                     # ended, no second job


def test_a_message_without_a_header_goes_on_the_states_clock_by_the_median_offset():
    rc = ReceiveClock(keep=5)
    assert rc.stamp(1000) == 1000                 # no state yet: its receive time
    for stamp, recv in ((100, 150), (200, 240), (300, 345), (400, 900), (500, 548)):
        rc.state(stamp, recv)                     # offsets -50 -40 -45 -500 -48
    assert rc.stamp(1000) == 1000 - 48            # the median: one outlier does not move it
    for k in range(5):
        rc.state(k, k + 10)                       # only the newest 5 count
    assert rc.stamp(1000) == 990


def test_an_adequate_significant_fit_is_pushed_then_held_by_the_push_period(exps):
    live = _identifier()
    est, r = live.refit([exps[0]], 10_000_000_000, 10.0)
    assert est.adequate and not est.pushed
    assert 'not known' in est.reason           # no push before the controller's values
    live.controller = {n: 0.7 * TRUE[n] for n in PUSHABLE}
    est, r = live.refit([exps[0]], 15_000_000_000, 10.0)
    assert r.iterations < 8                     # warm from the first estimate
    assert est.pushed and 'F_cc' in est.reason and '+42.' in est.reason
    for n in ESTIMATED:
        assert est.values[n] == pytest.approx(TRUE[n], rel=0.05)
    live.pushed({n: est.values[n] for n in PUSHABLE}, est.stamp_ns)
    live.controller['F_cc'] = 0.7 * TRUE['F_cc']         # as if it drifted again
    est, _ = live.refit([exps[0]], 20_000_000_000, 10.0)
    assert not est.pushed and 'push_period' in est.reason
    est, _ = live.refit([exps[0]], 25_000_000_000, 10.0)
    assert est.pushed and est.reason.startswith('F_cc')     # only what changed is named
    live.pushed({n: est.values[n] for n in PUSHABLE}, est.stamp_ns)
    est, _ = live.refit([exps[0]], 40_000_000_000, 10.0)
    assert not est.pushed and 'no significant change' in est.reason


def test_an_inadequate_fit_is_never_pushed_nor_started_from(exps):
    live = _identifier(sigmas=0.0, rel_change=0.0, push_period=0.0)
    live.controller = {n: 0.5 * TRUE[n] for n in PUSHABLE}
    est, r = live.refit([exps[1]], 10_000_000_000, 10.0)     # the full model's rig
    assert not r.adequate and not est.adequate and not est.pushed
    assert est.failed == tuple(r.failed) and est.failed      # the rules, as data
    assert est.reason.startswith('not adequate') and live.estimate is None
    assert live.pushes == 0


def test_the_estimate_record_round_trips_and_a_malformed_one_is_named():
    e = c.ParameterEstimate(123_456_789_012, {'F_cc': 1046.9, 'c_c': 16100.0},
                            {'F_cc': 1.2, 'c_c': 7.0}, True, 'adequate: 1.00x',
                            True, 'F_cc 700 -> 1046.9', 10.0, 0.31, 4)
    back = c.estimate_from_msg(c.fill_estimate({'header': {'stamp': {}}}, e))
    assert back == e and back.failed == ()
    # a refit that failed rules names them; a writer from before failed_rules reads as none
    bad = e._replace(adequate=False, verdict='not adequate: ...',
                     failed=('agreement:F_cc', 'prediction:z_dot'))
    assert c.estimate_from_msg(c.fill_estimate({'header': {'stamp': {}}}, bad)) == bad
    old = c.fill_estimate({'header': {'stamp': {}}}, e)
    old['status'][0]['values'] = [kv for kv in old['status'][0]['values']
                                  if kv['key'] != 'failed_rules']
    assert c.estimate_from_msg(old) == e
    msg = c.fill_estimate({'header': {'stamp': {}}}, e)
    msg['status'][0]['values'] = [kv for kv in msg['status'][0]['values']
                                  if kv['key'] != 'pushed']
    with pytest.raises(ValueError, match="lacks the values \\['pushed'\\]"):
        c.estimate_from_msg(msg)
    with pytest.raises(ValueError, match='without a status'):
        c.estimate_from_msg({'header': {'stamp': {'sec': 0, 'nanosec': 0}}, 'status': []})


def test_drift_follows_a_smooth_curve_and_checks_its_stages():
    assert smoothstep(0.0) == 0.0 and smoothstep(1.0) == 1.0 and smoothstep(0.5) == 0.5
    assert smoothstep(-1.0) == 0.0 and smoothstep(2.0) == 1.0
    d = Drift([DriftStage(10.0, 20.0, {'F_cc': -0.3}), DriftStage(40.0, 10.0, {'F_cc': 0.1})])
    assert d.at(TRUE, 0.0)['F_cc'] == TRUE['F_cc']
    assert d.at(TRUE, 20.0)['F_cc'] == pytest.approx(0.85 * TRUE['F_cc'])
    assert d.at(TRUE, 60.0)['F_cc'] == pytest.approx(0.8 * TRUE['F_cc'])
    with pytest.raises(ParameterError, match='duration'):
        Drift([DriftStage(0.0, 0.0, {'F_cc': -0.3})])
    with pytest.raises(ParameterError, match='> -1'):
        Drift([DriftStage(0.0, 1.0, {'F_cc': -1.5})])
    with pytest.raises(ParameterError, match='F_xx'):
        Drift([DriftStage(0.0, 1.0, {'F_xx': 0.1})])


def test_a_plant_takes_new_parameters_from_its_next_step():
    a, b = Plant(TRUE, 'simplified'), Plant(TRUE, 'simplified')
    b.set_params(TRUE.replace(F_sc=0.5 * TRUE['F_sc'], F_cc=0.5 * TRUE['F_cc']))
    u = np.tile([0.002, 0.0], (300, 1))
    za, zb = a.simulate(1e-3, u).z, b.simulate(1e-3, u).z
    assert zb[-1] > za[-1] + 1e-4        # less friction: the same current moves it further


def test_live_updates_follow_a_drifting_rig_in_process():
    """A short, fast version of ``bench drift``: friction falls 30 % over 15 s."""
    drift = Drift([DriftStage(15.0, 15.0, {'F_cc': -0.3, 'F_sc': -0.3})])
    res = run('live', 60.0, drift=drift)
    fits = [r for r in res['refits'] if 'estimates' in r]
    last = fits[-1]
    for n in ('F_cc', 'F_sc', 'c_c'):
        assert last['estimates'][n] == pytest.approx(last['truth'][n], rel=0.02), n
    assert res['pushes'] and res['pushes'][-1]['values']['F_cc'] == pytest.approx(
        0.7 * TRUE['F_cc'], rel=0.03)
    # while the friction changes inside a window the model does not fit it: never pushed
    assert all(r['adequate'] for r in fits if r['pushed'])


def _rosbags_estimates(out, estimates, storage='mcap'):
    """Write ``estimates`` as the live node does, with rosbags' writer (not ours)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    arr_t = T['diagnostic_msgs/msg/DiagnosticArray']
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with Writer(out, version=9, storage_plugin=plugin) as w:
        conn = w.add_connection('/axis1/parameter_estimates', arr_t.__msgtype__, typestore=ts)
        for e in estimates:
            d = c.fill_estimate({'header': {'stamp': {}}}, e)
            st = d['status'][0]
            msg = arr_t(
                header=T['std_msgs/msg/Header'](
                    stamp=T['builtin_interfaces/msg/Time'](**d['header']['stamp']),
                    frame_id=''),
                status=[T['diagnostic_msgs/msg/DiagnosticStatus'](
                    level=st['level'][0], name=st['name'], message=st['message'],
                    hardware_id=st['hardware_id'],
                    values=[T['diagnostic_msgs/msg/KeyValue'](key=kv['key'], value=kv['value'])
                            for kv in st['values']])])
            w.write(conn, e.stamp_ns, ts.serialize_cdr(msg, arr_t.__msgtype__))


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_the_trend_reads_a_bag_from_another_writer_and_plots_each_parameter(tmp_path, storage):
    from ros_ehs.tools.cli import main
    from ros_ehs.data.trend import read_estimates, trend_table
    est = [c.ParameterEstimate(int(5e9 * k) + 7, {'F_cc': 1000.0 - 10 * k, 'c_c': 16000.0},
                               {'F_cc': 2.0, 'c_c': 9.0}, k != 2, 'v', k == 3, 'r', 10.0,
                               0.3, 4) for k in range(6)]
    est.insert(1, c.ParameterEstimate(7_000_000_007, {}, {}, False, 'no fit: no excitation',
                                      window_s=10.0, wall_s=0.0))
    _rosbags_estimates(tmp_path / 'run', est, storage)
    back = read_estimates(tmp_path / 'run')
    assert back == sorted(est, key=lambda e: e.stamp_ns)
    table = trend_table(back)
    assert 'no fit: no excitation' in table and table.count('True') >= 5
    assert main(['trend', str(tmp_path / 'run'), '--out', str(tmp_path / 'trend.png')]) == 0
    assert (tmp_path / 'trend.png').stat().st_size > 10_000


def test_the_trend_of_a_bag_without_estimates_names_the_topics_it_has(tmp_path, capsys):
    from ros_ehs.tools.cli import main
    assert main(['trend', 'bags/sample_sine_1hz']) == 2
    err = capsys.readouterr().err
    assert "no topic 'parameter_estimates'" in err and '/state' in err


def test_a_live_window_with_a_load_cell_refits_the_specimens_stiffness():
    """The window keeps the load cell; a refit of k_L from it, with its standard error."""
    from ros_ehs.core.sim.specimen_runs import run_axis
    truth = preset('fatigue_actuator', k_L=5e6, specimen_life=1e12, specimen_compliance=0.0,
                   load_cell_noise=20.0)
    run = run_axis(truth, 3.0, lambda t: (0.0015 * math.sin(2 * math.pi * 2 * t),
                                          0.003 * math.pi * math.cos(2 * math.pi * 2 * t),
                                          math.nan), model='reduced')
    win = SampleWindow(2.0, 4000)
    rng = np.random.default_rng(3)              # the bench's sensor noise
    for k, t in enumerate(run.t):
        st = int(round(t * 1e9))
        win.add_state(st, run.z[k] + 5e-6 * rng.standard_normal(),
                      run.z_dot[k] + 1e-3 * rng.standard_normal())
        win.add_command(st, run.i[k])
        win.add_load(st, run.load[k])
        win.add_pressure(0, st, run.p_a[k] + 2e4 * rng.standard_normal())
        win.add_pressure(1, st, run.p_b[k] + 2e4 * rng.standard_normal())
    win.add_load(0, math.nan)                  # a non-finite reading is not kept
    exps = win.experiments()
    assert len(exps) == 1 and exps[0].load_cell is not None
    live = LiveIdentifier(truth.replace(k_L=4e6), free=['k_L'], pushable=['k_L'],
                          model='reduced', sigmas=3.0, rel_change=0.02, push_period=0.0)
    live.controller = {'k_L': 4e6}
    est, r = live.refit(exps, int(run.t[-1] * 1e9), 2.0)
    assert est.values['k_L'] == pytest.approx(5e6, rel=0.01)
    assert 0 < est.stderr['k_L'] < 0.01 * 5e6
    assert est.pushed and 'k_L' in est.reason
