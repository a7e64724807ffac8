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
The numerical core: every rule of ros_ehs, with no ROS and no file I/O (layer 1 of 4).

numpy, scipy and numba only, and the topic contract's plain records
(:mod:`ros_ehs_msgs_py`). Parameters and settings (:mod:`~ros_ehs.core.params`), the models
(:mod:`~ros_ehs.core.model`), the controller and its loop rules (:mod:`~ros_ehs.core.control`),
the simulated axis and closed loops (:mod:`~ros_ehs.core.sim`) and identification
(:mod:`~ros_ehs.core.identify`). Clocks are passed in; verdicts come back as data.
"""
