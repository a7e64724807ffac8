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
Thin rclpy wrappers over the core: plant, controller, reference, recorder, player, identify.

Each module has a ``main(args=None)`` that ``ros2 run ros_ehs <node>`` calls. What they
share: :mod:`ros_ehs.nodes.parameters` (options and parameters declared from the settings, live
changes validated), :mod:`ros_ehs.nodes.scheduling` (SCHED_FIFO, CPU placement) and
:mod:`ros_ehs.nodes.ros_common` (QoS, messages, diagnostics, the run loop with a clean
SIGINT/SIGTERM shutdown); loop timing statistics, which need no ROS, are in
:mod:`ros_ehs.nodes.loop_stats`.
"""
