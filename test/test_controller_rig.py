"""
The controller node on a rig driver that follows ros2_control's conventions (not our plant).

The driver (``test/ros2_control_driver.py``) publishes ``/joint_states`` (the piston among
other joints, position only) and takes ``/servo_valve_controller/commands``
(Float64MultiArray, no header) at 500 Hz; the controller closes the loop on it, and the
tracking is compared with our own plant node's on the same model, in the same test, and each
with the same controller in process (the driver applies a command a period later). Delta-P
stabilisation reads the piston's effort: with a driver that exports none, the controller
refuses to drive; with one that does, it tracks as in process.
"""

import json
from pathlib import Path
import sys
import time

import numpy as np
import pytest
from ros_ehs.core.control.waveforms import Sine
from ros_ehs.core.params import Params
from ros_ehs.core.sim.closed_loop import run_closed_loop
from ros_ehs.data.bag import open_bag
from ros_ehs.data.experiments import load_experiments
from ros_ehs.data.mapping import TopicMap
from ros_ehs.nodes.processes import NodeProcesses, recording, reference_started
import ros_ehs_msgs_py as c

pytestmark = pytest.mark.ros
DRIVER = Path(__file__).resolve().with_name('ros2_control_driver.py')
RATE = 500.0
JOINT = 'actuator_z'
RIG = TopicMap(state='/joint_states', joint=JOINT, command='/servo_valve_controller/commands',
               pressure_p=None, pressure_t=None)


def _tracking(bag: Path, state: str, joint: str, skip: float = 2.0) -> tuple[float, int]:
    """
    RMS of z_ref - z [m] after ``skip`` s of the reference, and the states counted.

    A reference that went silent for more than the controller's reference_timeout (0.1 s) is
    held, then ramped back onto over ramp_time (1 s), by design: from the gap to a ramp_time
    after it is not tracking, and is left out (a reference node stalled 0.33 s in a full run).
    So is 0.2 s from a period our plant's watchdog zeroed the valve (the state's applied
    current exactly 0 A: a plant tick the machine made late, twice in one fresh-clone run).
    """
    b = open_bag(bag)
    ref = sorted(c.reference_from_cdr(m.data) for m in b.messages(['/reference']))
    tr = np.array([r.stamp_ns for r in ref])
    zr = np.array([r.z_ref for r in ref])
    vr = np.array([r.v_ref for r in ref])
    st = [c.state_from_cdr(m.data, joint) for m in b.messages([state])]
    ts = np.array([s.stamp_ns for s in st])
    z = np.array([s.z for s in st])
    k = np.clip(np.searchsorted(tr, ts, side='right') - 1, 0, tr.size - 1)
    z_ref = zr[k] + vr[k] * (ts - tr[k]) * 1e-9      # the controller's first-order hold
    m = (ts > tr[0] + skip * 1e9) & (ts < ts[-1] - 0.2e9)
    for g in np.flatnonzero(np.diff(tr) > 0.1e9):
        m &= ~((ts > tr[g]) & (ts < tr[g + 1] + 1.0e9))
    for k in np.flatnonzero(np.array([s.i for s in st]) == 0.0):
        m &= ~((ts >= ts[k]) & (ts < ts[k] + 0.2e9))
    return float(np.sqrt(np.mean((z_ref[m] - z[m]) ** 2))), int(m.sum())


def _start_controller_and_driver(procs, controller=None, driver=()):
    """Start the controller on the driver's topics (with ``controller`` options), then it."""
    procs.start('controller', {
        'rate_hz': RATE, 'state_topic': '/joint_states', 'joint': JOINT,
        'command_interface': 'forward_command',
        'command_topic': '/servo_valve_controller/commands', **(controller or {})})
    assert procs.wait_for_log('controller', 'PID')
    return procs.start('driver', cmd=[sys.executable, str(DRIVER), '--rate', str(RATE),
                                      '--joint', JOINT, *driver])


def test_the_controller_closes_the_loop_on_a_ros2_control_driver(dom, tmp_path):
    seconds = 5.0
    rig_bag, our_bag = tmp_path / 'rig', tmp_path / 'ours'
    with NodeProcesses(dom, tmp_path / 'logs') as procs:
        procs.start('recorder', {'out': str(rig_bag), 'topics': [
            '/joint_states', '/servo_valve_controller/commands', '/reference', '/events']})
        assert procs.wait_status(c.RECORDER_STATUS, lambda st: True)
        drv = _start_controller_and_driver(procs)
        assert procs.wait_status(c.RECORDER_STATUS, recording('/joint_states'), 30), \
            procs['recorder'].output()[-2000:]
        procs.start('reference', {'wait_subscribers': 2})
        assert procs.wait_status(c.REFERENCE_STATUS, reference_started, 30)
        time.sleep(seconds)
        codes = procs.stop(['recorder', 'reference', 'controller', 'driver'])
        figures = json.loads(drv.output().strip().splitlines()[-1])
        logs = {n: procs[n].output()[-1500:] for n in ('controller', 'reference')}
    assert codes == {'recorder': 0, 'reference': 0, 'controller': 0, 'driver': 0}
    rms_rig, n_rig = _tracking(rig_bag, '/joint_states', JOINT)
    b = open_bag(rig_bag)
    n_cmd = b.topics['/servo_valve_controller/commands'].count
    n_states = b.topics['/joint_states'].count
    assert n_states > 0.8 * seconds * RATE                # the loop ran at the driver's rate
    assert n_rig > 0.3 * (seconds - 2.4) * RATE           # and most of it is measured
    # the states were answered (on a loaded machine the recorder, which keeps the last 10 a
    # reliable writer holds, misses some: 67 % were in its bag in one run beside a benchmark)
    assert n_cmd > 0.5 * b.topics['/joint_states'].count
    # the controller's last word was 0 A: the forward controller holds it after we are gone
    assert figures['commands'] > 0.5 * figures['cycles'] and figures['last_command_a'] == 0.0
    with NodeProcesses(dom, tmp_path / 'logs2') as procs:      # our own plant, the same model
        procs.start_loop('realtime', bag=our_bag, plant={'rate_hz': RATE},
                         controller={'rate_hz': RATE})
        time.sleep(seconds)
        procs.stop(['recorder', 'reference', 'plant', 'controller'])
    rms_ours, _ = _tracking(our_bag, '/state', c.JOINT_PISTON)
    # the same controller in process on the same model: our plant applies a command on
    # arrival (command_delay 0); a ros2_control hardware interface writes it at its next cycle
    # (1 period, 2 ms at 500 Hz), so the rig tracks worse by what that period costs
    pred = {}
    for d in (0, 1, 2):             # 2: every answer a period later still (for the message)
        r = run_closed_loop(Params(), Sine(0.04, 1.0), seconds, model='simplified',
                            dt=1.0 / RATE, supervised=True, command_delay=d)
        pred[d] = float(np.sqrt(np.mean((r.z_ref - r.z)[r.t > 2.0] ** 2)))
    print(f'tracking RMS: ros2_control driver {rms_rig * 1e3:.4f} mm (in process, a period '
          f'late: {pred[1] * 1e3:.4f}, two: {pred[2] * 1e3:.4f}), our plant '
          f'{rms_ours * 1e3:.4f} mm (in process: {pred[0] * 1e3:.4f}); driver cycles without '
          'a new command '
          f"{figures['stale_cycles']} of {figures['cycles']}, periods the axis ran unread "
          f"{figures['unread_periods']}")
    # measured over DDS: 0.16-0.19 mm against 0.147 predicted, 0.10-0.11 mm against 0.101
    assert 0.7 < rms_rig / pred[1] < 1.5 and 0.7 < rms_ours / pred[0] < 1.5, (
        rms_rig, rms_ours, pred, figures, logs)
    # and the rig's bag, recorded by our recorder in the driver's layout, reads as a rig's
    runs = load_experiments(rig_bag, topics=RIG)
    assert runs and all(e.derived == ('z_dot',) and e.commands is not None for e in runs)
    assert all(abs(e.dt - 1.0 / RATE) < 0.05 / RATE for e in runs)


@pytest.mark.parametrize('effort', [False, True], ids=['position_only', 'with_effort'])
def test_delta_p_on_a_ros2_control_driver_needs_its_effort_interface(dom, tmp_path, effort):
    """
    ``dp_gain`` > 0 reads the hydraulic force from the state's effort.

    A driver that exports the piston's position only: the controller commands 0 A, says why
    in its diagnostics and its log, and the axis stays where it is. The same driver with the
    effort interface: the loop closes and tracks as the same controller does in process.
    """
    dp = {'dp_gain': 1.5e-7, 'dp_tau': 0.05}
    bag = tmp_path / 'rig'
    with NodeProcesses(dom, tmp_path / 'logs') as procs:
        procs.start('recorder', {'out': str(bag), 'topics': ['/joint_states', '/reference']})
        assert procs.wait_status(c.RECORDER_STATUS, lambda st: True)
        drv = _start_controller_and_driver(procs, dp, ['--effort'] if effort else [])
        assert procs.wait_status(c.CONTROLLER_STATUS,                  # the driver's states
                                 lambda st: int(st.values.get('answered', 0)) > 250, 30)
        procs.start('reference', {'wait_subscribers': 2})
        assert procs.wait_status(c.REFERENCE_STATUS, reference_started, 30)
        time.sleep(5.0)
        status = procs.status(c.CONTROLLER_STATUS)
        log = procs['controller'].output()
        procs.stop(['recorder', 'reference', 'controller', 'driver'])
        figures = json.loads(drv.output().strip().splitlines()[-1])
    assert figures['commands'] > 0.5 * figures['cycles'], (figures, status.values)
    if effort:
        r = run_closed_loop(Params(), Sine(0.04, 1.0), 5.0, model='simplified', dt=1.0 / RATE,
                            supervised=True, command_delay=1,
                            controller_params=Params().replace(**dp))
        pred = float(np.sqrt(np.mean((r.z_ref - r.z)[r.t > 2.0] ** 2)))
        rms, _ = _tracking(bag, '/joint_states', JOINT)   # stalled references left out
        print(f'tracking RMS with delta-P: ros2_control driver {rms * 1e3:.4f} mm (in process, '
              f'a period late: {pred * 1e3:.4f})')
        assert rms < 2.0 * pred, (rms, pred, figures, status, log[-2000:])
        assert 'hydraulic force' not in log + status.message
    else:
        assert figures['max_command_a'] == 0.0 and abs(figures['z']) < 1e-6, figures
        assert status.level == 2 and 'no hydraulic force' in status.message, status
        assert 'dp_gain > 0 needs the hydraulic force' in log
