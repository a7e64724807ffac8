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
The controller node: PID + damping/Stribeck feedforward (:class:`ros_ehs.core.control.Controller`).

It answers every ``state`` message with one ``servo_current`` command stamped with that
state's stamp (so the plant measures the round trip and lock-step stays exact). Gains and
feedforward parameters are ROS parameters declared from the one table with their ranges;
a live change is validated as a whole and rejected with the reason.

Edge-case policy (tested in ``test/test_nodes.py`` and ``test/test_stamps.py``):

* safety (:mod:`ros_ehs.core.control.safety`, docs/safety.md): limit and error detectors run on
  every state, inside the command that answers it; each trip is latched, logged once,
  published on ``events`` and counted in diagnostics; ``~/reset`` (std_srvs/Trigger) clears
  the latches (refused, with the reason, while a detector still trips), ``~/enable``
  (std_srvs/SetBool) turns the hydraulics on (ramp-on from the measured position) or off
  (0 A). In real time a state older than ``feedback_timeout`` (checked every 10 ms) trips
  the feedback detector;
* non-finite position: the feedback detector (default action power_off: 0 A, latched);
  non-finite reference: 0 A and ``fault`` (the PID's policy), until a finite one;
* malformed message (no ``piston`` joint, empty arrays): ignored and counted;
* stamps (any publisher on the bench network can send a ``state``: a bag player, a rig
  driver with another clock, a restarted plant):

  - real time: a state stamped more than ``future_tolerance`` ahead of this node's clock is
    dropped and counted (``future``, in diagnostics), never adopted: one stray stamp an hour
    ahead must not make every true state look out of order;
  - a repeated stamp (lock-step resend): the same command again, no PID update;
  - an older stamp than the last answered, by at most ``EPOCH_PERIODS`` periods (reordering):
    ignored and counted (``out_of_order``);
  - older by more (a restarted plant, a replayed bag, a lock-step plant started again at
    ``start_time``): a new run. The PID and feedforward restart from rest, the lock-step
    reference buffer is cleared, the stamp is answered at once; counted (``epochs``) and
    logged (at most once a second);

* a state older than ``stale_timeout`` on arrival: not used; the held command is repeated;
* no state for ``LOST_FACTOR * stale_timeout`` (checked every 10 ms, real time only): 0 A is
  published once, and the PID restarts from rest when states return. (A plain late state
  is only held: a non-real-time kernel has 5-20 ms hiccups that must not reset the PID.);
* before the first reference: hold the first measured position; between references,
  first-order hold to the state's stamp (``z_ref + v_ref * (t_state - t_ref)``, forward so
  the reference may run slower than the loop, back for one stamped after the state);
  a reference older than ``reference_timeout``: hold its position with zero velocity (logged,
  counted in ``reference_stale``); when references come back, the axis ramps onto them from
  the held position over ``ramp_time`` (a reference node that stalled 0.33 s came back 63 mm
  on, and following it at once saturated the valve);
* ``lockstep``: the references come as ``reference_trajectory`` (the reference node sends
  the coming periods in one message per ``/clock``) into a buffer keyed by stamp (at most
  ``REF_BUFFER`` stamps, oldest dropped first; a used one is dropped at once); a state is
  answered only with the reference of the same stamp, waiting for it if needed, so the loop
  is deterministic; commands go out over the contract's ``LOCKSTEP_QOS`` (reliable) so a
  recorder gets every one.
"""

from __future__ import annotations

import functools
import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from ros_ehs.core.control.feedforward import MODEL_PARAMS
from ros_ehs.core.control.supervised import AxisController
from ros_ehs.core.control.waveforms import first_order_hold
from ros_ehs.core.errors import ParameterError
from ros_ehs.core.params import CONTROL_SPECS, Params, SAFETY_SPECS, spec
from ros_ehs.nodes.loop_stats import Window
from ros_ehs.nodes.options import (declare_options, declare_specs, node_params, Option,
                                   update_options, validate_changes)
from ros_ehs.nodes.ros_common import (diagnostics, EPOCH_PERIODS, ERROR, OK, qos_profile, read_msg,
                                      run, steady_clock, WARN)
from ros_ehs.nodes.scheduling import CPU_AFFINITY, RT_PRIORITY
import ros_ehs_msgs_py as contract
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory

__all__ = ['OPTIONS', 'ControllerNode', 'SPECS', 'main']

#: States missing for this many ``stale_timeout`` mean the plant is gone (see the policy).
LOST_FACTOR = 10

#: ros2_control's forward command controller's input (``<controller>/commands``), relative.
FORWARD_TOPIC = 'servo_valve_controller/commands'

#: Lock-step references kept ahead of the states (stamps; 4 s at 1 kHz).
REF_BUFFER = 4096

#: The parameters the controller declares: its own, the safety layer's and the plant values
#: its feedforward uses.
SPECS = CONTROL_SPECS + SAFETY_SPECS + tuple(spec(n) for n in MODEL_PARAMS)

OPTIONS = (
    Option('rate_hz', 1000.0, 'control period rate [Hz]; must match the plant', 10.0, 5000.0),
    Option('lockstep', False, 'lock-step bench: answer a state only with the reference of '
           'the same stamp; commands over reliable QoS'),
    Option('reference_timeout', 0.1, 'a reference older than this is held at zero velocity; '
           'when references come back the axis ramps onto them over ramp_time [s]', 1.0e-3,
           100.0, read_only=False),
    Option('diagnostics_period', 1.0, 'period of the diagnostics message [s]', 0.05, 60.0),
    Option('future_tolerance', 0.05, 'real time: a state stamped further ahead of this '
           "node's clock is dropped and counted [s]", 1.0e-4, 3600.0, read_only=False),
    Option('start_enabled', True, 'hydraulics on at start (ramp-on from the first measured '
           'position); false: 0 A until ~/enable'),
    Option('state_topic', contract.STATE.name, "sensor_msgs/JointState with the axis's "
           "joint: the contract's `state`, or a rig driver's /joint_states"),
    Option('joint', contract.JOINT_PISTON, "the axis's joint in the state (a rig's own name; "
           'position required, velocity optional)'),
    Option('command_interface', 'joint_state', "joint_state: the contract's servo_current "
           '(JointState, stamped with the state it answers); forward_command: a ros2_control '
           "forward command controller's Float64MultiArray (no header)",
           choices=('joint_state', 'forward_command')),
    Option('command_topic', '', 'where commands go (default: servo_current, or '
           'servo_valve_controller/commands for forward_command)'),
    Option('command_index', 0, "forward_command: this axis's element of the array", 0, 255),
    Option('command_size', 1, "forward_command: length of the array (the controller's "
           'joints; the others get 0 A)', 1, 256),
    Option('command_scale', 1.0, 'forward_command: units per A the driver takes (1000: mA)',
           1.0e-6, 1.0e6),
    RT_PRIORITY,
    CPU_AFFINITY,
)


class ControllerNode(Node):
    """Position controller on the contract topics (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('controller', **kwargs)
        self.opt = declare_options(self, OPTIONS)
        self.rt_priority = int(self.opt['rt_priority'])     # applied by run()
        self.cpu_affinity = int(self.opt['cpu_affinity'])   # applied by run()
        declare_specs(self, SPECS, Params())
        self.params = node_params(self, Params(), SPECS)
        self.dt = 1.0 / float(self.opt['rate_hz'])
        self.axis = AxisController(self.params, self.dt, bool(self.opt['start_enabled']))
        self.ctrl = self.axis.ctrl
        self._meas = (-1, math.nan, math.nan, math.nan)    # newest state: stamp, z, z_dot, F
        self._no_force = False          # dp_gain > 0 and the states carry no force (logged)
        self.lockstep = bool(self.opt['lockstep'])
        # staleness is a wall-clock notion: off under sim time and in lock-step (where the
        # plant waits for us, so nothing can be stale)
        self.wall = not (self.get_parameter('use_sim_time').value or self.lockstep)
        self._limits()
        self._pending: Params | None = None
        self._refs: dict[int, tuple[float, float]] = {}     # insertion-ordered
        self._ref = None                 # latest (z_ref, v_ref, rx time)
        self._ref_stale = False          # held: older than reference_timeout
        self._hold_z: float | None = None
        self._waiting = None             # a state parked until its reference comes
        self._last_stamp = -1
        self._lost = False
        self.counts = dict.fromkeys(('answered', 'bad', 'nonfinite', 'stale', 'out_of_order',
                                     'future', 'epochs', 'repeated', 'state_lost_events',
                                     'param_rejects', 'events', 'reference_stale'), 0)
        self._dt_ns = int(round(self.dt * 1e9))
        self._diag_future = 0
        self.err = Window(2000)
        self.compute = Window(2000)

        self.forward = self.opt['command_interface'] == 'forward_command'
        if self.forward:      # ros2_control's ~/commands: reliable (SystemDefaultsQoS), so
            # a forward command controller's reliable subscription matches
            self._cmd = [0.0] * int(self.opt['command_size'])
            if int(self.opt['command_index']) >= len(self._cmd):
                raise ParameterError(f"`command_index` = {self.opt['command_index']} is not "
                                     f"below `command_size` = {self.opt['command_size']}")
            self.pub_cmd = self.create_publisher(
                Float64MultiArray, self.opt['command_topic'] or FORWARD_TOPIC,
                qos_profile(contract.RECORD_QOS))
        else:
            cmd_qos = qos_profile(contract.COMMAND.qos_in(self.lockstep))
            self.pub_cmd = self.create_publisher(JointState, self.opt['command_topic'] or
                                                 contract.COMMAND.name, cmd_qos)
        joint = self.opt['joint']
        self._read_state = (contract.state_from_cdr if joint == contract.JOINT_PISTON else
                            functools.partial(contract.state_from_cdr, joint=joint))
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              qos_profile(contract.DIAGNOSTICS.qos))
        self.pub_events = self.create_publisher(DiagnosticArray, contract.EVENTS.name,
                                                qos_profile(contract.EVENTS.qos))
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.create_service(SetBool, '~/enable', self._on_enable)
        # raw: the state's CDR bytes are read directly (ros_ehs_msgs_py.wire, the fast path)
        self.create_subscription(JointState, self.opt['state_topic'], self._on_state,
                                 qos_profile(contract.STATE.qos), raw=True)
        self._last_rx = time.monotonic()
        if self.wall:     # a timer, not a QoS deadline: that would need every
            # state publisher (a rig, a bag player) to offer a deadline too
            self.create_timer(0.01, self._check_lost, clock=steady_clock())
        if self.lockstep:
            self.create_subscription(JointTrajectory, contract.REFERENCE_TRAJECTORY.name,
                                     self._on_trajectory,
                                     qos_profile(contract.REFERENCE_TRAJECTORY.qos), raw=True)
        else:
            self.create_subscription(JointState, contract.REFERENCE.name, self._on_reference,
                                     qos_profile(contract.REFERENCE.qos), raw=True)
        self.add_on_set_parameters_callback(self._check_params)
        self.add_post_set_parameters_callback(self._apply_params)
        self.create_timer(float(self.opt['diagnostics_period']), self._diagnose,
                          clock=steady_clock())
        sync = ', reference-synchronised (lock-step)' if self.lockstep else ''
        self.get_logger().info(f'PID + feedforward at {self.opt["rate_hz"]:g} Hz{sync}')

    # -- references --------------------------------------------------------------------------
    def _on_reference(self, data: bytes) -> None:
        r = read_msg(self, contract.reference_from_cdr, data, 'reference')
        if r is None:
            self.counts['bad'] += 1
            return
        self._ref = (r.z_ref, r.v_ref, time.monotonic(), r.stamp_ns)

    def _on_trajectory(self, data: bytes) -> None:
        refs = read_msg(self, contract.reference_trajectory_from_cdr, data,
                        'reference_trajectory')
        if refs is None:
            self.counts['bad'] += 1
            return
        buf = self._refs
        for r in refs:
            buf[r.stamp_ns] = (r.z_ref, r.v_ref)
        while len(buf) > REF_BUFFER:
            del buf[next(iter(buf))]
        w = self._waiting
        if w is not None and w.stamp_ns in buf:
            self._waiting = None
            self._answer(w, *buf.pop(w.stamp_ns))

    def _reference_for(self, s: contract.AxisState):
        if self.lockstep:
            return self._refs.pop(s.stamp_ns, None)
        if self._ref is None:
            if self._hold_z is None and math.isfinite(s.z):
                self._hold_z = s.z
            return (self._hold_z if self._hold_z is not None else math.nan), 0.0
        z, v, rx, stamp = self._ref
        if time.monotonic() - rx > self._ref_timeout:
            if not self._ref_stale:
                self._ref_stale = True
                self.counts['reference_stale'] += 1
                self.get_logger().warning(
                    f'no reference for {self._ref_timeout:g} s: holding its last position')
            return z, 0.0
        if self._ref_stale:        # back, and moved on meanwhile: ramp onto it, no step
            self._ref_stale = False
            self.axis.supervisor.ramp_again()
            self.get_logger().info('the reference is back: ramping onto it from the held '
                                   'position')
        # to the state's instant, forward or back (carried only forward, the demand led the
        # state by up to a reference period, 0.25 mm at 0.25 m/s and 1 kHz, by the random
        # phase of the two nodes' timers: tracking varied 0.055-0.22 mm run to run)
        return first_order_hold(z, v, stamp, s.stamp_ns, self._ref_timeout), v

    # -- states ------------------------------------------------------------------------------
    def _on_state(self, data: bytes) -> None:
        self._last_rx = time.monotonic()
        s = read_msg(self, self._read_state, data, 'state')
        if s is None:
            self.counts['bad'] += 1
            return
        if self.wall:
            # real time: this node's clock is the system clock (time_ns: no Time object)
            age = time.time_ns() - s.stamp_ns
            if age < self._future_ns:
                self.counts['future'] += 1
                self.get_logger().warning(
                    f'dropped a state stamped {-age * 1e-9:.6g} s ahead of this clock',
                    throttle_duration_sec=1.0)
                return
        if s.stamp_ns == self._last_stamp:
            self.counts['repeated'] += 1
            self._publish(s.stamp_ns, self.ctrl.output)
            return
        if s.stamp_ns < self._last_stamp:
            if self._last_stamp - s.stamp_ns <= EPOCH_PERIODS * self._dt_ns:
                self.counts['out_of_order'] += 1
                return
            self._new_epoch(s.stamp_ns)
        if self.wall:
            if age > self._stale_ns:
                self.counts['stale'] += 1
                self._last_stamp = s.stamp_ns
                self._publish(s.stamp_ns, self.ctrl.output)
                return
        ref = self._reference_for(s)
        if ref is None:
            self._waiting = s
            return
        self._answer(s, *ref)

    def _new_epoch(self, stamp_ns: int) -> None:
        """Start a new run at ``stamp_ns``: PID from rest, lock-step references forgotten."""
        back = (self._last_stamp - stamp_ns) * 1e-9
        self.counts['epochs'] += 1
        self.axis.restart()
        self._last_stamp = -1
        self._refs.clear()
        self._waiting = None
        self.get_logger().info(f'new run: the state stamp jumped back {back:.6g} s; PID '
                               f'restarted from rest (run {self.counts["epochs"] + 1})',
                               throttle_duration_sec=1.0)

    def _answer(self, s: contract.AxisState, z_ref: float, v_ref: float) -> None:
        t0 = time.perf_counter()
        if self._lost:
            self._lost = False
            self.ctrl.reset()
            self.get_logger().info('states are back; PID restarted from rest')
        i = self.axis.step(s.stamp_ns, s.z, s.z_dot, s.force, z_ref, v_ref)
        if not (math.isfinite(s.z) and math.isfinite(z_ref) and math.isfinite(v_ref)):
            self.counts['nonfinite'] += 1
            if not self.axis.supervisor.latches['feedback'].tripped:   # else reported once
                self.get_logger().warning('non-finite state or reference: command 0 A',
                                          throttle_duration_sec=1.0)
        elif self.ctrl.force_missing(s.force):
            self.counts['nonfinite'] += 1
            if not self._no_force:
                self._no_force = True
                self.get_logger().error('dp_gain > 0 needs the hydraulic force in each state '
                                        '(effort[0]) and this one has none: command 0 A')
        elif self._no_force and math.isfinite(s.force):
            self._no_force = False
            self.get_logger().info('the hydraulic force is back in the state: delta-P on')
        self._meas = (s.stamp_ns, s.z, s.z_dot, s.force)
        self._last_stamp = s.stamp_ns
        self.counts['answered'] += 1
        self._publish(s.stamp_ns, i)
        if self.axis.events:     # after the command: off the loop's path
            self._report(self.axis.events)
        if math.isfinite(s.z) and math.isfinite(z_ref):
            self.err.add(z_ref - s.z)
        self.compute.add(time.perf_counter() - t0)

    # -- safety ------------------------------------------------------------------------------
    def _report(self, events) -> None:
        """Log each event once, publish it on ``events``, count it."""
        log = self.get_logger()
        ns = self.get_namespace().strip('/') or 'axis'
        for e in events:
            self.counts['events'] += 1
            msg = contract.fill_event(DiagnosticArray(), e, 'controller', ns,
                                      DiagnosticStatus(), KeyValue)
            self.pub_events.publish(msg)
            level = contract.event_level(e)
            text = f'safety {e.kind} {e.detector}: {e.message}' if e.detector else \
                f'safety {e.kind}: {e.message}'
            # rclpy ties a severity to its call site: one call per level
            if level == ERROR:
                log.error(text)
            elif level == WARN:
                log.warning(text)
            else:
                log.info(text)

    def _feedback_age(self) -> float:
        """Return the age of the newest state [s] (0 where staleness is off: lock-step)."""
        return time.monotonic() - self._last_rx if self.wall else 0.0

    def _on_reset(self, request, response):
        stamp, z, z_dot, force = self._meas
        ok, why, ev = self.axis.supervisor.reset(stamp, z, z_dot, force, self._feedback_age())
        if ok:
            self.ctrl.reset()
        self._report([ev])
        response.success, response.message = ok, why
        return response

    def _on_enable(self, request, response):
        stamp = self._meas[0]
        ok, why, ev = self.axis.supervisor.enable(bool(request.data), stamp)
        if ok:
            self.ctrl.reset()
        self._report([ev])
        response.success, response.message = ok, why
        return response

    def _publish(self, stamp_ns: int, i: float) -> None:
        if self.forward:      # no header: the driver applies the newest at its next write
            self._cmd[self.opt['command_index']] = i * self.opt['command_scale']
            self.pub_cmd.publish(contract.float64_array_to_cdr(self._cmd))
            return
        self.pub_cmd.publish(contract.command_to_cdr(contract.Command(stamp_ns, i)))

    def close(self) -> None:
        """Send 0 A once on the way out: a forward command controller holds the last one."""
        if self.forward:
            self._publish(0, 0.0)

    def _check_lost(self) -> None:
        if self._last_stamp >= 0:
            ev = self.axis.supervisor.feedback_lost(self._feedback_age(), self._meas[0])
            if ev:
                self._report(ev)
                if not self.axis.supervisor.enabled or self.axis.supervisor.action == \
                        'power_off':
                    self.ctrl.reset()
                    self._publish(self.get_clock().now().nanoseconds, 0.0)
        limit = LOST_FACTOR * float(self.params['stale_timeout'])
        if self._last_stamp < 0 or self._lost or time.monotonic() - self._last_rx < limit:
            return
        self._lost = True
        self.counts['state_lost_events'] += 1
        self.ctrl.pid.last_u = 0.0
        self._publish(self.get_clock().now().nanoseconds, 0.0)
        ms = LOST_FACTOR * self.params['stale_timeout'] * 1e3
        self.get_logger().warning(f'no state for {ms:g} ms: command 0 A')

    # -- parameters and diagnostics ----------------------------------------------------------
    def _check_params(self, changes):
        res, self._pending = validate_changes(self.params, changes, SPECS, OPTIONS)
        if not res.successful:
            self.counts['param_rejects'] += 1
            self.get_logger().warning(f'parameter change rejected: {res.reason}')
        return res

    def _apply_params(self, changes) -> None:
        new, self._pending = self._pending, None
        if new is not None and new != self.params:
            self.params = new
            self.axis.set_params(new)
            self.get_logger().info('parameters changed: ' + ', '.join(
                f'{p.name}={p.value}' for p in changes))
        update_options(self.opt, changes, OPTIONS)
        self._limits()

    def _limits(self) -> None:
        """Take the live limits the per-state path compares with, in its units, once."""
        self._future_ns = -float(self.opt['future_tolerance']) * 1e9
        self._stale_ns = float(self.params['stale_timeout']) * 1e9
        self._ref_timeout = float(self.opt['reference_timeout'])

    def figures(self) -> dict:
        """Return the figures the diagnostics report."""
        e = self.err.values()
        f = dict(self.counts)
        f.update(tracking_rms_m=float(math.sqrt((e * e).mean())) if e.size else math.nan,
                 tracking_max_m=float(abs(e).max()) if e.size else math.nan,
                 command_a=float(self.ctrl.output), fault=self.ctrl.fault,
                 saturated=self.ctrl.pid.saturated, feedforward_a=float(self.ctrl.last_ff),
                 delta_p_a=float(self.ctrl.dp.last),
                 compute_p99_us=self.compute.pct(99) * 1e6, state_lost=self._lost)
        sup = self.axis.supervisor
        f.update(mode=sup.mode, interlock=sup.action, tripped=','.join(sup.tripped()),
                 **{f'trips_{d}': n for d, n in sup.counts.items()})
        return f

    def _diagnose(self) -> None:
        level, msg = OK, 'running'
        sup = self.axis.supervisor
        act = sup.action
        if act in ('hold', 'stop', 'power_off'):
            level, msg = ERROR, f'interlock {act}: {", ".join(sup.tripped())} (~/reset)'
        elif not sup.enabled:
            level, msg = WARN, 'hydraulics off: 0 A (~/enable)'
        elif act == 'indicate':
            level, msg = WARN, f'limit indicated: {", ".join(sup.tripped())} (~/reset)'
        elif self.ctrl.fault:
            level, msg = ERROR, ('no hydraulic force in the state for dp_gain: command 0 A'
                                 if self.ctrl.force_missing(self._meas[3]) else
                                 'non-finite input: command 0 A')
        elif self._lost:
            level, msg = WARN, 'no state: command 0 A'
        elif self.counts['future'] > self._diag_future:
            level, msg = WARN, 'dropped states stamped ahead of this clock'
        elif self.counts['answered'] == 0:
            level, msg = WARN, 'waiting for states'
        self._diag_future = self.counts['future']
        self.pub_diag.publish(diagnostics(self, contract.CONTROLLER_STATUS, level, msg,
                                          self.figures()))


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs controller``."""
    return run(ControllerNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
