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
The controller node: the control loop (:class:`ros_ehs.core.control.loop.ControlLoop`) on a bench.

It answers every ``state`` message with one ``servo_current`` command stamped with that
state's stamp (so the plant measures the round trip and lock-step stays exact). The loop
decides the stamp policy, the reference hold and interpolation, lost states, the limit and
error detectors with their latched actions, ramp-on and delta-P (its docstring states each
rule, and docs/safety.md the safety layer); this node converts messages, calls it and
publishes. Gains and feedforward parameters are ROS parameters declared from the one table
with their ranges; a live change is validated as a whole and rejected with the reason.

* safety events (trips, resets, hydraulics on/off) are published on ``events``, logged once
  and counted in diagnostics; ``~/reset`` (std_srvs/Trigger) clears the latches (refused,
  with the reason, while a detector still trips), ``~/enable`` (std_srvs/SetBool) turns the
  hydraulics on (ramp-on from the measured position) or off (0 A);
* a malformed message (no ``piston`` joint, empty arrays) is ignored and counted;
* in real time a timer checks every 10 ms for lost states (wall clock: off under sim time and
  in lock-step, where the plant waits for this node);
* ``lockstep``: the references come as ``reference_trajectory`` (the reference node sends the
  coming periods in one message per ``/clock``); commands go out over the contract's
  ``LOCKSTEP_QOS`` (reliable) so a recorder gets every one;
* ``command_interface: forward_command``: commands go to a ros2_control forward command
  controller as Float64MultiArray (no header);
* the load cell comes with each state (joint ``load_joint``) or, with ``load_topic``, from a
  WrenchStamped topic (ros2_control's force_torque_sensor_broadcaster; ``load_axis``);
* ``control_mode`` (a parameter, set live through the parameter services like any other)
  switches between displacement, force and specimen protect: a switch the loop refuses (no
  valid load cell, an interlock latched) rejects the parameter change with the reason, and
  both are events on ``events``; when the loop ends force control itself (a specimen break)
  the parameter follows;
* on SIGINT or SIGTERM the node sends 0 A once and no command after it (a forward command
  controller holds the last command it got), then exits within a bounded time, whatever its
  executor does (:func:`ros_ehs.nodes.ros_common.run`).
"""

from __future__ import annotations

import functools
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_ehs.core.control.loop import ControlLoop, Reply
from ros_ehs.core.control.safety import unprotected
from ros_ehs.core.errors import ParameterError
from ros_ehs.core.options import CONTROLLER, CONTROLLER_SPECS
from ros_ehs.core.params import Params
from ros_ehs.nodes.loop_stats import Ring
from ros_ehs.nodes.parameters import (declare_settings, node_params, update_settings,
                                      validate_changes)
from ros_ehs.nodes.ros_common import (diagnostics, ERROR, OK, qos_profile, read_msg,
                                      run, steady_clock, WARN)
import ros_ehs_msgs_py as contract
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory

__all__ = ['OPTIONS', 'ControllerNode', 'SPECS', 'main']

#: ros2_control's forward command controller's input (``<controller>/commands``), relative.
FORWARD_TOPIC = 'servo_valve_controller/commands'

#: The parameters the controller declares (:data:`ros_ehs.core.options.CONTROLLER_SPECS`).
SPECS = CONTROLLER_SPECS

#: the node's options (declared in :mod:`ros_ehs.core.options`)
OPTIONS = CONTROLLER


class ControllerNode(Node):
    """The control loop on the contract topics (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('controller', **kwargs)
        self.opt = declare_settings(self, OPTIONS)
        self.rt_priority = int(self.opt['rt_priority'])     # applied by run()
        self.cpu_affinity = int(self.opt['cpu_affinity'])   # applied by run()
        declare_settings(self, SPECS, Params())
        self.params = node_params(self, Params(), SPECS)
        o = self.opt
        self.lockstep = bool(o['lockstep'])
        # staleness is a wall-clock notion: off under sim time and in lock-step (where the
        # plant waits for us, so nothing can be stale)
        wall = not (self.get_parameter('use_sim_time').value or self.lockstep)
        self.realtime, self.carries_loop = wall, True     # for run()'s automatic placement
        self.loop = ControlLoop(self.params, rate_hz=float(o['rate_hz']), lockstep=self.lockstep,
                                wall=wall, start_enabled=bool(o['start_enabled']),
                                reference_timeout=float(o['reference_timeout']),
                                future_tolerance=float(o['future_tolerance']),
                                load_source='topic' if o['load_topic'] else 'state')
        for why in unprotected(self.params):       # once, at the start
            self.get_logger().warning(why)
        self._pending: Params | None = None
        self.compute = Ring(2000)
        self._stopped = False               # stop(): no command after the safe one
        self._cmd_lock = threading.Lock()
        self.forward = o['command_interface'] == 'forward_command'
        if self.forward:      # ros2_control's ~/commands: reliable (SystemDefaultsQoS), so
            # a forward command controller's reliable subscription matches
            self._cmd = [0.0] * int(o['command_size'])
            if int(o['command_index']) >= len(self._cmd):
                raise ParameterError(f"`command_index` = {o['command_index']} is not below "
                                     f"`command_size` = {o['command_size']}")
            self.pub_cmd = self.create_publisher(Float64MultiArray,
                                                 o['command_topic'] or FORWARD_TOPIC,
                                                 qos_profile(contract.RECORD_QOS))
        else:
            self.pub_cmd = self.create_publisher(
                JointState, o['command_topic'] or contract.COMMAND.name,
                qos_profile(contract.COMMAND.qos_in(self.lockstep)))
        joint, load_joint = o['joint'], o['load_joint']
        self._read_state = (contract.state_from_cdr if (joint, load_joint) == (
            contract.JOINT_PISTON, contract.JOINT_LOAD) else functools.partial(
                contract.state_from_cdr, joint=joint, load_joint=load_joint))
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              qos_profile(contract.DIAGNOSTICS.qos))
        self.pub_events = self.create_publisher(DiagnosticArray, contract.EVENTS.name,
                                                qos_profile(contract.EVENTS.qos))
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.create_service(SetBool, '~/enable', self._on_enable)
        # raw: the state's CDR bytes are read directly (ros_ehs_msgs_py.wire, the fast path)
        self.create_subscription(JointState, o['state_topic'], self._on_state,
                                 qos_profile(contract.STATE.qos), raw=True)
        if o['load_topic']:     # a rig's load cell on its own (ros2_control's broadcaster)
            self.create_subscription(WrenchStamped, o['load_topic'], self._on_load,
                                     qos_profile(contract.LOAD_CELL.qos), raw=True)
        if wall:     # a timer, not a QoS deadline: that would need every state publisher
            # (a rig, a bag player) to offer a deadline too
            self.create_timer(0.01, self._tick, clock=steady_clock())
        if self.lockstep:
            self.create_subscription(JointTrajectory, contract.REFERENCE_TRAJECTORY.name,
                                     self._on_trajectory,
                                     qos_profile(contract.REFERENCE_TRAJECTORY.qos), raw=True)
        else:
            self.create_subscription(JointState, contract.REFERENCE.name, self._on_reference,
                                     qos_profile(contract.REFERENCE.qos), raw=True)
        self.add_on_set_parameters_callback(self._check_params)
        self.add_post_set_parameters_callback(self._apply_params)
        self.create_timer(float(o['diagnostics_period']), self._diagnose, clock=steady_clock())
        sync = ', reference-synchronised (lock-step)' if self.lockstep else ''
        self.get_logger().info(f'PID + feedforward at {o["rate_hz"]:g} Hz{sync}')

    # -- messages in -------------------------------------------------------------------------
    def _on_reference(self, data: bytes) -> None:
        r = read_msg(self, contract.reference_from_cdr, data, 'reference')
        if r is None:
            self.loop.malformed()
            return
        self.loop.reference(r, time.monotonic())

    def _on_trajectory(self, data: bytes) -> None:
        refs = read_msg(self, contract.reference_trajectory_from_cdr, data,
                        'reference_trajectory')
        if refs is None:
            self.loop.malformed()
            return
        self._send(self.loop.trajectory(refs))

    def _on_load(self, data: bytes) -> None:
        r = read_msg(self, self._read_load, data, 'load_cell')
        if r is None:
            self.loop.malformed()
            return
        self._send(self.loop.load(r, time.monotonic()))

    def _read_load(self, data: bytes) -> contract.Load:
        return contract.load_from_cdr(data, self.opt['load_axis'])

    def _on_state(self, data: bytes) -> None:
        now = time.monotonic()
        s = read_msg(self, self._read_state, data, 'state')
        if s is None:
            self.loop.malformed(now)
            return
        t0 = time.perf_counter()
        # real time: this node's clock is the system clock (time_ns: no Time object)
        reply = self.loop.state(s, now, time.time_ns())
        self.compute.add(time.perf_counter() - t0)
        self._send(reply)

    def _tick(self) -> None:
        reply, events = self.loop.tick(time.monotonic(), self.get_clock().now().nanoseconds)
        if reply is not None:
            self._publish(reply.stamp_ns, reply.current)
        self._report(events)

    # -- messages out ------------------------------------------------------------------------
    def _send(self, reply: Reply | None) -> None:
        """Publish a reply's command, then (off the loop's path) its events and the notes."""
        if reply is not None:
            self._publish(reply.stamp_ns, reply.current)
            self._report(reply.events)
            if any(e.kind == 'mode' for e in reply.events):    # the core ended force control
                self._mode_param()
        elif self.loop.notes:
            self._report(())

    def _mode_param(self) -> None:
        """Keep the ``control_mode`` parameter the mode the loop runs in."""
        mode = self.loop.axis.mode
        if self.get_parameter('control_mode').value != mode:
            self.set_parameters([Parameter('control_mode', value=mode)])

    def _publish(self, stamp_ns: int, i: float, last: bool = False) -> None:
        with self._cmd_lock:
            if self._stopped:
                return
            self._stopped = last
            if self.forward:   # no header: the driver applies the newest at its next write
                self._cmd[self.opt['command_index']] = i * self.opt['command_scale']
                self.pub_cmd.publish(contract.float64_array_to_cdr(self._cmd))
                return
            self.pub_cmd.publish(contract.command_to_cdr(contract.Command(stamp_ns, i)))

    def _report(self, events) -> None:
        """Publish each event on ``events`` and log it once; log the loop's notes."""
        log = self.get_logger()
        ns = self.get_namespace().strip('/') or 'axis'
        for e in events:
            msg = contract.fill_event(DiagnosticArray(), e, 'controller', ns,
                                      DiagnosticStatus(), KeyValue)
            self.pub_events.publish(msg)
            text = f'safety {e.kind} {e.detector}: {e.message}' if e.detector else \
                f'safety {e.kind}: {e.message}'
            _log(log, contract.event_level(e), text)
        notes = self.loop.notes
        while notes:
            level, text = notes.pop(0)
            _log(log, {'error': ERROR, 'warning': WARN}.get(level, OK), text)

    # -- operator ----------------------------------------------------------------------------
    def _on_reset(self, request, response):
        ok, why, ev = self.loop.reset(time.monotonic())
        self._report([ev])
        response.success, response.message = ok, why
        return response

    def _on_enable(self, request, response):
        ok, why, ev = self.loop.enable(bool(request.data))
        self._report([ev])
        response.success, response.message = ok, why
        return response

    def stop(self) -> None:
        """
        On the way out, first: send 0 A once, and no command after it.

        A forward command controller holds the last command it got; a driver of the
        contract's commands takes it as the answer to the newest state (our plant's watchdog
        zeroes the valve anyway).
        """
        self._publish(max(self.loop.last_stamp, 0), 0.0, last=True)
        self.get_logger().info('stopping: 0 A sent')

    # -- parameters and diagnostics ----------------------------------------------------------
    def _check_params(self, changes):
        res, self._pending = validate_changes(self.params, changes, SPECS, OPTIONS)
        mode = next((p.value for p in changes if p.name == 'control_mode'), None)
        if res.successful and mode is not None:
            why = self.loop.check_mode(mode)
            if why:
                res = SetParametersResult(successful=False, reason=f'control_mode: {why}')
                self._pending = None
                _, _, ev = self.loop.set_mode(mode)      # refused: its event for the bag
                self._report([ev])
        if not res.successful:
            self.loop.counts['param_rejects'] += 1
            self.get_logger().warning(f'parameter change rejected: {res.reason}')
        return res

    def _apply_params(self, changes) -> None:
        new, self._pending = self._pending, None
        if new is not None and new != self.params:
            self.params = new
            self.loop.set_params(new)
            if new['control_mode'] != self.loop.axis.mode:
                _, _, ev = self.loop.set_mode(str(new['control_mode']))
                self._report([ev])
            self.get_logger().info('parameters changed: ' + ', '.join(
                f'{p.name}={p.value}' for p in changes))
        update_settings(self.opt, changes, OPTIONS)
        self.loop.configure(reference_timeout=float(self.opt['reference_timeout']),
                            future_tolerance=float(self.opt['future_tolerance']))

    def figures(self) -> dict:
        """Return the figures the diagnostics report."""
        return {**self.loop.figures(), 'compute_p99_us': self.compute.pct(99) * 1e6}

    def _diagnose(self) -> None:
        self._report(())
        level, msg = self.loop.diagnosis()
        self.pub_diag.publish(diagnostics(self, contract.CONTROLLER_STATUS, level, msg,
                                          self.figures()))


def _log(log, level: int, text: str) -> None:
    """Log ``text`` at diagnostics ``level`` (rclpy ties a severity to its call site)."""
    if level == ERROR:
        log.error(text)
    elif level == WARN:
        log.warning(text)
    else:
        log.info(text)


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs controller``."""
    return run(ControllerNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
