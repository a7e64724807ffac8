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
"""A cycle's levels under noise: the fitted extremes are unbiased where the raw ones are not."""

import math

import numpy as np
import pytest
from ros_ehs.core.control.levels import CycleLevels, HARMONICS


def _cycle(y, fit=True):
    lv = CycleLevels(fit)
    n = len(y)
    for j, v in enumerate(y):
        lv.add(j / n, float(v))
    return lv


def test_a_clean_distorted_sine_is_fitted_to_its_own_extremes():
    x = np.arange(100) / 100.0
    y = 5500.0 + 4500.0 * np.sin(2 * np.pi * x) + 80.0 * np.sin(6 * np.pi * x + 0.3) + \
        30.0 * np.cos(14 * np.pi * x)          # a 3rd and a 7th harmonic, as a loop adds
    fine = np.arange(20000) / 20000.0
    true = 5500.0 + 4500.0 * np.sin(2 * np.pi * fine) + 80.0 * np.sin(6 * np.pi * fine + 0.3) \
        + 30.0 * np.cos(14 * np.pi * fine)
    hi, lo = _cycle(y).levels()
    assert hi == pytest.approx(true.max(), abs=0.5) and lo == pytest.approx(true.min(), abs=0.5)


def test_noise_biases_the_raw_extremes_and_not_the_fitted_ones():
    rng = np.random.default_rng(1)
    x = np.arange(100) / 100.0
    raw, fit = [], []
    for _ in range(400):
        y = 5500.0 + 4500.0 * np.sin(2 * np.pi * x) + rng.normal(0.0, 100.0, x.size)
        lv = _cycle(y)
        raw.append(lv.raw()[0] - lv.raw()[1])
        fit.append(lv.levels()[0] - lv.levels()[1])
    # the fitted curve's own noise still lifts its extremes, a little: 0.13 % of the range
    assert abs(np.mean(fit) - 9000.0) < 0.002 * 9000.0
    assert np.mean(raw) - 9000.0 > 150.0                        # some 2 % of the range long
    # its scatter: about sigma sqrt((2 h + 1) / n) on each extreme
    assert np.std(fit) < 2.0 * 100.0 * math.sqrt((2 * HARMONICS + 1) / 100.0)


def test_a_cycle_that_cannot_be_fitted_keeps_its_raw_extremes_and_a_nan_spoils_it():
    assert _cycle([1.0, 3.0, 2.0]).levels() == (3.0, 1.0)           # too few samples
    y = np.sin(2 * np.pi * np.arange(100) / 100.0)
    assert _cycle(y, fit=False).levels() == _cycle(y, fit=False).raw()   # a triangle's
    y[50] = math.nan
    hi, lo = _cycle(y).levels()
    assert math.isnan(hi) and math.isnan(lo)
