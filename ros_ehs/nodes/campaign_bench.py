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
A campaign's coupons tested on the lock-step bench: the nodes, one bench per coupon.

:class:`BenchCoupons` is the ``test`` of :func:`ros_ehs.data.campaign.run_campaign` that
runs each specimen through the nodes a rig runs (plant, controller, procedure node,
recorder, each its own process, lock-step over DDS): the level's procedure is written to the
specimen's folder, the procedure node runs it through the controller and its limit
detectors, and the result is read back from what the nodes published: the procedure's
status (its result and reason) and the cycle records in the specimen's bags. The coupon is
the plant's specimen model with the specimen's own seed (``specimen_seed``).

Everything of a specimen lives in ``<out>/<specimen>/``: ``procedure.yaml``, the procedure
node's ``checkpoint.json``, one bag per start (``bag0``, ``bag1``, ...) and the nodes' logs.
A campaign killed mid-specimen (every process at once) and started again finds that
specimen's checkpoint: the bench comes back with the coupon as it was (the plant's specimen
aged by the cycles the checkpoint counted, :meth:`~ros_ehs.core.model.specimen.Specimen.aged`),
the procedure node restores the test ``interrupted`` and the bench resumes it; the record
names every bag of the specimen. The store is the truth (``run_campaign``): a specimen is
recorded once, when its test has ended.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Callable

from ros_ehs.core.campaign.runner import achieved_levels, Next, specimen_result
from ros_ehs.core.campaign.spec import Campaign
from ros_ehs.core.model.specimen import Specimen
from ros_ehs.core.options import CONTROLLER_SPECS
from ros_ehs.core.params import Params, PLANT_SPECS
from ros_ehs.data.campaign import procedure_hash, specimen_seed, utc_now
from ros_ehs.data.fatigue import read_cycles
from ros_ehs.data.store import SpecimenRecord
from ros_ehs.nodes.processes import NodeProcesses
import ros_ehs_msgs_py as contract

__all__ = ['BenchCoupons']

#: how long a wait may see the test's clock stand still before the bench is given up [s]
STALL_S = 60.0


class BenchCoupons:
    """
    Test ``campaign``'s specimens on the lock-step bench (see the module docstring).

    ``rig``: the rig's model with its specimen (``specimen_*``); ``out``: the campaign's
    folder; ``seed``: the campaign's (each coupon's is :func:`specimen_seed`);
    ``domain_id``: the nodes' ROS domain; ``say``: where progress lines go.
    """

    def __init__(self, campaign: Campaign, rig: Params, out: str | Path, *, seed: int = 1,
                 model: str = 'simplified', domain_id: int | None = None,
                 bound: float = 60.0, say: Callable[[str], None] = print) -> None:
        self.campaign = campaign
        self.rig = rig
        self.out = Path(out)
        self.seed = int(seed)
        self.model = model
        self.domain_id = domain_id
        self.bound = float(bound)
        self.say = say
        self._ros = None

    # -- one specimen ---------------------------------------------------------------------
    def __call__(self, nxt: Next) -> SpecimenRecord:
        """Run ``nxt``'s test on the bench (or resume it) and return its record."""
        d = self.out / nxt.specimen
        d.mkdir(parents=True, exist_ok=True)
        doc = self.campaign.procedure_doc(nxt.level, nxt.specimen)
        proc_file = d / 'procedure.yaml'
        if not proc_file.exists():
            tmp = proc_file.with_suffix('.tmp')
            tmp.write_text(json.dumps(doc, indent=1))      # JSON is YAML
            tmp.replace(proc_file)
        checkpoint = d / 'checkpoint.json'
        bags = _bags(d)
        saved = json.loads(checkpoint.read_text()) if checkpoint.exists() else None
        started = _started(d)
        p = self.rig.replace(specimen_seed=float(specimen_seed(self.seed, nxt.index)))
        proc = self.campaign.procedure(nxt.level, nxt.specimen)
        step = self.campaign.level_step_of(proc)
        if saved is not None and saved.get('state') == 'finished':
            # ended before the campaign could record it (killed in between): as it ended
            st = {'result': saved.get('result', ''), 'reason': saved.get('reason', ''),
                  'total_cycles': int(saved.get('total', 0))}
        else:
            if saved is not None:
                counted = int(saved.get('total', 0))
                peak, valley = _specified(self.campaign, nxt.level)
                p = p.replace(**Specimen(p).aged(p, counted, peak - valley))
                self.say(f'  {nxt.specimen}: resuming at cycle {counted} (its checkpoint)')
            bag = d / f'bag{len(bags)}'
            opts = {'file': str(proc_file), 'checkpoint': str(checkpoint),
                    'autostart': saved is None, 'recover_bag': str(bags[-1]) if bags else ''}
            with NodeProcesses(self.domain_id, d / 'logs', bound=self.bound) as procs:
                self._loop(procs, bag, p, opts)
                if saved is not None:
                    self._wait(procs, lambda v: v['state'] == 'interrupted' and
                               int(v['stamp_ns']) > 0 and v.get('controller_mode'))
                    self._trigger('/procedure/resume')
                st = self._until_finished(procs)
                procs.stop()
            bags = _bags(d)
        per_bag = [read_cycles([b]) for b in bags]
        cycles = read_cycles(bags)
        ach = achieved_levels(cycles, step.control_mode)
        result, reason = specimen_result(self.campaign, nxt.level, st['result'], st['reason'],
                                         ach)
        (d / 'started').unlink(missing_ok=True)
        return SpecimenRecord(
            specimen=nxt.specimen, level=nxt.level, result=result,
            cycles=int(st['total_cycles']), reason=reason, mean=ach.mean,
            amplitude=ach.amplitude, r_ratio=ach.r_ratio,
            amplitude_spread=ach.amplitude_spread, peak=ach.peak, valley=ach.valley,
            # each start's clock begins at 0: the rig's time is the sum of the starts'
            duration_s=float(sum(t[:, 2].max() for t in per_bag if len(t))),
            started=started, ended=utc_now(),
            bags=tuple(str(b) for b in bags), procedure_hash=procedure_hash(doc),
            params={k: self.rig[k] for k in self.rig},
            note=f'virtual coupon on the lock-step bench, specimen_seed '
                 f'{specimen_seed(self.seed, nxt.index)}, {self.model} model'
                 + (f', {len(bags)} starts' if len(bags) > 1 else ''))

    # -- the bench --------------------------------------------------------------------------
    def _loop(self, procs: NodeProcesses, bag: Path, p: Params, opts: dict) -> None:
        """Start the coupon's lock-step bench: the procedure in the reference's place."""
        fast = {'diagnostics_period': 0.2}
        procs.start_loop('lockstep', bag=bag, procedure={**fast, **opts},
                         controller={**fast, **{s.name: p[s.name] for s in CONTROLLER_SPECS}},
                         plant={'model': self.model, 'duration': 1.0e7, **fast,
                                **{s.name: p[s.name] for s in PLANT_SPECS}})

    def _wait(self, procs: NodeProcesses, pred, bound: float | None = None) -> dict:
        if not procs.wait_status(contract.PROCEDURE_STATUS, lambda st: pred(st.values),
                                 bound or self.bound):
            raise RuntimeError('the procedure node did not get there: '
                               f'{procs.status(contract.PROCEDURE_STATUS)}')
        return procs.status(contract.PROCEDURE_STATUS).values

    def _until_finished(self, procs: NodeProcesses) -> dict:
        """Wait for the test's end while its clock moves (:data:`STALL_S` still: fail)."""
        last = None
        while True:
            st = procs.status(contract.PROCEDURE_STATUS)
            v = st.values if st is not None else {}
            if v.get('state') == 'finished':
                return v
            dead = [n for n, q in procs.procs.items() if not q.alive()]
            if dead:
                raise RuntimeError(f'{", ".join(dead)} ended before the test did: '
                                   + procs.procs[dead[0]].output()[-1500:])
            clock = (int(v.get('total_cycles', -1)), int(v.get('stamp_ns', -1)))
            if last is not None and clock == last:
                raise RuntimeError(f'the test stood still for {STALL_S:g} s: {v}')
            last = clock
            procs.wait_status(contract.PROCEDURE_STATUS,       # ends early when a node dies
                              lambda s: s.values.get('state') == 'finished' or
                              any(not q.alive() for q in procs.procs.values()), STALL_S)

    def _trigger(self, name: str) -> None:
        """Call a Trigger service until it answers (a restarted server lingers a while)."""
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from ros_ehs.nodes.ros_common import call_service
        from std_srvs.srv import Trigger
        if self._ros is None:
            ctx = rclpy.Context()
            rclpy.init(context=ctx, domain_id=self.domain_id)
            node = rclpy.create_node('campaign_bench', context=ctx)
            exe = SingleThreadedExecutor(context=ctx)
            exe.add_node(node)
            self._ros = ctx, node, exe
        _, node, exe = self._ros
        call_service(node, exe, Trigger, name, Trigger.Request(), self.bound)

    def close(self) -> None:
        """Shut down the bench's own ROS context (if a service was called)."""
        if self._ros is not None:
            import rclpy
            ctx, node, exe = self._ros
            exe.shutdown()
            node.destroy_node()
            rclpy.shutdown(context=ctx)
            self._ros = None


def _bags(d: Path) -> list[Path]:
    """Return a specimen's bags in the order they were started."""
    return sorted((b for b in d.glob('bag*') if b.name[3:].isdigit()),
                  key=lambda b: int(b.name[3:]))


def _started(d: Path) -> str:
    """Return when the specimen's test first started (kept in ``started`` until it ends)."""
    f = d / 'started'
    if f.exists():
        return f.read_text().strip()
    now = utc_now()
    f.write_text(now)
    return now


def _specified(campaign: Campaign, level: float) -> tuple[float, float]:
    from ros_ehs.core.campaign.runner import specified_levels
    peak, valley = specified_levels(campaign, level)
    if not (math.isfinite(peak) and math.isfinite(valley)):
        raise RuntimeError(f'level {level:g}: no specified peak and valley')
    return peak, valley
