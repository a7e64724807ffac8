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
A campaign on the rig, specimen by specimen as its operator asks: the campaign node's rules.

ROS-free, as the axis's rules are: the node decodes, calls and publishes. The operator asks
for the next specimen (:meth:`RigCampaign.next_specimen`, with the id on the coupon or the plan's);
the campaign's rules (:func:`~ros_ehs.core.campaign.runner.judge`, on what the store holds)
give its level, and its procedure is written to ``<out>/<specimen>/procedure.yaml`` for the
procedure node to load (with its checkpoint beside it). While it runs, every cycle record
the procedure node publishes goes to ``<out>/<specimen>/cycles.csv`` (appended, synced to
disk a batch at a time); when the procedure node says that test has finished, its result
(:func:`~ros_ehs.core.campaign.runner.specimen_result`: failed, run out, or invalid with the
reason, and invalid when the achieved levels missed the level) is recorded in the store with
the achieved levels from those records, and the campaign judges again.

**The specimen under way** is ``<out>/current.json``, written before the procedure node is
asked to load it and removed only after its record is committed: a campaign node restarted
(killed, a power cut) finds it and waits for that test's end again, so the specimen is
recorded once. The store is the truth for what has ended. Cycle records published while the
campaign node was down come again when it subscribes again (the topic keeps its newest 100
batches for a subscriber that comes late), but not always before the test's end does: a test
that ended with records missing is recorded once they have come, or ``RECORDS_WAIT_S`` after
its end was first heard (the clock passed in). Records that never come (the procedure node
restarted too, its history gone) leave the achieved levels to those it has, and the record's
note says how many of how many.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from ros_ehs.core.campaign.runner import achieved_levels, judge, specimen_result, Verdict
from ros_ehs.core.campaign.spec import Campaign, SPECIMEN_ID, SPECIMEN_MAX
from ros_ehs.core.errors import InputError
from ros_ehs.data.campaign import campaign_hash, procedure_hash, utc_now
from ros_ehs.data.store import ResultStore, SpecimenRecord

__all__ = ['RECORDS_WAIT_S', 'RigCampaign', 'SPECIMEN_ID']

#: how long a test's end waits for cycle records still missing [s]
RECORDS_WAIT_S = 5.0


class RigCampaign:
    """
    ``campaign`` (from ``campaign_file``) run on the rig into ``store`` (module docstring).

    ``out``: the campaign's folder; ``params``: the rig's parameters in force, kept with each
    record; ``prefix``: the plan's specimen ids (``S01``...).
    """

    def __init__(self, campaign: Campaign, campaign_file: str | os.PathLike,
                 store: ResultStore, out: str | os.PathLike, *,
                 params: Mapping[str, float] | None = None, prefix: str = 'S') -> None:
        self.campaign = campaign
        self.store = store
        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.params = dict(params or {})
        self.prefix = prefix
        self.cid = store.campaign(campaign.name, campaign_hash(campaign_file))
        self._current_file = self.out / 'current.json'
        self._ended_at: float | None = None   # when the test's end came with records missing
        self.current: dict | None = None    #: the specimen under way, or None
        if self._current_file.exists():
            try:
                self.current = json.loads(self._current_file.read_text())
            except (OSError, ValueError) as err:
                raise InputError(f'{self._current_file}: not the campaign node record of the '
                                 f'specimen under way ({err}); move it away to go on '
                                 'without it') from None
            if self._recorded(self.current['specimen']):    # recorded, then killed
                self._clear()

    # -- the operator -------------------------------------------------------------------------
    def verdict(self) -> Verdict:
        """Return what the campaign's rules say after the specimens the store holds."""
        return judge(self.campaign, self.store.results(self.cid), self.prefix)

    def next_specimen(self, specimen: str = '') -> tuple[bool, str, dict | None]:
        """
        Make the next specimen the one under way: (ok, why, what the procedure node loads).

        ``specimen``: the id on the coupon ('' the plan's). Refused while one is under way,
        when the campaign has ended, or for an id that is not one or was tested already.
        """
        if self.current is not None:
            return False, (f"specimen {self.current['specimen']} is under way: its test ends "
                           'first (finished, stopped or failed)'), None
        v = self.verdict()
        if v.done:
            return False, f'the campaign has ended: {v.reason}', None
        nxt = v.next_specimen
        sid = specimen.strip() or nxt.specimen
        if not SPECIMEN_ID.match(sid):
            return False, (f'specimen id {sid!r}: letters, digits and _ . - only, '
                           f'{SPECIMEN_MAX} at most (it names a folder)'), None
        if self._recorded(sid):
            return False, f'specimen {sid} is in the store already', None
        d = self.out / sid
        d.mkdir(parents=True, exist_ok=True)
        doc = self.campaign.procedure_doc(nxt.level, sid)
        proc = d / 'procedure.yaml'
        _write_atomic(proc, json.dumps(doc, indent=1))            # JSON is YAML
        (d / 'cycles.csv').unlink(missing_ok=True)                # a run abandoned before
        self.current = {'specimen': sid, 'level': nxt.level, 'index': nxt.index,
                        'file': str(proc), 'checkpoint': str(d / 'checkpoint.json'),
                        'started': utc_now(), 'procedure_hash': procedure_hash(doc)}
        _write_atomic(self._current_file, json.dumps(self.current))
        return True, (f'{sid} at {nxt.level:g}: loading it into the procedure node; start the '
                      'test once the coupon is in'), dict(self.current)

    def abandon(self, why: str) -> None:
        """Forget the specimen under way (its procedure could not be loaded): ``why`` kept."""
        if self.current is not None:
            (self.out / self.current['specimen'] / 'abandoned').write_text(why + '\n')
        self._clear()

    # -- the procedure node -------------------------------------------------------------------
    def take_cycles(self, rows: Sequence[Sequence[float]]) -> None:
        """Keep cycle records (the contract's: count, step, flags, end stamp [ns], ...)."""
        if self.current is None or not rows:
            return
        with open(self.out / self.current['specimen'] / 'cycles.csv', 'a') as fh:
            fh.writelines(','.join(repr(float(x)) for x in r) + '\n' for r in rows)
            fh.flush()
            os.fsync(fh.fileno())

    def status(self, values: Mapping[str, Any],
               now: float | None = None) -> SpecimenRecord | None:
        """
        Take the procedure node's status; record the specimen when its test has finished.

        Returns the record (committed to the store), or None. ``now`` [s], a monotonic
        clock: a finished test with cycle records missing waits for them up to
        :data:`RECORDS_WAIT_S` (None: recorded at once with what has come).
        """
        cur = self.current
        if cur is None or values.get('file') != cur['file'] or \
                values.get('state') != 'finished':
            return None
        table = self._cycles()
        if now is not None and len(table) < int(values.get('total_cycles', 0)):
            self._ended_at = now if self._ended_at is None else self._ended_at
            if now - self._ended_at < RECORDS_WAIT_S:
                return None
        proc = self.campaign.procedure(cur['level'], cur['specimen'])
        step = self.campaign.level_step_of(proc)
        ach = achieved_levels(table, step.control_mode)
        total = int(values.get('total_cycles', 0))
        result, reason = specimen_result(self.campaign, cur['level'],
                                         str(values.get('result', '')),
                                         str(values.get('reason', '')), ach)
        have = len(table)
        rec = SpecimenRecord(
            specimen=cur['specimen'], level=float(cur['level']), result=result, cycles=total,
            reason=reason, mean=ach.mean, amplitude=ach.amplitude, r_ratio=ach.r_ratio,
            amplitude_spread=ach.amplitude_spread, peak=ach.peak, valley=ach.valley,
            duration_s=float(table[:, 2].max()) if have else math.nan,
            started=cur['started'], ended=utc_now(),
            bags=(str(self.out / cur['specimen'] / 'cycles.csv'),),
            procedure_hash=cur['procedure_hash'], params=self.params,
            note=f'on the rig; achieved levels from {have} of {total} cycle records')
        self.store.record(self.cid, rec)
        self._clear()
        return rec

    def may_protect(self, specimen: str, procedure: tuple[str, str] | None) -> bool:
        """
        Return whether specimen protect may still be switched on for ``specimen``'s coupon.

        Only for the specimen under way, and only before its test starts: ``procedure`` is
        the procedure node's (file, state) as last heard (None: not heard). A status of
        another file (the specimen's not loaded yet) or ``idle`` allows it; protect switched
        on under a running test would take it over.
        """
        cur = self.current
        if cur is None or cur['specimen'] != specimen:
            return False
        return procedure is None or procedure[0] != cur['file'] or procedure[1] == 'idle'

    def must_load(self, procedure: tuple[str, str] | None) -> bool | None:
        """
        Return whether the specimen under way must be loaded into the procedure node again.

        For a campaign node that starts with a specimen under way (it was restarted):
        ``procedure`` is the procedure node's (file, state) as first heard (None: not yet:
        returns None, ask again). A node that runs the specimen's file already is left as it
        is, whatever its state: loaded again, a test that ended while the campaign node was
        down would be put aside for a new one, and its result never recorded. Another file
        (the procedure node restarted with its own) is loaded over.
        """
        cur = self.current
        if cur is None:
            return False
        if procedure is None:
            return None
        return procedure[0] != cur['file']

    # -- inside -------------------------------------------------------------------------------
    def _cycles(self) -> np.ndarray:
        """Return the specimen's cycle table (n x 10, end in s), each count once."""
        f = self.out / self.current['specimen'] / 'cycles.csv'
        rows: dict[int, list[float]] = {}
        if f.exists():
            for line in f.read_text().splitlines():
                try:
                    r = [float(x) for x in line.split(',')]
                except ValueError:
                    continue                   # a line cut by a power cut
                if len(r) == 10:
                    rows.setdefault(int(r[0]), r)
        out = np.array([rows[k] for k in sorted(rows)], float).reshape(-1, 10)
        out[:, 2] *= 1e-9
        return out

    def _recorded(self, sid: str) -> bool:
        return any(r.specimen == sid for r in self.store.results(self.cid))

    def _clear(self) -> None:
        self._ended_at = None
        self.current = None
        self._current_file.unlink(missing_ok=True)


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + '.tmp')
    with open(tmp, 'w') as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    tmp.replace(path)
