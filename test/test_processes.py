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

import pytest
from ros_ehs.processes import node_command


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
                                 'topics': ['/a', '/b']})
    assert cmd[cmd.index('-m') + 1] == 'ros_ehs.nodes.plant'
    assert 'rate_hz:=1000.0' in cmd and 'k:=3' in cmd and 'on:=true' in cmd
    assert 'topics:=[/a,/b]' in cmd
    with pytest.raises(ValueError, match='unknown node'):
        node_command('plantt')


@pytest.mark.parametrize('allowed, pin, want', [
    ({0, 1}, None, (0, 1)), ({5, 3, 7}, None, (3, 5)), ({2}, None, None), ({2}, True, (2, 2)),
    ({0, 1}, False, None), ({4, 9}, True, (4, 9))])
def test_loop_placement_takes_the_first_two_allowed_cpus(monkeypatch, allowed, pin, want):
    import ros_ehs.processes as processes
    monkeypatch.setattr(processes.os, 'sched_getaffinity', lambda pid: set(allowed))
    assert processes.loop_placement(pin) == want
