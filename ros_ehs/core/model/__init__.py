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
Plant models: full 10-state and simplified 4-state (numba kernels + checked layer).

The names below are imported when first used (PEP 562, :mod:`ros_ehs.core.lazy_names`): a
process that needs only the valve's coefficients (a recorder, a reference, the controller)
does not load numba.
"""

from ros_ehs.core.lazy_names import attach

__getattr__, __dir__, __all__ = attach(__name__, submod_attrs={
    'coefficients': ['ff_force_gain', 'flow_gain_kq'],
    'plant': ['FULL_STATES', 'MODELS', 'Plant', 'SIMPLIFIED_STATES', 'SimResult', 'rhs']})
