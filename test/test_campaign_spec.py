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
"""Campaign files: checked whole, every level the plan can give rendered as a procedure."""

import pytest
from ros_ehs.core.campaign.spec import load_campaign, parse_campaign
from ros_ehs.core.errors import InputError
import yaml

TEMPLATE = {'name': 'coupon', 'control_mode': 'force', 'steps': [
    {'name': 'preload', 'type': 'ramp', 'to': 5000.0, 'rate': 2.0e4},
    {'name': 'fatigue', 'type': 'cyclic', 'waveform': 'sine', 'peak': 1.0e4, 'valley': 1.0e3,
     'frequency': 10.0, 'end': [{'stiffness_drop': {'drop': 0.1}}]}]}
GOOD = {'name': 'S-N', 'template': TEMPLATE, 'level': {'kind': 'max_load', 'R': 0.1},
        'run_out': 1.0e7, 'plan': {'method': 'levels', 'levels': [9000, 8000, 7000],
                                   'specimens': 3},
        'target': {'kind': 'load_at_life', 'life': 1.0e6, 'confidence': 0.9, 'width': 0.05}}


def test_a_campaign_renders_each_level_into_its_procedure():
    c = parse_campaign(GOOD)
    p = c.procedure(8000.0, 'C-07')
    step = p.steps[1]
    assert (step['peak'], step['valley']) == (8000.0, 800.0) and p.run_out == 10 ** 7
    assert 'C-07' in p.name and c.planned_levels() == [9000.0, 8000.0, 7000.0]
    assert c.target == {'kind': 'load_at_life', 'life': 1e6, 'confidence': 0.9,
                        'width': 0.05, 'min_specimens': 6}
    amp = parse_campaign({**GOOD, 'level': {'kind': 'amplitude', 'mean': 5500.0}})
    assert amp.procedure(3000.0).steps[1]['blocks'] == ((8500.0, 2500.0, 1),)


@pytest.mark.parametrize('plan, levels', [
    ({'method': 'pearl_string', 'start': 9000, 'step': 500, 'specimens': 4},
     [9000, 8500, 8000, 7500]),
    ({'method': 'staircase', 'start': 6000, 'step': 500, 'specimens': 3},
     [5000, 5500, 6000, 6500, 7000]),
    ({'method': 'adaptive', 'low': 5000, 'high': 9000, 'specimens': 12}, [5000, 7000, 9000]),
])
def test_every_plan_gives_its_levels(plan, levels):
    assert parse_campaign({**GOOD, 'plan': plan}).planned_levels() == levels


def test_each_plan_gives_the_next_level_from_the_results_so_far():
    c = parse_campaign(GOOD)                          # 3 at each of 9, 8, 7 kN, in turn
    done = []
    for want in [9000] * 3 + [8000] * 3 + [7000] * 3:
        assert c.next_level(done) == want
        done.append((want, True))
    assert c.next_level(done) is None
    stair = parse_campaign({**GOOD, 'plan': {'method': 'staircase', 'start': 6000,
                                             'step': 500, 'specimens': 5}})
    seq, done = [], []
    for failed in (True, True, False, True, False):  # x x o x o
        seq.append(stair.next_level(done))
        done.append((seq[-1], failed))
    assert seq == [6000, 5500, 5000, 5500, 5000] and stair.next_level(done) is None
    pearl = parse_campaign({**GOOD, 'plan': {'method': 'pearl_string', 'start': 9000,
                                             'step': 1000, 'specimens': 3}})
    assert [pearl.next_level([(0, True)] * j) for j in range(4)] == [9000, 8000, 7000, None]
    adaptive = parse_campaign({**GOOD, 'plan': {'method': 'adaptive', 'low': 5e3,
                                                'high': 9e3}})
    with pytest.raises(InputError, match='adaptive plan .* ask ros_ehs.core.campaign.runner'):
        adaptive.next_level([])


def test_a_procedure_file_is_found_beside_the_campaign(tmp_path):
    (tmp_path / 'coupon.yaml').write_text(yaml.safe_dump(TEMPLATE))
    doc = {k: v for k, v in GOOD.items() if k != 'template'}
    (tmp_path / 'c.yaml').write_text(yaml.safe_dump({**doc, 'procedure': 'coupon.yaml'}))
    c = load_campaign(tmp_path / 'c.yaml')
    assert c.procedure(9000.0).steps[1]['valley'] == 900.0
    with pytest.raises(InputError, match="c.yaml'.*cannot read"):
        (tmp_path / 'coupon.yaml').unlink()
        load_campaign(tmp_path / 'c.yaml')


@pytest.mark.parametrize('change, says', [
    ({'colour': 'red'}, "unknown keys \\['colour'\\]"),
    ({'procedure': 'x.yaml'}, 'one way'),
    ({'level': {'kind': 'max_load', 'R': 1.2}}, '`R` = 1.2'),
    ({'level': {'kind': 'stress'}}, "`kind` = 'stress'"),
    ({'level_step': 'preload'}, "`level_step` = 'preload' is not a cyclic step"),
    ({'plan': {'method': 'levels', 'levels': [9000]}}, 'two levels or more'),
    ({'plan': {'method': 'levels', 'levels': [9000, 9000]}}, 'repeat'),
    ({'plan': {'method': 'random'}}, "`method` = 'random'"),
    ({'plan': {'method': 'staircase', 'start': 6000}}, 'needs `step`'),
    ({'plan': {'method': 'pearl_string', 'start': 2000, 'step': 500, 'specimens': 6}},
     'reach zero'),
    ({'plan': {'method': 'adaptive', 'low': 9000, 'high': 5000}}, '`low` = 9000'),
    ({'target': {'kind': 'load_at_life', 'life': 1e6, 'confidence': 0.9, 'width': 0.05,
                 'min_specimens': 2}}, '`min_specimens` = 2 must be a whole number from 3'),
    ({'target': {'kind': 'load_at_life', 'life': 1e6, 'confidence': 1.5, 'width': 0.05}},
     '`confidence` = 1.5'),
    # a level the rendered procedure refuses, named with the procedure's step and key
    ({'level': {'kind': 'amplitude', 'mean': 0.0}, 'template': {
        'name': 'disp', 'steps': [TEMPLATE['steps'][1]]},
      'plan': {'method': 'levels', 'levels': [1.0, 3.0]}}, 'at level 3: step 1 .*beyond'),
])
def test_each_error_names_the_campaign_and_the_key(change, says):
    with pytest.raises(InputError, match=says) as err:
        parse_campaign({**GOOD, **change}, 'campaign c.yaml')
    assert 'campaign c.yaml' in str(err.value)
