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
The model's smooth saturation in plain Python, shared by the kernels and the controller.

The controller's feedforward calls :func:`smooth_clip` as it is (no numba: neither its
dispatch cost per call nor numba's import in the controller's process);
:mod:`ros_ehs.core.model.kernels` compiles this same function for the plant.
"""

import math

__all__ = ['smooth_clip']


def smooth_clip(f, lim):
    """
    Saturate ``f`` to +-``lim`` smoothly (corner width 1 % of ``lim``).

    Squares are products: Python's ``**`` raises OverflowError for ``|f|`` over 1e154 where a
    product gives inf (then NaN, which the PID answers with 0 A and ``fault``); an absurd
    sensor reading must not crash the controller.
    """
    d = 0.01 * lim + 1e-9
    a, b = f + lim, f - lim
    return 0.5 * (math.sqrt(a * a + d * d) - math.sqrt(b * b + d * d))
