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
The ros_ehs topic contract: names, message types, units, QoS, conversions.

Pure Python, no ROS import, so the numerical core and the bag reader use it as freely as the
nodes. Names are relative, so a namespace (``__ns:=/axis1``) runs several axes.

Five small modules, re-exported here: :mod:`~ros_ehs_msgs_py.topics` (names, types, units,
which node uses which topic), :mod:`~ros_ehs_msgs_py.qos` (QoS profiles as plain values),
:mod:`~ros_ehs_msgs_py.values` (:class:`AxisState`, :class:`Reference`, :class:`Command`,
:class:`Pressure`, ...), :mod:`~ros_ehs_msgs_py.conversions` (values to and from messages) and
:mod:`~ros_ehs_msgs_py.wire` (the loop's JointStates to and from CDR bytes, the fast path).
"""

from ros_ehs_msgs_py.conversions import (command_from_msg, CYCLE_RECORD, CYCLE_TAPERED,
                                         cycles_from_bytes,
                                         CYCLES_LABEL, cycles_to_bytes, empty_msg,
                                         estimate_from_msg, event_from_msg, event_level,
                                         fill_command, fill_estimate, fill_event, fill_load,
                                         fill_pressure, fill_procedure_event, fill_reference,
                                         fill_reference_trajectory, fill_state,
                                         fill_station_event, load_from_msg,
                                         pressure_from_msg, procedure_event_from_msg,
                                         reference_from_msg, reference_trajectory_from_msg,
                                         stamp_ns, state_from_msg, station_event_from_msg,
                                         statuses_from_msg, WRENCH_AXES)
from ros_ehs_msgs_py.qos import (CLOCK_QOS, EVENTS_QOS, LOCKSTEP_QOS, LOOP_QOS, QosSpec,
                                 RECORD_QOS)
from ros_ehs_msgs_py.topics import (by_name, CAMPAIGN_RESULTS, CAMPAIGN_STATUS, CAPTURES, CLOCK,
                                    COMMAND, CONTROLLER_STATUS, CYCLES,
                                    DIAGNOSTICS, ESTIMATES, EVENTS, IDENTIFY_STATUS, JOINT_LOAD,
                                    JOINT_PISTON, JOINT_SPOOL, JOINT_VALVE, LOAD_CELL,
                                    LOCKSTEP_NODE_TOPICS, NODE_TOPICS, NodeTopics, PLANT_STATUS,
                                    PRESSURE_P, PRESSURE_T, PROCEDURE_EVENTS, PROCEDURE_STATUS,
                                    RECORDER_STATUS, REFERENCE, REFERENCE_STATUS,
                                    REFERENCE_TRAJECTORY, STATE, STATION_EVENTS, STATION_STATUS,
                                    Topic, TOPICS)
from ros_ehs_msgs_py.values import (AxisState, Command, Load, NodeStatus, ParameterEstimate,
                                    Pressure, Reference, SafetyEvent)
from ros_ehs_msgs_py.wire import (clock_from_cdr, clock_to_cdr, command_from_cdr, command_to_cdr,
                                  decode_joint_state, float64_array_from_cdr, float64_array_to_cdr,
                                  float64_from_cdr, fluid_pressure_from_cdr, JointStateData,
                                  JointStateEncoder, load_from_cdr, load_to_cdr, pressure_to_cdr,
                                  reference_from_cdr, reference_to_cdr,
                                  reference_trajectory_from_cdr, reference_trajectory_to_cdr,
                                  state_from_cdr, state_to_cdr, wrench_from_cdr)

__all__ = [
    'CAMPAIGN_RESULTS', 'CAMPAIGN_STATUS',
    'CAPTURES', 'CYCLES', 'CYCLE_RECORD',
    'CYCLE_TAPERED', 'CYCLES_LABEL', 'PROCEDURE_EVENTS', 'PROCEDURE_STATUS',
    'cycles_from_bytes', 'cycles_to_bytes', 'fill_procedure_event', 'procedure_event_from_msg',
    'JOINT_LOAD', 'LOAD_CELL', 'Load', 'WRENCH_AXES', 'fill_load', 'load_from_cdr',
    'load_from_msg', 'load_to_cdr', 'wrench_from_cdr',
    'NodeStatus', 'statuses_from_msg', 'CONTROLLER_STATUS', 'IDENTIFY_STATUS', 'PLANT_STATUS',
    'RECORDER_STATUS',
    'REFERENCE_STATUS', 'STATION_EVENTS', 'STATION_STATUS', 'fill_station_event',
    'station_event_from_msg',
    'AxisState', 'CLOCK', 'CLOCK_QOS', 'COMMAND', 'Command', 'DIAGNOSTICS', 'ESTIMATES',
    'EVENTS', 'ParameterEstimate', 'estimate_from_msg', 'fill_estimate',
    'EVENTS_QOS', 'JOINT_PISTON', 'SafetyEvent', 'event_from_msg', 'event_level', 'fill_event',
    'JOINT_SPOOL', 'JOINT_VALVE', 'LOCKSTEP_NODE_TOPICS', 'LOCKSTEP_QOS', 'LOOP_QOS',
    'NODE_TOPICS', 'NodeTopics', 'PRESSURE_P', 'PRESSURE_T', 'Pressure', 'QosSpec', 'RECORD_QOS',
    'REFERENCE', 'REFERENCE_TRAJECTORY', 'Reference', 'STATE', 'TOPICS', 'Topic', 'by_name',
    'JointStateData', 'JointStateEncoder', 'clock_from_cdr', 'clock_to_cdr',
    'command_from_cdr', 'command_to_cdr',
    'decode_joint_state', 'float64_array_from_cdr', 'float64_array_to_cdr', 'float64_from_cdr',
    'fluid_pressure_from_cdr', 'pressure_to_cdr', 'reference_from_cdr', 'reference_to_cdr',
    'reference_trajectory_from_cdr', 'reference_trajectory_to_cdr',
    'state_from_cdr', 'state_to_cdr',
    'command_from_msg', 'empty_msg', 'fill_command', 'fill_pressure', 'fill_reference',
    'fill_reference_trajectory', 'fill_state', 'pressure_from_msg', 'reference_from_msg',
    'reference_trajectory_from_msg', 'stamp_ns', 'state_from_msg',
]
