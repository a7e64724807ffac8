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
"""A node's options and parameters: declared from the table, live changes validated."""

import math

import pytest
from ros_ehs.core.control.controller import Controller
from ros_ehs.core.control.feedforward import MODEL_PARAMS
from ros_ehs.core.params import CONTROL_SPECS, Params


@pytest.mark.ros
def test_live_changes_are_validated_as_a_whole_with_a_reason():
    from rclpy.parameter import Parameter
    from ros_ehs.nodes.controller import SPECS
    from ros_ehs.nodes.parameters import validate_changes
    cur = Params()
    res, new = validate_changes(cur, [Parameter('kp', value=1.5)], SPECS)
    assert res.successful and new['kp'] == 1.5
    res, new = validate_changes(cur, [Parameter('F_cc', value=cur['F_sc'] + 1.0)], SPECS)
    assert not res.successful and new is None and 'must not exceed' in res.reason
    res, _ = validate_changes(cur, [Parameter('u_max', value=5.0)], SPECS)
    assert not res.successful and 'u_max' in res.reason and 'outside' in res.reason
    res, new = validate_changes(cur, [Parameter('use_sim_time', value=True)], SPECS)
    assert res.successful and new is None          # not ours: nothing to rebuild
    from ros_ehs.nodes.parameters import rejected_names
    declared = {'kp', 'use_sim_time'}.__contains__
    assert rejected_names([Parameter('kp', value=1.5)], declared) is None
    assert rejected_names([Parameter('', value=1.0)], declared) == \
        'a parameter with an empty name'
    assert rejected_names([Parameter('kp', value=1.5), Parameter('nope', value=1.0)],
                          declared) == 'parameter `nope` is not declared by this node'
    assert 'restart the node' in rejected_names([Parameter('use_sim_time', value=True)],
                                                declared)
    res, _ = validate_changes(cur, [Parameter('antiwindup', value='clamp')], SPECS)
    assert not res.successful and "`antiwindup` = 'clamp' is not one of" in res.reason
    from ros_ehs.nodes.plant import OPTIONS
    from ros_ehs.core.params import PLANT_SPECS
    res, _ = validate_changes(cur, [Parameter('timing', value='bogus')], PLANT_SPECS, OPTIONS)
    assert not res.successful and res.reason == (
        "parameter `timing` = 'bogus' is not one of ['timer', 'thread']")


def test_controller_declares_every_value_its_feedforward_reads():
    names = {s.name for s in CONTROL_SPECS} | set(MODEL_PARAMS)
    p = Params()

    class Only(dict):
        def __getitem__(self, k):
            if k not in names:
                raise KeyError(f'the controller does not declare {k}')
            return dict.__getitem__(self, k)

    ctrl = Controller(Only(p.items()), 1e-3)       # raises if MODEL_PARAMS misses one
    assert math.isfinite(ctrl.step(0.01, 0.0, 0.0))


def test_the_docs_tables_are_generated_from_the_settings():
    from ros_ehs.core.params import markdown_table
    from ros_ehs.tools.docs import cli_markdown, DOCS, render
    text = (DOCS / 'nodes.md').read_text()
    assert render(text) == text, 'docs/nodes.md is stale: run python -m ros_ehs.tools.docs'
    from ros_ehs.tools.docs import procedure_markdown
    text = (DOCS / 'procedures.md').read_text()
    assert render(text, procedure_markdown) == text, \
        'docs/procedures.md is stale: run python -m ros_ehs.tools.docs'
    from ros_ehs.tools.docs import campaign_markdown
    text = (DOCS / 'campaigns.md').read_text()
    assert render(text, campaign_markdown) == text, \
        'docs/campaigns.md is stale: run python -m ros_ehs.tools.docs'
    assert (DOCS / 'cli.md').read_text() == cli_markdown() + '\n', \
        'docs/cli.md is stale: run python -m ros_ehs.tools.docs'
    assert (DOCS / 'parameters.md').read_text() == markdown_table() + '\n'


@pytest.mark.ros
def test_live_options_follow_accepted_changes_read_only_ones_do_not():
    from rclpy.parameter import Parameter
    from ros_ehs.nodes.plant import OPTIONS
    from ros_ehs.nodes.parameters import update_settings
    opt = {o.name: o.default for o in OPTIONS}
    update_settings(opt, [Parameter('watchdog_periods', value=5),
                          Parameter('rate_hz', value=500.0)], OPTIONS)
    assert opt['watchdog_periods'] == 5 and opt['rate_hz'] == 1000.0
