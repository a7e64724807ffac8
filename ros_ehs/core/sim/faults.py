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
The faults a simulated axis can be given (:class:`~ros_ehs.core.sim.axis.SimulatedAxis`).

Apart from the axis, so that the settings (:mod:`ros_ehs.core.options`), which every node
reads, name them without loading the model.
"""

__all__ = ['FAULTS', 'LOAD_DRIFT', 'LOST_SUPPLY']

#: The faults the axis can inject (their meaning: the plant's ``fault`` setting).
FAULTS = ('none', 'frozen_sensor', 'nan_sensor', 'stuck_valve', 'lost_pressure',
          'frozen_load_cell', 'nan_load_cell', 'drifting_load_cell')
#: How fast the ``drifting_load_cell`` fault's reading drifts from the truth [N/s].
LOAD_DRIFT = 100.0
#: The supply pressure of the ``lost_pressure`` fault [Pa] (the lowest p_s allows).
LOST_SUPPLY = 1.0e6
