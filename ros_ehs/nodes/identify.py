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
The identify node: ``ros2 run ros_ehs identify --ros-args -p bags:=[bags/run1]``.

A thin wrapper over :func:`ros_ehs.data.identification.run_identification` (what
``ehs_sim identify``
runs): it reads the bags, refits the free parameters, logs each iteration and writes the
report folder ``out`` (``identified_params.yaml``, ``summary.json``, figures). With
``push: true`` it then sets the fitted values the controller declares (friction, damping and
valve values its feedforward uses) on the running controller ``controller`` through its
``set_parameters_atomically`` service, so the cross-checks (F_cc <= F_sc) see the whole set,
and logs what the controller accepted or why it refused. The node exits when done: 0 on
success, 1 if the fit or the push failed, 2 for bad input (missing bag, foreign topics...).

**Live mode** (``live: true``, :mod:`ros_ehs.core.identify.live`): no bags; the node listens to
the running loop (``state``, the pressures and, where the state does not carry the applied
current, the commands: our contract, or a rig's topics and joint from the same options or
``topic_map``), keeps the last ``window`` seconds and every ``period`` seconds of the state
clock refits them on one low-priority thread (``refit_priority``: SCHED_IDLE by default, one
Jacobian thread; by default (``cpu_affinity`` -2) on a CPU the loop does not use), warm
from its last adequate estimate. Each refit is published on ``parameter_estimates`` (values,
standard errors, verdict, whether and why it was pushed: the recorder keeps it) and logged in
one line. With ``push: true`` an adequate fit whose values are all inside their bounds and
change by more than ``sigmas`` standard errors and ``rel_change`` is set on the controller, at
most once per ``push_period``; a refusal is logged with the controller's reason. It runs until
stopped.
"""

from __future__ import annotations

import functools
import math
import os
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.task import Future
from ros_ehs.core.errors import DataError, EhsError
from ros_ehs.core.identify.live import (LiveIdentifier, ReceiveClock, RefitSchedule, RefitThread,
                                        SampleWindow)
from ros_ehs.core.identify.verdict import why_adequate
from ros_ehs.core.options import CONTROLLER_SPECS, IDENTIFY
from ros_ehs.core.params import load_yaml, preset
from ros_ehs.data.identification import run_options
from ros_ehs.data.mapping import decoder, topic_map_of, TopicDecoder, TopicMap
from ros_ehs.nodes.parameters import declare_settings
from ros_ehs.nodes.ros_common import (diagnostics, msg_class, OK, qos_profile, read_msg, run,
                                      steady_clock, WARN)
import ros_ehs_msgs_py as contract

__all__ = ['OPTIONS', 'IdentifyNode', 'main', 'pushable']

#: the node's options (declared in :mod:`ros_ehs.core.options`)
OPTIONS = IDENTIFY

#: Live mode: how often to look for the mapped topics' types [s].
DISCOVERY_PERIOD = 0.5
#: Live mode: the subscriptions' queue depth (1 s of a 2 kHz state).
LIVE_QUEUE = 2000


def pushable(names) -> list[str]:
    """Return those of ``names`` that the controller node declares (in that order)."""
    declared = {s.name for s in CONTROLLER_SPECS}
    return [n for n in names if n in declared]


#: how long a stop waits for the refit thread's call into ROS under way [s]
STOP_IO = 2.0
#: how long a stop waits for a parked refit thread to end (else the process leaves without a
#: teardown, which is safe either way) [s]
STOP_PARKED = 0.2


class IdentifyNode(Node):
    """Identification job as a node (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('identify', **kwargs)
        self.opt = declare_settings(self, OPTIONS)
        self.cpu_affinity = int(self.opt['cpu_affinity'])
        self.result = None
        # the refit thread's calls into ROS (log, publish, the controller's services) hold
        # _io and are made only while not _closing: stop() sets it and waits for one under
        # way, so none comes after the node is destroyed (one did: a SIGSEGV at exit)
        self._io = threading.Lock()
        self._closing = threading.Event()
        if self.opt['live']:
            self.done = None        # runs until stopped
            self._start_live()
            return
        if not self.opt['bags']:
            raise EhsError('parameter `bags` is empty: give the bags to fit '
                           '(-p bags:=[bags/sample_sine_1hz])')
        self.done = Future()
        threading.Thread(target=self._job, daemon=True).start()

    def bag_topics(self) -> TopicMap:
        """Return where the signals are in the bags (or on the live topics), from the options."""
        return topic_map_of(self.opt)

    def _job(self) -> None:
        log = self.get_logger()
        o = self.opt
        try:
            result, files, _ = run_options(
                self.opt, progress=lambda e: log.info(f'iteration {e["iteration"]:3d}  '
                                                      f'cost {e["cost"]:.6g}'))
        except EhsError as err:
            log.error(str(err))
            self.done.set_result(2)
            return
        self.result = result
        log.info(f'{result.message} after {result.iterations} iterations, {result.nfev} '
                 f'evaluations, {result.wall_s:.1f} s')
        for n in result.free:
            log.info(f'{n:>7} = {result.x[n]:.6g} +- {result.stderr[n]:.3g}')
        for w in result.warnings:
            log.warning(w)
        if result.starts:
            log.info(f'robustness: {result.starts["message"]}')
        if result.excitation:
            weak = result.excitation.get('recommended') is not None
            (log.warning if weak else log.info)(f'excitation: {result.excitation["message"]}')
        if result.adequate:
            why = why_adequate(result.halves, result.jackknife)
            log.info(f'verdict: adequate: {why}')
        else:
            log.error('verdict: NOT ADEQUATE: ' + '; '.join(result.inadequacy))
            for a in result.advice:
                log.warning(f'advice: {a}')
        log.info(f'wrote {o["out"]}: ' + ', '.join(sorted(p.name for p in files.values())))
        rc = 0 if result.success and result.adequate else 1
        if o['push'] and result.params is not None:
            rc = max(rc, self._push(result))
        self.done.set_result(rc)

    def _push(self, result) -> int:
        log = self.get_logger()
        names = pushable(result.free)
        if not names:
            log.warning('nothing to push: the controller declares none of the fitted values')
            return 0
        client = AsyncParameterClient(self, self.opt['controller'])
        if not client.wait_for_services(timeout_sec=float(self.opt['push_timeout'])):
            log.error(f'push: no parameter services of `{self.opt["controller"]}` within '
                      f'{self.opt["push_timeout"]:g} s')
            return 1
        ok, why = self._set_on_controller(client, {n: result.params[n] for n in names})
        (log.info if ok else log.error)(f'push: {why}')
        return 0 if ok else 1

    def _set_on_controller(self, client, values: dict) -> tuple[bool, str]:
        """Set ``values`` on the controller at once (its cross-checks see the whole set)."""
        params = [Parameter(n, Parameter.Type.DOUBLE, float(v)) for n, v in values.items()]
        res = self._wait(client.set_parameters_atomically(params),
                         float(self.opt['push_timeout']))
        who = f'`{self.opt["controller"]}`'
        if res is None:
            return False, f'{who} did not answer'
        if not res.result.successful:
            return False, f'refused by {who}: {res.result.reason}'
        return True, f'pushed to {who}: ' + ', '.join(f'{p.name}={p.value:.6g}' for p in params)

    # -- live mode ---------------------------------------------------------------------------
    def _start_live(self) -> None:
        o = self.opt
        self.tmap = self.bag_topics()
        base = load_yaml(o['initial']) if o['initial'] else preset('table1_initial')
        self.live = LiveIdentifier(base, free=o['free'], model=o['model'],
                                   pushable=pushable(o['free']), sigmas=float(o['sigmas']),
                                   rel_change=float(o['rel_change']),
                                   push_period=float(o['push_period']),
                                   max_nfev=int(o['max_nfev']))
        cap = int(math.ceil(float(o['window']) * float(o['max_rate']) * 1.5))
        self.window = SampleWindow(float(o['window']), max(cap, 16))
        self.schedule = RefitSchedule(float(o['window']), float(o['period']))
        self.receive = ReceiveClock()
        self._lock = threading.Lock()        # the window: filled here, read by the refit
        # refits and pushes: the identifier counts them (self.live)
        self.counts = {'states': 0, 'bad': 0, 'refused': 0}
        self.pub_est = self.create_publisher(DiagnosticArray, contract.ESTIMATES.name,
                                             qos_profile(contract.ESTIMATES.qos))
        self._subscribed: dict[str, str] = {}
        roles = ('state', 'command') + (('pressure_p', 'pressure_t') if self.tmap.pressure_p
                                        else ()) + (('load_cell',) if self.tmap.load_cell
                                                    else ())
        self._wanted = {getattr(self.tmap, r): r for r in roles}
        # the contract's load cell is there only with a specimen: not waited for
        self._optional = {self.resolve_topic_name(contract.LOAD_CELL.name)}
        self.create_timer(DISCOVERY_PERIOD, self._discover, clock=steady_clock())
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              qos_profile(contract.DIAGNOSTICS.qos))
        self.create_timer(float(o['diagnostics_period']), self._diagnose, clock=steady_clock())
        self._client = AsyncParameterClient(self, o['controller']) if o['push'] else None
        self._worker = RefitThread(self._refit_once, self._refit_failed, self.schedule.done,
                                   self._prioritise)
        self._discover()
        self.get_logger().info(
            f'live: refit the last {o["window"]:g} s every {o["period"]:g} s ({o["model"]} '
            f'model, {len(self.live.free)} parameters), push '
            + (f'to `{o["controller"]}` at most every {o["push_period"]:g} s'
               if o['push'] else 'off'))

    def _discover(self) -> None:
        """Subscribe to each mapped topic once its type is known (a rig's, or ours)."""
        if len(self._subscribed) == len(self._wanted):
            return
        types = dict(self.get_topic_names_and_types())
        for name, role in self._wanted.items():
            full = self.resolve_topic_name(name)
            if full in self._subscribed or full not in types:
                continue
            msg_type = types[full][0]
            self._subscribed[full] = msg_type
            try:
                dec = decoder(self.tmap, role, msg_type)
            except EhsError as err:
                self.get_logger().error(f'live: {err} ({full})')        # said once
                continue
            qos = contract.STATE.qos if role == 'state' else contract.PRESSURE_P.qos
            # a deep queue: the refit thread holds the interpreter for a while at times, and
            # a depth of 1 then dropped states (a 10 s window fell into 9 runs)
            self.create_subscription(msg_class(msg_type), name,
                                     functools.partial(self._on_message, dec),
                                     qos_profile(qos, depth=LIVE_QUEUE), raw=True)
            self.get_logger().info(f'live: {role} from {full} ({msg_type})')

    def _diagnose(self) -> None:
        """Publish the live identifier's status: what it takes, how many refits and pushes."""
        values = {'subscribed': ','.join(sorted(self._subscribed)), **self.counts,
                  'refits': self.live.refits, 'pushes': self.live.pushes,
                  'busy': self.schedule.busy}
        level, msg = OK, 'refitting' if self.live.refits else 'filling the window'
        missing = {self.resolve_topic_name(n) for n in self._wanted} - set(self._subscribed)
        if missing - self._optional:
            level, msg = WARN, 'waiting for the mapped topics'
        self.pub_diag.publish(diagnostics(self, contract.IDENTIFY_STATUS, level, msg, values))

    def _on_message(self, dec: TopicDecoder, data: bytes) -> None:
        got = read_msg(self, dec, data, dec.role)
        if got is None:
            self.counts['bad'] += 1
            return
        received = self.get_clock().now().nanoseconds
        stamp = got[0] if got[0] is not None else self.receive.stamp(received)
        with self._lock:
            if dec.role == 'state':
                self.counts['states'] += 1
                self.receive.state(stamp, received)
                runs = self.window.runs
                self.window.add_state(stamp, got[1], got[2], got[3])
                new_run = self.window.runs != runs
            elif dec.role == 'command':
                self.window.add_command(stamp, got[1])
            elif dec.role == 'load_cell':
                self.window.add_load(stamp, got[1])
            else:
                self.window.add_pressure(int(dec.role == 'pressure_t'), stamp, got[1])
        if dec.role != 'state':
            return
        if new_run:
            self.get_logger().info('live: the state stamp jumped back: a new run, the window '
                                   'starts again')
        if self.schedule.state(stamp, new_run):
            self._worker.wake()

    def _prioritise(self) -> None:
        """Set the refit thread's ``refit_priority`` (idle: only CPU time nobody else wants)."""
        prio = self.opt['refit_priority']
        try:
            if prio == 'idle':
                os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
        except (OSError, AttributeError):
            prio = 'nice'
        if prio == 'nice':
            os.nice(19)        # this thread only: Linux keeps the nice value per thread

    def _refit_failed(self, err: Exception) -> None:
        with self._io:
            if not self._closing.is_set():
                self.get_logger().error(f'live: refit failed: {type(err).__name__}: {err}')

    @property
    def busy(self) -> bool:
        """
        Say if the refit thread has not ended (the process then exits without a teardown).

        That thread may be in compiled code (a fit, or numba compiling one in LLVM), and the
        interpreter's and LLVM's teardown under it crashed the process (a SIGSEGV once, an
        LLVM assertion once): a stop lets a parked thread end, and the process exits at once
        when it has not.
        """
        return bool(self.opt['live'] and self._worker.alive)

    def stop(self) -> None:
        """Stop talking to ROS from the refit thread (a refit under way is not published)."""
        self._closing.set()
        if self._io.acquire(timeout=STOP_IO):      # a call under way ends first
            self._io.release()
        if self.opt['live']:
            self._worker.stop(STOP_PARKED)      # a parked thread ends at once; a refit not

    def _refit_once(self) -> None:
        log = self.get_logger()
        with self._lock:
            stamp = self.window.last_stamp_ns
            try:
                exps = self.window.experiments('live')
            except DataError as err:
                exps, why = None, str(err)
        if exps is None:
            est = contract.ParameterEstimate(stamp, {}, {}, False, f'no fit: {why}',
                                             reason=f'no fit: {why}',
                                             window_s=float(self.opt['window']))
            with self._io:
                if not self._closing.is_set():
                    self._publish(est)
                    log.warning(f'live: no fit: {why}', throttle_duration_sec=30.0)
            return
        if self._client is not None and self.live.controller is None:
            with self._io:
                if not self._closing.is_set():
                    self._ask_controller()
        est, _ = self.live.refit(exps, stamp, float(self.opt['window']))
        vals = ', '.join(f'{n}={est.values[n]:.5g}' for n in self.live.free)
        verdict = 'adequate' if est.adequate else 'NOT adequate'
        with self._io:
            if self._closing.is_set():
                return
            log.info(f'live refit at {stamp * 1e-9:.3f} s: {verdict}, {est.iterations} '
                     f'iterations, {est.wall_s:.2f} s; {vals}; '
                     f'{"push" if est.pushed else "no push"}: {est.reason}')
            if est.pushed and self._client is not None:
                est = est._replace(pushed=self._push_live(est))
            else:
                est = est._replace(pushed=False)
            if not self._closing.is_set():
                self._publish(est)

    def _publish(self, est) -> None:
        msg = contract.fill_estimate(DiagnosticArray(), est, DiagnosticStatus(), KeyValue)
        self.pub_est.publish(msg)

    def _wait(self, fut, timeout: float):
        """Return the future's result within ``timeout`` s (None: none, or the node stops)."""
        ev = threading.Event()
        fut.add_done_callback(lambda f: ev.set())
        end = time.monotonic() + timeout
        while not ev.wait(min(0.05, max(0.0, end - time.monotonic()))):
            if self._closing.is_set() or time.monotonic() >= end:
                return None
        return fut.result()

    def _ask_controller(self) -> None:
        """Take the controller's current values of the pushed parameters (once)."""
        names = list(self.live.pushable)
        if not names or not self._client.services_are_ready():
            return
        res = self._wait(self._client.get_parameters(names), float(self.opt['push_timeout']))
        if res is None:
            return
        from rcl_interfaces.msg import ParameterType
        missing = [n for n, v in zip(names, res.values)
                   if v.type != ParameterType.PARAMETER_DOUBLE]
        if missing or len(res.values) != len(names):
            self.get_logger().error(
                f'live: `{self.opt["controller"]}` does not declare {missing or names} as '
                'numbers: nothing will be pushed', once=True)
            return
        self.live.controller = {n: v.double_value for n, v in zip(names, res.values)}
        self.get_logger().info('live: the controller has ' + ', '.join(
            f'{n}={v:.6g}' for n, v in self.live.controller.items()))

    def _push_live(self, est) -> bool:
        values = {n: est.values[n] for n in self.live.pushable}
        ok, why = self._set_on_controller(self._client, values)
        if not ok:
            self.counts['refused'] += 1
            self.get_logger().error(f'live push: {why}')
            return False
        self.live.pushed(values, est.stamp_ns)
        self.get_logger().info(f'live push to `{self.opt["controller"]}`: {est.reason}')
        return True


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs identify``."""
    return run(IdentifyNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
