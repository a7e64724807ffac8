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
The reference node: publishes z_ref [m] and v_ref [m/s] (or a force F_ref [N]) on ``reference``.

Trajectories (``kind``): sine (default 0.04 m at 1 Hz, the paper's test), step, chirp,
triangle or haversine (between ``offset`` -+ ``amplitude``, or through a block-loading
sequence ``blocks``), or a CSV file (``csv_path``, columns ``t`` [s] and ``z`` [m]; a drive
file). The generator (:class:`ros_ehs.core.control.reference.ReferenceGenerator`) decides
time zero, new runs, the samples of each period and the amplitude/phase (APC) and
peak/valley (PVC) corrections, and when each window may go out (its docstring states every
rule); this node converts messages, calls it and publishes.

In real time it ticks on a steady timer at ``rate_hz`` and stamps with its own clock.
Under ``use_sim_time`` (lock-step) it answers each ``/clock`` t with the samples at t, t +
1/``rate_hz``, ... up to t + ``preview`` as one ``reference_trajectory``
(trajectory_msgs/JointTrajectory, what the lock-step controller reads), and the sample at t
alone on ``reference`` (for a recorder and plots). ``/clock`` ticks further apart than
``preview`` leave the controller waiting, and the loop then advances only by the plant's
resends: keep ``preview`` above the plant's ``clock_period``. ``/clock`` is read raw (12 CDR
bytes); a malformed one from another client is logged, counted (``bad_clocks``) and answered
with nothing.

``wait_subscribers``, ``wait_loop`` (real time): time zero waits for that many subscribers on
``reference`` and for the plant's diagnostics to report its loop closed (status
``ros_ehs/plant`` at level OK; another node's OK or the plant's WARN do not count). A bench
starts the reference before the plant with both: the trajectory then starts at its beginning
on a closed loop holding position.

``amplitude_phase_control`` (kind sine, or chirp: a sine sweep) and ``peak_valley_control``
(kind triangle or haversine) correct the command each cycle from the measured position
(``state``); they freeze while a safety trip that acts is latched (the controller's
``events``) and while no state comes (docs/controller.md).

``control_mode: force``: the waveform is a force [N], published as each reference's effort
(no position); the corrections take the load cell, from the state (joint ``load_joint``) or
from ``load_topic`` (a WrenchStamped's ``load_axis``).
"""

from __future__ import annotations

import functools
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from ros_ehs.core.control.reference import ReferenceGenerator
from ros_ehs.core.control.waveforms import WAVEFORM
from ros_ehs.core.errors import EhsError
from ros_ehs.core.options import REFERENCE
from ros_ehs.nodes.parameters import declare_settings
from ros_ehs.nodes.ros_common import (diagnostics, OK, PLANT_STATUS, qos_profile, read_msg, run,
                                      steady_clock)
from ros_ehs.nodes.scheduling import REFERENCE_PRIORITY
import ros_ehs_msgs_py as contract
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

__all__ = ['OPTIONS', 'ReferenceNode', 'main']

#: the node's options (declared in :mod:`ros_ehs.core.options`)
OPTIONS = REFERENCE


class ReferenceNode(Node):
    """The reference generator on the contract topics (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('reference', **kwargs)
        self.opt = declare_settings(self, OPTIONS)
        self.cpu_affinity = int(self.opt['cpu_affinity'])   # applied by run()
        values = declare_settings(self, WAVEFORM)
        self.sim_time = bool(self.get_parameter('use_sim_time').value)
        # for run(): the setpoint's source on SCHED_FIFO under the loop, in real time
        self.rt_priority, self.realtime = int(self.opt['rt_priority']), not self.sim_time
        self.auto_priority = REFERENCE_PRIORITY
        self.gen = ReferenceGenerator(values, self.opt, sim_time=self.sim_time)
        # under sim time the reference follows /clock tick by tick (lock-step): every sample
        # counts, so it goes out over the lock-step QoS
        self.pub = self.create_publisher(JointState, contract.REFERENCE.name,
                                         qos_profile(contract.REFERENCE.qos_in(self.sim_time)))
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              qos_profile(contract.DIAGNOSTICS.qos))
        if self.sim_time:
            self.pub_traj = self.create_publisher(
                JointTrajectory, contract.REFERENCE_TRAJECTORY.name,
                qos_profile(contract.REFERENCE_TRAJECTORY.qos))
            # raw: the clock's 12 CDR bytes are read directly (ros_ehs_msgs_py.wire)
            self.create_subscription(Clock, contract.CLOCK.name, self._on_clock,
                                     qos_profile(contract.CLOCK.qos, depth=10), raw=True)
        else:
            self.create_timer(1.0 / float(self.opt['rate_hz']), self._tick,
                              clock=steady_clock())
        # real time, wait_loop: subscribed from the start and kept (1 Hz): a subscription
        # made or destroyed mid-run is a discovery event in every participant of the loop
        if not self.gen.closed:
            self.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self._on_diag,
                                     qos_profile(contract.DIAGNOSTICS.qos))
        self.force = self.opt['control_mode'] == 'force'
        self._read_state = functools.partial(contract.state_from_cdr,
                                             load_joint=self.opt['load_joint'])
        if self.gen.correction is not None:
            # raw: the state's CDR bytes are read directly (ros_ehs_msgs_py.wire); under
            # sim time every state counts, so over the lock-step QoS
            if self.force and self.opt['load_topic']:
                self.create_subscription(WrenchStamped, self.opt['load_topic'], self._on_load,
                                         qos_profile(contract.LOAD_CELL.qos_in(self.sim_time)),
                                         raw=True)
            else:
                self.create_subscription(JointState, contract.STATE.name, self._on_state,
                                         qos_profile(contract.STATE.qos_in(self.sim_time)),
                                         raw=True)
            self.create_subscription(DiagnosticArray, contract.EVENTS.name, self._on_event,
                                     qos_profile(contract.EVENTS.qos))
            if not self.sim_time:       # in lock-step a slow loop is not a lost one
                self.create_timer(0.05, self._watch, clock=steady_clock())
        self.add_on_set_parameters_callback(self._check)
        self.create_timer(float(self.opt['diagnostics_period']), self._diagnose,
                          clock=steady_clock())
        how = 'on /clock' if self.sim_time else f'{self.opt["rate_hz"]:g} Hz'
        self.get_logger().info(self.gen.describe().replace(' reference', f' reference, {how}',
                                                           1))

    def _check(self, changes):
        mine = {p.name: p.value for p in changes if p.name in self.gen.values}
        if not mine:
            return SetParametersResult(successful=True)
        try:
            self.gen.set_waveform(mine)     # a new waveform: its corrections start again
        except EhsError as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    # -- messages in -------------------------------------------------------------------------
    def _on_state(self, data: bytes) -> None:
        s = read_msg(self, self._read_state, data, 'state')
        if s is None:
            return
        self._measured(s.stamp_ns, s.load if self.force else s.z)

    def _on_load(self, data: bytes) -> None:
        r = read_msg(self, self._read_load, data, 'load_cell')
        if r is not None:
            self._measured(r.stamp_ns, r.force)

    def _read_load(self, data: bytes):
        return contract.load_from_cdr(data, self.opt['load_axis'])

    def _measured(self, stamp_ns: int, value: float) -> None:
        for refs in self.gen.state(stamp_ns, value, time.monotonic()):
            self._send_window(refs)
        self._log_notes()

    def _on_event(self, msg: DiagnosticArray) -> None:
        try:
            e = contract.event_from_msg(msg)
        except ValueError:
            return
        self.gen.event(e.kind, e.action)
        self._log_notes()

    def _on_diag(self, msg: DiagnosticArray) -> None:
        if any(st.name == PLANT_STATUS and st.level == bytes([OK]) for st in msg.status):
            self.gen.loop_closed()

    def _on_clock(self, data: bytes) -> None:
        t = read_msg(self, contract.clock_from_cdr, data, '/clock')
        if t is None:
            self.gen.malformed_clock()
            return
        refs = self.gen.clock(t, time.monotonic())
        if refs is not None:
            self._send_window(refs)
        self._log_notes()

    def _watch(self) -> None:
        self.gen.watch(time.monotonic())
        self._log_notes()

    def _tick(self) -> None:
        started = self.gen.started
        r = self.gen.tick(self.get_clock().now().nanoseconds, self.pub.get_subscription_count())
        if r is None:
            return
        self.pub.publish(contract.reference_to_cdr(r))
        if not started:
            self._log_notes()
            self._diagnose()                # started: say so now, not at the next period

    # -- messages out ------------------------------------------------------------------------
    def _send_window(self, refs) -> None:
        self.pub_traj.publish(contract.reference_trajectory_to_cdr(refs))    # serialized
        self.pub.publish(contract.reference_to_cdr(refs[0]))

    def _log_notes(self) -> None:
        notes = self.gen.notes
        while notes:
            level, text = notes.pop(0)
            (self.get_logger().warning if level == 'warning' else
             self.get_logger().info)(text)

    def _diagnose(self) -> None:
        self.pub_diag.publish(diagnostics(self, contract.REFERENCE_STATUS, OK,
                                          self.gen.values['kind'], self.gen.figures()))


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs reference``."""
    return run(ReferenceNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
