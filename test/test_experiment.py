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
"""Experiments read from bags: which current the fit replays."""

import numpy as np
from ros_ehs.data.bag import BagWriter
from ros_ehs.data.experiments import load_experiment
import ros_ehs_msgs_py as c


def test_identification_prefers_the_applied_current_over_the_command(tmp_path):
    """A watchdog zeroing shows in the applied current, not in the command topic."""
    n = 600
    applied = 0.002 * np.sin(np.arange(n) * 0.05)
    applied[300:310] = 0.0                       # the valve was zeroed here
    with BagWriter(tmp_path / 'b') as w:
        for tp in (c.STATE, c.COMMAND):
            w.add_topic('/' + tp.name, tp.msg_type, tp.qos)
        for k in range(n):
            ns = 10**9 + k * 10**6
            w.write_msg('/state', c.fill_state(c.empty_msg(c.STATE.msg_type), c.AxisState(
                ns, 0.001 * k, 0.1, 0.0, 0.0, float(applied[k]))), ns)
            w.write_msg('/servo_current', c.fill_command(
                c.empty_msg(c.COMMAND.msg_type), c.Command(ns, 0.005)), ns)
    e = load_experiment(tmp_path / 'b')
    np.testing.assert_array_equal(e.i[:-1], applied[1:])   # period k: reported at k + 1
    assert np.all(e.i[299:309] == 0.0)
