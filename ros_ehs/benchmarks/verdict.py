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
Verdict benchmark: the verdict on rigs whose truth the fit did not come from.

Each rig is the full model with Table 1's seven estimated parameters drawn at random within
+-25 %, recorded in closed loop as a ros2_control driver records it and written by rosbags
(:func:`ros_ehs.data.rig_bag.record_rig_bag`): JointState position only at 250 Hz-4 kHz, an
encoder quantised 0.1-5 um with 0.5-5 um noise (both log-uniform), stamp jitter of 20 % of a
period, 0.2 % of the states lost at random (the fit's run goes on over them), chamber
pressures at up to 1 kHz or none, commands timed by receive time. The reference is a sine
(10-30 mm, 0.5-1.5 Hz) with a 1-4 mm chirp from 1 to 15 Hz on top. Each bag is fitted with
the reduced model and with the default (simplified) one.

A fit is **good** when all five of d_c, F_cc, F_sc, l_iac and c_c are within 5 % of the truth,
**bad** when any is beyond 10 % (r_c and x_bias, the valve's null shape, are not counted:
no model pins them down from such bags). A good fit called not adequate is a false alarm, a
bad fit called adequate a miss. Prints each rig's fits and the confusion matrix per model;
the last line is one JSON object with ``good_fits``, ``false_alarms`` (and
``false_alarms_by_rule``: the rules they failed, from each fit's ``failed``), ``bad_fits``,
``misses``, the same per model, per state rate (``per_rate``) and per layout
(``per_pressures``: recorded with pressures or without), and under ``noise_verdict``
the same fits judged by the verdict this one replaced (every residual within 2x its sensor
noise): the yardstick, and under ``restarts`` per model what the second start from the
halves did (:func:`restarts`). ``--fits-out FILE`` also writes each fit as a JSON line: the rig's
layout, each judged parameter's error, the verdict's reasons and its statistics (the
held-out check's added residuals and their ratios, the halves' disagreement, the sensed
signals' noise ratios, the jackknife of a slow record without pressures), so another rule
can be tried on the same fits without fitting them again.
Targets: false alarms at most 5 % of the good fits, no miss, every simplified fit of a rig
away from Table 1 that is bad caught.
"""

import json
import math
from pathlib import Path
import tempfile
import time
import warnings

import numpy as np

from ros_ehs.benchmarks import count, positive, report
from ros_ehs.core.control.waveforms import Chirp, Sine
from ros_ehs.core.errors import IdentificationWarning
from ros_ehs.core.identify import identify
from ros_ehs.core.identify.verdict import median_noise_ratios
from ros_ehs.core.params import ESTIMATED, preset

#: the parameters a fit is judged good or bad on
JUDGED = ('d_c', 'F_cc', 'F_sc', 'l_iac', 'c_c')
GOOD, BAD = 0.05, 0.10
MODELS = ('reduced', 'simplified')
#: the state rates a rig is recorded at [Hz]
RATES = (250.0, 500.0, 1000.0, 2000.0, 4000.0)


class _Reference:
    """A sine with a chirp on top: (z_ref, v_ref) at times ``t``."""

    def __init__(self, sine: Sine, chirp: Chirp):
        self.sine, self.chirp = sine, chirp

    def __call__(self, t):
        z1, v1 = self.sine(t)
        z2, v2 = self.chirp(t)
        return z1 + z2, v1 + v2


def draw_rig(k: int, seconds: float) -> dict:
    """Return rig ``k`` of the matrix: its truth, layout and reference (seeded by ``k``)."""
    from ros_ehs.data.rig_bag import RigLayout
    rng = np.random.default_rng(1000 + k)
    base = preset('table1_estimated')
    truth = base.replace(**{n: float(base[n] * rng.uniform(0.75, 1.25)) for n in ESTIMATED})
    rate = float(rng.choice(RATES))
    quantum = float(np.exp(rng.uniform(math.log(0.1e-6), math.log(5e-6))))
    noise = float(np.exp(rng.uniform(math.log(0.5e-6), math.log(5e-6))))
    pressures = str(rng.choice(['fluid', 'none']))
    layout = RigLayout(rate_hz=rate, quantum_z=quantum, noise_z=noise, pressures=pressures,
                       pressure_rate_hz=min(1000.0, rate), jitter=0.2,
                       lost=max(1, int(0.002 * rate * seconds)))
    sine = Sine(float(rng.uniform(0.01, 0.03)), float(rng.uniform(0.5, 1.5)))
    chirp = Chirp(float(rng.uniform(0.001, 0.004)), 1.0, 15.0, seconds)
    return {'truth': truth, 'layout': layout, 'reference': _Reference(sine, chirp)}


def _fit(exps, model: str, truth) -> dict:
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)
        r = identify(exps, model=model)
    err = {n: r.x[n] / truth[n] - 1.0 for n in JUDGED}
    worst = max(abs(e) for e in err.values())
    # the yardstick: the verdict before this one, every residual within 2x its sensor noise
    # and the solver converged
    noise = all(m['noise_ratio'] <= 2.0 for sig in r.metrics.values() for m in sig.values())
    restarted = {}
    if r.restart:           # the second start from the halves ran: what it began from
        restarted = {'kept': r.restart['kept'],
                     'first_errors': {n: r.restart['first']['values'][n] / truth[n] - 1.0
                                      for n in JUDGED}}
    return {'model': model, 'kind': _kind(worst), 'worst_error': worst,
            'worst_parameter': max(err, key=lambda n: abs(err[n])), 'adequate': r.adequate,
            'noise_verdict': noise and r.status != 0,
            'reason': r.inadequacy[0] if r.inadequacy else '',
            'prediction': r.halves.get('prediction', {}), 'wall_s': time.perf_counter() - t0,
            'errors': err, 'reasons': list(r.inadequacy), 'failed': list(r.failed),
            'held_out': r.halves, 'jackknife': r.jackknife,
            'status': r.status, 'settled': r.settled, 'restart': restarted,
            'noise_ratio': median_noise_ratios(r.metrics)}


def _kind(worst: float) -> str:
    return 'good' if worst <= GOOD else 'bad' if worst > BAD else 'between'


def restarts(fits: list) -> dict:
    """
    Return what the second start from the halves did to ``fits``' values.

    ``ran``: fits whose halves pointed elsewhere (``verdict.restart``); ``kept``: those whose
    second fit is the result; of those, ``closer`` and ``farther``: the worst of the five
    errors fell or rose; ``moves``: how often a kind went to another (``between->good``).
    """
    ran = [f for f in fits if f.get('restart')]
    kept = [f for f in ran if f['restart']['kept']]
    moves: dict[str, int] = {}
    closer = 0
    for f in kept:
        first = max(abs(e) for e in f['restart']['first_errors'].values())
        closer += f['worst_error'] < first
        if _kind(first) != f['kind']:
            key = f"{_kind(first)}->{f['kind']}"
            moves[key] = moves.get(key, 0) + 1
    return {'ran': len(ran), 'kept': len(kept), 'closer': closer,
            'farther': len(kept) - closer, 'moves': moves}


def confusion(fits: list, key: str = 'adequate') -> dict:
    """
    Return the counts of a list of fits by verdict ``key``: good, false alarms, bad...

    For the verdict (``key`` 'adequate'), ``false_alarms_by_rule`` too: how many false alarms
    failed each rule (``verdict.RULES``; a fit that failed two counts under both).
    """
    good = [f for f in fits if f['kind'] == 'good']
    bad = [f for f in fits if f['kind'] == 'bad']
    out = {'fits': len(fits), 'good_fits': len(good),
           'false_alarms': sum(not f[key] for f in good), 'bad_fits': len(bad),
           'misses': sum(f[key] for f in bad),
           'between': len(fits) - len(good) - len(bad),
           'between_adequate': sum(f[key] for f in fits if f['kind'] == 'between')}
    if key == 'adequate':
        by: dict[str, int] = {}
        for f in good:
            if not f[key]:
                for rule in sorted({x.split(':')[0] for x in f['failed']}):
                    by[rule] = by.get(rule, 0) + 1
        out['false_alarms_by_rule'] = by
    return out


def main(argv=None) -> int:
    """Run the matrix and print its confusion matrix and figures."""
    import argparse
    from ros_ehs.data.experiments import load_experiments
    from ros_ehs.data.rig_bag import record_rig_bag
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks verdict')
    ap.add_argument('--rigs', type=count, default=60, help='rigs in the matrix')
    ap.add_argument('--seconds', type=positive, default=8.0, help="each rig's bag [s]")
    ap.add_argument('--first', type=int, default=0, help="the first rig's seed index")
    ap.add_argument('--fits-out', type=Path, default=None,
                    help='also write each fit, its verdict and its statistics to this file '
                    '(JSON lines)')
    a = ap.parse_args(argv)
    out = None
    if a.fits_out is not None:
        try:
            out = open(a.fits_out, 'w')
        except OSError as err:
            ap.error(f'argument --fits-out: cannot write {str(a.fits_out)!r}: {err.strerror}')
    fits = []
    print('rig  rate   encoder q/noise  pressures  model       kind     worst error   '
          'verdict')
    for k in range(a.first, a.first + a.rigs):
        rig = draw_rig(k, a.seconds)
        lay = rig['layout']
        with tempfile.TemporaryDirectory() as d:
            truth = record_rig_bag(f'{d}/rig', lay, plant_params=rig['truth'],
                                   reference=rig['reference'], duration=a.seconds, seed=k)
            exps = load_experiments(f'{d}/rig', topics=lay.topic_map(truth['input_delay']))
        for model in MODELS:
            f = _fit(exps, model, rig['truth'])
            f.update(rig=k, rate_hz=lay.rate_hz, quantum_um=lay.quantum_z * 1e6,
                     noise_um=lay.noise_z * 1e6, pressures=lay.pressures, runs=len(exps))
            fits.append(f)
            if out is not None:
                out.write(json.dumps(f, default=float) + '\n')
                out.flush()
            print(f'{k:3d} {lay.rate_hz:5.0f} Hz {f["quantum_um"]:5.2f}/{f["noise_um"]:4.2f} um '
                  f'{lay.pressures:9s}  {model:10s}  {f["kind"]:7s}  '
                  f'{100 * f["worst_error"]:6.1f} % {f["worst_parameter"]:5s} '
                  f'{"adequate" if f["adequate"] else "NOT ADEQUATE: " + f["reason"][:70]}',
                  flush=True)
    if out is not None:
        out.close()
    figures = confusion(fits)
    figures['per_model'] = {m: confusion([f for f in fits if f['model'] == m])
                            for m in MODELS}
    figures['per_rate'] = {f'{r:.0f}_hz': confusion([f for f in fits if f['rate_hz'] == r])
                           for r in RATES}
    figures['per_pressures'] = {
        'with': confusion([f for f in fits if f['pressures'] != 'none']),
        'without': confusion([f for f in fits if f['pressures'] == 'none'])}
    # the yardstick, same fits: the residual-against-noise verdict
    figures['noise_verdict'] = confusion(fits, 'noise_verdict')
    figures['restarts'] = {m: restarts([f for f in fits if f['model'] == m]) for m in MODELS}
    figures['rigs'] = a.rigs
    figures['seconds'] = a.seconds
    figures['fit_s_median'] = round(float(np.median([f['wall_s'] for f in fits])), 2)
    print('\nconfusion                good: adequate / not    bad: adequate / not')
    for m, c in [*figures['per_model'].items(),
                 *((k.replace('_', ' '), c) for k, c in figures['per_rate'].items()),
                 *((f'{k} pressures', c) for k, c in figures['per_pressures'].items()),
                 ('all', figures),
                 ('noise (old)', figures['noise_verdict'])]:
        print(f'{m:18s}  {c["good_fits"] - c["false_alarms"]:12d} / {c["false_alarms"]:<6d}'
              f'   {c["misses"]:10d} / {c["bad_fits"] - c["misses"]}')
    for m, c in figures['restarts'].items():
        print(f'second start from the halves, {m}: ran on {c["ran"]}, kept on {c["kept"]} '
              f'({c["closer"]} closer to the truth, {c["farther"]} farther; kinds moved: '
              f'{c["moves"] or "none"})')
    return report(figures)
