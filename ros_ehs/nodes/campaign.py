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
The campaign node: a fatigue campaign on the rig, specimen by specimen, into its store.

``ros2 run ros_ehs campaign --ros-args -p campaign:=plan.yaml -p store:=results.db``. The
rules are :class:`~ros_ehs.data.campaign_rig.RigCampaign` (ROS-free, tested in process); this
node decodes, calls and publishes:

* ``~/next`` (std_srvs/Trigger): the operator's next specimen, its id from the ``specimen``
  parameter (the id on the coupon; empty: the plan's), its level from the campaign's rules.
  Its procedure is written to ``<out>/<specimen>/`` and set into the procedure node (its
  ``file`` and ``checkpoint``, through its parameter service); the operator then starts the
  test there (``/procedure/start``, or the station) once the coupon is in. Refused, with
  the reason, while a specimen is under way or once the campaign has ended. With
  ``protect`` (the default) it also switches the controller to specimen protect
  (``control_mode`` ``displacement_force_limited``, through its parameter service) while the
  operator installs the coupon: gripping a coupon loads it, and protect keeps that load
  within ``protect_force``; a refusal (no valid load cell reading, an interlock) is said in
  the log and in the status's ``protect``, and the coupon is loaded all the same;
* in: the procedure node's cycle records (``procedure/cycles``) and its status in
  ``diagnostics``: a finished test of the specimen under way is recorded in the store, once;
* out: each record on ``campaign/results`` (at its start, the records already in the store
  too: the topic is transient-local, so a station or a recorder started later gets the
  campaign whole; a reader keeps one record per specimen), and the campaign's status
  ``ros_ehs/campaign`` in ``diagnostics`` (what it waits for, the counts so far, the next
  level, the fit so far, the verdict).

Killed and started again, it finds the specimen under way (``<out>/current.json``) and waits
for its test's end as before: a procedure node that runs the specimen's file already is left
as it is, so a test that ended while this node was down is recorded; one that runs another
file (restarted too) is given the specimen's file and checkpoint again.
"""

from __future__ import annotations

from pathlib import Path
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from ros_ehs.core.campaign.spec import load_campaign
from ros_ehs.core.errors import InputError
from ros_ehs.core.options import CAMPAIGN
from ros_ehs.data.campaign_rig import RigCampaign
from ros_ehs.data.store import ResultStore
from ros_ehs.nodes.parameters import declare_settings
from ros_ehs.nodes.ros_common import (diagnostics, ERROR, OK, qos_profile, run,
                                      set_parameters_request, steady_clock, WARN)
import ros_ehs_msgs_py as contract
from std_msgs.msg import UInt8MultiArray
from std_srvs.srv import Trigger

__all__ = ['CampaignNode', 'OPTIONS', 'main']

#: the node's options (declared in :mod:`ros_ehs.core.options`)
OPTIONS = CAMPAIGN


class CampaignNode(Node):
    """A campaign on the rig through the procedure node (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('campaign', **kwargs)
        self.opt = declare_settings(self, OPTIONS)
        self.cpu_affinity = int(self.opt['cpu_affinity'])   # applied by run()
        if not self.opt['campaign']:
            raise InputError('no campaign: give `campaign` (-p campaign:=plan.yaml)')
        out = Path(self.opt['out'])
        campaign = load_campaign(self.opt['campaign'])
        out.mkdir(parents=True, exist_ok=True)
        self.store = ResultStore(self.opt['store'] or out / 'campaign.db')
        self._where = self.store.engine.url.render_as_string(hide_password=True)
        self.rules = RigCampaign(campaign, self.opt['campaign'], self.store, out)
        self._unit = campaign.unit
        self._lock = threading.Lock()
        self._error = ''
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              qos_profile(contract.DIAGNOSTICS.qos))
        self.pub_results = self.create_publisher(DiagnosticArray, contract.CAMPAIGN_RESULTS.name,
                                                 qos_profile(contract.CAMPAIGN_RESULTS.qos))
        self.create_subscription(UInt8MultiArray, contract.CYCLES.name, self._on_cycles,
                                 qos_profile(contract.CYCLES.qos))
        self.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self._on_diag,
                                 qos_profile(contract.DIAGNOSTICS.qos))
        self.loader = self.create_client(SetParameters,
                                         f'/{self.opt["procedure"]}/set_parameters')
        self.protector = self.create_client(SetParameters,
                                            f'/{self.opt["controller"]}/set_parameters')
        self._protect = 'off'                  # the status's word on specimen protect
        self._protect_pending: str | None = None   # a coupon whose protect waits to be set
        self._procedure: tuple[str, str] | None = None   # the procedure node's file, state
        self.create_service(Trigger, '~/next', self._on_next)
        self.add_on_set_parameters_callback(self._on_set)
        self.create_timer(float(self.opt['diagnostics_period']), self._diagnose,
                          clock=steady_clock())
        self._pending: dict | None = None      # a specimen to load once the node answers
        self.create_timer(0.5, self._retry, clock=steady_clock())
        cur = self.rules.current
        for rec in self.store.results(self.rules.cid):
            self.pub_results.publish(_result_msg(self, rec))
        self.get_logger().info(
            f'campaign {campaign.name!r} in {self._where}: '
            + (f"specimen {cur['specimen']} under way: waiting for its test's end"
               if cur else f'{len(self.store.results(self.rules.cid))} specimens recorded'))
        # a specimen under way: loaded again only into a procedure node that does not run
        # it (restarted too), once its status is heard (RigCampaign.must_load)
        self._reload = cur

    # -- the operator -----------------------------------------------------------------------
    def _on_set(self, changes) -> SetParametersResult:
        for p in changes:
            if p.name == 'specimen':
                self.opt['specimen'] = str(p.value)
        return SetParametersResult(successful=True)

    def _on_next(self, request, response):
        with self._lock:
            try:
                ok, why, job = self.rules.next_specimen(str(self.opt['specimen']))
            except Exception as err:            # noqa: BLE001 the store: said, not raised
                ok, why, job = False, f'the store: {err}', None
        response.success, response.message = ok, why
        if ok:
            self.get_logger().info(f'~/next: {why}')
            self._load(job)
            if self.opt['protect']:
                self._protect_on(job['specimen'])
        else:
            self.get_logger().warning(f'~/next: {why}')
        return response

    def _load(self, job: dict) -> None:
        """Set the specimen's procedure into the procedure node (refused: abandoned, said)."""
        if not self.loader.service_is_ready():
            # asked again until it answers (never waited for in a callback: the executor
            # that would bring the answer is the one waiting)
            if self._pending is None:
                self.get_logger().warning(f'the procedure node /{self.opt["procedure"]} does '
                                          f"not answer yet: {job['specimen']} loads when it "
                                          'does')
            self._pending = job
            return
        self._pending = None

        fut = self.loader.call_async(set_parameters_request(file=job['file'],
                                                            checkpoint=job['checkpoint']))
        fut.add_done_callback(lambda f: self._loaded(f, job))

    def _protect_on(self, specimen: str) -> None:
        """Switch the controller to specimen protect for the coupon's installation."""
        ctl = self.opt['controller']
        if not self.protector.service_is_ready():
            # asked again until it answers, as a load is (never waited for in a callback)
            if self._protect_pending is None:
                self.get_logger().warning(f'{specimen}: specimen protect waits for /{ctl}, '
                                          'which does not answer yet')
            self._protect_pending = specimen
            self._protect = f'not set: /{ctl} does not answer yet'
            return
        self._protect_pending = None
        self._protect = 'asked'
        self.protector.call_async(set_parameters_request(
            control_mode='displacement_force_limited')).add_done_callback(
            lambda f: self._protected(f, specimen))

    def _protected(self, fut, specimen: str) -> None:
        try:
            res = fut.result().results[0]
            ok, why = res.successful, res.reason
        except Exception as err:                # noqa: BLE001 the service failed
            ok, why = False, str(err)
        self._protect = 'on' if ok else f'refused: {why}'
        if ok:          # rclpy ties a severity to its call site: two calls
            self.get_logger().info(f'{specimen}: specimen protect on for its installation')
        else:
            self.get_logger().warning(f'{specimen}: specimen protect {self._protect}')

    def _retry(self) -> None:
        if self._pending is not None:
            self._load(self._pending)
        if self._protect_pending is not None:
            # only while its test has not started: protect would take a running test over
            if self.rules.may_protect(self._protect_pending, self._procedure):
                self._protect_on(self._protect_pending)
            else:
                self._protect = ('not set: the test started (or ended) before the controller '
                                 'answered')
                self.get_logger().warning(f'{self._protect_pending}: specimen protect '
                                          f'{self._protect}')
                self._protect_pending = None

    def _loaded(self, fut, job: dict) -> None:
        try:
            res = fut.result().results
            ok = all(r.successful for r in res)
            why = '; '.join(r.reason for r in res if not r.successful)
        except Exception as err:                # noqa: BLE001 the service failed
            ok, why = False, str(err)
        if ok:
            self.get_logger().info(f"{job['specimen']} loaded into /{self.opt['procedure']}: "
                                   'start it once the coupon is in')
            return
        with self._lock:
            cur = self.rules.current
            if cur is not None and cur['specimen'] == job['specimen'] and \
                    'only when it is idle or finished' not in why:
                self.rules.abandon(f'the procedure node refused it: {why}')
        self.get_logger().error(f"{job['specimen']}: the procedure node refused it: {why}")

    # -- the procedure node -----------------------------------------------------------------
    def _on_cycles(self, msg: UInt8MultiArray) -> None:
        try:
            rows = contract.cycles_from_bytes(bytes(msg.data))
        except ValueError as err:
            self.get_logger().warning(f'ignored malformed cycle records: {err}',
                                      throttle_duration_sec=1.0)
            return
        with self._lock:
            try:
                self.rules.take_cycles(rows)
            except OSError as err:
                self._error = f'cycle records not written: {err}'

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for st in contract.statuses_from_msg(msg):
            if st.name != contract.PROCEDURE_STATUS:
                continue
            self._procedure = (str(st.values.get('file', '')), str(st.values.get('state', '')))
            if self._reload is not None:
                job, self._reload = self._reload, None
                if self.rules.must_load(self._procedure):
                    self._load(job)     # the procedure node was restarted too
                else:
                    self.get_logger().info(f"{job['specimen']}: /{self.opt['procedure']} runs "
                                           f'it already ({self._procedure[1]})')
            with self._lock:
                try:
                    rec = self.rules.status(st.values, time.monotonic())
                except Exception as err:        # noqa: BLE001 the store: said, kept trying
                    self._error = f'the record was not stored: {err}'
                    self.get_logger().error(self._error, throttle_duration_sec=10.0)
                    return
            if rec is not None:
                self._error = ''
                self.get_logger().info(f'{rec.specimen} recorded: {rec.result}, {rec.cycles} '
                                       f'cycles' + (f' ({rec.reason})' if rec.reason else ''))
                self.pub_results.publish(_result_msg(self, rec))

    # -- status -----------------------------------------------------------------------------
    def _diagnose(self) -> None:
        with self._lock:
            try:
                recs = self.store.results(self.rules.cid)
                v = self.rules.verdict()
            except Exception as err:            # noqa: BLE001 said in the status
                self.pub_diag.publish(diagnostics(self, contract.CAMPAIGN_STATUS, ERROR,
                                                  f'the store: {err}', {}))
                return
            cur = self.rules.current
        state = 'under_way' if cur else ('ended' if v.done else 'ready')
        counts = {k: sum(r.result == k for r in recs)
                  for k in ('failed', 'run_out', 'invalid')}
        nxt = v.next_specimen
        fit = v.fit
        values = {'state': state, 'specimen': cur['specimen'] if cur else '',
                  'level': float(cur['level']) if cur else float('nan'), 'tested': len(recs),
                  **counts, 'next_level': float(nxt.level) if nxt and not cur else float('nan'),
                  'verdict': v.reason if v.done else '', 'store': self._where,
                  'name': self.rules.campaign.name, 'unit': self._unit,
                  'protect': self._protect if cur else 'off',
                  'run_out_cycles': float(self.rules.campaign.run_out),
                  **{'fit_' + k: float(getattr(fit, k)) if fit else float('nan')
                     for k in ('a', 'k', 's')}}
        msg = {'under_way': f"{cur['specimen'] if cur else ''}: waiting for its test's end",
               'ready': f'ready: ~/next gives a specimen at {nxt.level:g}' if nxt else 'ready',
               'ended': f'the campaign has ended: {v.reason}'}[state]
        level = ERROR if self._error else (WARN if state == 'ended' else OK)
        self.pub_diag.publish(diagnostics(self, contract.CAMPAIGN_STATUS, level,
                                          self._error or msg, values))

    def close(self) -> None:
        """Close the store."""
        self.store.close()


def _result_msg(node: Node, rec) -> DiagnosticArray:
    arr = DiagnosticArray()
    arr.header.stamp = node.get_clock().now().to_msg()
    level = WARN if rec.result == 'invalid' else OK
    st = DiagnosticStatus(level=bytes([level]), name=f'ros_ehs/campaign/{rec.specimen}',
                          message=rec.result + (f': {rec.reason}' if rec.reason else ''),
                          hardware_id=node.get_namespace().strip('/') or 'axis')
    vals = {'specimen': rec.specimen, 'level': rec.level, 'result': rec.result,
            'cycles': rec.cycles, 'reason': rec.reason, 'peak': rec.peak, 'valley': rec.valley,
            'mean': rec.mean, 'amplitude': rec.amplitude, 'r_ratio': rec.r_ratio,
            'started': rec.started, 'ended': rec.ended}
    st.values = [KeyValue(key=k, value=(f'{v:.9g}' if isinstance(v, float) else str(v)))
                 for k, v in vals.items()]
    arr.status = [st]
    return arr


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs campaign``."""
    return run(CampaignNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
