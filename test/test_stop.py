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
A bounded stop: every node exits soon after SIGINT or SIGTERM, at any moment.

The test picks the moments: a node just up, a loop mid-run, a refit under way, a replay under
way, a controller whose axis a trip has powered off on a ros2_control driver. Each node must
exit with code 0 within ``STOP_BOUND`` of its signal, many times in a row (each loop node
four times: two runs for each signal, stopped in a random order at a random step; the
player, identify and the controller on the driver three times), whatever its executor does
(``ros_ehs.nodes.ros_common.run`` does not wait on it for more than its ``STOP_GRACE``), and
the controller's last command is 0 A, sent once.
"""

import os
from pathlib import Path
import signal
import sys

import numpy as np
import pytest
from ros_ehs.nodes.processes import DUMP_SIGNAL, NodeProcesses
from ros_ehs.nodes.ros_common import STOP_GRACE
import ros_ehs_msgs_py as c
from waits import BOUND, wait_value

pytestmark = pytest.mark.ros
ROOT = Path(__file__).resolve().parents[1]
#: a rig driver to ros2_control's conventions, as a process (not our plant)
DRIVER = ['-m', 'ros_ehs.benchmarks.ros2_control_driver']
#: a node has this long from its signal to its exit: its grace, its close (a bag's summary)
STOP_BOUND = STOP_GRACE + 20.0


def _stopped(procs, name, signum):
    """Signal node ``name``; assert it exits with 0 within the bound."""
    p = procs[name].popen
    p.send_signal(signum)
    try:
        code = p.wait(STOP_BOUND)
    except Exception:  # noqa: B902 - a TimeoutExpired: say what it was doing
        raise AssertionError(f'{name} did not exit within {STOP_BOUND:g} s of signal '
                             f'{signum}:\n' + procs[name].output()[-3000:]) from None
    assert code == 0, (name, code, procs[name].output()[-3000:])


#: a node whose close() does not return (what a hung process looks like to its supervisor)
STUCK = """
import sys, time
from rclpy.node import Node
from ros_ehs.nodes import ros_common
ros_common.STOP_DUMP = 0.5


class Stuck(Node):
    def __init__(self):
        super().__init__('stuck')
        self.said = self.create_timer(0.01, self.spinning)     # from the executor's thread

    def spinning(self):
        self.said.cancel()
        print('spinning', flush=True)

    def close(self):
        time.sleep(60)


sys.exit(ros_common.run(Stuck, []))
"""


def _until(stream, last) -> str:
    """Read lines of ``stream`` up to the first for which ``last(line)`` holds."""
    lines = []
    for line in stream:
        lines.append(line)
        if last(line):
            break
    return ''.join(lines)


def _in_run(line: str) -> bool:
    """Say if a dump's ``line`` is the main thread's frame in ros_common.run (its last but one)."""
    return 'ros_common.py' in line and line.endswith(' in run\n')


#: a node whose executor's thread receives the SIGINT (the kernel may deliver a process's
#: signal to any of its threads)
ON_ANOTHER_THREAD = """
import signal, sys, threading
from rclpy.node import Node
from ros_ehs.nodes import ros_common


class Signalled(Node):
    def __init__(self):
        super().__init__('signalled')
        self.tick = self.create_timer(0.01, self.on_tick)     # on the executor's thread

    def on_tick(self):
        self.tick.cancel()
        print('signalling', flush=True)
        signal.pthread_kill(threading.get_ident(), signal.SIGINT)


sys.exit(ros_common.run(Signalled, []))
"""


def test_a_signal_delivered_to_another_thread_stops_the_node(dom):
    """The main thread waits in a read the signal's wake-up fd ends, whatever thread took it."""
    import subprocess
    p = subprocess.Popen([sys.executable, '-c', ON_ANOTHER_THREAD], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True,
                         env={**os.environ, 'ROS_DOMAIN_ID': str(dom)})
    try:
        assert p.stdout.readline() == 'signalling\n'
        code = p.wait(BOUND)
    finally:
        p.kill()
        p.wait(BOUND)
    assert code == 0, p.stderr.read()


def test_a_node_that_hangs_after_its_stop_writes_every_threads_stack(dom):
    import subprocess
    p = subprocess.Popen([sys.executable, '-c', STUCK], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True,
                         env={**os.environ, 'ROS_DOMAIN_ID': str(dom)})
    try:
        assert p.stdout.readline() == 'spinning\n'
        p.send_signal(signal.SIGINT)
        said = _until(p.stderr, _in_run)    # bounded: close() ends
    finally:
        p.kill()
        p.wait(BOUND)
    # faulthandler's dump: the timeout, then each thread's frames, the newest first
    assert said.startswith('Timeout (') and 'most recent call first' in said, said
    assert said.index('in close') < said.index('in run'), said


def test_a_node_asked_for_its_stacks_writes_them_and_runs_on(dom):
    """
    DUMP_SIGNAL: every thread's stack, and the node runs on (it then stops as any node does).

    One signal only: faulthandler drops a signal that lands on another thread while a dump
    is still being written (its reentrancy guard), so a second one sent as soon as the first
    dump's last frame was read was lost once.
    """
    import subprocess
    p = subprocess.Popen([sys.executable, '-c', STUCK], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True,
                         env={**os.environ, 'ROS_DOMAIN_ID': str(dom)})
    try:
        assert p.stdout.readline() == 'spinning\n'
        p.send_signal(DUMP_SIGNAL)
        asked = _until(p.stderr, _in_run)
        p.send_signal(signal.SIGINT)      # it runs on: its stop, then its close hangs
        stopped = _until(p.stderr, _in_run)
    finally:
        p.kill()
        p.wait(BOUND)
    # every thread (each a header): the executor's spinning, the main one waiting in run()
    assert asked.count('(most recent call first)') == 2 and 'in spin' in asked, asked
    assert 'in close' not in asked and stopped.index('in close') < stopped.index('in run'), \
        stopped


def test_a_node_that_does_not_exit_in_time_is_asked_for_its_stacks_first(
        dom, ros, tmp_path, capfd):
    """NodeProcesses.stop: a node still there after its timeout writes its stacks, then dies."""
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        # a recorder hung in its close (its own dump much later than the supervisor's)
        hung = procs.start('recorder', cmd=[sys.executable, '-c',
                                            STUCK.replace('STOP_DUMP = 0.5', 'STOP_DUMP = 60')])
        # on the graph: its signal handlers are in place (set before the node is made)
        assert ros.spin(until=lambda: 'stuck' in ros.get_node_names(), timeout=BOUND)
        codes = procs.stop(timeout=1.0)
    assert codes == {'recorder': -signal.SIGKILL}
    log = hung.output()
    assert 'in close' in log and log.index('in close') < log.index('in run'), log
    assert f"recorder did not exit within 1 s of SIGINT: its threads' stacks are in " \
        f'{hung.log}' in capfd.readouterr().err


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM], ids=['INT', 'TERM'])
def test_every_loop_node_stops_at_any_moment_of_a_lockstep_run(dom, tmp_path, signum):
    rng = np.random.default_rng(7 + signum)
    nodes = ['recorder', 'reference', 'controller', 'plant']
    for k in range(2):
        with NodeProcesses(dom, tmp_path / f'logs{k}', bound=BOUND) as procs:
            procs.start_loop('lockstep', bag=tmp_path / f'bag{k}',
                             plant={'duration': 600.0, 'diagnostics_period': 0.05})
            # a moment of the test's choosing: at once, or some hundreds of periods on
            wait_value(procs, c.PLANT_STATUS, 'steps', int(rng.integers(1, 3)) * 200 * k + 1)
            for name in rng.permutation(nodes):      # each in its turn, in any order
                _stopped(procs, str(name), signum)


def test_the_player_and_a_refitting_identify_node_stop_at_once(dom, tmp_path):
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        for k in range(3):
            procs.start('player', {'bag': str(ROOT / 'bags' / 'sample_sine_1hz'),
                                   'rate': 0.5, 'loop': True}, name=f'player{k}')
            procs.start('identify', {'live': True, 'window': 2.0, 'period': 1.0,
                                     'use_sim_time': True, 'diagnostics_period': 0.05},
                        name=f'identify{k}')
            # mid-replay: before any refit, after one, and with one under way (its thread in
            # compiled code: the interpreter's teardown under it once ended in a SIGSEGV)
            assert procs.wait_status(c.IDENTIFY_STATUS, lambda st: int(st.values['states'])
                                     > 500 * (k + 1) and (
                                         k == 0 or (k == 1 and int(st.values['refits']) > 0)
                                         or st.values['busy'] == 'True'),
                                     BOUND), procs[f'identify{k}'].output()[-3000:]
            # by default the one refit thread runs at SCHED_IDLE, the rest of the node not
            pid = procs[f'identify{k}'].pid
            policies = [os.sched_getscheduler(int(t)) for t in os.listdir(f'/proc/{pid}/task')]
            assert policies.count(os.SCHED_IDLE) == 1 and len(policies) > 1, policies
            _stopped(procs, f'identify{k}', signal.SIGTERM)
            _stopped(procs, f'player{k}', signal.SIGINT)


def test_a_powered_off_controller_on_a_ros2_control_driver_stops_with_zero_once(
        dom, tmp_path, ros):
    """The case that once hung: SIGTERM after a power_off trip; the driver holds the last."""
    from std_msgs.msg import Float64MultiArray
    from ros_ehs.nodes.ros_common import qos_profile
    got = []
    ros.create_subscription(Float64MultiArray, '/servo_valve_controller/commands',
                            lambda m: got.append(m.data[0]), qos_profile(c.RECORD_QOS, 1000))
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        for k in range(3):
            before = len(got)
            procs.start('controller', {
                'rate_hz': 500.0, 'state_topic': '/joint_states', 'joint': 'actuator_z',
                'command_interface': 'forward_command', 'diagnostics_period': 0.05,
                'command_topic': '/servo_valve_controller/commands',
                'limit_position_max': -0.001, 'limit_position_max_action': 'power_off'},
                name=f'controller{k}')
            procs.start(f'driver{k}', cmd=[sys.executable, *DRIVER, '--rate', '500'])
            assert procs.wait_status(c.CONTROLLER_STATUS, lambda st: 'power_off' in
                                     st.values.get('interlock', ''), BOUND), \
                procs[f'controller{k}'].output()[-3000:]
            # this controller's commands reach us (matched, as discovery goes, both ways)
            assert ros.spin(until=lambda: len(got) > before, timeout=BOUND)
            ros.spin(0.2)
            n = len(got)
            _stopped(procs, f'controller{k}', signal.SIGTERM)
            assert ros.spin(until=lambda: len(got) > n and got[-1] == 0.0, timeout=BOUND)
            _stopped(procs, f'driver{k}', signal.SIGINT)
            out = procs[f'controller{k}'].output()
            assert out.count('stopping: 0 A sent') == 1 and 'did not return' not in out
