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
"""The loop statistics: fresh cycles, windows, percentiles."""

import math

import numpy as np
import pytest
from ros_ehs.nodes.loop_stats import LoopStats, Ring


def test_loop_stats_count_fresh_cycles_and_percentiles():
    s = LoopStats(n=100)
    for k in range(10):
        s.tick(k * 1e-3, fresh=k % 5 != 0)
    assert s.cycles == 10 and s.fresh == 8 and s.fresh_fraction == pytest.approx(0.8)
    assert s.period.pct(50) == pytest.approx(1e-3)
    w = Ring(3)
    for v in (1.0, 2.0, 3.0, 4.0):
        w.add(v)
    assert sorted(w.values()) == [2.0, 3.0, 4.0] and w.peak() == 4.0 and w.total == 4
    assert math.isnan(Ring(3).pct(50))


@pytest.mark.parametrize('n', [0, 1, 2, 5, 101, 25000])
def test_window_median_p99_and_max_in_one_pass_are_numpys(n):
    w = Ring(20000)
    for v in np.random.default_rng(n).exponential(1e-3, n):
        w.add(v)
    got = w.p50_p99_max()
    if n == 0:
        assert all(math.isnan(g) for g in got)
        return
    v = w.values()
    assert got == pytest.approx((np.percentile(v, 50), np.percentile(v, 99), v.max()),
                                rel=1e-12)


@pytest.mark.parametrize('n', [1, 2, 7, 2000, 2500])
@pytest.mark.parametrize('q', [0, 1, 50, 99, 99.9, 100])
def test_window_percentile_is_numpys(n, q):
    w = Ring(2000)
    for v in np.random.default_rng(n).exponential(1e-3, n):
        w.add(v)
    assert w.pct(q) == pytest.approx(np.percentile(w.values(), q), rel=1e-12)


@pytest.mark.parametrize('n, last', [(0, 10), (5, 10), (1500, 2000), (2500, 2000),
                                     (20000, 2000), (25000, 2000), (25000, 4999),
                                     (25000, 5001), (25000, 30000)])
def test_window_newest_samples_are_the_ones_ranked(n, last):
    # the diagnostics rank only the newest samples of the ring, across its wrap
    w = Ring(20000)
    seen = np.random.default_rng(n + last).exponential(1e-3, n)
    for v in seen:
        w.add(v)
    got = w.p50_p99_max(last)
    newest = seen[-min(last, 20000):]
    assert np.sort(w.values(last)) == pytest.approx(np.sort(newest), rel=0, abs=0)
    if n == 0:
        assert all(math.isnan(g) for g in got)
        return
    assert got == pytest.approx((np.percentile(newest, 50), np.percentile(newest, 99),
                                 newest.max()), rel=1e-12)
