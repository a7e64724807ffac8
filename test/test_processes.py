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
"""Process supervision without DDS: node commands, CPU placement."""

import math

from foreign import diagnostic_array
import pytest
from ros_ehs.nodes.processes import node_command


def test_bare_params_file_moves_inside_ros_args():
    from ros_ehs.nodes.ros_common import ros_args
    assert ros_args(['plant', '--params-file', 'a.yaml']) == \
        ['plant', '--ros-args', '--params-file', 'a.yaml']
    same = ['plant', '--ros-args', '--params-file', 'a.yaml', '-p', 'x:=1']
    assert ros_args(same) == same
    assert ros_args(['p', '--params-file', 'a.yaml', '--ros-args', '-p', 'x:=1']) == \
        ['p', '--ros-args', '-p', 'x:=1', '--ros-args', '--params-file', 'a.yaml']


def test_node_command_writes_doubles_as_doubles():
    cmd = node_command('plant', {'rate_hz': 1000.0, 'mode': 'lockstep', 'k': 3, 'on': True,
                                 'topics': ['/a', '/b'], 'action': 'off', 'q': "it's"})
    assert cmd[cmd.index('-m') + 1] == 'ros_ehs.nodes.plant'
    assert 'rate_hz:=1000.0' in cmd and 'k:=3' in cmd and 'on:=true' in cmd
    # strings quoted: '-p' values are YAML, where a bare off is the boolean false
    assert "topics:=['/a','/b']" in cmd and "mode:='lockstep'" in cmd
    assert "action:='off'" in cmd and "q:='it''s'" in cmd
    with pytest.raises(ValueError, match='unknown node'):
        node_command('plantt')


@pytest.mark.parametrize('allowed, pin, want', [
    ({0, 1}, None, (0, 1)), ({5, 3, 7}, None, (3, 5)), ({2}, None, None), ({2}, True, (2, 2)),
    ({0, 1}, False, None), ({4, 9}, True, (4, 9))])
def test_loop_placement_takes_the_first_two_allowed_cpus(monkeypatch, allowed, pin, want):
    import ros_ehs.nodes.processes as processes
    monkeypatch.delenv(processes.LOOP_CPUS_ENV, raising=False)
    monkeypatch.setattr(processes.os, 'sched_getaffinity', lambda pid: set(allowed))
    assert processes.loop_placement(pin) == want


def test_loop_placement_takes_the_cpus_the_environment_names(monkeypatch):
    import ros_ehs.nodes.processes as processes
    monkeypatch.setattr(processes.os, 'sched_getaffinity', lambda pid: {0, 1, 2})
    monkeypatch.setenv(processes.LOOP_CPUS_ENV, '2,0')
    assert processes.loop_placement() == (2, 0) and processes.loop_placement(False) is None
    for bad in ('1', '1,7', 'a,b', '0,1,2'):
        monkeypatch.setenv(processes.LOOP_CPUS_ENV, bad)
        with pytest.raises(ValueError, match=f'ROS_EHS_LOOP_CPUS = {bad!r}'):
            processes.loop_placement()


def test_readiness_is_read_from_the_statuses_a_diagnostics_message_carries():
    import ros_ehs_msgs_py as c
    from ros_ehs.nodes.processes import loop_closed, recording, reference_started
    msg = diagnostic_array([
        (c.RECORDER_STATUS, 0, 'recording', [('recording', '/reference,/servo_current,/state'),
                                             ('matched', '/reference')]),
        (c.PLANT_STATUS, 1, 'waiting for the first command', []),
        (c.REFERENCE_STATUS, 0, 'sine', [('started', 'True'), ('published', '3')])],
        sec=5, nanosec=7)
    rec, plant, ref = c.statuses_from_msg(msg)
    assert rec == c.NodeStatus(5_000_000_007, c.RECORDER_STATUS, 0, 'recording',
                               {'recording': '/reference,/servo_current,/state',
                                'matched': '/reference'})
    assert rec.listed('matched') == {'/reference'} and rec.listed('nothing') == set()
    assert recording(c.STATE, c.COMMAND)(rec) and recording('/reference')(rec)
    assert not recording(c.STATE, '/joint_states')(rec)
    assert not loop_closed(plant) and plant.level == 1
    assert loop_closed(plant._replace(level=0))
    assert reference_started(ref) and not reference_started(ref._replace(values={}))
    assert c.statuses_from_msg(diagnostic_array([])) == []


@pytest.mark.parametrize('bound', [0.0, -1.0, math.nan, math.inf])
def test_a_bound_that_is_no_time_is_refused(bound):
    from ros_ehs.nodes.processes import NodeProcesses
    with pytest.raises(ValueError, match=r'`bound` = .* s must be finite and > 0'):
        NodeProcesses(bound=bound, clean_shm=False)


@pytest.mark.ros
def test_start_loop_names_the_status_it_waited_for(dom, tmp_path):
    """A recorder told to record no loop topic never matches the commands: named, with why."""
    from ros_ehs.nodes.processes import NodeProcesses, StartupError
    with NodeProcesses(dom, tmp_path / 'logs') as procs:
        with pytest.raises(StartupError, match=r"the recorder did not match the controller's "
                                               r'commands \(ros_ehs/recorder in diagnostics, '
                                               r"10 s; its status: 'recording' .*'recording': "
                                               r"'/diagnostics'.*\); recorder log:"):
            # the bound is every step's: 3 s was too short for the recorder's first status
            # on a loaded machine (a fresh-clone run beside a benchmark)
            procs.start_loop(bag=tmp_path / 'bag', reference=False, timeout=10.0,
                             recorder={'topics': ['/diagnostics']})
        assert procs.watch is not None and 'plant' not in procs.procs
    assert procs.watch is None


def test_the_test_process_holds_a_ros_domain_of_its_own():
    """The conftest reserves ROS_DOMAIN_ID for this process: no other worker can take it."""
    import os
    import socket
    from domain_coordinator.impl import PORT_BASE
    d = int(os.environ['ROS_DOMAIN_ID'])
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        with pytest.raises(OSError):
            s.bind(('', PORT_BASE + d))
