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
A campaign run specimen after specimen into its store, and its virtual coupons.

:func:`run_campaign` asks the campaign's rules (:func:`ros_ehs.core.campaign.runner.judge`)
for the next specimen, has ``test`` run it, and records its result in the store, until the
rules say the campaign has ended. The store is the truth: a campaign started again on the
same store goes on from what it holds (a specimen under way when the process died is tested
again; none is recorded twice). ``test`` is what runs one specimen's procedure: a virtual
coupon in process (:func:`virtual_specimen`), or the rig through the procedure node.

A virtual coupon is the specimen model of the rig's parameters with its own seed
(``specimen_seed`` from the campaign's seed and the specimen's place), so that its life
scatters as ``specimen_scatter`` says and the same seed gives the same campaign.
"""

from __future__ import annotations

from dataclasses import dataclass
import datetime as _dt
import hashlib
import json
import math
from pathlib import Path
import time
from typing import Callable

from ros_ehs.core.campaign.runner import achieved_levels, judge, Next, specimen_result, Verdict
from ros_ehs.core.campaign.spec import Campaign
from ros_ehs.core.errors import InputError
from ros_ehs.data.store import ResultStore, SpecimenRecord

__all__ = ['CampaignOutcome', 'campaign_hash', 'run_campaign', 'specimen_seed', 'utc_now',
           'virtual_specimen']

#: the largest seed the specimen model takes
_SEED_MAX = 2 ** 31 - 1


def utc_now() -> str:
    """Return the time now, UTC, ISO 8601 to the second (a record's ``started``/``ended``)."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec='seconds')


def campaign_hash(path: str | Path) -> str:
    """Return the SHA-256 of a campaign file's bytes (what the store links its records to)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def procedure_hash(doc: dict) -> str:
    """Return the SHA-256 of a rendered procedure (its JSON, keys sorted)."""
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def specimen_seed(seed: int, index: int) -> int:
    """Return the specimen model's seed of a campaign's ``index``-th coupon (1-based)."""
    return int((int(seed) * 1_000_003 + int(index)) % _SEED_MAX) or 1


def virtual_specimen(campaign: Campaign, nxt: Next, params, *, seed: int = 1,
                     model: str = 'simplified', rate_hz: float = 1000.0,
                     max_seconds: float | None = None, exact: bool = False
                     ) -> SpecimenRecord:
    """
    Test the next specimen as a virtual coupon: its procedure run on the model in process.

    ``params``: the rig's model with its specimen (``specimen_*``); the coupon's seed is
    :func:`specimen_seed`. The failure detectors end the test as on the rig. The settled
    cycles are jumped (:mod:`ros_ehs.core.sim.jumps`) unless ``exact``.
    """
    from ros_ehs.core.sim.jumps import CycleJumps
    from ros_ehs.core.sim.virtual_test import run_procedure
    doc = campaign.procedure_doc(nxt.level, nxt.specimen)
    proc = campaign.procedure(nxt.level, nxt.specimen)
    p = params.replace(specimen_seed=float(specimen_seed(seed, nxt.index)))
    started = utc_now()
    step = campaign.level_step_of(proc)
    limit = max_seconds if max_seconds is not None else \
        2.0 * campaign.run_out / float(step['frequency']) + 60.0
    r = run_procedure(proc, p, model=model, rate_hz=rate_hz, observe=False,
                      max_seconds=limit, jumps=None if exact else CycleJumps())
    ach = achieved_levels(r.cycles, step.control_mode)
    result, reason = specimen_result(campaign, nxt.level, r.result, r.reason, ach)
    return SpecimenRecord(
        specimen=nxt.specimen, level=nxt.level, result=result, cycles=int(r.total_cycles),
        reason=reason, mean=ach.mean, amplitude=ach.amplitude, r_ratio=ach.r_ratio,
        amplitude_spread=ach.amplitude_spread, peak=ach.peak, valley=ach.valley,
        duration_s=float(r.rig_s), started=started, ended=utc_now(), bags=(),
        procedure_hash=procedure_hash(doc),
        params={k: p[k] for k in p},
        note=(f'virtual coupon, specimen_seed {specimen_seed(seed, nxt.index)}, {model} model, '
              + ('every cycle simulated' if exact else f'{r.jumped} cycles jumped')))


@dataclass(frozen=True)
class CampaignOutcome:
    """How a campaign ended: the rules' last verdict and the records in the store."""

    verdict: Verdict
    records: list
    campaign_id: int
    tested: int                   #: specimens tested in this call (the rest were in the store)
    wall_s: float


def run_campaign(campaign: Campaign, store: ResultStore,
                 test: Callable[[Next], SpecimenRecord], *, file_hash: str = '',
                 prefix: str = 'S', max_specimens: int | None = None,
                 progress: Callable[[SpecimenRecord, Verdict], None] | None = None
                 ) -> CampaignOutcome:
    """
    Run ``campaign`` into ``store`` until its rules end it (or ``max_specimens`` are tested).

    ``test(next)`` runs one specimen and returns its record; ``progress(record, verdict)`` is
    called after each is recorded.
    """
    if max_specimens is not None and max_specimens < 0:
        raise InputError(f'`max_specimens` = {max_specimens!r} must be >= 0')
    cid = store.campaign(campaign.name, file_hash)
    t0 = time.monotonic()
    tested = 0
    records = store.results(cid)
    verdict = judge(campaign, records, prefix)     # once a specimen: it refits the curve
    while not (verdict.done or (max_specimens is not None and tested >= max_specimens)):
        nxt = verdict.next_specimen
        rec = test(nxt)
        if rec.specimen != nxt.specimen or not math.isclose(rec.level, nxt.level):
            raise InputError(f'the test returned specimen {rec.specimen!r} at '
                             f'{rec.level:g} for {nxt.specimen!r} at {nxt.level:g}')
        store.record(cid, rec)
        tested += 1
        records = store.results(cid)
        verdict = judge(campaign, records, prefix)
        if progress is not None:
            progress(rec, verdict)
    return CampaignOutcome(verdict, records, cid, tested, time.monotonic() - t0)
