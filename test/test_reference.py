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
"""Reference trajectories from their declared specs."""

import math

import numpy as np
import pytest
from ros_ehs.core.control.waveforms import (Chirp, first_order_hold, make, Sine, Step,
                                            WAVEFORM)
from ros_ehs.core.errors import ParameterError


def test_reference_specs_build_each_kind_and_reject_bad_values(tmp_path):
    assert isinstance(make({}), Sine) and make({}).amplitude == 0.04
    assert isinstance(make({'kind': 'step', 'amplitude': 0.01}), Step)
    assert make({'kind': 'chirp'})(np.array([0.0]))[0][0] == 0.0
    csv = tmp_path / 't.csv'
    csv.write_text('t,z\n0,0\n1,0.01\n')
    assert make({'kind': 'csv'}, str(csv))(np.array([0.5]))[0][0] == pytest.approx(0.005)
    with pytest.raises(ParameterError, match='csv_path'):
        make({'kind': 'csv'})
    with pytest.raises(ParameterError, match='frequency'):
        make({'frequency': -1.0})
    assert {s.name for s in WAVEFORM} >= {'kind', 'amplitude', 'frequency'}


@pytest.mark.parametrize('offset_ms', [-0.9, -0.3, 0.0, 0.4, 2.5, 3.9])
def test_the_hold_gives_the_reference_at_the_states_instant_whichever_came_first(offset_ms):
    """A sample older (a slow reference) or newer (it came after the state) than the state."""
    sine = Sine(0.04, 1.0)
    t_state = 0.1234
    t_ref = t_state - offset_ms * 1e-3          # negative offset: the sample is the newer
    (z,), (v,) = sine([t_ref])
    got = first_order_hold(z, v, round(t_ref * 1e9), round(t_state * 1e9), 0.1)
    # exact to the sine's curvature over the offset (w^2 A dt^2 / 2: 0.03-5 um), where taking
    # the newer sample as it is misses by v dt (up to 0.23 mm here)
    curvature = (2 * np.pi) ** 2 * 0.04 * (offset_ms * 1e-3) ** 2 / 2
    assert got == pytest.approx(float(sine([t_state])[0][0]), abs=1.01 * curvature + 1e-12)
    if offset_ms < 0:
        assert abs(z - float(sine([t_state])[0][0])) > 50e-6


def test_the_hold_carries_a_sample_by_at_most_its_limit_either_way():
    assert first_order_hold(0.01, 0.2, 0, 3_000_000_000, 0.1) == pytest.approx(0.01 + 0.02)
    assert first_order_hold(0.01, 0.2, 3_000_000_000, 0, 0.1) == pytest.approx(0.01 - 0.02)
    assert first_order_hold(0.01, 0.2, 5, 5, 0.1) == 0.01


def test_a_chirp_holds_still_before_and_after_its_sweep():
    """Outside ``[0, duration)`` the position holds, so the velocity is zero (not cos's)."""
    ch = Chirp(0.005, 1.0, 4.0, 2.0)
    z, v = ch(np.array([-0.1, 1.0, 2.0, 2.5, 10.0]))
    assert v[0] == 0.0 and v[1] != 0.0 and np.all(v[2:] == 0.0)
    assert z[2] == z[3] == z[4] == pytest.approx(0.005 * math.sin(2 * math.pi * (2 + 3)))
    # inside, the velocity is the position's derivative
    t = np.linspace(0.1, 1.9, 50)
    h = 1e-6
    num = (ch(t + h)[0] - ch(t - h)[0]) / (2 * h)
    np.testing.assert_allclose(ch(t)[1], num, rtol=0, atol=1e-6)
