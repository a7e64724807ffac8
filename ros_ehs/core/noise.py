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
"""
The white-noise level of a sampled signal (ROS-free): what a fit's residuals are judged by.

Used by bag reading (the noise of a velocity derived from position) and by identification
(each measured signal's sigma, the verdict's yardstick).
"""

from __future__ import annotations

import math

import numpy as np
from ros_ehs.core.errors import DataError

__all__ = ['noise_sigma']


def noise_sigma(y: np.ndarray, t: np.ndarray | None = None) -> float:
    """
    Robust white-noise level of a sampled signal [its unit].

    The third difference of a smooth signal is tiny while white noise of sigma gives
    sigma * sqrt(20); the median absolute deviation keeps stick-slip spikes out. With the
    sample times ``t`` [s] of a signal sampled unevenly (a driver's jitter), the third
    *divided* difference scaled by ``6 h^3`` (``h`` the mean step) is used instead: zero for
    a quadratic at any sample times, so the jitter does not pass for noise. Sample times
    that do not increase (a sample repeated) raise :class:`DataError`: their divided
    differences have no value, and a NaN noise would pass every residual judged by it.
    """
    y = np.asarray(y, dtype=float)
    x = None if t is None or y.size < 8 else np.asarray(t, dtype=float)
    rising = np.diff(x) > 0 if x is not None else None
    if rising is not None and not rising.all():
        k = int(np.argmin(rising))
        raise DataError(f'noise_sigma: the sample times must increase: sample {k + 1} at '
                        f'{float(x[k + 1]):.9g} s follows {float(x[k]):.9g} s')
    if x is not None and np.any(np.abs(np.diff(x, 2)) > 1e-9 * (x[-1] - x[0])):
        d = y
        for order in (1, 2, 3):
            d = (d[1:] - d[:-1]) / (x[order:] - x[:-order])
        d = 6.0 * float(np.mean(np.diff(x))) ** 3 * d
    else:
        d = np.diff(y, 3)
    mad = np.median(np.abs(d - np.median(d))) * 1.4826
    floor = 1e-6 * max(np.ptp(y), np.finfo(float).tiny)
    return float(max(mad / math.sqrt(20.0), floor))
