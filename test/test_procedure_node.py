"""
The procedure node in a lock-step loop: a test run start to end, and one that survives a kill.

The rules are tested in ``test_procedure.py``; here the node's part: it takes the reference
node's place on the contract topics, answers ``~/start`` and ``~/resume``, records its cycles,
captures and events in the bag, checkpoints, and a SIGKILL of it loses no cycle and counts
none twice. Lock-step: the loop waits for the procedure, so the runs do not depend on the
machine's timing; every wait is on a status, a reply or the bag.
"""

import contextlib
import os
from pathlib import Path
import shutil
import signal
import time

import numpy as np
import pytest
from ros_ehs.data.checkpoint import read_checkpoint
from ros_ehs.data.fatigue import (read_captures, read_cycles, read_procedure_events,
                                  write_fatigue_report)
from ros_ehs.nodes.processes import NodeProcesses, recording
import ros_ehs_msgs_py as c
from waits import BOUND, call_service

pytestmark = pytest.mark.ros
FIXTURE = Path(__file__).parent / 'fixtures' / 'procedure_short.yaml'
FAST = {'diagnostics_period': 0.05}
#: a specimen that does not break, for the load cell
SPECIMEN = {'k_L': 1.0e6, 'specimen_life': 1.0e12}
CYCLES = 20


def _call(ros, name):
    from std_srvs.srv import Trigger
    return call_service(ros, Trigger, name, Trigger.Request())


def _loop(procs, bag, proc_opts, seconds=8.0):
    """Start the recorder, the controller, the procedure (sim time), then the lock-step plant."""
    procs.start('recorder', {'out': str(bag), 'use_sim_time': True})
    assert procs.wait_status(c.RECORDER_STATUS, lambda st: True, BOUND)
    # the hydraulics ramp on in 50 ms, before the test starts (nothing learnt from a ramp-on)
    procs.start('controller', {'lockstep': True, 'ramp_time': 0.05, 'k_L': SPECIMEN['k_L'],
                               **FAST})
    procs.start('procedure', {'use_sim_time': True, 'ramp_time': 0.05, **FAST, **proc_opts})
    assert procs.wait_status(c.RECORDER_STATUS, recording(
        c.COMMAND, c.REFERENCE, c.CYCLES, c.PROCEDURE_EVENTS), BOUND)
    procs.start('plant', {'mode': 'lockstep', 'duration': seconds, 'wait_subscribers': 3,
                          **SPECIMEN, **FAST})


def _checkpointed(path, n):
    """Wait until the checkpoint at ``path`` holds ``n`` cycles or more."""
    end = time.monotonic() + BOUND
    while time.monotonic() < end:
        cp = read_checkpoint(path)
        if cp is not None and cp['total'] >= n:
            return
        time.sleep(0.05)
    raise AssertionError(f'after {BOUND:g} s the checkpoint holds {read_checkpoint(path)}')


def _status(procs, pred, name='procedure'):
    st = procs.wait_status(c.PROCEDURE_STATUS, lambda st: pred(st.values), BOUND)
    assert st is not None, \
        (procs.status(c.PROCEDURE_STATUS), procs.watch_report(), procs[name].output()[-3000:])
    return st.values


def test_a_procedure_runs_from_start_to_end_and_its_bag_holds_every_cycle(dom, tmp_path, ros):
    bag = tmp_path / 'bag'
    proc = tmp_path / 'test.yaml'
    shutil.copy(FIXTURE, proc)
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        _loop(procs, bag, {'file': str(proc)})
        _status(procs, lambda v: v['state'] == 'idle' and int(v['stamp_ns']) > 0 and
                v['controller_mode'])
        res = _call(ros, '/procedure/resume')
        assert not res.success and 'idle' in res.message        # nothing to resume
        res = _call(ros, '/procedure/start')
        assert res.success, res.message
        st = _status(procs, lambda v: v['state'] == 'finished')
        # the procedure publishes what it holds and waits for the recorder's acknowledgement
        # as it closes; the recorder closes the bag whole
        procs.stop(['procedure', 'plant', 'controller', 'recorder'])
    assert st['result'] == 'completed' and st['total_cycles'] == str(CYCLES), st
    table = read_cycles(bag)
    assert list(table[:, 0]) == list(range(1, CYCLES + 1))
    # a 1 mm sine about 2 mm, tracked by the controller: every cycle's extremes near it
    assert np.all(np.abs(table[2:, 5] - 0.003) < 2e-4) and np.all(
        np.abs(table[2:, 6] - 0.001) < 2e-4), table[:, 5:7]
    # the first 3 tapered in (flagged); peak/valley control learns from the 4th on and
    # corrects the command from the 5th: its peak is no longer the specified one
    assert list(table[:, 9]) == [1.0] * 3 + [0.0] * (CYCLES - 3)
    assert np.all(table[:3, 5] <= 0.003 + 1e-4) and np.all(table[4:, 3] > 0.003 + 1e-6)
    assert [cap['count'] for cap in read_captures(bag)] == [1, 2, 5, 10, 20]
    kinds = [e['kind'] for e in read_procedure_events(bag)]
    assert kinds[0] == 'running' and kinds[-1] == 'finished' and kinds.count('step') == 3
    cp = read_checkpoint(str(proc) + '.checkpoint.json')
    assert cp['state'] == 'finished' and cp['total'] == CYCLES
    # the report a test engineer reads on Monday
    rep = write_fatigue_report(bag, tmp_path / 'report')
    assert rep.cycles == CYCLES and rep.result == 'completed', rep
    rows = np.loadtxt(tmp_path / 'report' / 'cycles.csv', delimiter=',', skiprows=1)
    assert rows.shape == (CYCLES, 11)        # the table and the stiffness
    assert np.all(np.abs(rows[:, 10] / SPECIMEN['k_L'] - 1.0) < 0.02)   # and the stiffness
    written = {f.name for f in rep.files}
    assert {'peak_valley.png', 'stiffness.png', 'hysteresis.png'} <= written


def test_a_killed_procedure_resumes_at_its_count_and_no_cycle_counts_twice(
        dom, tmp_path, ros):
    import yaml
    bag = tmp_path / 'bag'
    proc = tmp_path / 'test.yaml'
    # the cyclic step outlasts the test, which ends it with ~/stop: however late this process
    # sees the count, the loop cannot have finished the test before the kill (with the
    # fixture's 20 cycles, a starved test process once killed a finished one)
    doc = yaml.safe_load(FIXTURE.read_text())
    doc['steps'][-1]['count'] = 10**6
    proc.write_text(yaml.safe_dump(doc))
    opts = {'file': str(proc), 'recover_bag': str(bag)}
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        _loop(procs, bag, {**opts, 'autostart': True}, seconds=1.0e5)
        # killed once 7 cycles are on disk (a kill between a count and its checkpoint, a
        # fraction of a millisecond, applies that cycle again: the benchmark measures it)
        _checkpointed(str(proc) + '.checkpoint.json', 7)
        procs['procedure'].popen.send_signal(signal.SIGKILL)
        procs['procedure'].popen.wait(BOUND)
        # lock-step: the loop waits for the reference, nothing moves meanwhile
        procs.start('procedure', {'use_sim_time': True, 'ramp_time': 0.05, **FAST, **opts},
                    name='procedure2')
        # restored, and the plant's resent state measured
        st = _status(procs, lambda v: v['state'] == 'interrupted' and int(v['stamp_ns']) > 0
                     and v['controller_mode'], 'procedure2')    # the mode read: resume
        before = int(st['total_cycles'])
        res = _call(ros, '/procedure/resume')
        assert res.success, res.message
        _status(procs, lambda v: int(v['total_cycles']) >= before + 3, 'procedure2')
        res = _call(ros, '/procedure/stop')
        assert res.success, res.message
        st = _status(procs, lambda v: v['state'] == 'finished', 'procedure2')
        procs.stop(['procedure2', 'plant', 'controller', 'recorder'])
    total = int(st['total_cycles'])
    assert st['result'] == 'stopped' and total >= before + 3, st
    from ros_ehs.data.bag import open_bag
    raw = [r[0] for _, m in open_bag(bag).decoded(['/procedure/cycles'])
           for r in c.cycles_from_bytes(bytes(m.data))]
    # every count once, in order: the restarted node went on from the last recorded cycle
    assert raw == list(range(1, total + 1)) and before >= 7, (raw, before)
    kinds = [e['kind'] for e in read_procedure_events(bag)]
    assert 'restored' in kinds and kinds[-1] == 'finished'


def test_a_step_in_force_switches_the_controller_and_loads_the_specimen(dom, tmp_path):
    """Displacement to a preload, then a force step: the node sets the controller's mode."""
    import yaml
    k = 5.0e6                                        # test_force_nodes' specimen and gains
    proc = tmp_path / 'force.yaml'
    proc.write_text(yaml.safe_dump({'name': 'force step', 'steps': [
        {'name': 'preload', 'type': 'ramp', 'to': 0.0004, 'rate': 0.004},
        {'name': 'load', 'type': 'ramp', 'to': 3000.0, 'rate': 2.0e3, 'control_mode': 'force'},
        {'name': 'hold', 'type': 'dwell', 'time': 1.0, 'control_mode': 'force'}],
        'stop_level': 2000.0}))
    bag = tmp_path / 'bag'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start('recorder', {'out': str(bag), 'use_sim_time': True})
        assert procs.wait_status(c.RECORDER_STATUS, lambda st: True, BOUND)
        procs.start('controller', {'lockstep': True, 'ramp_time': 0.05, 'k_L': k,
                                   'force_kp': 1.675e-7, 'force_ki': 5.0e-7, **FAST})
        procs.start('procedure', {'use_sim_time': True, 'file': str(proc), 'autostart': True,
                                  'ramp_time': 0.05, **FAST})
        assert procs.wait_status(c.RECORDER_STATUS, recording(
            c.COMMAND, c.REFERENCE, c.PROCEDURE_EVENTS), BOUND)
        procs.start('plant', {'mode': 'lockstep', 'duration': 6.0, 'wait_subscribers': 3,
                              'k_L': k, 'F_cc': 50.0, 'F_sc': 100.0, 'specimen_life': 1.0e12,
                              **FAST})
        st = _status(procs, lambda v: v['state'] == 'finished')
        assert procs.wait_status(c.CONTROLLER_STATUS,
                                 lambda st: st.values.get('driving') == 'force', BOUND)
        procs.stop(['procedure', 'plant', 'controller', 'recorder'])
    assert st['result'] == 'completed', st
    events = read_procedure_events(bag)
    assert any(e['kind'] == 'running' and 'control mode force' in e['message']
               for e in events), [e['message'] for e in events]
    from ros_ehs.data.bag import open_bag
    b = open_bag(bag)
    loads = [c.load_from_cdr(m.data).force for m in b.messages(['/load_cell'])]
    assert max(loads) == pytest.approx(3000.0, rel=0.03)      # loaded to the step's level


def _estimate(k_L, stderr, adequate=True):
    """Return a refit as an identify node sends it, built field by field (not our encoder)."""
    from foreign import estimate
    return estimate({'k_L': repr(k_L), 'k_L.stderr': repr(stderr), 'd_c': '0.0005',
                     'd_c.stderr': '1e-06', 'adequate': 'true' if adequate else 'false',
                     'pushed': 'false', 'reason': 'not pushed', 'window_s': '10.0',
                     'wall_s': '1.0', 'iterations': '12'}, adequate)


def test_a_live_fit_of_a_softer_specimen_fails_the_test(dom, tmp_path, ros):
    """
    ``fitted_stiffness_drop``: the node judges each refit on ``parameter_estimates``.

    The estimates come from this test's own publisher (the identify node's refits take
    minutes; its rules are tested in test_live_identify): the reference once the step has
    settled, then a specimen 30 % softer, beyond its standard errors: the test fails, held at
    its stop level, and the bag says why.
    """
    import yaml
    from diagnostic_msgs.msg import DiagnosticArray
    from ros_ehs.nodes.ros_common import qos_profile
    proc = tmp_path / 'fitted.yaml'
    proc.write_text(yaml.safe_dump({'name': 'fitted stiffness', 'steps': [
        {'name': 'to mean', 'type': 'ramp', 'to': 0.002, 'rate': 0.01},
        {'name': 'cycles', 'type': 'cyclic', 'waveform': 'sine', 'mean': 0.002,
         'amplitude': 0.001, 'frequency': 5.0, 'count': 1000,
         'end': [{'fitted_stiffness_drop': {'settling': 2, 'reference': 1, 'persist': 1}}]}]}))
    bag = tmp_path / 'bag'
    pub = ros.create_publisher(DiagnosticArray, '/' + c.ESTIMATES.name,
                               qos_profile(c.ESTIMATES.qos))
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        _loop(procs, bag, {'file': str(proc), 'autostart': True}, seconds=300.0)
        # settled: 2 cycles judged (the step's first 3 taper in, unjudged)
        _status(procs, lambda v: int(v['total_cycles']) >= 6)
        pub.publish(_estimate(1.0e6, 1.0e3, adequate=False))       # not adequate: not judged
        pub.publish(_estimate(1.0e6, 1.0e3))
        st = _status(procs, lambda v: int(v['fitted_stiffness_drop.reference_at']) >= 6)
        assert st['state'] == 'running', st
        pub.publish(_estimate(0.7e6, 1.0e3))
        st = _status(procs, lambda v: v['state'] == 'finished')
        procs.stop(['procedure', 'plant', 'controller', 'recorder'])
    assert st['result'] == 'failed' and 'fitted_stiffness_drop' in st['reason'], st
    assert 6 <= int(st['failed_at']) < 1000, st
    events = read_procedure_events(bag)
    failure = [e for e in events if e['kind'] == 'failure']
    assert len(failure) == 1 and 'k_L 700000' in failure[0]['message'], failure


@contextlib.contextmanager
def _in_process(tmp_path, dom):
    """Yield a factory of procedure nodes in this process (a context of their own), no spin."""
    import rclpy
    from rclpy.parameter import Parameter
    from ros_ehs.nodes.procedure import ProcedureNode
    proc = tmp_path / 'procedure.yaml'
    shutil.copy(FIXTURE, proc)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=dom)
    try:
        yield lambda: ProcedureNode(context=ctx, parameter_overrides=[
            Parameter('file', value=str(proc)),
            Parameter('checkpoint', value=str(tmp_path / 'cp.json'))])
    finally:
        rclpy.shutdown(context=ctx)


def test_close_waits_for_a_running_callback_and_no_callback_runs_after_it(tmp_path, dom):
    """A stuck executor: close() neither tears the checkpoint nor lets a callback run on."""
    import threading

    from std_srvs.srv import Trigger
    with _in_process(tmp_path, dom) as node:
        # a callback holds the runner (an executor stuck in it): close gives up after its wait
        stuck = node()
        held, release = threading.Event(), threading.Event()

        def callback():
            with stuck._lock:
                held.set()
                release.wait(BOUND)
        t = threading.Thread(target=callback)
        t.start()
        assert held.wait(BOUND)
        assert stuck.close(wait=0.05) is False
        release.set()
        t.join(BOUND)
        # nothing runs after close: a request is refused, a state is not measured
        response = stuck._on_request('start', Trigger.Request(), Trigger.Response())
        assert not response.success and 'closing' in response.message
        stuck._on_state(b'not even a message')         # returns before decoding
        assert stuck.runner.last_stamp < 0
        stuck.destroy_node()

        # no callback running: close writes the last checkpoint
        free = node()
        assert free.close() is True
        assert read_checkpoint(tmp_path / 'cp.json')['state'] == 'idle'
        free.destroy_node()


def test_a_procedure_the_rig_cannot_follow_is_refused_at_start_by_step(dom, tmp_path):
    """With the rig's parameters given, the node exits at once, naming the step and limit."""
    import sys
    import yaml
    from ros_ehs.core.params import Params, save_yaml
    from scripts import run_script
    proc = tmp_path / 'fast.yaml'
    proc.write_text(yaml.safe_dump({'name': 'too fast', 'steps': [
        {'name': 'shake', 'type': 'cyclic', 'waveform': 'sine', 'mean': 0.0,
         'amplitude': 0.005, 'frequency': 60.0, 'count': 10}]}))
    rig = tmp_path / 'rig.yaml'
    save_yaml(rig, Params())
    exe = Path(sys.executable).parent / 'procedure'
    r = run_script([str(exe), '--ros-args', '-p', f'file:={proc}', '-p', f'rig_params:={rig}'],
                   timeout=BOUND, env={**os.environ, 'ROS_DOMAIN_ID': str(dom)})
    assert r.returncode == 2, r.stdout + r.stderr
    assert "'too fast' step 1 (shake): the piston must move at 1.885 m/s" in r.stderr
    assert '60 Hz is above' in r.stderr


def test_without_rig_params_the_start_is_judged_by_the_controllers_values(dom, tmp_path, ros):
    """
    No rig file: the node reads the rig's values from the controller (nominal or identified).

    A test the controller's rig cannot follow is refused at ~/start, naming the step and the
    limit (the same rule with other values: test_procedure.py).
    """
    import yaml
    proc = tmp_path / 'fast.yaml'
    proc.write_text(yaml.safe_dump({'name': 'too fast', 'steps': [
        {'name': 'shake', 'type': 'cyclic', 'waveform': 'sine', 'mean': 0.0,
         'amplitude': 0.005, 'frequency': 60.0, 'count': 10, 'compensation': 'none'}]}))
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start('controller', {'lockstep': True, **FAST})
        procs.start('procedure', {'use_sim_time': True, 'file': str(proc), **FAST})
        end = time.monotonic() + BOUND
        r = _call(ros, '/procedure/start')
        while 'not known yet' in r.message and time.monotonic() < end:
            r = _call(ros, '/procedure/start')     # until the node has read the controller
        assert not r.success
        assert "'too fast' step 1 (shake): the piston must move at 1.885 m/s" in r.message
        assert '60 Hz is above' in r.message
        assert "the rig cannot follow: 'too fast' step 1" in procs['procedure'].output()
        procs.stop(['procedure', 'controller'])


def test_records_published_lately_stay_in_the_checkpoint_and_a_restart_publishes_them(
        tmp_path, dom):
    """A power cut just after a batch went out: the recorder may not have it on disk."""
    with _in_process(tmp_path, dom) as node:
        first = node()
        rows = [(n, 0, n * 10**8, 1.0, 0.0, 1e-3, 0.0, 0.0, 0.0, 0) for n in (1, 2, 3)]
        first._rows = list(rows)
        first._publish_rows()                       # out, but perhaps not yet on disk
        first._rows = [(4, 0, 4 * 10**8, 1.0, 0.0, 1e-3, 0.0, 0.0, 0.0, 0)]   # not yet out
        cp = first._checkpoint()
        assert [r[0] for r in cp['unconfirmed_cycles']] == [1, 2, 3, 4]
        assert first.close() is True                # writes the checkpoint: the cut comes now
        first.destroy_node()
        again = node()
        assert [r[0] for r in again._rows] == [1, 2, 3, 4]     # published again on resume
        again.destroy_node()


def _set_file(ros, **values):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    req = SetParameters.Request(parameters=[
        Parameter(name=k, value=ParameterValue(type=ParameterType.PARAMETER_STRING,
                                               string_value=str(v))) for k, v in values.items()])
    return call_service(ros, SetParameters, '/procedure/set_parameters', req).results[0]


def test_a_new_file_loads_the_next_test_only_when_idle_or_finished(dom, tmp_path, ros):
    """
    The next specimen's test without a new process: ``file`` set while finished (or idle).

    Refused while a test runs, and a file that is not a procedure is refused with its error,
    the loaded test untouched; the next one starts from ~/start with its own checkpoint.
    """
    bag = tmp_path / 'bag'
    first, second = tmp_path / 'first.yaml', tmp_path / 'second.yaml'
    shutil.copy(FIXTURE, first)
    second.write_text(FIXTURE.read_text().replace('short displacement test', 'the second')
                      .replace('count: 20', 'count: 6'))
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        _loop(procs, bag, {'file': str(first)}, seconds=20.0)
        _status(procs, lambda v: v['state'] == 'idle' and int(v['stamp_ns']) > 0 and
                v['controller_mode'])
        assert _call(ros, '/procedure/start').success
        _status(procs, lambda v: int(v['total_cycles']) >= 2)
        busy = _set_file(ros, file=second)
        assert not busy.successful and 'only when it is idle or finished' in busy.reason
        _status(procs, lambda v: v['state'] == 'finished')
        bad = _set_file(ros, file=tmp_path / 'nope.yaml')
        assert not bad.successful and 'nope.yaml' in bad.reason, bad.reason
        ok = _set_file(ros, file=second)
        assert ok.successful, ok.reason
        st = _status(procs, lambda v: v['file'] == str(second) and v['state'] == 'idle')
        assert st['checkpoint'] == str(second) + '.checkpoint.json'
        assert _call(ros, '/procedure/start').success
        st = _status(procs, lambda v: v['file'] == str(second) and v['state'] == 'finished')
        procs.stop(['procedure', 'plant', 'controller', 'recorder'])
    assert st['result'] == 'completed' and st['total_cycles'] == '6', st
    events = read_procedure_events(bag)
    assert [e['kind'] for e in events].count('finished') == 2
    assert read_checkpoint(str(first) + '.checkpoint.json')['total'] == CYCLES
    assert read_checkpoint(str(second) + '.checkpoint.json')['total'] == 6
