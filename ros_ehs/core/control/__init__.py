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
Controller core: PID (eq. 19), feedforward (eqs. 9-20), their combination (eq. 18), safety.

:class:`AxisController` is what the controller node runs: the safety :class:`Supervisor`
(limit and error detectors, latched actions, ramp-on) in front of :class:`Controller`.
"""

import importlib

__all__ = ['AxisController', 'Controller', 'DETECTORS', 'DelayLine', 'DeltaP', 'Feedforward',
           'Pid', 'PidGains', 'SafetyConfig', 'Supervisor', 'braking_distance', 'psc_force',
           'stribeck_estimate', 'xi_blend']

#: where each public name lives (imported when first used, PEP 562: a node that needs one
#: module of this package loads that one)
_HOME = {'Controller': 'controller', 'DeltaP': 'controller', 'DelayLine': 'feedforward',
         'Feedforward': 'feedforward', 'psc_force': 'feedforward',
         'stribeck_estimate': 'feedforward', 'xi_blend': 'feedforward', 'Pid': 'pid',
         'PidGains': 'pid', 'braking_distance': 'safety', 'DETECTORS': 'safety',
         'SafetyConfig': 'safety', 'Supervisor': 'safety', 'AxisController': 'supervised'}


def __getattr__(name: str):
    if name in _HOME:
        return getattr(importlib.import_module(f'{__name__}.{_HOME[name]}'), name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')


def __dir__():
    return sorted(set(globals()) | set(__all__))
