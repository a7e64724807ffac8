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
Bag and data I/O (layer 2 of 4): rosbag2 bags, a rig's topic map, reports, drive files.

It imports the core and never rclpy: :mod:`~ros_ehs.data.bag` (the rosbag2 MCAP and sqlite3
reader and writer), :mod:`~ros_ehs.data.mapping` (where a rig's signals are, and their
decoders), :mod:`~ros_ehs.data.experiments` (bags to identification experiments), the
identification job and its report, the live estimates' trend, drive files, and the
simulated recordings (:mod:`~ros_ehs.data.synthetic_bag`, :mod:`~ros_ehs.data.rig_bag`).
"""
