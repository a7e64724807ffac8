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
"""The contract's topics: names (relative), message types, content and units, QoS; joint names."""

from __future__ import annotations

from typing import NamedTuple

from ros_ehs_msgs_py.qos import (CLOCK_QOS, EVENTS_QOS, LOCKSTEP_QOS, LOOP_QOS, QosSpec,
                                 RECORD_QOS)

__all__ = ['CLOCK', 'COMMAND', 'DIAGNOSTICS', 'ESTIMATES', 'EVENTS', 'JOINT_LOAD',
           'JOINT_PISTON', 'JOINT_SPOOL', 'JOINT_VALVE', 'LOAD_CELL',
           'LOCKSTEP_NODE_TOPICS', 'NODE_TOPICS', 'NodeTopics', 'PRESSURE_P', 'PRESSURE_T',
           'REFERENCE', 'REFERENCE_TRAJECTORY', 'STATE', 'TOPICS', 'Topic', 'by_name',
           'CONTROLLER_STATUS', 'IDENTIFY_STATUS', 'PLANT_STATUS', 'RECORDER_STATUS',
           'REFERENCE_STATUS', 'STATION_EVENTS', 'STATION_STATUS', 'CAMPAIGN_RESULTS',
           'CAMPAIGN_STATUS']

JOINT_PISTON = 'piston'
JOINT_SPOOL = 'spool'
JOINT_VALVE = 'servo_valve'
JOINT_LOAD = 'load_cell'

# The nodes' status names in ``diagnostics`` and the readiness each reports there (what a
# supervisor, a reference with ``wait_loop`` or an operator's tool waits on; never log text):
#: level OK once its loop is closed: in real time the watchdog armed by a first command and not
#: tripped, in lock-step stepping; message ``lock-step run complete`` when a lock-step run of
#: ``duration`` has ended.
PLANT_STATUS = 'ros_ehs/plant'
#: values ``recording`` (the topics it subscribed to and writes, comma-separated absolute
#: names) and ``matched`` (those whose subscription has matched a publisher); level ERROR with
#: the reason when it stopped recording (the bag stays readable).
RECORDER_STATUS = 'ros_ehs/recorder'
#: value ``started``: ``True`` from the trajectory's time zero on.
REFERENCE_STATUS = 'ros_ehs/reference'
#: the loop's tracking and the safety layer's state.
CONTROLLER_STATUS = 'ros_ehs/controller'
#: the live identify node: values ``subscribed`` (the topics it takes, comma-separated),
#: ``states``, ``refits``, ``pushes``, ``refused``, ``busy`` (a refit runs).
IDENTIFY_STATUS = 'ros_ehs/identify'
#: the procedure node: level OK (WARN interrupted or held, ERROR failed or a checkpoint that
#: cannot be written); message the state; values state, step, step_index, step_cycles,
#: total_cycles, time_to_go_s, result, reason, failed_at, checkpoint (the file), file,
#: controller_mode (the controller's, once read: '' until then, when a start or a resume is
#: refused; wait for it).
PROCEDURE_STATUS = 'ros_ehs/procedure'
#: the operator's station: level OK serving (WARN: the controller not heard); values url,
#: pages (open pages), updates_per_s (frames sent to the pages), actions, refused.
STATION_STATUS = 'ros_ehs/station'
#: the campaign node: level OK (WARN: the campaign has ended; ERROR: the store cannot be
#: written); message what it waits for; values state (``ready``: ~/next gives a specimen;
#: ``under_way``: a specimen's test; ``ended``), specimen, level, tested, failed, run_out,
#: invalid, next_level, verdict (why it ended, or ''), store, name, unit (the levels': N or m),
#: run_out_cycles (the plan's run-out count), protect (what ~/next asked of the controller for
#: the coupon under way's installation: on (specimen protect switched on), asked, refused:
#: why, not set: why; off with no coupon under way), fit_a, fit_k, fit_s (the S-N fit so far,
#: Basquin log10 N = a - k log10 S with scatter s decades; nan before three failures at two
#: levels).
CAMPAIGN_STATUS = 'ros_ehs/campaign'


class Topic(NamedTuple):
    """One topic of the contract."""

    name: str
    msg_type: str
    content: str
    qos: QosSpec = LOOP_QOS

    def qos_in(self, lockstep: bool) -> QosSpec:
        """Return this topic's QoS in real time or lock-step (best-effort topics turn reliable)."""
        if lockstep and self.qos.reliability == 'best_effort':
            return LOCKSTEP_QOS
        return self.qos


REFERENCE = Topic('reference', 'sensor_msgs/msg/JointState',
                  'joint `piston`: position z_ref [m], velocity [m/s]; effort = the force '
                  'reference F_ref [N] when there is one (force control)')
STATE = Topic('state', 'sensor_msgs/msg/JointState',
              '`piston`: z [m], z_dot [m/s], effort = hydraulic force [N]; `spool`: x [m]; '
              '`servo_valve` (plant node): effort = current applied over the period [A]; '
              '`load_cell` (plant node): effort = the specimen force the load cell reads [N]')
LOAD_CELL = Topic('load_cell', 'geometry_msgs/msg/WrenchStamped',
                  "the specimen force [N] on wrench.force.z, tension positive (as ros2_control's "
                  'force_torque_sensor_broadcaster publishes a sensor), stamped as the state')
PRESSURE_P = Topic('pressure/chamber_p', 'sensor_msgs/msg/FluidPressure',
                   'chamber P pressure [Pa]')
PRESSURE_T = Topic('pressure/chamber_t', 'sensor_msgs/msg/FluidPressure',
                   'chamber T pressure [Pa]')
COMMAND = Topic('servo_current', 'sensor_msgs/msg/JointState',
                'joint `servo_valve`: effort = i [A]')
DIAGNOSTICS = Topic('diagnostics', 'diagnostic_msgs/msg/DiagnosticArray',
                    'loop timing, tracking error, watchdog', RECORD_QOS)
EVENTS = Topic('events', 'diagnostic_msgs/msg/DiagnosticArray',
               'safety events of the controller, one status each: name '
               '`ros_ehs/controller/<detector or kind>`, level, message; values kind, '
               'detector, value, limit, unit, action, stamp_ns (the state it happened on)',
               EVENTS_QOS)
ESTIMATES = Topic('parameter_estimates', 'diagnostic_msgs/msg/DiagnosticArray',
                  'live identification, one status per refit: name '
                  '`ros_ehs/identify/estimate`, level OK (adequate) or WARN (not), message '
                  'the verdict; values `<parameter>` and `<parameter>.stderr` (SI), adequate, '
                  "pushed, reason, window_s, wall_s, iterations, failed_rules (the verdict's "
                  'rules it failed, comma-separated: `rate`, `agreement:F_cc`...; absent from '
                  'a writer before it)', EVENTS_QOS)
CLOCK = Topic('/clock', 'rosgraph_msgs/msg/Clock',
              'published by the plant in lock-step mode', CLOCK_QOS)
REFERENCE_TRAJECTORY = Topic(
    'reference_trajectory', 'trajectory_msgs/msg/JointTrajectory',
    'lock-step (reference under use_sim_time): the coming periods in one message, joint '
    '`piston`: positions z_ref [m], velocities v_ref [m/s], effort F_ref [N] when there is '
    'one, each at header.stamp + time_from_start', LOCKSTEP_QOS)

PROCEDURE_EVENTS = Topic(
    'procedure/events', 'diagnostic_msgs/msg/DiagnosticArray',
    'the events of the procedure, one status each: name `ros_ehs/procedure/<kind>` (started, '
    'step, step_end, held, interrupted, restored, running, failure, detector, run_out, '
    'stopping, finished, ...), level, message; values kind, what, value, total_cycles, step, '
    'stamp_ns', EVENTS_QOS)
CYCLES = Topic(
    'procedure/cycles', 'std_msgs/msg/UInt8MultiArray',
    'the extremes of every counted cycle, packed: records of CYCLE_RECORD (40 bytes: count, '
    'step, flags (1: tapered), end stamp [ns], command hi/lo [m or N], z hi/lo [m], load '
    'hi/lo [N]), '
    'a batch a message; layout.dim[0] label `ros_ehs_cycle_v1`, size the records, stride 40',
    EVENTS_QOS)
CAPTURES = Topic(
    'procedure/captures', 'std_msgs/msg/Float64MultiArray',
    'a full cycle at a log-spaced count (1, 2, 5, 10, 20, ...): rows t [s from the start of '
    'the cycle], command, z [m], load [N]; layout.dim[0] label `cycle <count>` size 4, dim[1] '
    'the samples', EVENTS_QOS)

STATION_EVENTS = Topic(
    'station/events', 'diagnostic_msgs/msg/DiagnosticArray',
    "every operator's action at the station, one status each: name "
    '`ros_ehs/station/<action>` (reset, enable, disable, start, hold, resume, stop), level OK '
    '(done) or WARN (refused or not answered), message the answer; values action, origin (the '
    "page's address and browser), result, reason", EVENTS_QOS)

CAMPAIGN_RESULTS = Topic(
    'campaign/results', 'diagnostic_msgs/msg/DiagnosticArray',
    'each specimen the campaign node recorded in its store (at its start, those the store '
    'holds already: one record per specimen, the newest, is what a reader keeps), one status '
    'each: name '
    '`ros_ehs/campaign/<specimen>`, level OK (failed or run out) or WARN (invalid), message '
    'the result and its reason; values specimen, level, result, cycles, reason, peak, valley, '
    'mean, amplitude, r_ratio, started, ended', EVENTS_QOS)

TOPICS = (REFERENCE, STATE, LOAD_CELL, PRESSURE_P, PRESSURE_T, COMMAND, DIAGNOSTICS, EVENTS,
          ESTIMATES, CLOCK, REFERENCE_TRAJECTORY, PROCEDURE_EVENTS, CYCLES, CAPTURES,
          STATION_EVENTS, CAMPAIGN_RESULTS)


class NodeTopics(NamedTuple):
    """The contract topics a node publishes and subscribes (its part of the contract)."""

    publishes: tuple[Topic, ...]
    subscribes: tuple[Topic, ...]


#: What each loop node creates in its default (real-time) mode.
NODE_TOPICS = {
    'plant': NodeTopics((STATE, LOAD_CELL, PRESSURE_P, PRESSURE_T, DIAGNOSTICS), (COMMAND,)),
    'controller': NodeTopics((COMMAND, DIAGNOSTICS, EVENTS), (STATE, REFERENCE)),
    'reference': NodeTopics((REFERENCE, DIAGNOSTICS), ()),
    'procedure': NodeTopics((REFERENCE, DIAGNOSTICS, PROCEDURE_EVENTS, CYCLES, CAPTURES),
                            (STATE, EVENTS, ESTIMATES)),
    'station': NodeTopics((DIAGNOSTICS, STATION_EVENTS),
                          (STATE, REFERENCE, DIAGNOSTICS, EVENTS, PROCEDURE_EVENTS, ESTIMATES,
                           CAMPAIGN_RESULTS)),
    'campaign': NodeTopics((DIAGNOSTICS, CAMPAIGN_RESULTS), (DIAGNOSTICS, CYCLES)),
}

#: The same in lock-step (plant ``mode: lockstep``, controller ``lockstep: true``, reference
#: under ``use_sim_time``): the plant publishes CLOCK, the reference follows it and sends the
#: coming periods as one REFERENCE_TRAJECTORY, which is what the controller reads.
LOCKSTEP_NODE_TOPICS = {
    'plant': NodeTopics((STATE, LOAD_CELL, PRESSURE_P, PRESSURE_T, DIAGNOSTICS, CLOCK),
                        (COMMAND,)),
    'controller': NodeTopics((COMMAND, DIAGNOSTICS, EVENTS), (STATE, REFERENCE_TRAJECTORY)),
    'reference': NodeTopics((REFERENCE, REFERENCE_TRAJECTORY, DIAGNOSTICS), (CLOCK,)),
    'procedure': NodeTopics((REFERENCE, REFERENCE_TRAJECTORY, DIAGNOSTICS, PROCEDURE_EVENTS,
                             CYCLES, CAPTURES), (CLOCK, STATE, EVENTS, ESTIMATES)),
}


def by_name(name: str) -> Topic:
    """Return the contract topic called ``name`` (leading ``/`` ignored except ``/clock``)."""
    for t in TOPICS:
        if name in (t.name, '/' + t.name):
            return t
    raise KeyError(f'{name!r} is not a contract topic; known: {[t.name for t in TOPICS]}')
