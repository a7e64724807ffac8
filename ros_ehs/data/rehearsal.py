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
A campaign rehearsed on the model: its plan run many times, in parallel, before a coupon is cut.

Each **replicate** draws the campaign's coupons afresh (seeded from the rehearsal's seed and
its number) and runs the campaign's rules to their end (:func:`run_campaign`, an adaptive
plan in order), its records in memory; then the replicate's fit, the target's interval, its
rig hours and run-outs are what it reports. The replicates of every plan run as tasks of
**Dask distributed**: an embedded local cluster by default (no set-up), or a lab's scheduler
by address; the same seed gives the same results on any number of workers (a replicate
depends on its seed and number only, and the results are gathered in order). A worker that
dies has its tasks run again elsewhere: a replicate is a pure function of its inputs.

**Lives** (``lives``): ``virtual`` tests each coupon as a jumped virtual test of its
procedure on the model (:func:`~ros_ehs.data.campaign.virtual_specimen`: rig hours and
achieved levels as on the rig); ``law`` draws each coupon's end from its specimen model in
closed form (the cycle at which the level step's first failure detector would trip, or the
fracture; :func:`~ros_ehs.core.sim.virtual_test.model_trip_cycle`), at the specified levels,
its hours its cycles over the frequency. The law is what the virtual test reproduces within
its jumps' 0.5 %, at no cost: the statistics of a plan are studied on it.

**The truth** of a rehearsal is the specimen model's own: the Basquin slope is Paris'
exponent, the scatter ``specimen_scatter``, and the target's true value the median
specimen's (scatter 0): each replicate's intervals are checked against it (``coverage``).

**Plans** (``plans='all'``): besides the campaign's own, the other plans at the same number
of specimens over the same range of levels: ``levels`` (4 levels log-spaced, or 3 under 8
specimens), ``pearl_string`` (down from the highest in equal steps to the lowest),
``staircase`` (from the geometric middle, a sixth of the range a step), ``adaptive`` (over the
range).
"""

from __future__ import annotations

from dataclasses import dataclass, replace as _replace
import math
import time
from typing import Any, Callable, Sequence

import numpy as np
from ros_ehs.core.campaign.runner import Next, specified_levels
from ros_ehs.core.campaign.spec import Campaign
from ros_ehs.core.errors import DataError, InputError
from ros_ehs.data.campaign import run_campaign, specimen_seed, virtual_specimen
from ros_ehs.data.store import SpecimenRecord

__all__ = ['LIVES', 'MemoryStore', 'Rehearsal', 'alternative_plans', 'law_specimen',
           'rehearse', 'rehearse_replicate', 'truth']

LIVES = ('law', 'virtual')
#: how long a scheduler given by address may take to answer [s]
CONNECT_TIMEOUT_S = 10.0


class MemoryStore:
    """A results store in memory (a rehearsal's replicate): the store's methods, no database."""

    def __init__(self) -> None:
        self._recs: list[SpecimenRecord] = []

    def campaign(self, name: str, file_hash: str = '') -> int:
        """Return the campaign's id (one campaign)."""
        return 1

    def results(self, campaign_id: int) -> list[SpecimenRecord]:
        """Return the records, in order."""
        return list(self._recs)

    def record(self, campaign_id: int, rec: SpecimenRecord) -> None:
        """Record a specimen's result, once."""
        rec.check()
        if any(r.specimen == rec.specimen for r in self._recs):
            raise InputError(f'specimen {rec.specimen!r} is already recorded')
        self._recs.append(rec)


def _level_step(campaign: Campaign, level: float):
    """Return the level step of the procedure at ``level`` (its detectors, taper, frequency)."""
    step = campaign.level_step_of(campaign.procedure(level))
    if step.control_mode != 'force' or len(step['blocks']) != 1:
        raise InputError(f'{campaign.source}: lives from the law need a force-controlled '
                         'constant-amplitude level step (use lives: virtual)')
    return step


def _law_cycles(campaign: Campaign, level: float, params, step) -> float:
    """
    Return the cycle a coupon of ``params`` ends at, at ``level``, by its specimen model.

    ``step``: the level step (:func:`_level_step`: what does not change with the level).
    """
    from ros_ehs.core.model.specimen import Specimen
    from ros_ehs.core.sim.virtual_test import model_trip_cycle
    peak, valley = specified_levels(campaign, level)
    sp = Specimen(params)
    ends = [sp.cycles_to(1.0, peak - valley) + 0.5]          # the break, at the next peak
    for e in step.end:
        if e.failure and e.kind in ('stiffness_drop', 'peak_valley_change'):
            ends.append(model_trip_cycle(sp, e.kind, e.values, peak, valley,
                                         taper=step['taper']))
    return min(ends)


def law_specimen(campaign: Campaign, nxt: Next, params, *, seed: int = 1) -> SpecimenRecord:
    """Test the next specimen by its specimen model's closed form (module docstring)."""
    p = params.replace(specimen_seed=float(specimen_seed(seed, nxt.index)))
    step = _level_step(campaign, nxt.level)
    n = _law_cycles(campaign, nxt.level, p, step)
    out = n >= campaign.run_out
    cycles = int(campaign.run_out) if out else int(math.floor(n))
    peak, valley = specified_levels(campaign, nxt.level)
    return SpecimenRecord(
        specimen=nxt.specimen, level=nxt.level, result='run_out' if out else 'failed',
        cycles=max(cycles, 1), reason='run-out' if out else 'the specimen law',
        mean=0.5 * (peak + valley), amplitude=0.5 * (peak - valley), r_ratio=valley / peak,
        amplitude_spread=0.0, peak=peak, valley=valley,
        duration_s=cycles / float(step['frequency']),
        note=f'law coupon, specimen_seed {specimen_seed(seed, nxt.index)}')


def truth(campaign: Campaign, params) -> dict:
    """Return the specimen law's truth: slope, scatter and the target's true value."""
    p = params.replace(specimen_scatter=0.0)
    out = {'k': float(params['specimen_paris_m']),
           'scatter': float(params['specimen_scatter'])}
    t = campaign.target
    if t is None:
        return out
    levels = campaign.planned_levels()
    step = _level_step(campaign, levels[0])
    if t['kind'] == 'life_at_load':
        out['target'] = _law_cycles(campaign, t['load'], p, step)
        return out
    # the load whose median life is `life`, within reach of the levels
    lo, hi = min(levels) / 1000.0, min(max(levels) * 10.0, 9.9e6)
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        if _law_cycles(campaign, mid, p, step) > t['life']:
            lo = mid
        else:
            hi = mid
        if hi / lo < 1 + 1e-12:
            break
    out['target'] = math.sqrt(lo * hi)
    return out


def alternative_plans(campaign: Campaign) -> dict[str, Campaign]:
    """Return the campaign's own plan and the others at its specimen count (module docstring)."""
    levels = campaign.planned_levels()
    lo, hi = min(levels), max(levels)
    p = campaign.plan
    n = (int(p['specimens']) * len(p['levels']) if p['method'] == 'levels'
         else int(p['specimens']))
    out = {f"{p['method']} (given)": campaign}
    nl = 4 if n >= 8 else 3
    alts = {'levels': {'method': 'levels',
                       'levels': [float(v) for v in np.geomspace(hi, lo, nl)],
                       'specimens': max(1, n // nl)},
            'pearl_string': {'method': 'pearl_string', 'start': hi,
                             'step': (hi - lo) / max(n - 1, 1), 'specimens': max(n, 2)},
            'staircase': {'method': 'staircase', 'start': math.sqrt(lo * hi),
                          'step': (hi - lo) / 6.0, 'specimens': max(n, 2)},
            'adaptive': {'method': 'adaptive', 'low': lo, 'high': hi, 'specimens': max(n, 3)}}
    for name, plan in alts.items():
        if name != p['method'] and hi > lo:
            out[name] = _replace(campaign, plan=plan)
    return out


def rehearse_replicate(campaign: Campaign, params, seed: int, replicate: int,
                       lives: str = 'law', true: dict | None = None) -> dict:
    """Run one replicate of a campaign (module docstring); return what it reports."""
    if lives not in LIVES:
        raise InputError(f'`lives` = {lives!r} must be one of {list(LIVES)}')
    rseed = specimen_seed(seed, 10 ** 6 + replicate)
    if lives == 'law':
        def test(nxt):
            return law_specimen(campaign, nxt, params, seed=rseed)
    else:
        def test(nxt):
            return virtual_specimen(campaign, nxt, params, seed=rseed)
    out = run_campaign(campaign, MemoryStore(), test)
    recs, v = out.records, out.verdict
    valid = [r for r in recs if r.result != 'invalid']
    res: dict[str, Any] = {
        'replicate': replicate, 'specimens': len(recs), 'ended': v.reason,
        'rig_h': sum(r.duration_s for r in recs) / 3600.0,
        'run_outs': sum(r.result == 'run_out' for r in recs), 'invalid': len(recs) - len(valid),
        'levels': [r.level for r in recs], 'cycles': [r.cycles for r in recs],
        'k': None, 'k_interval': None, 'target': None}
    if v.fit is not None:
        res['k'], res['k_interval'] = v.fit.k, list(v.fit.k_interval)
    if v.target is not None:
        res['target'] = {'estimate': v.target['estimate'],
                         'interval': list(v.target['interval']), 'width': v.target['width'],
                         'met': v.target['met']}
    if true is not None:
        res['covers'] = {
            'slope': None if res['k_interval'] is None else
            bool(res['k_interval'][0] <= true['k'] <= res['k_interval'][1]),
            'target': None if res['target'] is None or 'target' not in true else
            bool(res['target']['interval'][0] <= true['target'] <=
                 res['target']['interval'][1])}
    return res


@dataclass
class Rehearsal:
    """What a rehearsal found: each plan's replicates and their summary."""

    truth: dict
    plans: dict                  #: plan name -> summary (rig hours, run-outs, widths, coverage)
    replicates: dict             #: plan name -> each replicate's report, in order
    workers: int                 #: the engine's workers (0: in process, no engine)
    wall_s: float                #: from the first replicate submitted to the last back
    startup_s: float = 0.0       #: the engine's start (a local cluster) or connection


def _quantiles(v: Sequence[float]) -> dict | None:
    v = [x for x in v if x is not None and math.isfinite(x)]
    if not v:
        return None
    q = np.quantile(v, [0.1, 0.5, 0.9])
    return {'p10': float(q[0]), 'median': float(q[1]), 'p90': float(q[2])}


def _summary(reps: list[dict]) -> dict:
    n = len(reps)
    fitted = [r for r in reps if r['k'] is not None]
    out = {'replicates': n, 'fitted': len(fitted),
           'specimens': _quantiles([r['specimens'] for r in reps]),
           'rig_h': _quantiles([r['rig_h'] for r in reps]),
           'run_out_fraction': float(np.mean([r['run_outs'] / max(r['specimens'], 1)
                                              for r in reps])) if reps else None,
           'target_width': _quantiles([r['target']['width'] for r in reps if r['target']]),
           'target_met': (sum(bool(r['target'] and r['target']['met']) for r in reps) / n
                          if n else None)}
    cov = {}
    for q in ('slope', 'target'):
        judged = [r['covers'][q] for r in reps if r.get('covers') and
                  r['covers'][q] is not None]
        cov[q] = {'covered': float(np.mean(judged)), 'judged': len(judged)} if judged else None
    out['coverage'] = cov
    return out


def _client(scheduler: str | None, workers: int | None):
    """Return a Dask client: a local cluster of ``workers`` processes, or the scheduler's."""
    from distributed import Client, LocalCluster
    if scheduler:
        try:
            return Client(scheduler, timeout=CONNECT_TIMEOUT_S), None
        except (OSError, TimeoutError) as err:
            raise DataError(f'no Dask scheduler answered at {scheduler!r} within '
                            f'{CONNECT_TIMEOUT_S:g} s: {err}') from None
    cluster = LocalCluster(n_workers=workers or 2, threads_per_worker=1, processes=True,
                           dashboard_address=None, silence_logs=40)
    return Client(cluster), cluster


def rehearse(campaign: Campaign, params, replicates: int, *, seed: int = 1,
             lives: str = 'law', plans: str = 'given', scheduler: str | None = None,
             workers: int | None = None,
             progress: Callable[[int, int], None] | None = None) -> Rehearsal:
    """
    Rehearse ``campaign`` ``replicates`` times per plan on the model of ``params``.

    ``plans``: ``given`` or ``all`` (:func:`alternative_plans`); ``scheduler``: a Dask
    scheduler's address, or None for a local cluster of ``workers`` processes;
    ``workers=0``: in this process, without the engine. ``progress(done, total)``: after each
    replicate.
    """
    if not (isinstance(replicates, int) and replicates >= 1):
        raise InputError(f'`replicates` = {replicates!r} must be a whole number >= 1')
    if plans not in ('given', 'all'):
        raise InputError(f"`plans` = {plans!r} must be 'given' or 'all'")
    if lives not in LIVES:
        raise InputError(f'`lives` = {lives!r} must be one of {list(LIVES)}')
    chosen = alternative_plans(campaign)
    if plans == 'given':
        chosen = dict(list(chosen.items())[:1])
    true = truth(campaign, params)
    jobs = [(name, c, r) for name, c in chosen.items() for r in range(replicates)]
    t0 = time.monotonic()
    startup = 0.0
    results: dict[tuple[str, int], dict] = {}
    if workers == 0 and not scheduler:
        for j, (name, c, r) in enumerate(jobs):
            results[(name, r)] = rehearse_replicate(c, params, seed, r, lives, true)
            if progress is not None:
                progress(j + 1, len(jobs))
        n_workers = 0
        wall = time.monotonic() - t0
    else:
        from distributed import as_completed
        client, cluster = _client(scheduler, workers)
        try:
            if cluster is not None:
                client.wait_for_workers(workers or 2)
            n_workers = len(client.scheduler_info(n_workers=-1)['workers'])
            startup = time.monotonic() - t0
            t0 = time.monotonic()
            futs = {client.submit(rehearse_replicate, c, params, seed, r, lives, true,
                                  pure=False, retries=2): (name, r) for name, c, r in jobs}
            for j, f in enumerate(as_completed(futs)):
                results[futs[f]] = f.result()
                if progress is not None:
                    progress(j + 1, len(jobs))
            wall = time.monotonic() - t0
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    reps = {name: [results[(name, r)] for r in range(replicates)] for name in chosen}
    return Rehearsal(true, {name: _summary(v) for name, v in reps.items()}, reps, n_workers,
                     wall, startup)
