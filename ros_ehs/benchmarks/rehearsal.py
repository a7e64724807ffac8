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
``python -m ros_ehs.benchmarks rehearsal``: jumped virtual tests, and campaigns rehearsed.

* ``jump``: a matrix of virtual tests to failure (:data:`MATRIX`: force control at two
  levels, Paris exponents 2.5-5, compliance growth 1 and 3, scatter drawn from a seed; the
  same specimens in displacement control; block programs), each run exact (every period
  simulated: the yardstick) and jumped (:class:`~ros_ehs.core.sim.jumps.CycleJumps`
  defaults). Per case: both runs' trip cycles of the stiffness-drop and peak/valley-change
  detectors (observed: the test goes on) and the fracture, their differences, both speeds
  (the rig's time over wall time), and ``ok``: every difference within 0.5 % or one cycle.
* ``runout_1e7_wall_s``: a 10^7-cycle run-out at 20 Hz (139 h on the rig) at a level whose
  life is 2*10^7 cycles (the crack grows all along), jumped: its wall time (target 60 s);
  ``failure_2e5_wall_s``: a test of a 2*10^5-cycle life to its fracture (the controller's
  break detector ends it), jumped (target 10 s).

* ``scaling``: the example campaign (:data:`EXAMPLE`) rehearsed ``--scaling-replicates``
  times, lives from the specimen law, in this process without the engine and on a local
  Dask cluster of 1 and of 2 workers: replicates per second from the first submitted to the
  last back (the cluster's start apart, in ``startup_s``), and ``two_over_one`` (target 1.8);
  ``identical``: the three gave the same replicates.
* ``coverage``: the example campaign and the other plans at its 12 specimens, each rehearsed
  ``--replicates`` times (lives from the law, whose truth is known): the fraction of the
  nominal 90 % intervals of the slope and of the target (the load at 10^5 cycles) that hold
  the truth, per plan (target 85-95 %); ``plans``: the rehearsal's table (rig hours,
  run-out fraction, the target's interval width, how often it was met).
* ``virtual``: the given plan rehearsed ``--virtual-replicates`` times with each coupon a
  jumped virtual test: its rig hours and run-outs beside the law's.

The last line is one JSON object with ``jump``, ``jump_ok`` (every case within its target),
``runout_1e7_wall_s``, ``failure_2e5_wall_s``, ``scaling``, ``coverage``, ``plans`` and
``virtual``.
"""

from __future__ import annotations

import argparse
import sys

from ros_ehs.benchmarks import count, report

FREQ = 20.0
#: the specimen's life at the reference range 9 kN, for the matrix [cycles]
LIFE = 3000.0
DETECTORS = [{'stiffness_drop': {'drop': 0.10}}, {'peak_valley_change': {'tolerance': 0.05}}]
#: (name, control mode, level: peak [N] / amplitude [m] / blocks, Paris m, compliance,
#: scatter) for each case; the seed is the case's place
MATRIX = (
    [(f'force {peak / 1e3:g} kN m={m:g} c={lam:g}', 'force', peak, m, lam, 0.2 * (j % 2))
     for j, (peak, m, lam) in enumerate((p, m, lam) for p in (10000.0, 8000.0)
                                        for m in (2.5, 3.0, 4.0, 5.0) for lam in (1.0, 3.0))]
    + [(f'displacement m={m:g} c={lam:g}', 'displacement', 4.5e-4, m, lam, 0.2)
       for m in (3.0, 4.0) for lam in (1.0, 3.0)]
    + [(f'blocks m={m:g}', 'force', ((10000.0, 1000.0, 4), (7000.0, 1000.0, 4)), m, 1.0, 0.0)
       for m in (3.0, 4.0)])


def _procedure(mode: str, level, run_out: int = 10 ** 9, end=DETECTORS) -> dict:
    if mode == 'displacement':
        mean = 5.5e-4                       # 1e7 N/m: 1-10 kN at the full amplitude
        cyc = {'mean': mean, 'amplitude': level}
        pre = {'name': 'to mean', 'type': 'ramp', 'to': mean, 'rate': 0.01}
    else:
        cyc = ({'blocks': [list(b) for b in level]} if isinstance(level, tuple) else
               {'peak': level, 'valley': 0.1 * level})
        pre = {'name': 'to mean', 'type': 'ramp', 'to': 5500.0, 'rate': 2.0e4}
    return {'name': 'matrix', 'control_mode': mode, 'run_out': run_out, 'steps': [
        pre, {'name': 'settle', 'type': 'dwell', 'time': 0.2},
        {'name': 'cycles', 'type': 'cyclic', 'waveform': 'sine', 'frequency': FREQ,
         'end': end, **cyc}]}


def _rig(m: float, lam: float, scatter: float, seed: int, life: float = LIFE):
    from ros_ehs.core.params import preset
    return preset('fatigue_actuator', k_L=1.0e7, specimen_life=life,
                  specimen_life_range=9000.0, specimen_paris_m=m, specimen_compliance=lam,
                  specimen_scatter=scatter, specimen_seed=float(seed))


def _case(j: int, case) -> dict:
    from ros_ehs.core.procedure.spec import parse_procedure
    from ros_ehs.core.sim.jumps import CycleJumps
    from ros_ehs.core.sim.virtual_test import run_procedure
    name, mode, level, m, lam, scatter = case
    proc = parse_procedure(_procedure(mode, level))
    p = _rig(m, lam, scatter, j + 1)
    out = {'case': name}
    runs = {}
    for kind, jumps in (('exact', None), ('jumped', CycleJumps())):
        r = run_procedure(proc, p, jumps=jumps, keep_cycles=1000, max_seconds=2.0e5)
        runs[kind] = r
        out[kind] = {'result': r.result, 'cycles': r.total_cycles,
                     'tripped': dict(r.tripped), 'fracture': r.fractured_at,
                     'jumped': r.jumped, 'speed': round(r.rig_speed, 1)}
    ex, ju = runs['exact'], runs['jumped']
    diffs, ok = {}, True
    kinds = ('stiffness_drop', 'peak_valley_change')
    pairs = [(k, ex.tripped.get(k), ju.tripped.get(k)) for k in kinds]
    pairs.append(('fracture', ex.fractured_at, ju.fractured_at))
    for k, a, b in pairs:
        if a is None or b is None:
            diffs[k] = None
            ok = ok and a is None and b is None
            continue
        d = b - a
        diffs[k] = {'cycles': d, 'rel': round(d / a, 5)}
        ok = ok and abs(d) <= max(1.0, 0.005 * a)
    out['diff'] = diffs
    out['ok'] = ok
    return out


def _long(life: float, run_out: int | None) -> dict:
    from ros_ehs.core.procedure.spec import parse_procedure
    from ros_ehs.core.sim.jumps import CycleJumps
    from ros_ehs.core.sim.virtual_test import run_procedure
    # a life of `life` at the 1-10 kN level
    p = _rig(3.0, 1.0, 0.0, 1, life)
    # the failure: the break (the controller's), at the fracture
    proc = parse_procedure(_procedure('force', 10000.0, run_out or 10 ** 9, []))
    r = run_procedure(proc, p, jumps=CycleJumps(), keep_cycles=1000,
                      max_seconds=1.0e6, observe=False)
    return {'result': r.result, 'cycles': r.total_cycles, 'jumped': r.jumped,
            'rig_h': round(r.rig_s / 3600.0, 2), 'wall_s': round(r.wall_s, 2),
            'speed': round(r.rig_speed)}


#: the example campaign: 12 coupons at 4 levels, R = 0.1, 20 Hz, its target the load at
#: 10^5 cycles within +-5 % at 90 %; the coupons' law: life 2*10^4 at 9 kN, slope 3 (Paris),
#: scatter 0.15 decades
EXAMPLE = {'name': 'example', 'level': {'kind': 'max_load', 'R': 0.1}, 'run_out': 1.2e5,
           'plan': {'method': 'levels', 'levels': [10000, 8000, 6500, 5000], 'specimens': 3},
           'target': {'kind': 'load_at_life', 'life': 1.0e5, 'confidence': 0.9,
                      'width': 0.05},
           'template': {'name': 'coupon', 'control_mode': 'force', 'steps': [
               {'name': 'preload', 'type': 'ramp', 'to': 5000.0, 'rate': 2.0e4},
               {'name': 'fatigue', 'type': 'cyclic', 'waveform': 'sine', 'peak': 1.0e4,
                'valley': 1.0e3, 'frequency': 20.0,
                'end': [{'stiffness_drop': {'drop': 0.1}}]}]}}
EXAMPLE_RIG = {'k_L': 1.0e7, 'specimen_life': 2.0e4, 'specimen_life_range': 9000.0,
               'specimen_scatter': 0.15}


#: the example campaign's specimens a level (``--specimens``)
_PER_LEVEL = [3]


def _example():
    from ros_ehs.core.campaign.spec import parse_campaign
    from ros_ehs.core.params import preset
    doc = {**EXAMPLE, 'plan': {**EXAMPLE['plan'], 'specimens': _PER_LEVEL[0]}}
    return parse_campaign(doc), preset('fatigue_actuator', **EXAMPLE_RIG)


def _scaling(replicates: int) -> dict:
    from ros_ehs.data.rehearsal import rehearse
    c, p = _example()
    out, reps = {}, {}
    for name, workers in (('in_process', 0), ('1_worker', 1), ('2_workers', 2)):
        r = rehearse(c, p, replicates, seed=11, lives='law', workers=workers)
        out[name] = {'replicates_per_s': round(replicates / r.wall_s, 3),
                     'startup_s': round(r.startup_s, 2), 'workers': r.workers}
        reps[name] = r.replicates
    out['two_over_one'] = round(out['2_workers']['replicates_per_s'] /
                                out['1_worker']['replicates_per_s'], 3)
    out['identical'] = reps['in_process'] == reps['1_worker'] == reps['2_workers']
    return out


def _coverage(replicates: int) -> tuple[dict, dict, dict]:
    from ros_ehs.data.rehearsal import rehearse
    c, p = _example()
    r = rehearse(c, p, replicates, seed=21, lives='law', plans='all', workers=2)
    cov = {}
    for plan, s in r.plans.items():
        for q in ('slope', 'target'):
            got = s['coverage'][q]
            cov[f'{plan}/{q}'] = None if got is None else round(got['covered'], 3)
    table = {plan: {k: s[k] for k in ('specimens', 'rig_h', 'run_out_fraction',
                                      'target_width', 'target_met', 'fitted')}
             for plan, s in r.plans.items()}
    return cov, table, {'truth': r.truth, 'wall_s': round(r.wall_s, 1)}


def _virtual(replicates: int) -> dict:
    from ros_ehs.data.rehearsal import rehearse
    c, p = _example()
    out = {}
    for lives in ('virtual', 'law'):
        r = rehearse(c, p, replicates, seed=31, lives=lives, workers=2)
        s = r.plans['levels (given)']
        out[lives] = {'rig_h': s['rig_h'], 'run_out_fraction': s['run_out_fraction'],
                      'target_width': s['target_width'], 'wall_s': round(r.wall_s, 1)}
    return out


def main(argv=None) -> int:
    """Run the benchmark and print its figures."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks rehearsal',
                                 description=__doc__.strip().splitlines()[0])
    ap.add_argument('--cases', type=count, default=len(MATRIX),
                    help=f'the first this many cases of the matrix (of {len(MATRIX)})')
    ap.add_argument('--runout', type=count, default=10 ** 7,
                    help='the run-out test [cycles] (its life: twice as many)')
    ap.add_argument('--failure', type=count, default=2 * 10 ** 5,
                    help="the test to failure's life [cycles]")
    ap.add_argument('--replicates', type=count, default=200,
                    help='rehearsed campaigns per plan for the coverage')
    ap.add_argument('--scaling-replicates', type=count, default=24,
                    help='rehearsed campaigns for each of the scaling runs')
    ap.add_argument('--virtual-replicates', type=count, default=4,
                    help='rehearsed campaigns of jumped virtual coupons')
    ap.add_argument('--specimens', type=count, default=3,
                    help="the example campaign's specimens at each of its 4 levels")
    a = ap.parse_args(argv)
    _PER_LEVEL[0] = a.specimens
    fig: dict = {}
    fig['jump'] = [_case(j, c) for j, c in enumerate(MATRIX[:a.cases])]
    fig['jump_ok'] = all(c['ok'] for c in fig['jump'])
    run_out = _long(2.0 * a.runout, a.runout)
    fig['runout'] = run_out
    fig['runout_1e7_wall_s'] = run_out['wall_s'] if a.runout == 10 ** 7 else None
    failure = _long(float(a.failure), None)
    fig['failure'] = failure
    fig['failure_2e5_wall_s'] = failure['wall_s'] if a.failure == 2 * 10 ** 5 else None
    fig['scaling'] = _scaling(a.scaling_replicates)
    fig['coverage'], fig['plans'], fig['coverage_run'] = _coverage(a.replicates)
    fig['virtual'] = _virtual(a.virtual_replicates)
    return report(fig)


if __name__ == '__main__':
    sys.exit(main())
