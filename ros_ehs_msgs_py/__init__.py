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
The ros_ehs topic contract (DESIGN.md section 3): names, message types, units.

Pure data, no ROS import. Names are relative, so a namespace (``__ns:=/axis1``) runs several
axes. QoS presets and message conversions arrive with the nodes (issue #4).
"""

from typing import NamedTuple

__all__ = ['Topic', 'TOPICS']


class Topic(NamedTuple):
    """One topic of the contract."""

    name: str
    msg_type: str
    content: str


TOPICS = (
    Topic('reference', 'sensor_msgs/msg/JointState',
          'joint `piston`: position z_ref [m], velocity [m/s]'),
    Topic('state', 'sensor_msgs/msg/JointState',
          '`piston`: z [m], z_dot [m/s], effort = hydraulic force [N]; `spool`: x [m]'),
    Topic('pressure/chamber_p', 'sensor_msgs/msg/FluidPressure', 'chamber P pressure [Pa]'),
    Topic('pressure/chamber_t', 'sensor_msgs/msg/FluidPressure', 'chamber T pressure [Pa]'),
    Topic('servo_current', 'sensor_msgs/msg/JointState', 'joint `servo_valve`: effort = i [A]'),
    Topic('diagnostics', 'diagnostic_msgs/msg/DiagnosticArray',
          'loop timing, tracking error, watchdog'),
    Topic('/clock', 'rosgraph_msgs/msg/Clock', 'published by the plant in lock-step mode'),
)
