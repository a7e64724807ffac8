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

from ros_ehs.core.lazy_names import attach

# each name is imported when first used (PEP 562, ros_ehs.core.lazy_names): a node that needs
# one module of this package loads that one
__getattr__, __dir__, __all__ = attach(__name__, submod_attrs={
    'controller': ['Controller', 'DeltaP'],
    'feedforward': ['DelayLine', 'Feedforward', 'psc_force', 'stribeck_estimate', 'xi_blend'],
    'pid': ['Pid', 'PidGains'],
    'safety': ['braking_distance', 'DETECTORS', 'SafetyConfig', 'Supervisor'],
    'supervised': ['AxisController']})
