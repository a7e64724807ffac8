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
"""The one parameter table: validation, presets and ROS 2 YAML round trips."""

import math

import pytest

from ros_ehs.core.errors import ParameterError
from ros_ehs.core.params import ALL_SPECS, ESTIMATED, load_yaml, Params, preset, save_yaml, spec


def test_every_spec_has_unit_meaning_and_default_inside_its_range():
    for s in ALL_SPECS:
        assert s.meaning, s.name
        if not s.is_choice:
            assert s.lo <= s.default <= s.hi, s.name


def test_table1_presets_carry_the_papers_columns():
    ini, est = preset('table1_initial'), preset('table1_estimated')
    assert ini['d_c'] == 1e-6 and ini['F_cc'] == 200.0 and ini['c_c'] == 8000.0
    assert est['d_c'] == 8.4918e-6 and est['F_sc'] == 2201.9 and est['l_iac'] == 0.14417
    for name in ESTIMATED:
        s = spec(name)
        assert s.est_lo <= s.initial and s.est_lo <= s.estimated
        assert s.scale > 0


@pytest.mark.parametrize('name,value,match', [
    ('p_s', -1.0, r'`p_s` = -1.0 Pa is outside its valid range'),
    ('m_p', math.nan, r'`m_p` = nan is not finite'),
    ('kp', 'fast', r'`kp` = .fast. must be a number'),
    ('friction_law', 'lugre', r'`friction_law` = .lugre. is not one of'),
    ('no_such', 1.0, r'unknown parameter `no_such`'),
    ('limit_load_lead', 0.1, r'`limit_load_lead` = 0.1 s is outside its valid range'),
    ('limit_load_lead', math.nan, r'`limit_load_lead` = nan is not finite'),
])
def test_bad_parameter_names_the_parameter_its_value_and_range(name, value, match):
    with pytest.raises(ParameterError, match=match):
        Params({name: value})


def test_cross_checks_reject_inconsistent_sets():
    with pytest.raises(ParameterError, match='F_cc'):
        preset(F_cc=3000.0, F_sc=2000.0)
    with pytest.raises(ParameterError, match='stroke'):
        preset(l_iac=0.05, stroke=0.1)
    with pytest.raises(ParameterError, match='K_m'):
        preset(K_m=7.0)


def test_params_are_immutable_and_replace_validates():
    p = preset()
    with pytest.raises(TypeError):
        p['p_s'] = 1.0
    q = p.replace(c_c=2.0e4)
    assert q['c_c'] == 2.0e4 and p['c_c'] == 1.61e4
    with pytest.raises(ParameterError):
        p.replace(c_c=-5.0)


def test_parameter_doc_is_generated_from_the_table():
    from pathlib import Path
    from ros_ehs.core.params import markdown_table
    doc = Path(__file__).resolve().parents[1] / 'docs' / 'parameters.md'
    assert doc.read_text() == markdown_table() + '\n', 'run: ehs_sim params-doc'


def test_yaml_round_trip_writes_doubles_as_doubles(tmp_path):
    p = preset('table1_initial', p_t=0.0)
    f = save_yaml(tmp_path / 'p.yaml', p, node_name='controller')
    text = f.read_text()
    assert 'controller:' in text and 'ros__parameters:' in text
    assert 'p_t: 0.0' in text and 'F_cc: 200.0' in text
    assert load_yaml(f) == p


def test_yaml_loader_accepts_ints_ignores_foreign_keys_and_names_the_file(tmp_path):
    f = tmp_path / 'x.yaml'
    f.write_text('plant:\n  ros__parameters:\n    c_c: 9000\n    use_sim_time: true\n')
    assert load_yaml(f)['c_c'] == 9000.0
    f.write_text('plant:\n  ros__parameters:\n    c_c: -1.0\n')
    with pytest.raises(ParameterError, match=r'x\.yaml.*`c_c`'):
        load_yaml(f)
    f.write_text('just a string')
    with pytest.raises(ParameterError, match='not a ROS 2 parameters file'):
        load_yaml(f)
