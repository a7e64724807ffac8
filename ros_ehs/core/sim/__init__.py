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
Simulation in process, without ROS: the simulated axis, the closed loop, the bags it records.

* :mod:`~ros_ehs.core.sim.axis`: the axis the plant node serves (``SimulatedAxis``: the model
  stepped on a period grid, the command stamp policy, the watchdog, lock-step, faults);
* :mod:`~ros_ehs.core.sim.closed_loop`: plant and controller in one loop (``run_closed_loop``);
* :mod:`~ros_ehs.data.synthetic_bag`: a closed-loop run with sensor noise, recorded as our
  bench records it (``record_synthetic_bag``);
* :mod:`~ros_ehs.data.rig_bag`: a rig's bag in a ros2_control layout, written by rosbags
  (``record_rig_bag``);
* :mod:`~ros_ehs.core.sim.paper_runs`: the paper's test runs and figures.
"""
