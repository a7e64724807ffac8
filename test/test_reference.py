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

import numpy as np
import pytest
from ros_ehs.errors import ParameterError
from ros_ehs.reference import make, REFERENCE_SPECS, Sine, Step


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
    assert {s.name for s in REFERENCE_SPECS} >= {'kind', 'amplitude', 'frequency'}
