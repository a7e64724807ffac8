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
The procedure node: runs a test from a procedure file through the reference and the controller.

``ros2 run ros_ehs procedure --ros-args -p file:=test.yaml``. It takes the reference node's
place: it publishes ``reference`` (and under ``use_sim_time`` answers each ``/clock`` with a
``reference_trajectory`` window, as the reference node does), so every step goes through the
controller and its limit detectors. The rules are
:class:`~ros_ehs.core.procedure.runner.ProcedureRunner`'s (docs/procedures.md); this node
decodes, calls and publishes:

* in: ``state`` (the piston and, joint ``load_joint``, the load cell; or ``load_topic``),
  the controller's ``events`` (an acting trip interrupts the test, the specimen break fails
  it), ``/clock`` under sim time;
* out: ``reference`` (and ``reference_trajectory``), ``procedure/events`` (every state change,
  step, detector and failure), ``procedure/cycles`` (each counted cycle's extremes, a
  40-byte record a cycle, in batches of 10 cycles or 1 s, at a state change and at the end),
  ``procedure/captures`` (full cycles at 1, 2, 5, 10, ...), and its status
  ``ros_ehs/procedure`` in ``diagnostics``;
* services ``~/start``, ``~/hold``, ``~/resume``, ``~/stop`` (std_srvs/Trigger: success and
  the reason); a step in the other control mode sets the controller's ``control_mode``
  through its parameter service (under sim time the window answering ``/clock`` t goes out
  once state t is measured, and ends at the switch's stamp: the lock-step loop waits at the
  next state, the switch is sent then, and the window goes on from there once answered, so
  the switch lands at the same state in every run);
* before the first start it reads the controller's ``control_mode`` and the rig's values it
  holds (:data:`~ros_ehs.core.procedure.envelope.RIG_NAMES`, nominal or identified) through
  its ``get_parameters``; a start or a resume of a procedure that rig cannot follow is
  refused, each step named with the limit it breaks;
* the checkpoint (``checkpoint``) is rewritten atomically at every counted cycle, every state
  change and every 10 s of the stamps, off the executor's thread (the newest wins), with the
  cycle records not yet published and those published in the last ``RECENT_S`` (a recorder
  killed with them in memory loses them). Started with a checkpoint on disk, the test
  comes back ``interrupted`` at its step and count (plus the cycles ``recover_bag`` holds
  beyond it) and waits for ``~/resume``; a checkpoint of a finished test is renamed
  ``<checkpoint>.finished_<time>.json`` and a new test begins.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
import queue
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from rcl_interfaces.msg import ParameterType, SetParametersResult
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.node import Node
from ros_ehs.core.errors import InputError
from ros_ehs.core.options import PROCEDURE
from ros_ehs.core.params import load_yaml
from ros_ehs.core.procedure.envelope import require_envelope, RIG_NAMES
from ros_ehs.core.procedure.runner import ProcedureRunner
from ros_ehs.core.procedure.spec import load_procedure
from ros_ehs.data.checkpoint import resume_point, write_checkpoint
from ros_ehs.data.fatigue import read_cycles
from ros_ehs.nodes.parameters import declare_settings
from ros_ehs.nodes.ros_common import (diagnostics, ERROR, OK, qos_profile, read_msg, run,
                                      set_parameters_request, steady_clock, WARN)
from ros_ehs.nodes.scheduling import REFERENCE_PRIORITY
import ros_ehs_msgs_py as contract
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, UInt8MultiArray
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

__all__ = ['OPTIONS', 'ProcedureNode', 'main', 'recovered_total']

#: the node's options (declared in :mod:`ros_ehs.core.options`)
OPTIONS = PROCEDURE
_LEVEL = {'failure': ERROR, 'interrupted': WARN, 'held': WARN, 'detector': WARN}
#: cycle records go out in batches of this many, or older than CYCLES_BATCH_NS, or at a state
#: change
CYCLES_BATCH = 10
#: a control mode switch unanswered this long [s] is asked again (three times at most)
MODE_RESEND = 5.0
CYCLES_BATCH_NS = 1_000_000_000
#: how long records already published stay in the checkpoint [s]: a recorder holds what it
#: received up to its flush_period (50 ms) in memory, and one killed then loses it; the
#: restarted node publishes them again, and the readers keep each count once
RECENT_S = 2.0
#: how long :meth:`ProcedureNode.close` waits for a callback still running [s] (an executor
#: that did not return in time: ``ros_common.run`` closes the node anyway)
CLOSE_WAIT = 1.0


def _guarded(callback):
    """Run a callback under the node's lock, and not at all once the node has closed."""
    @functools.wraps(callback)
    def guarded(self, *args):
        with self._lock:
            if self._closed:
                return None
            return callback(self, *args)
    return guarded


def recovered_total(bag: str) -> int | None:
    """Return the highest cycle count a bag's ``procedure/cycles`` holds (None: none there)."""
    table = read_cycles(bag)
    return int(table[:, 0].max()) if len(table) else None


class _CheckpointWriter:
    """Write the newest checkpoint on a thread of its own (an fsync takes milliseconds)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.written = 0
        self.error = ''
        self.last_s = 0.0
        self._q: queue.Queue = queue.Queue()
        self._t = threading.Thread(target=self._run, name='ehs-checkpoint', daemon=True)
        self._t.start()

    def put(self, state: dict) -> None:
        self._q.put(state)

    def _run(self) -> None:
        while True:
            state = self._q.get()
            if state is None:
                return
            while not self._q.empty():          # only the newest matters
                nxt = self._q.get()
                if nxt is None:
                    self._write(state)
                    return
                state = nxt
            self._write(state)

    def _write(self, state: dict) -> None:
        t0 = time.perf_counter()
        try:
            write_checkpoint(self.path, state)
            self.written += 1
            self.error = ''
        except OSError as err:
            self.error = f'cannot write the checkpoint {str(self.path)!r}: {err}'
        self.last_s = time.perf_counter() - t0

    def close(self, timeout: float = 5.0) -> None:
        self._q.put(None)
        self._t.join(timeout)


class ProcedureNode(Node):
    """A procedure file run on the contract topics (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('procedure', **kwargs)
        self.opt = declare_settings(self, OPTIONS)
        self.cpu_affinity = int(self.opt['cpu_affinity'])   # applied by run()
        if not self.opt['file']:
            raise InputError('no procedure: give `file` (-p file:=test.yaml)')
        if not self.opt['rig_params']:
            self.get_logger().info("no rig_params: the procedure is checked against the rig's "
                                   'parameters the controller gives, at start')
        self.sim_time = bool(self.get_parameter('use_sim_time').value)
        # for run(): the setpoint's source on SCHED_FIFO under the loop, in real time
        self.rt_priority, self.realtime = int(self.opt['rt_priority']), not self.sim_time
        self.auto_priority = REFERENCE_PRIORITY
        rate = float(self.opt['rate_hz'])
        self.dt_ns = int(round(1e9 / rate))
        self.preview_ns = int(round(float(self.opt['preview']) * 1e9))
        self.procedure, self.runner, self.cp_path = self._open(self.opt['file'],
                                                               self.opt['checkpoint'])
        self._rows: list[tuple] = []          # cycle records not yet published
        self._recent: list[tuple[float, list]] = []   # (monotonic [s], rows) published lately
        # the callbacks and close() change the runner under it; reentrant: a future already
        # done runs its callback inside the call that adds it
        self._lock = threading.RLock()
        self._closed = False
        restored = self._restore()
        self.writer = _CheckpointWriter(self.cp_path)
        self.pub = self.create_publisher(JointState, contract.REFERENCE.name,
                                         qos_profile(contract.REFERENCE.qos_in(self.sim_time)))
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              qos_profile(contract.DIAGNOSTICS.qos))
        self.pub_events = self.create_publisher(DiagnosticArray, contract.PROCEDURE_EVENTS.name,
                                                qos_profile(contract.PROCEDURE_EVENTS.qos))
        self.pub_cycles = self.create_publisher(UInt8MultiArray, contract.CYCLES.name,
                                                qos_profile(contract.CYCLES.qos))
        self.pub_captures = self.create_publisher(Float64MultiArray, contract.CAPTURES.name,
                                                  qos_profile(contract.CAPTURES.qos))
        if self.sim_time:
            self.pub_traj = self.create_publisher(
                JointTrajectory, contract.REFERENCE_TRAJECTORY.name,
                qos_profile(contract.REFERENCE_TRAJECTORY.qos))
            self.create_subscription(Clock, contract.CLOCK.name, self._on_clock,
                                     qos_profile(contract.CLOCK.qos, depth=10), raw=True)
        else:
            self.create_timer(1.0 / rate, self._tick, clock=steady_clock())
        self._read_state = functools.partial(contract.state_from_cdr,
                                             load_joint=self.opt['load_joint'])
        self._load = math.nan
        if self.opt['load_topic']:
            self.create_subscription(WrenchStamped, self.opt['load_topic'], self._on_load,
                                     qos_profile(contract.LOAD_CELL.qos_in(self.sim_time)),
                                     raw=True)
        self.create_subscription(JointState, contract.STATE.name, self._on_state,
                                 qos_profile(contract.STATE.qos_in(self.sim_time)), raw=True)
        self.create_subscription(DiagnosticArray, contract.EVENTS.name, self._on_event,
                                 qos_profile(contract.EVENTS.qos))
        self.create_subscription(DiagnosticArray, contract.ESTIMATES.name, self._on_estimate,
                                 qos_profile(contract.ESTIMATES.qos))
        self._fits_k_L = self.procedure.ends_on('fitted_stiffness_drop')
        self._said_no_k_L = False
        for name in ('start', 'hold', 'resume', 'stop'):
            self.create_service(Trigger, f'~/{name}', functools.partial(self._on_request,
                                                                        name))
        self.add_on_set_parameters_callback(self._on_set)
        self.mode_client = self.create_client(SetParameters,
                                              f'/{self.opt["controller"]}/set_parameters')
        # the controller's mode is read before a start or a resume (it may hold another)
        self.mode_reader = self.create_client(GetParameters,
                                              f'/{self.opt["controller"]}/get_parameters')
        self.runner.mode_known = False
        self._rig: dict[str, float] = {}       # the rig's values the controller gave
        self._states = 0
        self._mode_read: tuple | None = None   # (future, when sent)
        self.create_timer(0.1, self._read_mode, clock=steady_clock())
        self._mode_call = None
        self._clock_due = -1            # sim time: the newest /clock not answered yet [ns]
        self._parked = False            # ... and whether the loop waits for a switch
        self._mode_sent: tuple | None = None   # (mode, when, requests)
        self.create_timer(MODE_RESEND / 5.0, self._resend_mode, clock=steady_clock())
        self.create_timer(float(self.opt['diagnostics_period']), self._diagnose,
                          clock=steady_clock())
        self.get_logger().info(f'procedure {self.procedure.name!r}: '
                               f'{len(self.procedure.steps)} steps, checkpoint '
                               f'{str(self.cp_path)!r}' + (f'; {restored}' if restored else ''))

    def _open(self, file: str, checkpoint: str) -> tuple:
        """Return a procedure file's procedure (checked whole), its runner and checkpoint."""
        procedure = load_procedure(file)
        if self.opt['rig_params']:        # refused before anything moves, each step named
            require_envelope(procedure, load_yaml(self.opt['rig_params']))
        runner = ProcedureRunner(procedure, latency=float(self.opt['preview']),
                                 harmonics=int(self.opt['apc_harmonics']),
                                 rate_hz=float(self.opt['rate_hz']),
                                 ramp_time=float(self.opt['ramp_time']),
                                 lockstep=self.sim_time)
        return procedure, runner, Path(checkpoint or file + '.checkpoint.json')

    def _on_set(self, changes) -> SetParametersResult:
        """
        Take a new ``file`` (and ``checkpoint``): the next test, while idle or finished.

        The file is checked whole before anything changes (a bad one is refused with its
        error, the old test stays); the new test's checkpoint is restored as at a start
        (a test under way comes back interrupted, for ~/resume). The controller's mode, once
        read, carries over.
        """
        new = {p.name: p.value for p in changes if p.name in ('file', 'checkpoint')}
        if not new or getattr(self, 'runner', None) is None:
            return SetParametersResult(successful=True)
        with self._lock:
            if self.runner.state not in ('idle', 'finished'):
                return SetParametersResult(successful=False, reason=(
                    f'the test is {self.runner.state}: a new procedure loads only when it is '
                    'idle or finished (stop it first)'))
            file = str(new.get('file', self.opt['file']))
            checkpoint = str(new.get('checkpoint', '' if 'file' in new else
                                     self.opt['checkpoint']))
            try:
                procedure, runner, cp_path = self._open(file, checkpoint)
            except Exception as err:          # noqa: BLE001 refused, named; the node goes on
                return SetParametersResult(successful=False, reason=str(err))
            old = self.runner
            if self._rig:
                runner.rig_params(self._rig)
            if old.mode_known:
                runner.controller_mode(old.mode)
            else:
                runner.mode_known = False
            self.writer.close()
            self.procedure, self.runner, self.cp_path = procedure, runner, cp_path
            self.opt['file'], self.opt['checkpoint'] = file, checkpoint
            self._rows, self._recent, self._states = [], [], 0
            restored = self._restore(recover=False)
            self.writer = _CheckpointWriter(self.cp_path)
            self._fits_k_L = procedure.ends_on('fitted_stiffness_drop')
        self.get_logger().info(f'procedure {procedure.name!r} loaded: {len(procedure.steps)} '
                               f'steps, checkpoint {str(cp_path)!r}'
                               + (f'; {restored}' if restored else ''))
        return SetParametersResult(successful=True)

    def _restore(self, recover: bool = True) -> str:
        cp, note = resume_point(self.cp_path)
        if cp is None:
            return note
        extra = recovered_total(self.opt['recover_bag']) if recover and \
            self.opt['recover_bag'] else None
        rows = cp.get('unconfirmed_cycles', cp.get('unpublished_cycles', []))
        self._rows = [tuple(r) for r in rows if extra is None or r[0] > extra]
        return self.runner.restore(cp, extra)

    # -- messages in -------------------------------------------------------------------------
    @_guarded
    def _on_state(self, data: bytes) -> None:
        s = read_msg(self, self._read_state, data, 'state')
        if s is None:
            return
        load = self._load if self.opt['load_topic'] else s.load
        if s.stamp_ns <= self.runner.last_stamp and self.runner.last_stamp >= 0 and \
                s.stamp_ns < self.runner.last_stamp - 10**9:
            self.runner.new_run()          # the states' clock went back: a restarted plant
        self.runner.measure(s.stamp_ns, s.z, load)
        self._states += 1
        # autostart from the second state: by then the controller has answered the first (in
        # lock-step the plant steps only on its command), so it holds a load cell reading when
        # the first step asks it to switch to force
        if self.opt['autostart'] and self.runner.state == 'idle' and self._states >= 2:
            self.runner.start(s.stamp_ns)
        self._after()

    @_guarded
    def _on_load(self, data: bytes) -> None:
        r = read_msg(self, self._read_wrench, data, 'load_cell')
        if r is not None:
            self._load = r.force

    def _read_wrench(self, data: bytes):
        return contract.load_from_cdr(data, self.opt['load_axis'])

    @_guarded
    def _on_event(self, msg: DiagnosticArray) -> None:
        try:
            e = contract.event_from_msg(msg)
        except ValueError:
            return
        self.runner.event(e.kind, e.detector, e.action, e.stamp_ns)
        self._after()

    @_guarded
    def _on_estimate(self, msg: DiagnosticArray) -> None:
        try:
            e = contract.estimate_from_msg(msg)
        except ValueError as err:
            self.get_logger().warning(f'parameter_estimates: {err}', once=True)
            return
        if 'k_L' not in e.values:
            if self._fits_k_L and not self._said_no_k_L:
                self._said_no_k_L = True
                self.get_logger().warning(
                    'parameter_estimates: the live fit has no k_L, so fitted_stiffness_drop '
                    'cannot judge it (the identify node fits k_L when its `free` holds it)')
            return
        self.runner.estimate(e.stamp_ns, e.values['k_L'], e.stderr.get('k_L', math.nan),
                             e.adequate)
        self._after()

    @_guarded
    def _on_clock(self, data: bytes) -> None:
        t = read_msg(self, contract.clock_from_cdr, data, '/clock')
        if t is None:
            return
        self._clock_due = max(self._clock_due, t)
        self._after()

    def _answer_clock(self) -> None:
        """Publish the window of the newest ``/clock`` once its state is measured."""
        r, t = self.runner, self._clock_due
        if t < 0 or r.last_stamp < t:
            return              # nothing measured yet (nothing to hold), or not its state yet
        refs = r.window(t, self.preview_ns)
        if not refs:
            return              # switching, the loop waits past the window's end: said later
        self._clock_due = -1
        self.pub_traj.publish(contract.reference_trajectory_to_cdr(refs))
        self.pub.publish(contract.reference_to_cdr(refs[0]))

    @_guarded
    def _tick(self) -> None:
        if self.runner.last_stamp < 0:
            return
        r = self.runner.sample(self.get_clock().now().nanoseconds)
        self.pub.publish(contract.reference_to_cdr(r))
        self._after()

    def _on_request(self, name: str, request, response):
        with self._lock:
            if self._closed:
                response.success, response.message = False, 'refused: the node is closing'
                return response
            return self._request(name, response)

    def _request(self, name: str, response):
        stamp = max(self.runner.last_stamp, 0)
        ok, why = getattr(self.runner, name)(stamp)
        response.success, response.message = bool(ok), why
        self._log(not ok, f'~/{name}: {why}')
        self._after()
        return response

    # -- messages out ------------------------------------------------------------------------
    def _after(self) -> None:
        """Publish what the runner left: events, cycles, captures; checkpoint; mode switch."""
        r = self.runner
        if r.cycles:
            self._rows.extend((c.count, c.step, c.end_ns, c.cmd_hi, c.cmd_lo, c.z_hi, c.z_lo,
                               c.f_hi, c.f_lo, c.flags) for c in r.cycles)
            r.cycles.clear()
        # in batches (a message carries ~48 bytes besides its records), and at a state change
        # but 'interrupted': the records not yet out are in the checkpoint, rewritten at every
        # cycle; a restarted node holds those it restored until the test runs again (sent at
        # once, they went out before the recorder had discovered the new node, and were lost)
        if self._rows and r.state != 'interrupted' and (
                len(self._rows) >= CYCLES_BATCH or r.state != 'running' or
                r.last_stamp - self._rows[0][2] >= CYCLES_BATCH_NS):
            self._publish_rows()
        while r.captures:
            cap = r.captures.pop(0)
            t0 = cap['t'][0]
            n = len(cap['t'])
            msg = Float64MultiArray()
            msg.layout.dim = [MultiArrayDimension(label=f'cycle {cap["count"]}', size=4,
                                                  stride=4 * n),
                              MultiArrayDimension(label='samples', size=n, stride=n)]
            msg.data = [(t - t0) * 1e-9 for t in cap['t']] + [float(v) for v in cap['cmd']] + \
                [float(v) for v in cap['z']] + [float(v) for v in cap['f']]
            self.pub_captures.publish(msg)
        while r.events:
            kind, what, value, message = r.events.pop(0)
            out = DiagnosticArray()
            contract.fill_procedure_event(out, max(r.last_stamp, 0), _LEVEL.get(kind, OK),
                                          kind, what, value, r.total, r.step_index, message,
                                          DiagnosticStatus(), KeyValue)
            self.pub_events.publish(out)
            self._log(kind in _LEVEL, message)
        while r.notes:
            self.get_logger().info(r.notes.pop(0)[1])
        if r.checkpoint_due:
            self.writer.put(self._checkpoint())
        if r.request_mode is not None and self._mode_call is None and \
                (r.parked or not self.sim_time):
            self._switch(r.request_mode)
        if self.sim_time:
            if self._parked and r.state != 'switching':
                # the loop waits at the state measured last, and no /clock comes while it does
                self._clock_due = max(self._clock_due, r.last_stamp)
            self._parked = r.parked
            self._answer_clock()

    def _log(self, warn: bool, text: str) -> None:
        # rclpy allows one severity per call site
        if warn:
            self.get_logger().warning(text)
        else:
            self.get_logger().info(text)

    def _switch(self, mode: str) -> None:
        if not self.mode_client.service_is_ready():
            self.runner.mode_switched(False, f'the controller /{self.opt["controller"]} does '
                                      'not answer', max(self.runner.last_stamp, 0))
            self._after()
            return
        self._mode_call = self.mode_client.call_async(set_parameters_request(control_mode=mode))
        self._mode_call.add_done_callback(self._switched)
        self._mode_sent = (mode, time.monotonic(), self._mode_sent[2] + 1
                           if self._mode_sent and self._mode_sent[0] == mode else 1)

    @_guarded
    def _resend_mode(self) -> None:
        """Send the switch again when unanswered for MODE_RESEND s; give up after three."""
        fut = self._mode_call
        if fut is None or fut.done() or self._mode_sent is None:
            return
        mode, sent, tries = self._mode_sent
        if time.monotonic() - sent < MODE_RESEND:
            return
        # a request sent before the server had discovered this client is never answered
        self.mode_client.remove_pending_request(fut)
        self._mode_call = None
        if tries >= 3:
            self._mode_sent = None
            self.runner.mode_switched(False, f'the controller /{self.opt["controller"]} did not '
                                      f'answer the switch to {mode} ({tries} requests)',
                                      max(self.runner.last_stamp, 0))
            self._after()
            return
        self._switch(mode)

    @_guarded
    def _read_mode(self) -> None:
        """Ask the controller its control mode until it answers (again after MODE_RESEND)."""
        if self.runner.mode_known or not self.mode_reader.service_is_ready():
            return
        if self._mode_read is not None:
            fut, sent = self._mode_read
            if not fut.done() and time.monotonic() - sent < MODE_RESEND:
                return
            if not fut.done():
                self.mode_reader.remove_pending_request(fut)
        fut = self.mode_reader.call_async(GetParameters.Request(
            names=['control_mode', *RIG_NAMES]))
        fut.add_done_callback(self._mode_answered)
        self._mode_read = (fut, time.monotonic())

    @_guarded
    def _mode_answered(self, fut) -> None:
        try:
            values = fut.result().values
            mode = values[0].string_value
        except Exception:                     # noqa: BLE001 unanswered: asked again
            return
        if mode and not self.runner.mode_known:
            rig = {n: v.double_value for n, v in zip(RIG_NAMES, values[1:])
                   if v.type == ParameterType.PARAMETER_DOUBLE}
            if len(rig) == len(RIG_NAMES):
                self._rig = rig
                self.runner.rig_params(rig)
            else:
                self.get_logger().warning(
                    f'the controller /{self.opt["controller"]} does not give the rig\'s '
                    f'parameters ({", ".join(n for n in RIG_NAMES if n not in rig)}): the '
                    'procedure is checked against what the rig can do only with rig_params')
            self.runner.controller_mode(mode)
            self.get_logger().info(f'the controller is in {mode} control')
            for line in self.runner.beyond_rig:
                self.get_logger().error(f'the rig cannot follow: {line}')
            self._after()

    @_guarded
    def _switched(self, fut) -> None:
        if fut is not self._mode_call:
            return                            # one given up on
        self._mode_call = None
        self._mode_sent = None
        try:
            res = fut.result().results[0]
            ok, why = res.successful, res.reason
        except Exception as err:              # noqa: BLE001 the service failed
            ok, why = False, str(err)
        self.runner.mode_switched(ok, why, max(self.runner.last_stamp, 0))
        self._after()

    @_guarded
    def _diagnose(self) -> None:
        st = self.runner.status()
        level = {'failed': ERROR}.get(st['result'], OK)
        if st['state'] in ('held', 'interrupted'):
            level = max(level, WARN)
        if self.writer.error:
            level = ERROR
        values = {**st, 'checkpoint': str(self.cp_path), 'file': self.opt['file'],
                  'checkpoints_written': self.writer.written,
                  'checkpoint_ms': self.writer.last_s * 1e3}
        msg = self.writer.error or (f"{st['state']}: {st['step']} at cycle "
                                    f"{st['step_cycles']} ({st['total_cycles']} in all)")
        self.pub_diag.publish(diagnostics(self, contract.PROCEDURE_STATUS, level, msg, values))

    def close(self, wait: float = CLOSE_WAIT) -> bool:
        """
        Publish the cycles not yet out and write the last checkpoint (as the node closes).

        No callback runs from then on. A callback still running after ``wait`` s (an executor
        stuck in it) would make that checkpoint a torn one: the last one written stands, it
        says so, and returns False.
        """
        held = self._lock.acquire(timeout=wait)
        try:
            self._closed = True
            if held:
                if self._rows:
                    self._publish_rows()
                self.writer.put(self._checkpoint())
            else:
                self.get_logger().error(
                    f'closing while a callback still runs after {wait:g} s: the last '
                    f'checkpoint written stands ({self.writer.written} written this run; '
                    'rewritten at each cycle, it holds the cycles not yet published)')
            self.writer.close()
            return held
        finally:
            if held:
                self._lock.release()

    def _publish_rows(self) -> None:
        rows, self._rows = self._rows, []
        now = time.monotonic()
        self._recent = [(t, r) for t, r in self._recent if now - t < RECENT_S] + [(now, rows)]
        msg = UInt8MultiArray()
        msg.layout.dim = [MultiArrayDimension(label=contract.CYCLES_LABEL, size=len(rows),
                                              stride=contract.CYCLE_RECORD.size)]
        msg.data = contract.cycles_to_bytes(rows)
        self.pub_cycles.publish(msg)

    def _checkpoint(self) -> dict:
        # with the cycle records not yet published, and those published in the last RECENT_S
        # (a recorder killed with them may not have them on disk): a restart publishes them
        now = time.monotonic()
        recent = [row for t, rows in self._recent if now - t < RECENT_S for row in rows]
        return {**self.runner.checkpoint(),
                'unconfirmed_cycles': [list(r) for r in recent + self._rows]}


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs procedure``."""
    return run(ProcedureNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
