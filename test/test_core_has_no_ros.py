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
"""The numerical core (model, control, identification, bag I/O) never imports rclpy."""

import subprocess
import sys

CORE = ['ros_ehs_msgs_py', 'ros_ehs.params', 'ros_ehs.model', 'ros_ehs.control',
        'ros_ehs.sim.closed_loop',
        'ros_ehs.reference', 'ros_ehs.metrics', 'ros_ehs.noise', 'ros_ehs.cli', 'ros_ehs.bag',
        'ros_ehs.bag.experiment', 'ros_ehs.identify', 'ros_ehs.identify.run',
        'ros_ehs.identify.report', 'ros_ehs.identify.live', 'ros_ehs.identify.trend',
        'ros_ehs.model.drift', 'ros_ehs.sim', 'ros_ehs.sim.synthetic_bag', 'ros_ehs.sim.rig_bag',
        'ros_ehs.sim.paper_runs', 'ros_ehs.sim.axis']


def test_core_modules_import_without_rclpy():
    code = ('import importlib, sys\n'
            f'for m in {CORE!r}:\n'
            '    importlib.import_module(m)\n'
            'bad = sorted(m for m in sys.modules\n'
            "             if m.split('.')[0] in ('rclpy', 'rcl_interfaces'))\n"
            'assert not bad, bad\n')
    res = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
