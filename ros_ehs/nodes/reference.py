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
The reference node: publishes z_ref [m] and v_ref [m/s] on ``reference``.

Trajectories (``kind``): sine (default 0.04 m at 1 Hz, the paper's test), step, chirp,
triangle or haversine (between ``offset`` -+ ``amplitude``, or through a block-loading
sequence ``blocks``), or a CSV file (``csv_path``, columns ``t`` [s] and ``z`` [m]; a drive
file). Time zero is the first tick. In real
time it ticks on a steady timer at ``rate_hz``. Under ``use_sim_time`` (lock-step) it answers
each ``/clock`` t with the samples at t, t + 1/``rate_hz``, ... up to t + ``preview`` as one
``reference_trajectory`` (trajectory_msgs/JointTrajectory, what the lock-step controller
reads), and the sample at t alone on ``reference`` (for a recorder and plots). One message
covers many periods, so the plant needs to publish ``/clock`` only every ``clock_period``
(shorter than ``preview``), and the loop carries two messages per period, as a bare
ping-pong does. After ``duration`` (0: never) it holds the last position with zero velocity.

Stamps: in real time the reference stamps with its own clock and reads none. Under
``use_sim_time`` each ``/clock`` is answered with its whole window, so a resend or a reordered
clock needs no special case (the samples are the same); more than ``EPOCH_PERIODS`` periods
back is a new run (a lock-step plant started again, a replayed bag): the trajectory restarts
from its beginning at that time, logged at most once a second. ``/clock`` ticks further apart
than ``preview`` leave the controller waiting, and the loop then advances only by the plant's
resends (tested): keep ``preview`` above the plant's ``clock_period``. ``/clock`` is read raw
(12 CDR bytes); a malformed one from another client is logged, counted (``bad_clocks`` in
the diagnostics) and answered with nothing (tested).

``wait_subscribers`` (real time): time zero is the first tick at which ``reference`` has that
many subscribers; until then nothing is published. ``wait_loop`` (real time): time zero also
waits for the plant's diagnostics to report its loop closed (status ``ros_ehs/plant`` at
level OK: watchdog armed, not tripped; another node's OK or the plant's WARN do not count,
tested). A bench starts the reference before the plant, so that no participant joins a
running loop, with both: the trajectory then starts at its beginning on a closed loop
holding position, with the controller and the recorder listening, instead of somewhere
mid-stroke on a piston that has not moved yet.

``amplitude_phase_control`` (kind sine, or chirp: a sine sweep): the command's amplitude,
phase and mean are corrected each cycle from the measured position (``state``, joint
``piston``), as a test controller's APC does (:class:`ros_ehs.core.control.apc.
AmplitudePhaseControl`, docs/controller.md); a sweep corrects the fundamental only.
``peak_valley_control`` (kind triangle or haversine): each block's command is corrected so
that its peaks and valleys reach their targets (:class:`ros_ehs.core.control.pvc.
PeakValleyControl`). For both, the corrections freeze, and the command keeps its last
amplitude and phase, while a safety trip that acts (hold, stop, power off: the controller's
``events``) is latched, and while no state has come for ``APC_LOST`` seconds; they resume
after a reset or when states return, without a jump. No cycle that overlaps the controller's
ramp-on is learnt from (``ramp_time``, from time zero and after a reset). A correction starts
``preview`` after the end of the cycle it was learnt from, so no sample already sent changes;
under ``use_sim_time`` a ``/clock`` whose window holds a correction is answered only once the
state that ends its cycle has been measured (on time in lock-step: the plant sends that state
with that clock), which makes the run the in-process loop's to 1e-9 m (tested).
"""

from __future__ import annotations

import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from ros_ehs.core.control.apc import AmplitudePhaseControl
from ros_ehs.core.control.cycles import CycleCorrection
from ros_ehs.core.control.pvc import PeakValleyControl
from ros_ehs.core.control.waveforms import cyclic_blocks, make, WAVEFORM
from ros_ehs.core.errors import ParameterError
from ros_ehs.core.options import REFERENCE
from ros_ehs.nodes.parameters import declare_settings
from ros_ehs.nodes.ros_common import (diagnostics, EPOCH_PERIODS, OK, PLANT_STATUS, qos_profile,
                                      read_msg, run, steady_clock)
import ros_ehs_msgs_py as contract
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

__all__ = ['OPTIONS', 'ReferenceNode', 'main']

#: the node's options (declared in :mod:`ros_ehs.core.options`)
OPTIONS = REFERENCE

#: APC: no state for this long freezes the corrections [s] (real time).
APC_LOST = 0.2
#: APC under sim time: states kept from before the first /clock (time zero's own)
EARLY_STATES = 100


class ReferenceNode(Node):
    """Reference generator (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('reference', **kwargs)
        self.opt = declare_settings(self, OPTIONS)
        self.cpu_affinity = int(self.opt['cpu_affinity'])   # applied by run()
        values = declare_settings(self, WAVEFORM)
        self.traj = make(values, self.opt['csv_path'], self.opt['blocks'])
        self.values = values
        self.correction = self._make_correction(values)
        self._frozen_by: set[str] = set()      # the reasons the APC is frozen
        self._last_state = time.monotonic()
        self._measured_ns = -1          # the newest state stamp the APC has taken
        self._early: list[tuple[int, float]] = []   # states before time zero (sim time)
        self._waiting: list[int] = []   # /clock stamps whose window waits for states
        self.t_first: int | None = None
        self.last_ns = -1
        self.count = 0
        self.bad = 0        # malformed /clock messages ignored
        self.runs = 1
        self.sim_time = bool(self.get_parameter('use_sim_time').value)
        # under sim time the reference follows /clock tick by tick (lock-step): every sample
        # counts, so it goes out over the lock-step QoS
        self.pub = self.create_publisher(JointState, contract.REFERENCE.name,
                                         qos_profile(contract.REFERENCE.qos_in(self.sim_time)))
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              qos_profile(contract.DIAGNOSTICS.qos))
        self._dt_ns = int(round(1e9 / float(self.opt['rate_hz'])))
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
        self.loop_closed = not (self.opt['wait_loop'] and not self.sim_time)
        if not self.loop_closed:
            self.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self._on_diag,
                                     qos_profile(contract.DIAGNOSTICS.qos))
        if self.correction is not None:
            # raw: the state's CDR bytes are read directly (ros_ehs_msgs_py.wire); under
            # sim time every state counts, so over the lock-step QoS
            self.create_subscription(JointState, contract.STATE.name, self._on_state,
                                     qos_profile(contract.STATE.qos_in(self.sim_time)),
                                     raw=True)
            self.create_subscription(DiagnosticArray, contract.EVENTS.name, self._on_event,
                                     qos_profile(contract.EVENTS.qos))
            if not self.sim_time:       # in lock-step a slow loop is not a lost one
                self.create_timer(0.05, self._watch_states, clock=steady_clock())
        self.add_on_set_parameters_callback(self._check)
        self.create_timer(float(self.opt['diagnostics_period']), self._diagnose,
                          clock=steady_clock())
        how = 'on /clock' if self.sim_time else f'{self.opt["rate_hz"]:g} Hz'
        corr = {type(None): '', AmplitudePhaseControl: ', amplitude/phase control',
                PeakValleyControl: ', peak/valley control'}[type(self.correction)]
        self.get_logger().info(f'{values["kind"]} reference, {how}{corr}')

    def _make_correction(self, values: dict) -> CycleCorrection | None:
        """Return the cycle-by-cycle correction the options ask for (APC, PVC), or None."""
        apc, pvc = self.opt['amplitude_phase_control'], self.opt['peak_valley_control']
        if not (apc or pvc):
            return None
        if apc and pvc:
            raise ParameterError('amplitude_phase_control corrects a sine, peak_valley_control a '
                                 'triangle or haversine: choose one')
        kinds = ('sine', 'chirp') if apc else ('triangle', 'haversine')
        name = 'amplitude_phase_control' if apc else 'peak_valley_control'
        kind = values['kind']
        if kind not in kinds:
            raise ParameterError(f'{name} corrects a {" or ".join(kinds)}: `kind` is '
                                 f'{kind!r}')
        preview = float(self.opt['preview'])
        f = float(values['frequency'])
        if kind == 'chirp':         # the sweep's shortest period bounds the preview
            f = max(float(values['f0']), float(values['f1']))
        share = 1.0 if apc else 0.5
        if preview * f >= share:
            raise ParameterError(f'{name}: `preview` = {preview:g} s must be under '
                                 f'{"the" if apc else "half the"} period ({1 / f:g} s)')
        # a correction starts `preview` after the cycle it was learnt from: every sample
        # already sent stays as it was sent, and under sim time each window can wait for
        # the states it depends on (in process: the same latency gives the same numbers)
        ramp = float(self.opt['ramp_time'])
        if apc:
            if kind == 'chirp':         # a sweep: the fundamental only (docs/controller.md)
                return AmplitudePhaseControl(float(values['amplitude']),
                                             float(values['f0']), 0.0,
                                             sweep_to=float(values['f1']),
                                             sweep_time=float(values['chirp_duration']),
                                             latency=preview, learn_from=ramp)
            return AmplitudePhaseControl(float(values['amplitude']), float(values['frequency']),
                                         float(values['offset']),
                                         harmonics=int(self.opt['apc_harmonics']),
                                         latency=preview, learn_from=ramp)
        return PeakValleyControl(cyclic_blocks(values, self.opt['blocks']), f, values['kind'],
                                 latency=preview, learn_from=ramp)

    def _check(self, changes):
        new = dict(self.values)
        new.update({p.name: p.value for p in changes if p.name in new})
        try:
            traj = make(new, self.opt['csv_path'], self.opt['blocks'])
            corr = self._make_correction(new) if self.correction is not None else None
        except (ParameterError, ValueError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        self.traj, self.values = traj, new
        if corr is not None:
            self.correction = corr          # a new waveform: its corrections start again
        return SetParametersResult(successful=True)

    # -- amplitude/phase and peak/valley control ------------------------------------------
    def _freeze(self, reason: str, on: bool) -> None:
        was = bool(self._frozen_by)
        (self._frozen_by.add if on else self._frozen_by.discard)(reason)
        if bool(self._frozen_by) != was:
            self.correction.freeze(bool(self._frozen_by))
            self.get_logger().info(('APC frozen: ' if self._frozen_by else 'APC resumed: ') +
                                   reason)

    def _on_state(self, data: bytes) -> None:
        s = read_msg(self, contract.state_from_cdr, data, 'state')
        if s is None:
            return
        self._last_state = time.monotonic()
        if 'states lost' in self._frozen_by:
            self._freeze('states lost', False)
        if self.t_first is None:
            if self.sim_time and len(self._early) < EARLY_STATES:    # time zero's own state
                self._early.append((s.stamp_ns, s.z))
            return
        self._measure(s.stamp_ns, s.z)
        if self._waiting:
            self._answer_waiting()

    def _measure(self, stamp_ns: int, z: float) -> None:
        # once per stamp, in order: a lock-step resend is the same state again
        if stamp_ns <= self._measured_ns or stamp_ns < self.t_first:
            return
        self._measured_ns = stamp_ns
        self.correction.measure((stamp_ns - self.t_first) * 1e-9, z)

    def _ready(self, t_ns: int) -> bool:
        """Whether the APC has measured every state the window of clock ``t_ns`` depends on."""
        if self.correction is None:
            return True
        # the samples up to t + preview use corrections from the cycles that ended by
        # t + preview - latency = t: their ends must have been measured
        end = (t_ns - self.t_first) * 1e-9
        boundary = self.correction.cycle_start(self.correction.cycle_of(end))
        return boundary <= 0.0 or self._measured_ns >= self.t_first + int(
            round(boundary * 1e9)) - 1000

    def _answer_waiting(self) -> None:
        while self._waiting and self._ready(self._waiting[0]):
            self._answer(self._waiting.pop(0))

    def _watch_states(self) -> None:
        if self.t_first is not None and time.monotonic() - self._last_state > APC_LOST:
            self._freeze('states lost', True)

    def _on_event(self, msg: DiagnosticArray) -> None:
        try:
            e = contract.event_from_msg(msg)
        except ValueError:
            return
        if e.kind == 'trip' and e.action in ('hold', 'stop', 'power_off'):
            self._freeze('safety trip', True)
        elif e.kind in ('reset', 'enabled'):
            if 'safety trip' in self._frozen_by and self.t_first is not None:
                # the controller ramps onto the trajectory again: not learnt from
                self.correction.learn_from = (self.last_ns - self.t_first) * 1e-9 + float(
                    self.opt['ramp_time'])
            self._freeze('safety trip', False)

    def _on_clock(self, data: bytes) -> None:
        # Answer clock t with the whole window [t, t + preview] (at least t + one period):
        # the controller then has the coming periods before their states arrive. A resend
        # or a reordered clock gets its window again: the same samples, so no special case.
        t = read_msg(self, contract.clock_from_cdr, data, '/clock')
        if t is None:
            self.bad += 1
            return
        if t < self.last_ns - EPOCH_PERIODS * self._dt_ns:   # /clock went back: a new run
            self.runs += 1
            self.get_logger().info(f'new run: /clock jumped back {(self.last_ns - t) * 1e-9:.6g}'
                                   f' s; trajectory from its start (run {self.runs})',
                                   throttle_duration_sec=1.0)
            self.t_first = None
            if self.correction is not None:         # a new run: its corrections start again
                self.correction = self._make_correction(self.values)
                self._measured_ns, self._waiting = -1, []
        if self.t_first is None or t < self.t_first:
            self.t_first = t
            if self.correction is not None:
                early, self._early = self._early, []
                for stamp, z in sorted(early):
                    self._measure(stamp, z)
        self.last_ns = t
        if not self._ready(t):            # the states it depends on are on their way
            if t not in self._waiting:
                self._waiting.append(t)
            return
        self._answer(t)

    def _answer(self, t: int) -> None:
        n = max(1, int(float(self.opt['preview']) * 1e9 // self._dt_ns))
        stamps = np.arange(n + 1, dtype=np.int64) * self._dt_ns + t
        z, v = self._sample(stamps)
        refs = [contract.Reference(int(st), float(zz), float(vv))
                for st, zz, vv in zip(stamps, z, v)]
        self.pub_traj.publish(contract.reference_trajectory_to_cdr(refs))    # serialized
        self.pub.publish(contract.reference_to_cdr(refs[0]))
        self.count += 1

    def _on_diag(self, msg: DiagnosticArray) -> None:
        if any(st.name == PLANT_STATUS and st.level == bytes([OK]) for st in msg.status):
            self.loop_closed = True

    def _tick(self) -> None:
        if self.t_first is None:
            need = int(self.opt['wait_subscribers'])
            have = self.pub.get_subscription_count()
            if have < need or not self.loop_closed:
                return
            if need or self.opt['wait_loop']:
                self.get_logger().info(
                    f'time zero: {have} subscriber(s) on {contract.REFERENCE.name}' +
                    (', the plant reports its loop closed' if self.opt['wait_loop'] else ''))
            self._publish(self.get_clock().now().nanoseconds)
            self._diagnose()                # started: say so now, not at the next period
            return
        self._publish(self.get_clock().now().nanoseconds)

    def _sample(self, stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return z_ref [m] and v_ref [m/s] at ``stamps_ns`` (held after ``duration``)."""
        t = (stamps_ns - self.t_first) * 1e-9
        dur = float(self.opt['duration'])
        traj = self.traj if self.correction is None else self._corrected_samples
        if dur <= 0:
            return traj(t)
        hold = t > dur
        z, v = traj(np.minimum(t, dur))
        return z, np.where(hold, 0.0, v)

    def _corrected_samples(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        zv = [self.correction.reference(float(x)) for x in np.atleast_1d(t)]
        return np.array([a for a, _ in zv]), np.array([b for _, b in zv])

    def _publish(self, stamp_ns: int) -> None:
        if self.t_first is None:
            self.t_first = stamp_ns
        z, v = self._sample(np.array([stamp_ns], dtype=np.int64))
        self.pub.publish(contract.reference_to_cdr(contract.Reference(stamp_ns, float(z[0]),
                                                                      float(v[0]))))
        self.last_ns = stamp_ns
        self.count += 1

    def _diagnose(self) -> None:
        t = 0.0 if self.t_first is None else (self.last_ns - self.t_first) * 1e-9
        values = {'started': self.t_first is not None, 'published': self.count, 'time_s': t,
                  'bad_clocks': self.bad}
        if isinstance(self.correction, PeakValleyControl):
            last = self.correction.history[-1] if self.correction.history else {}
            values.update(pvc_cycles=len(self.correction.history),
                          pvc_error=float(last.get('error', float('nan'))),
                          pvc_converged=self.correction.converged_at is not None,
                          pvc_frozen=','.join(sorted(self._frozen_by)))
        elif self.correction is not None:
            last = self.correction.history[-1] if self.correction.history else {}
            values.update(apc_cycles=self.correction.cycles,
                          apc_amp_ratio=float(last.get('amp_ratio', float('nan'))),
                          apc_phase_deg=float(last.get('phase_deg', float('nan'))),
                          apc_harmonics_pct=float(last.get('harmonics_pct', float('nan'))),
                          apc_converged=self.correction.converged_at is not None,
                          apc_frozen=','.join(sorted(self._frozen_by)))
        self.pub_diag.publish(diagnostics(self, contract.REFERENCE_STATUS, OK, self.values['kind'],
                                          values))


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs reference``."""
    return run(ReferenceNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
