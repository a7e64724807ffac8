"""
The controller node on a rig driver that follows ros2_control's conventions (not our plant).

The driver (``ros_ehs/benchmarks/ros2_control_driver.py``) publishes ``/joint_states`` (the
piston among other joints, position only) and takes ``/servo_valve_controller/commands``
(Float64MultiArray, no header) at 500 Hz, writing each at its next cycle; here it cycles in
lock-step, so the run is compared with the same controller in process (a command a period
late) to 1e-9 m. Delta-P stabilisation reads the piston's effort: with a driver that exports
none, the controller refuses to drive; with one that does, it tracks as in process.
"""

import json
import sys

import numpy as np
import pytest
from ros_ehs.core.control.waveforms import Sine
from ros_ehs.core.params import Params
from ros_ehs.core.sim.closed_loop import run_closed_loop
from ros_ehs.data.bag import open_bag
from ros_ehs.data.experiments import load_experiments
from ros_ehs.data.mapping import TopicMap
from ros_ehs.nodes.processes import NodeProcesses, recording
import ros_ehs_msgs_py as c
from waits import BOUND, wait_for_bag

pytestmark = pytest.mark.ros
#: a rig driver to ros2_control's conventions, as a process (not our plant)
DRIVER = ['-m', 'ros_ehs.benchmarks.ros2_control_driver']
RATE = 500.0
JOINT = 'actuator_z'
RIG = TopicMap(state='/joint_states', joint=JOINT, command='/servo_valve_controller/commands',
               pressure_p=None, pressure_t=None)


def _run_on_driver(procs, bag, seconds, controller=None, driver=(), topics=()):
    """
    Run the controller on the driver in lock-step for ``seconds``; return the driver's figures.

    The recorder (``topics``), then the controller on the driver's topics (forward_command,
    ``controller`` options), the reference under sim time, then the driver, which starts once
    the controller and the recorder listen; the run ends when the driver has cycled through
    ``seconds`` of its clock.
    """
    procs.start('recorder', {'out': str(bag), 'use_sim_time': True,
                             'topics': ['/joint_states', '/servo_valve_controller/commands',
                                        '/reference', '/events', *topics]})
    assert procs.wait_status(c.RECORDER_STATUS, lambda st: True, BOUND)
    procs.start('controller', {
        'rate_hz': RATE, 'state_topic': '/joint_states', 'joint': JOINT, 'lockstep': True,
        'command_interface': 'forward_command', 'diagnostics_period': 0.05,
        'command_topic': '/servo_valve_controller/commands', **(controller or {})})
    procs.start('reference', {'use_sim_time': True, 'rate_hz': RATE})
    assert procs.wait_status(c.RECORDER_STATUS, recording('/servo_valve_controller/commands',
                                                          '/reference'), BOUND)
    drv = procs.start('driver', cmd=[sys.executable, *DRIVER, '--rate', str(RATE),
                                     '--joint', JOINT, '--lockstep', '--seconds', str(seconds),
                                     '--wait-subscribers', '2', *driver])
    assert drv.popen.wait(BOUND) == 0, drv.output()[-3000:]
    n = int(round(seconds * RATE)) + 1
    wait_for_bag(bag, {'/joint_states': n, '/servo_valve_controller/commands': n - 1})
    return json.loads(drv.output().strip().splitlines()[-1])


def test_the_controller_closes_the_loop_on_a_ros2_control_driver(dom, tmp_path):
    """
    The controller closes the loop on a driver to ros2_control's conventions, in lock-step.

    JointState of several joints, position only; Float64MultiArray commands without a
    header, written at the next cycle.

    Every cycle answered, the run the in-process loop's with a command a period late to
    1e-9 m, the controller's last word 0 A, and the recording reads as a rig's bag. (How it
    tracks in real time, where the machine makes answers late, is a figure of the ``loop``
    benchmark.)
    """
    seconds = 4.0
    bag = tmp_path / 'rig'
    n = int(round(seconds * RATE))
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        figures = _run_on_driver(procs, bag, seconds)
        # the controller stops first: its last word goes into the bag too
        codes = procs.stop(['controller'])
        wait_for_bag(bag, {'/servo_valve_controller/commands': n + 2})
        codes.update(procs.stop(['recorder', 'reference']))
    assert codes == {'recorder': 0, 'reference': 0, 'controller': 0}
    assert figures['cycles'] == 0 and figures['commands'] >= n      # lock-step: no timer
    b = open_bag(bag)
    st = sorted((s.stamp_ns, s.z) for s in (c.state_from_cdr(m.data, JOINT)
                                            for m in b.messages(['/joint_states'])))
    assert len(st) == n + 1 and all(b_[0] - a_[0] == int(1e9 / RATE)
                                    for a_, b_ in zip(st, st[1:]))
    r = run_closed_loop(Params(), Sine(0.04, 1.0), seconds, model='simplified', dt=1.0 / RATE,
                        supervised=True, command_delay=1)
    np.testing.assert_allclose([z for _, z in st], r.z, rtol=0, atol=1e-9)
    # the answer to state k is what the plant applies over period k + 1, a period late
    cmds = [c.float64_array_from_cdr(m.data)[0] for m in
            b.messages(['/servo_valve_controller/commands'])]
    np.testing.assert_allclose(cmds[:n - 1], r.i[1:n], rtol=0, atol=1e-9)
    # the controller's last word was 0 A, once: a forward controller holds it after we are
    # gone (every state answered once, states 0 to n, then the stop's)
    assert len(cmds) == n + 2 and cmds[-1] == 0.0 and cmds[-2] != 0.0
    # and the rig's bag, recorded by our recorder in the driver's layout, reads as a rig's
    runs = load_experiments(bag, topics=RIG)
    assert runs and all(e.derived == ('z_dot',) and e.commands is not None for e in runs)
    assert all(abs(e.dt - 1.0 / RATE) < 0.05 / RATE for e in runs)


@pytest.mark.parametrize('effort', [False, True], ids=['position_only', 'with_effort'])
def test_delta_p_on_a_ros2_control_driver_needs_its_effort_interface(dom, tmp_path, effort):
    """
    ``dp_gain`` > 0 reads the hydraulic force from the state's effort.

    A driver that exports the piston's position only: the controller commands 0 A, says why
    in its diagnostics and its log, and the axis stays where it is. The same driver with the
    effort interface: the loop closes and is the same controller's in process (lock-step).
    """
    dp = {'dp_gain': 1.5e-7, 'dp_tau': 0.05}
    seconds = 3.0
    bag = tmp_path / 'rig'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        figures = _run_on_driver(procs, bag, seconds, dp, ['--effort'] if effort else [])
        assert procs.wait_status(c.CONTROLLER_STATUS, lambda st: int(st.values.get(
            'answered', 0)) >= seconds * RATE, BOUND)
        status = procs.status(c.CONTROLLER_STATUS)
        procs.stop(['recorder', 'reference', 'controller'])
        log = procs['controller'].output()
    assert figures['commands'] >= seconds * RATE, (figures, status.values)
    if effort:
        r = run_closed_loop(Params(), Sine(0.04, 1.0), seconds, model='simplified',
                            dt=1.0 / RATE, supervised=True, command_delay=1,
                            controller_params=Params().replace(**dp))
        b = open_bag(bag)
        z = [s.z for s in sorted((c.state_from_cdr(m.data, JOINT) for m in
                                  b.messages(['/joint_states'])), key=lambda s: s.stamp_ns)]
        np.testing.assert_allclose(z, r.z, rtol=0, atol=1e-9)
        assert np.ptp(z) > 0.07                      # it really tracked the sine
        assert 'hydraulic force' not in log + status.message
    else:
        assert figures['max_command_a'] == 0.0 and abs(figures['z']) < 1e-6, figures
        assert status.level == 2 and 'no hydraulic force' in status.message, status
        assert 'dp_gain > 0 needs the hydraulic force' in log
