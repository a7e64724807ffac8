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
The nodes over real DDS: each test on its own ROS_DOMAIN_ID, nodes as separate processes.

Lock-step vs the in-process loop, recorder crash safety and external readers, the plant's
watchdog, bad messages, live parameters, the contract, the player, the identify node.
"""

import contextlib
import json
import math
import os
from pathlib import Path
import time

import numpy as np
import pytest
from ros_ehs.core.control.waveforms import Sine
from ros_ehs.core.options import PLANT
from ros_ehs.core.params import Params
from ros_ehs.core.sim.closed_loop import run_closed_loop
from ros_ehs.data.bag import bag_counts, open_bag
from ros_ehs.nodes.processes import loop_closed, loop_placement, node_command, NodeProcesses
import ros_ehs_msgs_py as c
from scripts import run_script
from waits import BOUND, lockstep_complete, status_value, wait_for_bag, wait_value
import yaml

#: the plant's watchdog at its default, in ms of a 1 kHz loop
WD_MS = float(next(o.default for o in PLANT if o.name == 'watchdog_periods'))

pytestmark = pytest.mark.ros
ROOT = Path(__file__).resolve().parents[1]
FIXTURES = Path(__file__).resolve().parent / 'fixtures' / 'rosbag2'


def _states(bag_path):
    """Return (stamps [ns], z, current) of the recorded states, one per stamp."""
    bag = open_bag(bag_path)
    seen = {}
    for _, msg in bag.decoded(['/state']):
        s = c.state_from_msg(msg)
        seen[s.stamp_ns] = s
    ks = sorted(seen)
    return (np.array(ks), np.array([seen[k].z for k in ks]), np.array([seen[k].i for k in ks]))


def _sent_commands(bag_path) -> dict:
    """
    Return each period's commands as the reference sent them: stamp [ns] -> set of z_ref.

    Read by rosbags from the bag's ``/reference_trajectory`` (every window, resends
    included), so a window answered early shows as two values for one stamp.
    """
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    sent = {}
    with Reader(bag_path) as r:
        for conn, _, raw in r.messages([x for x in r.connections
                                        if x.topic == '/reference_trajectory']):
            m = ts.deserialize_cdr(raw, conn.msgtype)
            t0 = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            for p in m.points:
                k = t0 + p.time_from_start.sec * 10**9 + p.time_from_start.nanosec
                sent.setdefault(k, set()).add(round(p.positions[0], 12))
    return sent


def _corrected_lockstep(dom, tmp_path, duration: float, reference: dict, correction,
                        plant: dict | None = None):
    """
    Run the bench's loop in lock-step with ``reference`` options, and the same in process.

    Checks that every period's command was sent one way only (a window answered before the
    states it depends on would have sent an old one first) and that the position and the
    commands equal the in-process loop's with ``correction`` (the node's default preview and
    the controller's ramp_time) to 1e-9 m. ``plant``: its extra options. Returns the
    reference node's log.
    """
    bag = tmp_path / 'corrected'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start_loop('lockstep', bag=bag, plant={'duration': duration, **(plant or {})},
                         reference=reference)
        lockstep_complete(procs)
        n = int(round(duration * 1000))
        wait_for_bag(bag, {'/state': n + 1})      # the last states on their way to it
        codes = procs.stop(['recorder', 'reference', 'controller', 'plant'])
        out = procs['reference'].output()
    assert codes == {'recorder': 0, 'reference': 0, 'controller': 0, 'plant': 0}
    t, z, _ = _states(bag)
    assert len(t) == n + 1 and np.all(np.diff(t) == 1_000_000)
    ref = run_closed_loop(Params(), correction, duration, model='simplified', dt=1e-3,
                          supervised=True)
    sent = _sent_commands(bag)
    assert all(len(v) == 1 for v in sent.values())
    np.testing.assert_allclose([next(iter(sent[k])) for k in t], ref.z_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(z, ref.z, rtol=0, atol=1e-9)
    return ref, out


# -- lock-step ---------------------------------------------------------------------------------
#: the longest the recorder is paused [s]: Fast DDS's shared-memory health check takes a
#: process frozen for about a second for a crashed one, can hold its writers that long and
#: drop a writer's path to it for good (docs/recording.md, "A recorder that stalls")
RECORDER_PAUSE = 0.3


def test_lockstep_over_dds_reproduces_the_in_process_loop(dom, tmp_path):
    """
    Tolerance: 1e-9 m on the position and 1e-9 A on the current, at every period.

    The arithmetic is the same; only the reference's time differs in the last bits (the node
    computes it from stamps in ns, the in-process loop as k * dt). The recorder is paused
    (SIGSTOP) mid-run while the loop runs 300 periods (at most RECORDER_PAUSE), as a busy
    machine does: nothing waits for it, and over the reliable lock-step QoS it still gets every
    state (best effort lost ~100 here).
    """
    import signal
    duration = 2.0
    n = int(round(duration * 1000))
    bag = tmp_path / 'lockstep'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        # split into files of 150 kB as it records: the pause falls across splits; the
        # plant says how far it has stepped every 20 ms
        procs.start_loop('lockstep', bag=bag,
                         plant={'duration': duration, 'diagnostics_period': 0.05},
                         recorder={'max_bag_size': 150_000, 'compression': 'none'})
        _assert_placed(procs)
        wait_for_bag(bag, {'/state': 200})
        rec = procs['recorder'].popen
        wait_value(procs, c.PLANT_STATUS, 'steps', 1)
        steps = status_value(procs, c.PLANT_STATUS, 'steps')
        rec.send_signal(signal.SIGSTOP)           # paused, as a busy machine pauses it
        # while the loop runs on 300 periods (on a quiet machine), at most RECORDER_PAUSE
        procs.wait_status(c.PLANT_STATUS,
                          lambda st: float(st.values['steps']) >= min(n, steps + 300),
                          RECORDER_PAUSE)
        rec.send_signal(signal.SIGCONT)
        lockstep_complete(procs)
        # what the pause made the recorder miss is repaired at the writers' next heartbeat
        # (0.1 s on the nodes' Fast DDS profile; 3 s on Fast DDS's own, where a recorder
        # stopped before it lost 120-150 of the 201 /clock and /reference): its lock-step
        # drain outlasts it (docs/recording.md); it is stopped first, while the writers run
        wait_for_bag(bag, {'/state': n + 1})
        codes = procs.stop(['recorder', 'reference', 'controller', 'plant'])
    assert codes == {'recorder': 0, 'reference': 0, 'controller': 0, 'plant': 0}
    t, z, i = _states(bag)
    assert len(t) == n + 1 and np.all(np.diff(t) == 1_000_000)
    # split, and nothing lost or doubled across the files: every state the plant sent
    # (resends included) once, for rosbags as for us
    f = procs['plant'].figures()
    files = yaml.safe_load((bag / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']['relative_file_paths']
    assert len(files) >= 4 and open_bag(bag).topics['/state'].count == n + 1 + f['resends']
    from rosbags.rosbag2 import Reader
    with Reader(bag) as r:
        assert sum(x.msgcount for x in r.connections if x.topic == '/state') == \
            n + 1 + f['resends']
    loop = ('/state', '/servo_current', '/reference', '/reference_trajectory')
    assert {k: tp.qos[0]['reliability'] for k, tp in open_bag(bag).topics.items()
            if k in loop} == dict.fromkeys(loop, 'reliable')
    ref = run_closed_loop(Params(), Sine(0.04, 1.0), duration, model='simplified', dt=1e-3,
                          supervised=True)      # the node's computation, ramp-on included
    # what the controller read, decoded by a reader we did not write: every period of the
    # run covered, each sample the sine at its stamp; /clock every 10 periods (clock_period)
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    cover, clocks = {}, []
    with Reader(bag) as r:
        for conn, _, raw in r.messages([x for x in r.connections
                                        if x.topic in ('/reference_trajectory', '/clock')]):
            m = ts.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == '/clock':
                clocks.append(m.clock.sec * 10**9 + m.clock.nanosec)
                continue
            assert list(m.joint_names) == ['piston'] and len(m.points) == 21
            t0 = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            for p in m.points:
                cover[t0 + p.time_from_start.sec * 10**9 + p.time_from_start.nanosec] = (
                    p.positions[0], p.velocities[0])
    assert set(t) <= set(cover)
    zr, vr = Sine(0.04, 1.0)((t - t[0]) * 1e-9)
    np.testing.assert_allclose([cover[k] for k in t], np.c_[zr, vr], rtol=0, atol=1e-12)
    grid = set(range(t[0], t[-1] + 1, 10_000_000))
    assert grid <= set(clocks) and len(set(clocks) - grid) <= f['resends']
    np.testing.assert_allclose(z, ref.z, rtol=0, atol=1e-9)
    # state k reports the current applied over the period that ended at it
    np.testing.assert_allclose(i[1:], ref.i[:-1], rtol=0, atol=1e-9)
    assert np.ptp(z) > 0.07          # the loop really tracked the 0.04 m sine
    assert f['steps'] == n and f['model_faults'] == 0


def _assert_placed(procs):
    """
    Check the default placement of ``NodeProcesses.start_loop``, in lock-step and in real time.

    Plant and controller on one CPU, the reference on another, as each node's log says once
    the kernel has moved its threads (nothing to place on a machine with one CPU).
    """
    assert procs.placement == loop_placement()
    if procs.placement is not None:
        loop_cpu, ref_cpu = procs.placement
        for name, cpu in (('plant', loop_cpu), ('controller', loop_cpu),
                          ('reference', ref_cpu)):
            assert f'threads on CPU {cpu}' in procs[name].output(), name


# -- recording ----------------------------------------------------------------------------------
def _realtime_bench(procs, bag, reference=True):
    procs.start_loop('realtime', bag=bag, reference=reference)


def test_recorded_bench_bag_is_read_by_external_readers(dom, tmp_path):
    bag = tmp_path / 'bench'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        # this test is about the bag's readers: a state answered late on the suite's loaded
        # machine (no real-time priority) is noted, not held (loop_timing held the axis once,
        # 20.8 ms, and the pressures read back were those of a still piston)
        procs.start_loop('realtime', bag=bag, controller={'loop_timing_action': 'indicate'})
        _assert_placed(procs)
        wait_for_bag(bag, {'/state': 1000, '/servo_current': 900})
        assert procs.stop(['recorder'])['recorder'] == 0
    ours = open_bag(bag)
    assert not ours.truncated
    # the reference started on the closed loop, with the recorder listening: its first
    # recorded sample is the sine's time zero
    first = c.reference_from_msg(next(ours.decoded(['/reference']))[1])
    assert first.z_ref == 0.0 and first.v_ref == pytest.approx(2 * math.pi * 0.04)
    # and the states from before time zero on: the plant reports its loop running only once
    # the recorder listens to it too (a bag once began 1.5 s into the trajectory)
    first_state = c.state_from_msg(next(ours.decoded(['/state']))[1])
    assert first_state.stamp_ns < first.stamp_ns, (first_state.stamp_ns, first.stamp_ns)
    # the loop closed before the sine began, and the bag holds it: the reference's time zero
    # waits for the plant's diagnostics to report a first command, and start_loop starts the
    # plant only once the recorder has matched the controller's commands (a bag once began with
    # 2 s of commands, another with its commands 2 s late). How soon after the plant's first
    # state the controller answers is the middleware's discovery (0.3 s once on a loaded
    # machine): the plant steps at 0 A until then, and the bag shows it
    first_command = c.command_from_msg(next(ours.decoded(['/servo_current']))[1])
    assert first_state.stamp_ns <= first_command.stamp_ns < first.stamp_ns
    counts = {k: v.count for k, v in ours.topics.items()}
    assert counts['/state'] > 1000 and counts['/servo_current'] > 900
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as r:
        conns = {x.topic: x for x in r.connections}
        assert conns['/state'].msgtype == 'sensor_msgs/msg/JointState'
        assert conns['/diagnostics'].msgtype == 'diagnostic_msgs/msg/DiagnosticArray'
        qos = conns['/state'].ext.offered_qos_profiles[0]
        assert qos.depth == 1 and qos.reliability.name.lower() == 'best_effort'
        # the recorder's own status is in the bag: what it records and has matched
        rec = [s for _, _, raw in r.messages(connections=[conns['/diagnostics']])
               for s in c.statuses_from_msg(ts.deserialize_cdr(raw, conns['/diagnostics'].msgtype))
               if s.name == c.RECORDER_STATUS]
        assert rec and rec[-1].level == 0 and rec[-1].values['bag'] == str(bag)
        assert {'/state', '/servo_current', '/reference'} <= rec[-1].listed('matched') <= \
            rec[-1].listed('recording')
        n_state = 0
        for conn, t, raw in r.messages(connections=[conns['/state']]):
            m = ts.deserialize_cdr(raw, conn.msgtype)
            assert list(m.name) == ['piston', 'spool', 'servo_valve']
            assert abs(t - (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)) < 10**9
            n_state += 1
        assert n_state == counts['/state'] == r.message_count - sum(
            v for k, v in counts.items() if k != '/state')
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DeprecationWarning)
        from mcap_ros2.reader import read_ros2_messages
        ms = list(read_ros2_messages(str(next(bag.glob('*.mcap'))),
                                     topics=['/pressure/chamber_p']))
    assert len(ms) == counts['/pressure/chamber_p']
    # mcap_ros2 decodes exactly what our reader does, and the values are live pressures
    theirs = [m.ros_msg.fluid_pressure for m in ms]
    assert theirs == [m.fluid_pressure for _, m in ours.decoded(['/pressure/chamber_p'])]
    assert np.all(np.isfinite(theirs)) and np.ptp(theirs) > 1e5
    # in real time the pressures go out after the state's command, apart from the state:
    # still stamped as the state they belong to (its force is A_p times their difference)
    force = {s.stamp_ns: s.force for s in (c.state_from_msg(m) for _, m in
                                           ours.decoded(['/state']))}
    pa, pt = ({c.stamp_ns(m.header): m.fluid_pressure for _, m in ours.decoded([t])}
              for t in ('/pressure/chamber_p', '/pressure/chamber_t'))
    both = sorted(force.keys() & pa.keys() & pt.keys())
    assert len(both) > 0.9 * len(force), (len(both), len(force))
    A_p = Params()['A_p']
    assert all(abs(A_p * (pa[k] - pt[k]) - force[k]) <= 1e-9 * abs(A_p * pa[k]) + 1e-6
               for k in both)


def test_a_sigkilled_recorder_keeps_everything_it_had_flushed(dom, tmp_path):
    """
    A recorder killed mid-run: its bag reads, marked truncated, with all it held on disk.

    (How much a kill loses, the last flush period at most, is a real-time figure: the
    ``record`` benchmark measures it, ``sigkill_lost_ms``.)
    """
    bag = tmp_path / 'killed'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        _realtime_bench(procs, bag)
        wait_for_bag(bag, {'/state': 1500})
        held = bag_counts(bag)              # on disk, as another reader sees it now
        procs.kill('recorder')
    b = open_bag(bag)
    assert b.truncated, b.problem
    assert all(b.topics[k].count >= n for k, n in held.items()), (held, b.describe())


# -- safety -------------------------------------------------------------------------------------
def test_killing_the_controller_trips_the_watchdog_within_its_periods(dom, tmp_path):
    bag = tmp_path / 'wd'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        # the controller holds position; the plant says its watchdog's state every 50 ms
        procs.start_loop('realtime', bag=bag, reference=False,
                         plant={'diagnostics_period': 0.05})
        wait_for_bag(bag, {'/state': 1500})
        procs.kill('controller')
        assert procs.wait_status(c.PLANT_STATUS, lambda st: st.values['watchdog'] == 'tripped',
                                 BOUND)
        wait_for_bag(bag, {'/state': bag_counts(bag)['/state'] + 1100})   # a second on
        procs.stop(['recorder', 'plant'])
        f = procs['plant'].figures()
    assert f['watchdog'] == 'tripped'
    # the zeroing tick came at most watchdog_periods (1 ms each) after the last fresh command
    # arrived, plus that tick's own lateness (a busy 2-core machine delays a thread by ms at
    # times)
    assert f['watchdog_latency_ms'] - max(0.0, f['watchdog_tick_late_ms']) <= WD_MS + 1e-3, f
    # and it is counted as the controller's, not as a late plant tick's: even when the tick
    # after the kill comes late (a killed process makes the machine busy: 5 ms here once),
    # the next on-time tick finds the command too old as well
    assert f['watchdog_trips'] - f['watchdog_trips_late_tick'] >= 1, f
    assert f['watchdog_trip_log'][-1][3] is False, f      # the last trip: the kill's
    # in the bag: the applied current is zero from the trip to the end (>= 1 s), the state
    # stays finite, and the valve was zeroed soon after the stamp of the command it applied
    # last (found by its value: the best-effort recorder may miss the last few commands
    # on a loaded machine; the loop has ms of jitter: the exact figure is above)
    t, z, i = _states(bag)
    assert np.all(np.isfinite(z))
    k = np.flatnonzero(i != 0.0)[-1]
    last_nonzero = t[k]
    bagr = open_bag(bag)
    cmds = [c.command_from_msg(m) for _, m in bagr.decoded(['/servo_current'])]
    # (once, in a full run: a nonzero current 1 ms before the bag's end, 2.8 s after the
    # kill; the message says which commands the bag holds from the last second)
    assert (t[-1] - last_nonzero) / 1e9 >= 1.0, (
        (t[-1] - last_nonzero) / 1e9, i[-5:].tolist(), f,
        [(x.stamp_ns - t[0], x.i) for x in cmds if x.stamp_ns > t[-1] - 1_000_000_000])
    # the current the valve had last is one the controller sent for a state no later than the
    # one that carries it (the stamp policy refuses an answer from the future). How many periods
    # after that state's stamp the valve was zeroed is not bounded here: it adds the controller's
    # own lateness to the watchdog's periods (a command answering an old state is applied on
    # arrival, correctly) and what the best-effort recorder missed: 36 periods once in a loaded
    # full run, and the bag cannot tell the two apart.
    # The rule counts from the command's arrival, in the plant's figures above, and without a
    # clock in test_sim_axis.
    applied = [x.stamp_ns for x in cmds if x.i == i[k] and x.stamp_ns <= last_nonzero]
    assert applied, (i[k], [(x.stamp_ns - t[0], x.i) for x in cmds[-20:]])
    # the trip is in the bag too: the plant's recorded diagnostics end tripped, with the same
    # latency rule, stamped after the last state the valve had current in
    plant = [s for _, m in bagr.decoded(['/diagnostics']) for s in c.statuses_from_msg(m)
             if s.name == c.PLANT_STATUS]
    tripped = [s for s in plant if s.values['watchdog'] == 'tripped']
    assert plant[-1].values['watchdog'] == 'tripped', plant[-1]
    assert tripped[-1].stamp_ns > last_nonzero
    v = tripped[-1].values
    assert float(v['watchdog_latency_ms']) - max(0.0, float(v['watchdog_tick_late_ms'])) \
        <= WD_MS + 1e-3, v


@contextlib.contextmanager
def _plant_on_a_moved_clock(dom, monkeypatch, subscribers=None, **params):
    """
    Yield a real-time plant node whose clock the test moves, and ``at(ms)``, which sets it.

    ``state`` counts ``subscribers[0]`` subscribers (a list the test may change), and the
    plant starts when they are enough; without ``subscribers`` it has started at 0 ms.
    ``params``: the node's parameters.
    """
    import rclpy
    from rclpy.parameter import Parameter
    import ros_ehs.nodes.plant as plant_mod
    from types import SimpleNamespace
    clock = [10**12]       # ns
    monkeypatch.setattr(plant_mod, 'time', SimpleNamespace(
        monotonic_ns=lambda: clock[0], monotonic=lambda: clock[0] * 1e-9))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=dom)
    try:
        node = plant_mod.PlantNode(context=ctx, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        t0 = node.axis._wall0_ns

        def at(ms):
            clock[0] = t0 + int(round(ms * 1e6))

        started = subscribers is None
        subscribers = subscribers or [node.opt['wait_subscribers']]
        monkeypatch.setattr(node.pub_state, 'get_subscription_count', lambda: subscribers[0])
        if started:
            assert node.axis.start(t0, subscribers[0])
        yield node, at
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


def test_only_a_lockstep_plant_node_takes_paused(dom, monkeypatch):
    """``paused`` (the axis's rule, tested in test_sim_axis): refused in real time, by name."""
    from rclpy.parameter import Parameter
    with _plant_on_a_moved_clock(dom, monkeypatch) as (node, _):
        res = node.set_parameters([Parameter('paused', value=True)])[0]
        assert not res.successful and '`paused`: only a lock-step axis' in res.reason
        assert node.get_parameter('paused').value is False and not node.axis.paused
        assert node.set_parameters([Parameter('paused', value=False)])[0].successful
    with _plant_on_a_moved_clock(dom, monkeypatch, mode='lockstep') as (node, _):
        assert node.set_parameters([Parameter('paused', value=True)])[0].successful
        assert node.axis.paused and node.figures()['paused'] is True
        assert node.set_parameters([Parameter('paused', value=False)])[0].successful
        assert not node.axis.paused


def test_the_watchdog_tells_a_late_plant_tick_from_a_late_command(dom, monkeypatch):
    """
    The plant's real-time tick, on a clock the test moves (in-process, nothing spun).

    A tick that comes 1.8 ms late with the command on time trips (the rule holds whoever is
    late) and is counted as the plant's lateness alone; a controller that stops trips as a late
    command; a late tick followed by a stopped controller is re-counted as the controller's.
    (A stalled plant process cannot show this end to end: the command waiting in its queue is
    taken, fresh, before the late tick.) The watchdog at 3 periods, as the loop benchmarks set it.
    """
    with _plant_on_a_moved_clock(dom, monkeypatch, watchdog_periods=3) as (node, at):
        def answer(ms):          # the controller answers the latest state at t0 + ms
            at(ms)
            node._on_command(c.command_to_cdr(c.Command(node.axis.stamp_ns(), 0.01)))

        def tick(ms):
            at(ms)
            node._tick()
            return node.axis.trips, node.axis.trips_late_tick

        answer(0.2)
        assert tick(1.0) == (0, 0)
        answer(1.2)
        assert tick(3.8) == (1, 1)          # due at 2 ms, 1.8 ms late: the plant's lateness
        answer(4.1)
        assert tick(4.2) == (1, 1) and node.axis.applied == pytest.approx(0.01)   # back
        assert tick(5.0) == (1, 1) and tick(6.0) == (1, 1)
        assert tick(7.0) == (2, 1)          # no command since 4.1: the controller's
        answer(7.2)
        assert tick(8.0) == (2, 1)
        answer(8.2)
        assert tick(10.8) == (3, 2)         # late tick, command on time ...
        assert tick(11.0) == (3, 1)         # ... but none on time either: the controller's
        log = [t.as_list() for t in node.axis.trip_log]
        assert [alone for *_, alone in log] == [True, False, False]
        assert log[0][1] == pytest.approx(1.8) and log[0][2] == pytest.approx(2.6)


def test_a_real_time_plant_starts_when_its_state_has_wait_subscribers(dom, monkeypatch):
    """No state, step or watchdog before; then time restarts at the tick that saw them."""
    subscribers = [1]
    with _plant_on_a_moved_clock(dom, monkeypatch, subscribers,
                                 wait_subscribers=2) as (node, at):
        states = []
        publish = node.pub_state.publish
        monkeypatch.setattr(node.pub_state, 'publish', lambda data: (
            states.append(c.state_from_cdr(data).stamp_ns), publish(data)))
        for ms in (1.0, 2.0, 3.0, 10.0):
            at(ms)
            node._tick()
        assert states == [] and node.axis.k == 0 and not node.axis.armed and node.axis.trips == 0
        # a command before any state (another run's controller) answers none: no arming
        node._on_command(c.command_to_cdr(c.Command(node.axis.stamp_ns(), 0.01)))
        assert not node.axis.armed and node.axis.counts['stale'] == 1
        subscribers[0] = 2      # the recorder's reader has matched: start here
        at(10.4)                # a tick woken 0.4 ms into its period
        node._tick()
        t_start = node.axis.t0_ns
        assert states == [] and node.axis.k == 0
        at(11.1)                # the next, woken earlier in its period: still one step
        node._tick()
        assert states == [t_start + 1_000_000] and node.axis.k == 1     # a period after the start
        node._on_command(c.command_to_cdr(c.Command(states[-1], 0.01)))
        assert node.axis.armed
        at(12.05)
        node._tick()
        assert states == [t_start + 1_000_000, t_start + 2_000_000]
        assert node.axis.trips == 0 and node.axis.applied == pytest.approx(0.01)


def test_the_pressures_of_every_state_go_out_after_its_command_or_the_next_tick(
        dom, monkeypatch):
    """In real time, on a clock the test moves: late ticks catch up without losing any."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import FluidPressure
    from types import SimpleNamespace
    with _plant_on_a_moved_clock(dom, monkeypatch) as (node, at):
        sent = []              # (what, stamp) in the order they went out
        for what, name in (('state', 'pub_state'), ('p', 'pub_p'), ('t', 'pub_t')):
            setattr(node, name, SimpleNamespace(publish=lambda data, what=what: sent.append(
                (what, (c.state_from_cdr(data).stamp_ns if what == 'state' else
                        c.stamp_ns(deserialize_message(data, FluidPressure).header)))),
                get_subscription_count=lambda: 1))

        def tick(ms):
            at(ms)
            node._tick()

        tick(1.0)
        node._on_command(c.command_to_cdr(c.Command(node.axis.stamp_ns(), 0.01)))
        tick(2.0)
        tick(6.0)                       # 3 periods late: four states at once
        node._on_command(c.command_to_cdr(c.Command(node.axis.stamp_ns(), 0.01)))
        tick(7.0)
        states = [s for w, s in sent if w == 'state']
        assert len(states) == 7 and len(set(states)) == 7
        for w in ('p', 't'):            # one of each per state, stamped as it, none lost
            assert [s for x, s in sent if x == w] == states[:-1]     # the last: not yet
        # each state's pressures after that state (the loop's message first), in order
        assert all(sent.index(('p', s)) > sent.index(('state', s)) for s in states[:-1])


def test_bad_messages_crash_nothing(dom, tmp_path, ros):
    from sensor_msgs.msg import JointState
    from ros_ehs.nodes.ros_common import qos_profile
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start('plant')
        procs.start('controller')
        assert procs.wait_status(c.PLANT_STATUS, loop_closed), procs['plant'].output()
        states = []
        ros.create_subscription(JointState, 'state', states.append,
                                qos_profile(c.STATE.qos, depth=100))
        pub_cmd = ros.create_publisher(JointState, 'servo_current', qos_profile(c.LOOP_QOS))
        pub_state = ros.create_publisher(JointState, 'state', qos_profile(c.LOOP_QOS))
        now = time.time_ns() + 10**9

        def jmsg(names, eff=(), pos=(), vel=(), stamp=now):
            m = JointState(name=list(names), effort=list(eff), position=list(pos),
                           velocity=list(vel))
            m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp, 10**9)
            return m

        bad_cmds = [jmsg(['servo_valve'], [math.nan]), jmsg(['servo_valve'], [math.inf]),
                    jmsg(['servo_valve'], [-math.inf]), jmsg([]), jmsg(['servo_valve']),
                    jmsg(['wrong_name'], [0.01]), jmsg(['servo_valve'], [1e308])]
        bad_states = [jmsg(['piston'], [0.0], [math.nan], [0.0]), jmsg([]),
                      jmsg(['piston'], [], [0.1], []), jmsg(['x'], [1.0], [1.0], [1.0]),
                      jmsg(['piston'], [0.0], [math.inf], [math.nan])]
        # the plant hears our commands; the controller and we ourselves hear our states
        assert ros.spin(until=lambda: pub_cmd.get_subscription_count() >= 1
                        and pub_state.get_subscription_count() >= 2 and len(states) > 10,
                        timeout=30)
        for _ in range(20):
            for m in bad_cmds:
                pub_cmd.publish(m)
            for m in bad_states:      # one at a time: a depth-1 reader keeps only the last
                pub_state.publish(m)  # of a burst: paced, a stall made on purpose
                ros.spin(0.003)
            ros.spin(0.02)
        # the nodes counted them, and go on answering
        wait_value(procs, c.PLANT_STATUS, 'bad_commands', 1)
        wait_value(procs, c.CONTROLLER_STATUS, 'bad', 1)
        # and the plant goes on stating: a count of its own states (ours are in `states` too),
        # not of a time's worth (how many reach a busy test process in a second is the machine's)

        def plants():
            return sum('spool' in m.name for m in states)
        n = plants()
        assert ros.spin(until=lambda: plants() >= n + 200, timeout=BOUND), (n, plants())
        assert procs['plant'].alive() and procs['controller'].alive()
        procs.stop(['controller', 'plant'])
    f = procs['plant'].figures()
    assert f['bad_commands'] > 0
    ours = [c.state_from_msg(m) for m in states if 'spool' in m.name]
    assert all(math.isfinite(s.z) and math.isfinite(s.z_dot) and math.isfinite(s.force)
               for s in ours)
    assert all(abs(s.i) <= 2 * Params()['i_rated'] for s in ours)   # 1e308 was clamped
    log = procs['controller'].output()
    assert 'Traceback' not in log and 'Traceback' not in procs['plant'].output()
    assert 'ignored a malformed state' in log


# -- parameters ---------------------------------------------------------------------------------
def test_controller_parameters_from_file_and_live_with_reasons(dom, tmp_path, ros):
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    pf = tmp_path / 'ctrl.yaml'
    pf.write_text('controller:\n  ros__parameters:\n    kp: 2\n    F_cc: 500.0\n')
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        bare = node_command('controller')[:-1]          # without --ros-args: the bare form
        procs.start('controller', cmd=bare + ['--params-file', str(pf)])
        cli = AsyncParameterClient(ros, 'controller')
        assert ros.spin(until=lambda: cli.services_are_ready(), timeout=BOUND), \
            procs['controller'].output()

        def call(fut):
            ros.spin(until=fut.done, timeout=BOUND)
            return fut.result()

        got = call(cli.get_parameters(['kp', 'F_cc', 'ki']))
        if got is None:
            # the first call of a fresh clone's run got no reply in 10 s; most likely it was
            # answered before the client's reply reader had matched the server's writer
            # (discovery is per endpoint) and the reply was lost. A get is safe to repeat
            got = call(cli.get_parameters(['kp', 'F_cc', 'ki']))
        assert [v.double_value for v in got.values] == [2.0, 500.0, 0.051]
        ok = call(cli.set_parameters([Parameter('kp', Parameter.Type.DOUBLE, 1.5)]))
        assert ok.results[0].successful
        neg = call(cli.set_parameters([Parameter('kp', Parameter.Type.DOUBLE, -1.0)]))
        assert not neg.results[0].successful
        cross = call(cli.set_parameters_atomically(
            [Parameter('F_cc', Parameter.Type.DOUBLE, 5000.0)]))
        assert not cross.result.successful and 'must not exceed' in cross.result.reason
        got = call(cli.get_parameters(['kp', 'F_cc']))
        assert [v.double_value for v in got.values] == [1.5, 500.0]
        procs.stop()
    assert 'parameter change rejected' in procs['controller'].output()


def test_bad_configuration_is_one_clear_line(dom, tmp_path):
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        p = procs.start('player', {'bag': str(tmp_path / 'nope')})
        assert p.popen.wait(60) == 2
        assert 'no bag at' in p.output() and 'Traceback' not in p.output()
        q = procs.start('plant', {'p_s': -5.0}, name='bad_plant')
        assert q.popen.wait(60) == 2
        assert 'p_s' in q.output() and 'Traceback' not in q.output()
        r = procs.start('recorder', {'out': str(tmp_path / 'bag'), 'min_free_space': 2 ** 62})
        assert r.popen.wait(60) == 2
        assert 'not recording to' in r.output() and 'below min_free_space' in r.output()
        assert 'Traceback' not in r.output() and not (tmp_path / 'bag').exists()
        r = procs.start('recorder', {'out': str(tmp_path / 'bag'), 'compression': 'gzip'},
                        name='bad_recorder')
        assert r.popen.wait(60) == 2
        assert "'gzip' is not one of" in r.output() and 'Traceback' not in r.output()


# -- contract -------------------------------------------------------------------------------
@pytest.mark.parametrize('lockstep', [False, True], ids=['realtime', 'lockstep'])
def test_nodes_create_exactly_the_contract_topics(dom, tmp_path, ros, lockstep):
    infra = {'/rosout', '/parameter_events'}
    topics = c.LOCKSTEP_NODE_TOPICS if lockstep else c.NODE_TOPICS
    proc = {'file': str(FIXTURES.parent / 'procedure_short.yaml'),
            'checkpoint': str(tmp_path / 'checkpoint.json')}
    import yaml
    from ros_ehs.benchmarks.campaign import BENCH_CAMPAIGN
    plan = tmp_path / 'campaign.yaml'
    plan.write_text(yaml.safe_dump(BENCH_CAMPAIGN))
    modes = {'plant': {'mode': 'lockstep'}, 'controller': {'lockstep': True},
             'reference': {'use_sim_time': True},
             'procedure': {'use_sim_time': True, **proc}} if lockstep else {
        'procedure': proc, 'campaign': {'campaign': str(plan), 'out': str(tmp_path / 'c')}}
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        for n in topics:
            procs.start(n, modes.get(n))

        def graph(name):
            try:
                pubs = ros.get_publisher_names_and_types_by_node(name, '/')
                subs = ros.get_subscriber_names_and_types_by_node(name, '/')
            except Exception:  # noqa: B902 - not discovered yet
                return None
            return ({(t, ty[0]) for t, ty in pubs if t not in infra},
                    {(t, ty[0]) for t, ty in subs if t not in infra})

        for name, want in topics.items():
            exp = ({('/' + t.name.lstrip('/'), t.msg_type) for t in want.publishes},
                   {('/' + t.name.lstrip('/'), t.msg_type) for t in want.subscribes})
            # each node's part of the graph, as discovery shows it (the processes start
            # meanwhile: the first look may find nothing yet)
            assert ros.spin(until=lambda: graph(name) == exp, timeout=BOUND), \
                (name, graph(name), exp)


# -- replay ---------------------------------------------------------------------------------
def test_player_replays_a_rosbag2_fixture_with_clock(dom, tmp_path, ros):
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import String
    got, clocks = [], []
    ros.create_subscription(String, '/topic', got.append, 100)
    from ros_ehs.nodes.ros_common import qos_profile
    ros.create_subscription(Clock, '/clock', clocks.append, qos_profile(c.CLOCK_QOS, 100))
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        p = procs.start('player', {'bag': str(FIXTURES / 'talker.mcap'), 'rate': 4.0,
                                   'topics': ['/topic'], 'wait_subscribers': 1})
        ros.spin(until=lambda: p.popen.poll() is not None, timeout=BOUND)
        ros.spin(until=lambda: len(got) >= 10, timeout=BOUND)      # the last on their way
        assert p.popen.returncode == 0, p.output()
    bag = open_bag(FIXTURES / 'talker.mcap')
    want = [m.data for _, m in bag.decoded(['/topic'])]
    assert [m.data for m in got] == want and len(want) == 10
    t = [m.clock.sec * 10**9 + m.clock.nanosec for m in clocks]
    assert t == sorted(t) and bag.start_ns <= t[0] and t[-1] <= bag.end_ns
    # looping: the bag starts over (and the player keeps running until stopped)
    got.clear()
    with NodeProcesses(dom, tmp_path / 'logs2', bound=BOUND) as procs:
        p = procs.start('player', {'bag': str(FIXTURES / 'talker.mcap'), 'rate': 20.0,
                                   'topics': ['/topic'], 'loop': True,
                                   'wait_subscribers': 1})
        assert ros.spin(until=lambda: len(got) >= 25, timeout=BOUND), len(got)
        assert p.alive()
        assert procs.stop(['player'])['player'] == 0
    assert [m.data for m in got[:20]] == want + want
    # a split rosbag2 bag plays as one bag, in file order
    meta = yaml.safe_load((FIXTURES / 'split_wbag' / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']
    with NodeProcesses(dom, tmp_path / 'logs3', bound=BOUND) as procs:
        p = procs.start('player', {'bag': str(FIXTURES / 'split_wbag'), 'clock': False,
                                   'start_delay': 0.0})
        assert p.popen.wait(60) == 0, p.output()
    done = [ln for ln in p.output().splitlines() if 'replay done' in ln][0]
    played = dict(x.split() for x in done.split('replay done: ')[1].split(', '))
    assert {k: int(v) for k, v in played.items()} == {
        t['topic_metadata']['name']: t['message_count'] for t in meta['topics_with_message_count']}
    # a window of a bag: only what lies in it
    with NodeProcesses(dom, tmp_path / 'logs4', bound=BOUND) as procs:
        p = procs.start('player', {'bag': str(ROOT / 'bags' / 'sample_sine_1hz'),
                                   'clock': False, 'start_delay': 0.0, 'rate': 20.0,
                                   'start': 2.0, 'end': 3.0, 'topics': ['/state']})
        assert p.popen.wait(60) == 0, p.output()
    assert 'replay done: /state 1001' in p.output()


# -- identification node ----------------------------------------------------------------------
def test_identify_node_pushes_the_fit_to_a_running_controller(dom, tmp_path, ros):
    from rclpy.parameter_client import AsyncParameterClient
    out = tmp_path / 'id'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start('controller')
        p = procs.start('identify', {'bags': [str(ROOT / 'bags' / 'sample_sine_1hz')],
                                     'out': str(out), 'figures': False, 'push': True,
                                     'push_timeout': 120.0})
        assert p.popen.wait(300) == 0, p.output()[-3000:]
        assert 'iteration' in p.output() and 'pushed to `controller`' in p.output()
        fit = json.loads((out / 'summary.json').read_text())['parameters']
        cli = AsyncParameterClient(ros, 'controller')
        assert ros.spin(until=lambda: cli.services_are_ready(), timeout=BOUND)
        fut = cli.get_parameters(['F_cc', 'F_sc', 'c_c'])
        ros.spin(until=fut.done, timeout=BOUND)
        vals = [v.double_value for v in fut.result().values]
        assert vals == pytest.approx([fit[n]['value'] for n in ('F_cc', 'F_sc', 'c_c')])
        assert vals[0] == pytest.approx(1046.9, rel=0.02)
        bad = procs.start('identify', {'bags': [str(FIXTURES / 'talker.mcap')],
                                       'out': str(tmp_path / 'x')}, name='bad')
        assert bad.popen.wait(120) == 2
        assert "has no topic 'state'" in bad.output() and '/topic' in bad.output()
        assert 'Traceback' not in bad.output()


def test_domain_isolation_env_is_respected(dom):
    """The children of NodeProcesses see the test's domain (so parallel tests never mix)."""
    procs = NodeProcesses(dom)
    assert procs.env['ROS_DOMAIN_ID'] == str(dom)
    assert procs.env['ROS_AUTOMATIC_DISCOVERY_RANGE'] in ('LOCALHOST', os.environ.get(
        'ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST'))


# -- launch scripts -----------------------------------------------------------------------------
def test_bench_launch_script_records_a_lockstep_run_and_stops_everything(dom, tmp_path):
    import sys
    out = tmp_path / 'bench'
    res = run_script([sys.executable, str(ROOT / 'launch_scripts' / 'bench.py'),
                      '--mode', 'lockstep', '--duration', '1.0', '--out', str(out),
                      '--domain-id', str(dom), '--no-noise', '--cpu-affinity',
                      '--rt-priority', '10'], cwd=tmp_path, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    assert 'bench: done' in res.stdout, res.stdout
    # the summary is what the bag holds (a lock-step resend is a message too: 1001 stamps)
    held = open_bag(out).topics['/state'].count
    assert f'/state {held},' in res.stdout and held >= 1001, res.stdout
    assert 'bench: Fast DDS profile' in res.stdout and 'fastdds_rt.xml' in res.stdout
    t, z, i = _states(out)
    assert len(t) == 1001 and np.all(np.diff(t) == 1_000_000)
    ref = run_closed_loop(Params(), Sine(0.04, 1.0), 1.0, model='simplified', dt=1e-3,
                          supervised=True)
    np.testing.assert_allclose(z, ref.z, rtol=0, atol=1e-9)
    logs = tmp_path / 'out' / 'logs' / 'bench'
    assert sorted(p.name for p in logs.iterdir()) == [
        'controller.log', 'plant.figures.json', 'plant.log', 'recorder.log', 'reference.log']
    f = json.loads((logs / 'plant.figures.json').read_text())
    assert f['steps'] == 1000 and f['finished'] and f['watchdog_trips'] == 0
    # --cpu-affinity: plant and controller share the loop's CPU, the reference has the other
    # (the first two, or as ROS_EHS_LOOP_CPUS names them; or each says why not, on a machine
    # with one CPU)
    loop_cpu, ref_cpu = loop_placement(True)
    for node, cpu in (('plant', loop_cpu), ('controller', loop_cpu), ('reference', ref_cpu)):
        text = (logs / f'{node}.log').read_text()
        assert f'threads on CPU {cpu}' in text or f'cpu_affinity {cpu} not applied' in text
        assert 'XMLPARSER' not in text          # the profile was read without a complaint
    for node in ('plant', 'controller'):         # --rt-priority: SCHED_FIFO, or why not
        text = (logs / f'{node}.log').read_text()
        assert 'threads on SCHED_FIFO priority 10' in text or 'rt_priority 10 not applied' in text
        # placed before raised: never moved while at SCHED_FIFO (docs/nodes.md)
        if 'threads on SCHED_FIFO' in text and 'threads on CPU' in text:
            assert text.index('threads on CPU') < text.index('threads on SCHED_FIFO'), text


@pytest.mark.parametrize('broken', [False, True])
def test_the_rt_fastdds_profile_is_read_and_carries_the_loop(dom, tmp_path, broken):
    # launch_scripts/fastdds_rt.xml: Fast DDS names a profile it cannot read (the broken copy
    # shows the check can fail); the good one carries the loop over both of its transports
    profile = ROOT / 'launch_scripts' / 'fastdds_rt.xml'
    if broken:
        bad = tmp_path / 'broken.xml'
        bad.write_text(profile.read_text().replace('</profiles>', '</profile>'))
        profile = bad
    env = {'FASTRTPS_DEFAULT_PROFILES_FILE': str(profile)}
    with NodeProcesses(dom, tmp_path / 'logs', env=env, bound=BOUND) as procs:
        procs.start_loop('lockstep', plant={'duration': 1.0})
        lockstep_complete(procs)
        procs.stop(['plant', 'controller'])
    out = procs['plant'].output() + procs['controller'].output()
    assert ('XMLPARSER' in out) == broken
    f = procs['plant'].figures()        # every period of the run, each answered once
    assert f['steps'] == 1000 and f['finished'] and f['model_faults'] == 0


def test_replay_launch_script_plays_a_bag_and_exits(dom, tmp_path):
    import sys
    env = dict(os.environ, ROS_DOMAIN_ID=str(dom))
    res = run_script([sys.executable, str(ROOT / 'launch_scripts' / 'replay.py'),
                      str(FIXTURES / 'talker.mcap'), '--rate', '10', '--topics', '/topic'],
                     env=env, timeout=120)
    assert res.returncode == 0, res.stderr
    assert 'replay done: /topic 10' in res.stderr + res.stdout


def test_a_reference_waiting_for_the_loop_starts_on_the_plants_ok_only(dom, tmp_path, ros):
    """
    ``wait_loop``: time zero waits for the plant's diagnostics at level OK.

    In the node (in process, nothing spun): another node's OK, the plant's WARN (waiting for
    its first command) and a plant's ERROR in an array of others do not close the loop; the
    plant's OK does. Over real DDS, from this test's own rclpy node, not from our plant: the
    first sample after the plant's OK is the trajectory's time zero.
    """
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rclpy.parameter import Parameter
    from ros_ehs.nodes.reference import ReferenceNode
    from ros_ehs.nodes.ros_common import qos_profile
    from sensor_msgs.msg import JointState

    def array(*statuses):
        return DiagnosticArray(status=[DiagnosticStatus(name=n, level=bytes([lv]))
                                       for n, lv in statuses])

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=dom)
    try:
        node = ReferenceNode(context=ctx, parameter_overrides=[
            Parameter('wait_loop', value=True)])
        for statuses in ([('ros_ehs/controller', 0)], [('ros_ehs/plant', 1)],
                         [('ros_ehs/plant', 2), ('ros_ehs/recorder', 0)]):
            node._on_diag(array(*statuses))
            assert not node.gen.closed, statuses          # not the plant's OK
            assert node.gen.tick(10**9, 5) is None
        node._on_diag(array(('ros_ehs/reference', 0), ('ros_ehs/plant', 0)))
        assert node.gen.closed and node.gen.tick(10**9, 0) is not None
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    got = []
    ros.create_subscription(JointState, 'reference', got.append,
                            qos_profile(c.REFERENCE.qos, depth=1000))
    pub = ros.create_publisher(DiagnosticArray, 'diagnostics', qos_profile(c.DIAGNOSTICS.qos))
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start('reference', {'wait_loop': True, 'wait_subscribers': 1,
                                  'rate_hz': 250.0})
        assert ros.spin(until=lambda: pub.get_subscription_count() >= 1, timeout=BOUND)
        pub.publish(array(('ros_ehs/controller', 0), ('ros_ehs/plant', 1)))
        # a plant says its status every second: so does this test, until the samples come
        for _ in range(120):
            pub.publish(array(('ros_ehs/reference', 0), ('ros_ehs/plant', 0)))
            if ros.spin(until=lambda: len(got) >= 10, timeout=1.0):
                break
        assert len(got) >= 10, procs['reference'].output()
        assert 'the plant reports its loop closed' in procs['reference'].output()
    first = c.reference_from_msg(got[0])
    assert first.z_ref == 0.0 and first.v_ref == pytest.approx(2 * math.pi * 0.04)


def test_the_bench_reports_a_child_that_exits_at_start_at_once(dom, tmp_path):
    """Too little disk: the recorder refuses, and the bench says so with its error, at once."""
    import sys
    r = run_script([sys.executable, str(ROOT / 'launch_scripts' / 'bench.py'),
                    '--duration', '5', '--out', str(tmp_path / 'bag'), '--no-machine-probe',
                    '--min-free-space', str(2 ** 62)],
                   timeout=120, env={**os.environ, 'ROS_DOMAIN_ID': str(dom)})
    # at once: the bench saw the child exit (not its start timeout run out)
    assert r.returncode == 1
    assert 'recorder exited with code 2 while the bench was starting' in r.stderr, r.stderr
    assert 'below min_free_space' in r.stderr


# -- amplitude/phase control in the reference node ------------------------------------------
@pytest.mark.parametrize('kind', ['sine', 'chirp'])
def test_apc_in_lockstep_over_dds_reproduces_the_in_process_loop(dom, tmp_path, kind):
    """
    The reference node's APC in lock-step is the in-process loop's, to 1e-9 m each period.

    The position and the commands it sent, and the corrections were really made; on a sine
    and on a sweep (kind chirp, whose cycles shorten as it goes). The sweep runs at a
    real-time factor of 3 (the plant holds each state until its time): the same result.

    It depends on the node answering each /clock only once it has measured the states the
    window's corrections come from (a correction starts ``preview`` after its cycle).
    """
    from ros_ehs.core.control.apc import AmplitudePhaseControl
    duration = 3.0
    if kind == 'sine':
        a, f = 0.008, 5.0
        options = {'amplitude': a, 'frequency': f}
        apc = AmplitudePhaseControl(a, f, latency=0.02, learn_from=1.0)
    else:
        a, f = 0.005, 3.0
        options = {'kind': 'chirp', 'amplitude': a, 'f0': f, 'f1': 8.0,
                   'chirp_duration': duration}
        apc = AmplitudePhaseControl(a, f, sweep_to=8.0, sweep_time=duration, latency=0.02,
                                    learn_from=1.0)
    paced = {'real_time_factor': 3.0} if kind == 'chirp' else {}
    ref, _ = _corrected_lockstep(dom, tmp_path, duration,
                                 {**options, 'amplitude_phase_control': True}, apc, paced)
    assert apc.cycles >= 8 and (kind == 'chirp' or apc.converged_at is not None)
    # the corrections made the command differ from the specified sine by more than 2 %
    assert np.abs(ref.z_ref - apc.desired(ref.t)).max() > 0.02 * a


def test_the_apc_reference_answers_a_clock_only_once_the_cycle_it_corrects_from_is_measured(
        dom):
    """
    A window that holds a correction waits for the state that ends the cycle it is from.

    In lock-step, /clock 0.21 s (a window to 0.23 s, where the correction learnt from the
    cycle that ends at 0.2 s starts at 0.22 s) comes before the state at 0.2 s: the node
    waits, and answers once that state has come, with the in-process APC's samples.
    """
    import rclpy
    from rclpy.parameter import Parameter
    from ros_ehs.core.control.apc import AmplitudePhaseControl
    from ros_ehs.nodes.reference import ReferenceNode
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=dom)
    t0 = 5 * 10**9
    try:
        node = ReferenceNode(context=ctx, parameter_overrides=[
            Parameter('use_sim_time', value=True), Parameter('frequency', value=5.0),
            Parameter('amplitude', value=0.008), Parameter('amplitude_phase_control', value=True),
            Parameter('ramp_time', value=0.0)])
        sent = []
        node.pub_traj.publish = lambda data: sent.append(c.reference_trajectory_from_cdr(data))
        node.pub.publish = lambda data: None
        twin = AmplitudePhaseControl(0.008, 5.0, latency=0.02)

        def state(k):     # a loop that halves the command
            z = 0.5 * twin.reference(k * 1e-3)[0]
            twin.measure(k * 1e-3, z)
            node._on_state(c.state_to_cdr(c.AxisState(t0 + k * 10**6, z, 0.0)))

        node._on_clock(c.clock_to_cdr(t0))
        for k in range(200):              # the first cycle, 0-0.199 s
            state(k)
        node._on_clock(c.clock_to_cdr(t0 + 210 * 10**6))
        assert len(sent) == 1             # the window from 0.21 s waits for state 0.2 s
        state(200)
        assert len(sent) == 2
        got = {r.stamp_ns: r.z_ref for r in sent[1]}
        assert min(got) == t0 + 210 * 10**6 and max(got) == t0 + 230 * 10**6
        for k in range(210, 231):
            assert got[t0 + k * 10**6] == pytest.approx(twin.reference(k * 1e-3)[0], abs=1e-12)
        # the correction is in from 0.22 s: the command there is no longer the sine's
        assert abs(got[t0 + 230 * 10**6] - twin.desired(0.23)) > 1e-4
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


def test_a_sweeping_apc_reference_waits_for_the_end_of_the_sweeps_own_cycle(dom):
    """
    A sweep's cycles are turns of its phase, not multiples of its first period.

    Chirp 2 -> 10 Hz in 2 s: the first cycle ends at 0.366 s (not 0.5 s). /clock 0.369 s (a
    window to 0.389 s, where the correction from that cycle starts at 0.386 s) waits for the
    state that ends it, and is then answered with the in-process APC's samples.
    """
    import rclpy
    from rclpy.parameter import Parameter
    from ros_ehs.core.control.apc import AmplitudePhaseControl
    from ros_ehs.nodes.reference import ReferenceNode
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=dom)
    t0, ms = 5 * 10**9, 10**6
    try:
        node = ReferenceNode(context=ctx, parameter_overrides=[
            Parameter('use_sim_time', value=True), Parameter('kind', value='chirp'),
            Parameter('f0', value=2.0), Parameter('f1', value=10.0),
            Parameter('chirp_duration', value=2.0), Parameter('amplitude', value=0.005),
            Parameter('amplitude_phase_control', value=True), Parameter('ramp_time', value=0.0)])
        sent = []
        node.pub_traj.publish = lambda data: sent.append(c.reference_trajectory_from_cdr(data))
        node.pub.publish = lambda data: None
        twin = AmplitudePhaseControl(0.005, 2.0, sweep_to=10.0, sweep_time=2.0, latency=0.02)
        end = twin.cycle_start(1)
        assert end == pytest.approx((math.sqrt(12.0) - 2.0) / 4.0)
        last = math.ceil(end * 1e3)             # the first state of the second cycle, 367

        def state(k):     # a loop that halves the command
            z = 0.5 * twin.reference(k * 1e-3)[0]
            twin.measure(k * 1e-3, z)
            node._on_state(c.state_to_cdr(c.AxisState(t0 + k * ms, z, 0.0)))

        node._on_clock(c.clock_to_cdr(t0))
        for k in range(last):
            state(k)
        node._on_clock(c.clock_to_cdr(t0 + (last + 2) * ms))
        assert len(sent) == 1             # waits for the state that ends the first cycle
        state(last)
        assert len(sent) == 2 and twin.cycles == 1
        got = {r.stamp_ns: r.z_ref for r in sent[1]}
        for k in range(last + 2, last + 23):
            assert got[t0 + k * ms] == pytest.approx(twin.reference(k * 1e-3)[0], abs=1e-12)
        # the correction is in from 0.386 s: the command is no longer the sweep's
        assert abs(got[t0 + (last + 22) * ms] - twin.desired((last + 22) * 1e-3)) > 1e-5
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


def test_pvc_block_loading_in_lockstep_over_dds_reproduces_the_in_process_loop(dom, tmp_path):
    """
    The reference node's PVC through a block-loading sequence, in lock-step over DDS.

    The position and each command sent equal the in-process loop's to 1e-9 m at every
    period, and the blocks' commands were corrected.
    """
    from ros_ehs.core.control.pvc import PeakValleyControl, parse_blocks
    duration, f, blocks = 4.0, 5.0, '0.005 -0.005 2; 0.008 0 2'
    pvc = PeakValleyControl(parse_blocks(blocks), f, 'triangle', latency=0.02, learn_from=1.0)
    _, out = _corrected_lockstep(dom, tmp_path, duration, {
        'kind': 'triangle', 'frequency': f, 'blocks': blocks, 'peak_valley_control': True}, pvc)
    assert 'triangle reference, on /clock, peak/valley control' in out, out
    assert len(pvc.history) >= 4
    assert abs(pvc.amp[1] / 0.004 - 1) > 0.01 or abs(pvc.amp[0] / 0.005 - 1) > 0.01


@pytest.mark.parametrize('params,match', [
    ({'peak_valley_control': True}, 'peak_valley_control corrects a triangle or haversine'),
    ({'kind': 'step', 'amplitude_phase_control': True},
     "corrects a sine or chirp: `kind` is 'step'"),
    ({'kind': 'triangle', 'peak_valley_control': True, 'amplitude_phase_control': True},
     'choose one'),
    ({'kind': 'triangle', 'peak_valley_control': True, 'blocks': '0.01 0'}, 'block 1'),
    ({'kind': 'haversine', 'peak_valley_control': True, 'frequency': 30.0},
     '`preview` = 0.02 s must be under half the period'),
    ({'kind': 'triangle', 'amplitude': 0.0}, '`amplitude` must not be 0'),
    # a sweep's preview is bounded by its shortest period, wherever it ends (here 1/60 s)
    ({'kind': 'chirp', 'f0': 60.0, 'f1': 1.0, 'amplitude': 0.001,
      'amplitude_phase_control': True}, r'`preview` = 0.02 s must be under the period \(0.0166'),
])
def test_a_reference_node_with_a_correction_it_cannot_make_names_why(dom, params, match):
    import rclpy
    from rclpy.parameter import Parameter
    from ros_ehs.core.errors import EhsError
    from ros_ehs.nodes.reference import ReferenceNode
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=dom)
    try:
        with pytest.raises(ValueError, match=match) as err:
            ReferenceNode(context=ctx, parameter_overrides=[
                Parameter(k, value=v) for k, v in params.items()])
        assert isinstance(err.value, EhsError)        # run() exits 2 with the message
    finally:
        rclpy.shutdown(context=ctx)
