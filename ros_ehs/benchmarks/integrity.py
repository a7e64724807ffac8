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
``python -m ros_ehs.benchmarks integrity``: what a test counts against what its specimen carried.

Virtual tests (the model's own force and position are the truth, not the sensors'):

* ``envelope``: on the plant's default rig (displacement, a sine of +-``AMP_DISP`` about 0)
  and on the fatigue rig (force, 1-10 kN on a 1e7 N/m specimen), the sine's frequency at
  50 %, 90 % and 150 % of the highest the rig's envelope allows
  (:func:`~ros_ehs.core.procedure.envelope.check_envelope`, found by bisection), each
  started at once and after a ramp to its mean, ``--cycles`` cycles counted with null pacing
  (``count_tolerance`` ``TOL``). Per case: the result and its reason, the cycles counted,
  those of them the specimen carried within ``TOL`` of the range (each counted cycle's true
  extremes over its own span), the piston's closest approach to an end stop and the
  command's largest position. 150 % is refused before anything moves (the limit named), and
  is also run unchecked (``check=False``): what the rig then does; on the default rig also
  unchecked with the step's frequency backing off (``frequency_min`` a quarter of it,
  ``backoff_cycles`` 5): it should complete, every counted cycle carried, at the frequency
  it came down to.
* ``noise``: the fatigue benchmark's 1-10 kN test of a degrading specimen (life 2000 cycles)
  without noise, with 100 N (1 sigma) on the load cell, and with 10 um on the position: the
  range the specimen truly carried over cycles 100-300 against the planned one, and each
  failure detector's trip cycle against the noise-free run's.

The last line is one JSON object with ``targets`` and ``met``: at 50 and 90 % every counted
cycle carried within ``TOL``; at 150 % refused, or stopped with the limit named, the piston
never within 5 mm of an end stop and no command beyond the stroke, no cycle counted that was
not carried; under noise the true range within 0.5 % of the planned one and each detector
within 1 % of its noise-free cycle.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np
from ros_ehs.benchmarks import count, report

#: null pacing's tolerance in these tests, and the one a counted cycle is judged by [1]
TOL = 0.02
#: the default rig's sine amplitude [m]
AMP_DISP = 0.005
#: the fatigue rig's levels [N] and its specimen [N/m]
PEAK, VALLEY, K = 1.0e4, 1.0e3, 1.0e7
FRACTIONS = (0.5, 0.9, 1.5)


def _proc(mode: str, peak: float, valley: float, f: float, n: int, first: str,
          rate: float, **more) -> dict:
    cyc = {'name': 'cycles', 'type': 'cyclic', 'waveform': 'sine', 'peak': peak,
           'valley': valley, 'frequency': f, 'count': n, 'count_tolerance': TOL,
           'null_cycles': 50, **more}
    pre = [{'name': 'to mean', 'type': 'ramp', 'to': 0.5 * (peak + valley), 'rate': rate}]
    return {'name': f'{mode} {f:.4g} Hz', 'control_mode': mode,
            'steps': (pre if first == 'after_ramp' else []) + [cyc]}


def f_limit(mode: str, params, peak: float, valley: float) -> float:
    """Return the highest sine frequency the rig's envelope allows at these levels [Hz]."""
    from ros_ehs.core.procedure.envelope import check_envelope, RigEnvelope
    from ros_ehs.core.procedure.spec import parse_procedure
    rig = RigEnvelope.from_params(params)

    def ok(f):
        return not check_envelope(parse_procedure(_proc(mode, peak, valley, f, 1, 'at_once',
                                                        1.0)), rig)
    lo, hi = 1e-3, 200.0
    if ok(hi):
        return hi
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


class _Truth:
    """A probe: the true signal (the piston's position, or the specimen's force) each period."""

    def __init__(self, mode: str, window: tuple[int, int] | None = None) -> None:
        self.mode, self.window = mode, window
        self.t: list[float] = []
        self.v: list[float] = []
        self.z_max = 0.0
        self.cmd_max = 0.0

    def __call__(self, axis, runner, reply, ref) -> None:
        z = float(axis.x[axis._iz])
        self.z_max = max(self.z_max, abs(z))
        if math.isfinite(ref.z_ref):
            self.cmd_max = max(self.cmd_max, abs(ref.z_ref))
        if self.window is not None and not self.window[0] <= runner.total < self.window[1]:
            return
        self.t.append(axis.k * axis.dt)
        self.v.append(axis.true_load() if self.mode == 'force' else z)


def _frequencies(r, f: float) -> np.ndarray:
    """Return each counted cycle's frequency [Hz]: ``f``, then as the back-offs said."""
    counts = r.cycles[:, 0] if r.cycles is not None and len(r.cycles) else np.empty(0)
    out = np.full(counts.size, f)
    for e in r.events:
        if e[0] == 'procedure' and e[1] == 'pacing' and 'backed off' in e[4]:
            out[counts > e[3]] = float(e[4].split(' to ')[1].split(' Hz')[0])
    return out


def _carried(r, truth: _Truth, peak: float, valley: float, f: float,
             rate_hz: float = 1000.0) -> tuple[int, int]:
    """
    Return (counted, carried within TOL): each counted cycle's true extremes over its span.

    The truth is sampled once a period: a sampled extreme lies up to ``A (1 - cos(pi f /
    rate))`` inside the true one (``A`` the amplitude), which widens the band on that side.
    """
    t, v = np.array(truth.t), np.array(truth.v)
    ends = r.cycles[:, 2] if r.cycles is not None and len(r.cycles) else np.empty(0)
    tol = TOL * (peak - valley)
    ok = 0
    for e, f in zip(ends, _frequencies(r, f)):
        inside = 0.5 * (peak - valley) * (1.0 - math.cos(math.pi * f / rate_hz))
        m = (t > e - 1.0 / f) & (t <= e)
        if not m.any():
            continue
        hi, lo = v[m].max(), v[m].min()
        if peak - tol - inside <= hi <= peak + tol and valley - tol <= lo <= valley + tol + inside:
            ok += 1
    return int(ends.size), ok


def _envelope_case(name, mode, p, peak, valley, f, n, first, rate, check, **more) -> dict:
    from ros_ehs.core.errors import InputError
    from ros_ehs.core.procedure.spec import parse_procedure
    from ros_ehs.core.sim.virtual_test import run_procedure
    proc = parse_procedure(_proc(mode, peak, valley, f, n, first, rate, **more))
    truth = _Truth(mode)
    try:
        r = run_procedure(proc, p, probe=truth, check=check,
                          max_seconds=10.0 + 3.0 * (n + 60) / f)
    except InputError as err:
        return {'case': name, 'frequency_hz': round(f, 3), 'result': 'refused',
                'reason': str(err).splitlines()[-1].strip(), 'counted': 0, 'carried': 0}
    counted, carried = _carried(r, truth, peak, valley, f)
    stroke = float(p['stroke'])
    out = {'case': name, 'frequency_hz': round(f, 3), 'result': r.result,
           'reason': r.reason[:160], 'counted': counted, 'carried': carried,
           'end_stop_mm': round((stroke - truth.z_max) * 1e3, 2),
           'cmd_max_mm': round(truth.cmd_max * 1e3, 3)}
    if more:
        fs = _frequencies(r, f)
        out['frequency_end_hz'] = round(float(fs[-1]), 3) if fs.size else None
    return out


def envelope(n: int) -> list[dict]:
    """Run the envelope cases (module docstring)."""
    from ros_ehs.benchmarks.fatigue import _rig
    from ros_ehs.core.params import Params
    rigs = (('default', 'displacement', Params(), AMP_DISP, -AMP_DISP, 0.05),
            ('fatigue', 'force', _rig(), PEAK, VALLEY, 2.0e4))
    out = []
    for rig, mode, p, peak, valley, rate in rigs:
        f_max = f_limit(mode, p, peak, valley)
        for x in FRACTIONS:
            for first in ('at_once', 'after_ramp'):
                name = f'{rig}/{round(x * 100)}%/{first}'
                out.append(_envelope_case(name, mode, p, peak, valley, x * f_max, n, first,
                                          rate, True))
                if x > 1.0:
                    out.append(_envelope_case(name + '/unchecked', mode, p, peak, valley,
                                              x * f_max, n, first, rate, False))
                if x > 1.0 and rig == 'default' and first == 'at_once':
                    out.append(_envelope_case(name + '/backoff', mode, p, peak, valley,
                                              x * f_max, n, first, rate, False,
                                              frequency_min=0.25 * x * f_max,
                                              backoff_cycles=5))
    return out


def noise() -> list[dict]:
    """Run the noise cases (module docstring)."""
    from ros_ehs.benchmarks.fatigue import _rig, FATIGUE
    from ros_ehs.core.procedure.spec import parse_procedure
    from ros_ehs.core.sim.virtual_test import run_procedure
    life = 2000.0
    proc = parse_procedure(FATIGUE)
    cases = (('clean', {}, (0.0, 0.0, 0.0)), ('load_cell_100N', {'load_cell_noise': 100.0},
                                              (0.0, 0.0, 0.0)),
             ('position_10um', {}, (1.0e-5, 0.0, 0.0)))
    out, clean = [], None
    for name, change, sensors in cases:
        p = _rig(life).replace(**change)
        truth = _Truth('force', window=(100, 300))
        r = run_procedure(proc, p, noise=sensors, probe=truth, keep_cycles=int(2 * life) + 100)
        t, v = np.array(truth.t), np.array(truth.v)
        ranges = []
        for c in range(int(t[0] * 10) + 1, int(t[-1] * 10)):      # whole 0.1 s cycles
            m = (t >= c * 0.1) & (t < (c + 1) * 0.1)
            if m.sum() > 50:
                ranges.append(v[m].max() - v[m].min())
        true_range = float(np.median(ranges))
        row = {'case': name, 'result': r.result, 'cycles': r.total_cycles,
               'true_range_n': round(true_range, 1),
               'range_short_pct': round((1.0 - true_range / (PEAK - VALLEY)) * 100.0, 3),
               'detectors': dict(r.tripped)}
        if clean is None:
            clean = row
        else:
            row['detector_rel'] = {k: round((n - clean['detectors'][k]) /
                                            clean['detectors'][k], 4)
                                   for k, n in row['detectors'].items()
                                   if clean['detectors'].get(k)}
        out.append(row)
    return out


def main(argv=None) -> int:
    """Run the benchmark; print each case, the last line JSON."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks integrity',
                                 description=__doc__.split('\n\n')[0])
    ap.add_argument('--cycles', type=count, default=30, help='cycles each envelope case counts')
    ap.add_argument('--only', choices=('envelope', 'noise'), nargs='*', default=None)
    a = ap.parse_args(argv)
    groups = a.only or ['envelope', 'noise']
    env = envelope(a.cycles) if 'envelope' in groups else []
    noisy = noise() if 'noise' in groups else []
    for row in env + noisy:
        print(row, flush=True)
    within = [c for c in env if not c['case'].split('/')[1] == '150%']
    beyond = [c for c in env if c['case'].split('/')[1] == '150%']
    met = {}
    if within:
        met['within_counted_all_carried'] = all(c['counted'] == c['carried'] and
                                                c['counted'] > 0 for c in within)
    if beyond:
        checked = [c for c in beyond if c['case'].split('/')[-1] in ('at_once', 'after_ramp')]
        unchecked = [c for c in beyond if c['case'].endswith('unchecked')]
        backed = [c for c in beyond if c['case'].endswith('backoff')]
        met['beyond_refused'] = all(c['result'] == 'refused' for c in checked)
        met['backoff_completed_all_carried'] = all(
            c['result'] == 'completed' and c['counted'] == c['carried'] > 0 and
            c['end_stop_mm'] >= 5.0 for c in backed)
        met['beyond_unchecked_safe'] = all(
            c['counted'] == c['carried'] and c.get('end_stop_mm', 99.0) >= 5.0 and
            c['result'] != 'completed' for c in unchecked)
    if noisy:
        rest = noisy[1:]
        met['noise_range_within_0.5pct'] = all(abs(c['range_short_pct']) <= 0.5 for c in rest)
        met['noise_detectors_within_1pct'] = all(abs(x) <= 0.01 for c in rest
                                                 for x in c.get('detector_rel', {}).values())
    return report({'tolerance': TOL, 'envelope': env, 'noise': noisy, 'met': met})


if __name__ == '__main__':
    sys.exit(main())
