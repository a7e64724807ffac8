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

The names below are imported when first used (PEP 562): a process that needs only the
valve's coefficients (a recorder, a reference, the controller) does not load numba.
"""

import importlib

__all__ = ['FULL_STATES', 'MODELS', 'Plant', 'SIMPLIFIED_STATES', 'SimResult', 'ff_force_gain',
           'flow_gain_kq', 'rhs']

#: where each public name lives
_HOME = {'ff_force_gain': 'coefficients', 'flow_gain_kq': 'coefficients',
         **dict.fromkeys(('FULL_STATES', 'MODELS', 'Plant', 'SIMPLIFIED_STATES', 'SimResult',
                          'rhs'), 'plant')}


def __getattr__(name: str):
    if name in _HOME:
        return getattr(importlib.import_module(f'{__name__}.{_HOME[name]}'), name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')


def __dir__():
    return sorted(set(globals()) | set(__all__))
