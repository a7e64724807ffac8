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
"""The rig's envelope: a procedure it cannot follow is refused when it loads, by step."""

import math

import pytest
from ros_ehs.core.errors import InputError
from ros_ehs.core.model.coefficients import flow_gain_kq
from ros_ehs.core.params import Params, preset
from ros_ehs.core.procedure.envelope import check_envelope, require_envelope, RigEnvelope
from ros_ehs.core.procedure.spec import parse_procedure
from ros_ehs.core.sim.virtual_test import run_procedure


def _cyclic(mode='displacement', **kw):
    step = {'name': 'c', 'type': 'cyclic', 'waveform': 'sine', 'count': 10, **kw}
    return parse_procedure({'name': 'p', 'control_mode': mode, 'steps': [step]})


def test_the_envelope_is_the_models_own():
    p = Params()
    rig = RigEnvelope.from_params(p)
    assert rig.v_max == pytest.approx(p['u_max'] * flow_gain_kq(p) * p['K_x'] / p['A_p'])
    assert rig.f_stall == pytest.approx((p['p_s'] - p['p_t']) * p['A_p'])
    assert rig.f_h == pytest.approx(math.sqrt(2 * p['beta_e'] * p['A_p'] / p['l_iac'] /
                                              p['m_p']) / 2 / math.pi)
    assert (rig.z_min, rig.z_max) == (-0.095, 0.095)          # the limits, 5 mm from the stops
    assert rig.speed_at(0.0) == rig.v_max and rig.speed_at(rig.f_stall) == 0.0


def test_what_the_default_rig_can_follow_passes_and_what_it_cannot_is_named():
    rig = RigEnvelope.from_params(Params())
    # +-2 mm at 40 Hz (0.50 m/s, 70 % of the valve's 0.72 m/s) and +-10 mm at 10 Hz pass
    assert check_envelope(_cyclic(mean=0.0, amplitude=0.002, frequency=40.0), rig) == []
    assert check_envelope(_cyclic(mean=0.0, amplitude=0.01, frequency=10.0), rig) == []
    # +-5 mm at 60 Hz: too fast, and beyond the oil column's natural frequency
    bad = check_envelope(_cyclic(mean=0.0, amplitude=0.005, frequency=60.0), rig)
    assert len(bad) == 2 and all("'p' step 1 (c)" in b for b in bad)
    assert '1.885 m/s' in bad[0] and '60 Hz' in bad[1]
    # a mean of 0.5 m on a 0.1 m stroke
    bad = check_envelope(_cyclic(mean=0.5, amplitude=0.001, frequency=1.0), rig)
    assert len(bad) == 1 and 'stroke' in bad[0]
    # a ramp at 100 m/s
    up = {'name': 'up', 'type': 'ramp', 'to': 0.05, 'rate': 100.0}
    ramp = parse_procedure({'name': 'r', 'steps': [up]})
    assert 'must move at 100 m/s' in check_envelope(ramp, rig)[0]


def test_a_force_step_beyond_the_stall_force_or_a_stiff_specimens_reach_is_refused():
    p = preset('fatigue_actuator', k_L=1.0e7)
    rig = RigEnvelope.from_params(p)
    assert check_envelope(_cyclic(mode='force', peak=1.0e4, valley=1.0e3, frequency=10.0),
                          rig) == []
    bad = check_envelope(_cyclic(mode='force', peak=3.0e4, valley=1.0e3, frequency=10.0), rig)
    assert any('reserve to accelerate' in b for b in bad)
    # 4 mm on 1e7 N/m is 40 kN
    bad = check_envelope(_cyclic(mean=0.002, amplitude=0.002, frequency=1.0), rig)
    assert any('needs 4e+04 N' in b for b in bad), bad


def test_a_virtual_test_refuses_what_the_rig_cannot_follow_before_it_moves():
    proc = _cyclic(mean=0.0, amplitude=0.005, frequency=60.0)
    with pytest.raises(InputError, match="(?s)cannot follow.*'p' step 1 \\(c\\)"):
        run_procedure(proc, Params())
    with pytest.raises(InputError, match='cannot follow'):
        require_envelope(proc, Params())
    r = run_procedure(proc, Params(), check=False, max_seconds=0.5)   # told not to check
    assert r.sim_s <= 0.5 + 1e-9


@pytest.mark.parametrize('kw, says', [
    ({'actions': [(1.0, 'jump')]}, "unknown action 'jump'"),
    ({'actions': [(math.nan, 'hold')]}, 'the hold action at nan s'),
    ({'actions': [(-1.0, 'resume')]}, 'the resume action at -1.0 s'),
    ({'settle_after': math.nan}, '`settle_after` = nan'),
    ({'fault': 'loose_cable'}, "`fault` = 'loose_cable'"),
    ({'progress_every': -1.0}, '`progress_every` = -1.0'),
])
def test_a_virtual_tests_bad_arguments_are_named(kw, says):
    proc = _cyclic(mean=0.0, amplitude=0.001, frequency=1.0)
    with pytest.raises(InputError) as err:
        run_procedure(proc, Params(), **kw)
    assert says in str(err.value)


def test_a_virtual_test_tells_its_progress_and_ends_with_its_test():
    from ros_ehs.core.sim.virtual_test import PROGRESS_PERIODS
    said = []
    proc = _cyclic(mean=0.0, amplitude=0.001, frequency=5.0)
    r = run_procedure(proc, Params(), progress=lambda *a: said.append(a), progress_every=0.0)
    assert r.result == 'completed' and r.sim_s < 60.0            # not at max_seconds
    n = int(r.sim_s * 1000) // PROGRESS_PERIODS + 1
    assert len(said) in (n - 1, n) and said[0][0] == 0.0
    assert [c for _, c, _ in said] == sorted(c for _, c, _ in said)      # counts only grow
    assert {st for _, _, st in said} <= {'running', 'stopping', 'idle'}


def test_a_rig_parameters_file_that_is_not_one_is_named(tmp_path):
    from ros_ehs.core.errors import ParameterError
    from ros_ehs.core.params import load_yaml
    bad = tmp_path / 'rig.yaml'
    bad.write_text('controller:\n  ros__parameters:\n    stroke: -1.0\n')
    with pytest.raises(ParameterError, match='rig.yaml.*stroke'):
        load_yaml(bad)
