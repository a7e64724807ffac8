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
The station node: the operator's page in the browser (docs/station.md).

``ros2 run ros_ehs station`` serves the page on ``http://127.0.0.1:8080/`` (options ``host``,
``port``, ``token``). The rules are ROS-free: what the page shows is
:class:`~ros_ehs.core.station.station.Station`'s, who may act
:class:`~ros_ehs.core.station.access.Access`'s, the web server :mod:`ros_ehs.web.app`'s; this
node decodes, calls and publishes:

* in: ``state`` and ``reference`` (best effort, whatever the loop's QoS: the page never
  slows the loop), ``diagnostics`` (the controller's, plant's, procedure's and live identify
  node's statuses), ``events``, ``procedure/events``, ``parameter_estimates``, and the
  campaign node's status and ``campaign/results`` (the campaign panel);
* a page's button calls the same services a ROS client does: the controller's ``~/reset``
  (std_srvs/Trigger) and ``~/enable`` (std_srvs/SetBool), the procedure's ``~/start``,
  ``~/hold``, ``~/resume``, ``~/stop``; the next specimen sets the campaign node's
  ``specimen`` parameter to the id the operator typed and calls its ``~/next``, as
  ``ros2 param set`` and ``ros2 service call`` would; the answer, or why it was refused,
  goes back to the page;
* out: every action, done or refused, on ``station/events`` with where it came from (so it is
  in the bag) and logged once; its status ``ros_ehs/station`` in ``diagnostics`` (url, open
  pages, frames sent a second, actions, refusals).
"""

from __future__ import annotations

import asyncio
import functools
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from ros_ehs.core.options import STATION
from ros_ehs.core.station.access import Access
from ros_ehs.core.station.station import Station
from ros_ehs.nodes.parameters import declare_settings
from ros_ehs.nodes.ros_common import (diagnostics, OK, qos_profile, read_msg, run,
                                      set_parameters_request, steady_clock, WARN)
from ros_ehs.web.app import make_app, StationServer, STOP_TIMEOUT
import ros_ehs_msgs_py as contract
from ros_ehs_msgs_py.qos import LOOP_QOS
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

__all__ = ['StationNode', 'main']

#: the node's options (declared in :mod:`ros_ehs.core.options`)
OPTIONS = STATION
#: a service that does not answer within this long is reported unanswered [s]
ANSWER_TIMEOUT = 5.0
_SOURCES = {contract.CONTROLLER_STATUS: 'controller', contract.PLANT_STATUS: 'plant',
            contract.PROCEDURE_STATUS: 'procedure', contract.IDENTIFY_STATUS: 'identify'}


class StationNode(Node):
    """The operator's station (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('station', **kwargs)
        o = self.opt = declare_settings(self, OPTIONS)
        self.cpu_affinity = int(o['cpu_affinity'])   # applied by run()
        self.station = Station(int(o['scope_samples']), int(o['scope_buckets']),
                               float(o['lost_after']))
        self.access = Access(str(o['token']))
        self.counts = {'actions': 0, 'refused': 0, 'pages': 0, 'malformed': 0}
        self._frames_seen = (time.monotonic(), 0)
        self.pub_events = self.create_publisher(DiagnosticArray, contract.STATION_EVENTS.name,
                                                qos_profile(contract.STATION_EVENTS.qos))
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              qos_profile(contract.DIAGNOSTICS.qos))
        self._read_state = functools.partial(contract.state_from_cdr,
                                             load_joint=o['load_joint'])
        loop_qos = qos_profile(LOOP_QOS)      # best effort: matches either kind of publisher
        self.create_subscription(JointState, contract.STATE.name, self._on_state, loop_qos,
                                 raw=True)
        self.create_subscription(JointState, contract.REFERENCE.name, self._on_reference,
                                 loop_qos, raw=True)
        self.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self._on_status,
                                 qos_profile(contract.DIAGNOSTICS.qos, depth=50))
        for topic, take in ((contract.EVENTS, self._on_safety_event),
                            (contract.PROCEDURE_EVENTS, self._on_procedure_event),
                            (contract.ESTIMATES, self._on_estimate),
                            (contract.CAMPAIGN_RESULTS, self._on_campaign_result)):
            self.create_subscription(DiagnosticArray, topic.name, take, qos_profile(topic.qos))
        ctl, proc = o['controller'], o['procedure']
        self.clients_ = {'reset': (self.create_client(Trigger, f'/{ctl}/reset'), Trigger, None),
                         'enable': (self.create_client(SetBool, f'/{ctl}/enable'), SetBool, True),
                         'disable': (self.create_client(SetBool, f'/{ctl}/enable'), SetBool,
                                     False)}
        for name in ('start', 'hold', 'resume', 'stop'):
            self.clients_[name] = (self.create_client(Trigger, f'/{proc}/{name}'), Trigger, None)
        camp = o['campaign']
        self.clients_['next'] = (self.create_client(Trigger, f'/{camp}/next'), Trigger, None)
        self.campaign_params = self.create_client(SetParameters, f'/{camp}/set_parameters')
        self._next_lock: asyncio.Lock | None = None      # made on the web server's loop
        self.create_timer(float(o['diagnostics_period']), self._diagnose, clock=steady_clock())
        app = make_app(self, self.access, float(o['push_rate']))
        self.server = StationServer(app, str(o['host']), int(o['port']))
        port = self.server.start()
        self.url = f'http://{o["host"]}:{port}/'
        self.get_logger().info(f'station serving {self.url}' + (
            '' if Access.local(str(o['host'])) else
            (' (other machines act with the token)' if o['token'] else
             ' (other machines watch only: no token)')))

    # -- messages in -------------------------------------------------------------------------
    def _decoded(self, convert, data: bytes, what: str):
        """Return ``convert(data)``, or None for a malformed message (counted)."""
        v = read_msg(self, convert, data, what)
        if v is None:
            self.counts['malformed'] += 1
        return v

    def _on_state(self, data: bytes) -> None:
        s = self._decoded(self._read_state, data, 'state')
        if s is not None:
            self.station.take_state(s)

    def _on_reference(self, data: bytes) -> None:
        r = self._decoded(contract.reference_from_cdr, data, 'reference')
        if r is not None:
            self.station.take_reference(r)

    def _on_status(self, msg: DiagnosticArray) -> None:
        now = time.monotonic()
        for st in contract.statuses_from_msg(msg):
            source = _SOURCES.get(st.name)
            if source is not None:
                self.station.take_status(source, now, st)
            elif st.name == contract.CAMPAIGN_STATUS:
                self.station.take_campaign_status(now, st)

    def _on_campaign_result(self, msg: DiagnosticArray) -> None:
        for st in contract.statuses_from_msg(msg):
            try:
                self.station.take_campaign_result(st)
            except ValueError as err:
                self.counts['malformed'] += 1
                self.get_logger().warning(f'ignored a campaign record: {err}',
                                          throttle_duration_sec=1.0)

    def _on_safety_event(self, msg: DiagnosticArray) -> None:
        e = read_msg(self, contract.event_from_msg, msg, 'event')
        if e is not None:
            self.station.take_event(time.time(), 'controller', e.kind, contract.event_level(e),
                                    e.message, detector=e.detector, action=e.action,
                                    value=e.value, limit=e.limit, unit=e.unit,
                                    stamp_ns=e.stamp_ns)

    def _on_procedure_event(self, msg: DiagnosticArray) -> None:
        e = read_msg(self, contract.procedure_event_from_msg, msg, 'procedure event')
        if e is not None:
            self.station.take_event(time.time(), 'procedure', e['kind'], e['level'],
                                    e['message'], step=e['step'],
                                    total_cycles=e['total_cycles'], stamp_ns=e['stamp_ns'])

    def _on_estimate(self, msg: DiagnosticArray) -> None:
        e = read_msg(self, contract.estimate_from_msg, msg, 'parameter estimate')
        if e is not None:
            self.station.take_estimate(time.monotonic(), e)

    # -- the web server's side (its own thread) ----------------------------------------------
    def frame(self, span: float, board: bool = True) -> dict:
        """Return one page frame."""
        body = self.station.frame(time.monotonic(), span, board)
        body['station'] = {'url': self.url, 'pages': self.counts['pages']}
        return body

    async def act(self, action: str, specimen: str = '') -> tuple[bool, str]:
        """Call ``action``'s service; (success, its message). ``specimen``: ``next``'s id."""
        client, srv, data = self.clients_[action]
        for c in (client, self.campaign_params) if action == 'next' else (client,):
            if not c.service_is_ready():
                return False, (f'{action}: the service {c.srv_name} is not available (is '
                               f'its node running?)')
        if action != 'next':
            res = await _call(client, srv.Request() if data is None else srv.Request(data=data))
            return bool(res.success), str(res.message)
        if self._next_lock is None:
            self._next_lock = asyncio.Lock()
        async with self._next_lock:          # one page's id, then its ~/next, not another's
            res = await _call(self.campaign_params, set_parameters_request(specimen=specimen))
            bad = [r.reason for r in res.results if not r.successful]
            if bad:
                return False, f'next: the campaign node refused the id {specimen!r}: {bad[0]}'
            res = await _call(client, Trigger.Request())
        return bool(res.success), str(res.message)

    def log_action(self, action: str, origin: str, result: str, reason: str) -> None:
        """Publish and log one action with its origin; count it."""
        self.counts['actions' if result == 'done' else 'refused'] += 1
        msg = contract.fill_station_event(DiagnosticArray(), time.time_ns(), action, origin,
                                          result, reason, DiagnosticStatus(), KeyValue)
        self.pub_events.publish(msg)
        self.station.take_event(time.time(), 'station', action, OK if result == 'done' else WARN,
                                f'{action} {result}: {reason}', origin=origin)
        text = f'station {action} from {origin}: {result}: {reason}'
        if result == 'done':          # rclpy ties a severity to its call site: two calls
            self.get_logger().info(text)
        else:
            self.get_logger().warning(text)

    def page_count(self, delta: int) -> None:
        """Count the open pages."""
        self.counts['pages'] += delta

    def reset_meters(self) -> None:
        """Forget the meters' min/max (the station's own state)."""
        self.station.reset_meters()

    # -- diagnostics and the end -------------------------------------------------------------
    def _diagnose(self) -> None:
        now = time.monotonic()
        t0, n0 = self._frames_seen
        n = self.station.frames
        self._frames_seen = (now, n)
        lost = self.station.board.lost(now)
        values = {'url': self.url, 'pages': self.counts['pages'],
                  'updates_per_s': (n - n0) / (now - t0) if now > t0 else 0.0,
                  'states': self.station.states, 'actions': self.counts['actions'],
                  'refused': self.counts['refused'], 'malformed': self.counts['malformed']}
        self.pub_diag.publish(diagnostics(self, contract.STATION_STATUS, WARN if lost else OK,
                                          lost or f'serving {self.url}', values))

    def close(self) -> None:
        """Stop serving (called once by :func:`run`)."""
        if not self.server.stop(STOP_TIMEOUT):
            self.get_logger().warning(f'the web server did not stop within {STOP_TIMEOUT:g} s: '
                                      'left behind')


async def _call(client, request):
    """Return a service's answer, awaited on the calling asyncio loop (ANSWER_TIMEOUT)."""
    loop = asyncio.get_running_loop()
    answer: asyncio.Future = loop.create_future()

    def done(f) -> None:
        loop.call_soon_threadsafe(lambda: answer.done() or answer.set_result(f.result()))

    client.call_async(request).add_done_callback(done)
    return await asyncio.wait_for(answer, ANSWER_TIMEOUT)


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs station``."""
    return run(StationNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
