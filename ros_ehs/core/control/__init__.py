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

from ros_ehs.core.control.controller import Controller, DeltaP
from ros_ehs.core.control.feedforward import (DelayLine, Feedforward, psc_force, stribeck_estimate,
                                              xi_blend)
from ros_ehs.core.control.pid import Pid, PidGains
from ros_ehs.core.control.safety import braking_distance, DETECTORS, SafetyConfig, Supervisor
from ros_ehs.core.control.supervised import AxisController

__all__ = ['AxisController', 'Controller', 'DETECTORS', 'DelayLine', 'DeltaP', 'Feedforward',
           'Pid', 'PidGains', 'SafetyConfig', 'Supervisor', 'braking_distance', 'psc_force',
           'stribeck_estimate', 'xi_blend']
