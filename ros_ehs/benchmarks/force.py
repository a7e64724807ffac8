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
Force benchmark: the force loop on two specimens, its switches, a break, protect, its tuning.

In process (the plant node's and the controller node's cores in lock-step,
:func:`ros_ehs.core.sim.specimen_runs.run_axis`), the full model as the rig with a fatigue
actuator's seals (preset ``fatigue_actuator``: Table 1's valve and cylinder, 50/100 N friction;
docs/controller.md says why), two specimens: ``stiff`` (5e7 N/m, a metal coupon in its load
train) and ``compliant`` (5e6 N/m, a component: 10 kN is 2 mm). Each specimen's force gains come
from ``ehs_sim tune``'s rule (:func:`ros_ehs.core.control.tuning.tune`: 20 Hz asked for, 10 dB
of gain margin, 45 deg of phase margin, linearised over a 4 kN step).

* ``sine``: per specimen and frequency, a 10 kN force sine about 0 N, ``cycles`` cycles: the
  response's amplitude ratio and phase at the fundamental and the RMS error over the amplitude,
  on the last two cycles, with amplitude/phase control (``apc``: harmonics to the fifth, the
  reference node's 0.02 s latency; ``cycles``: when it converged) and with the PIDF alone
  (``pidf``). Targets: within 0.5 %, 1 deg, RMS <= 1 %, in 30 cycles.
* ``switch``: held in displacement at 5 kN, switched to force (holding the force measured),
  then back to displacement (holding the position measured): the largest force deviation
  within 0.5 s of each switch [% of the 10 kN amplitude], and the largest period-to-period step
  of the command within 20 periods of either [% of i_rated]. Targets: 1 % and 1 %.
* ``break``: a 1-10 kN force sine at 5 Hz (with APC) on a specimen whose life at that range is
  20 cycles:
  it breaks at a 10 kN peak; the piston's travel from the break to where it is held
  (``travel_mm``; ``bound_mm``: :func:`ros_ehs.core.control.safety.break_travel`, the bound
  docs/safety.md gives) and its least distance to the end stop (``end_stop_distance_mm``); without
  the detector (``specimen_break`` and ``load_feedback`` off) the force loop's travel for
  comparison. Target: at least 10 mm from the end stop.
* ``protect``: in ``displacement_force_limited`` with ``protect_force`` 2 kN, a 5 mm move at 10
  mm/s into the stiff specimen: how far the largest force went over the limit [%]. Target: 5 %.
* ``tune``: per specimen, the tuning's predicted overshoot and bandwidth, and the overshoot of
  a +-2 kN square wave on the rig (feedforward off). Target: at most 10 %, within 3 points.
* ``table1_friction``: the APC sines at 10 Hz on the paper's cylinder (1.0/2.2 kN friction):
  the seals' stick-slip, which no loop on this valve removes.
"""

import argparse
import math

import numpy as np
from ros_ehs.benchmarks import count, positives, report
from ros_ehs.benchmarks.tracking import LATENCY, sine_figures
from ros_ehs.core.control.apc import AmplitudePhaseControl
from ros_ehs.core.control.safety import break_travel
from ros_ehs.core.control.tuning import tune
from ros_ehs.core.params import Params, preset
from ros_ehs.core.sim.specimen_runs import run_axis, square_wave

FREQUENCIES = (1, 5, 10, 20)
SPECIMENS = {'stiff': 5.0e7, 'compliant': 5.0e6}
AMPLITUDE = 1.0e4
#: the tuning asked for: closed-loop bandwidth [Hz], margins [dB, deg], step [N]
TUNE = {'bandwidth_hz': 20.0, 'gain_margin_db': 10.0, 'phase_margin_deg': 45.0, 'step': 4.0e3}
SQUARE = 2.0e3
RAMP = 0.2


def rig(k: float, name: str = 'fatigue_actuator', **changes) -> Params:
    """Return the rig with a specimen of stiffness ``k`` [N/m], unbreakable unless told."""
    return preset(name, **{'k_L': k, 'specimen_life': 1e12, 'ramp_time': RAMP, **changes})


def gains(p: Params):
    """Return the force loop's tuning for the rig ``p``."""
    return tune(p, 'force', **TUNE)


def _sine(p: Params, f: float, cycles: int, apc: bool) -> dict:
    p = p.replace(control_mode='force')
    duration = RAMP + cycles / f
    if apc:
        c = AmplitudePhaseControl(AMPLITUDE, f, latency=LATENCY, learn_from=RAMP)
        run = run_axis(p, duration, c, signal='force')
        return {**sine_figures(run.t, run.load, c.desired, f, AMPLITUDE),
                'cycles': c.converged_at}
    run = run_axis(p, duration, lambda t: (math.nan, math.nan,
                                           AMPLITUDE * math.sin(2 * math.pi * f * t)))
    return {**sine_figures(run.t, run.load, lambda t: AMPLITUDE * np.sin(2 * np.pi * f * t),
                           f, AMPLITUDE), 'cycles': None}


def _sines(p: Params, freqs, cycles: int) -> dict:
    return {str(f): {'apc': _sine(p, f, cycles, True), 'pidf': _sine(p, f, cycles, False)}
            for f in freqs}


def _switch(p: Params) -> dict:
    k = float(p['k_L'])
    z0 = 0.5 * AMPLITUDE / k                      # 5 kN
    t1, t2, end = 1.0, 2.0, 3.0
    run = run_axis(p.replace(control_mode='displacement'), end,
                   lambda t: (z0 if t < t2 else math.nan, 0.0 if t < t2 else math.nan,
                              math.nan if t < t2 else 0.5 * AMPLITUDE),
                   actions=((t1, 'mode', 'force'), (t2, 'mode', 'displacement')))
    out = {}
    steps = []
    for name, ts in (('to_force_pct', t1), ('to_displacement_pct', t2)):
        k0 = int(np.searchsorted(run.t, ts - 1e-9))
        f0 = run.load[k0 - 1]
        w = slice(k0, k0 + 500)
        out[name] = round(float(np.max(np.abs(run.load[w] - f0))) / AMPLITUDE * 100, 4)
        steps.append(float(np.max(np.abs(np.diff(run.i[k0 - 20:k0 + 20])))))
    out['current_step_pct'] = round(max(steps) / float(p['i_rated']) * 100, 4)
    out['modes'] = [a[1:] for a in run.answers]
    return out


def _break(p: Params, detector: bool = True) -> dict:
    p = p.replace(specimen_life=20.0, specimen_life_range=0.9 * AMPLITUDE,
                  specimen_compliance=0.0, control_mode='force')
    if not detector:
        p = p.replace(specimen_break_action='off', load_feedback_action='off')
    f, mean, amp = 5.0, 0.55 * AMPLITUDE, 0.45 * AMPLITUDE
    apc = AmplitudePhaseControl(amp, f, mean, latency=LATENCY, learn_from=RAMP)
    run = run_axis(p, RAMP + 40 / f + 1.0, apc, signal='force')
    broke = np.nonzero((run.load == 0.0) & (run.t > RAMP))[0]
    if not broke.size:
        return {'broke': False}
    kb = int(broke[0])
    zb = run.z[kb]
    after = run.z[kb:]
    stroke = float(p['stroke'])
    trips = [e.detector for e in run.events if e.kind == 'trip']
    peak = float(np.max(run.load[max(0, kb - 100):kb]))
    return {'broke': True, 'at_cycle': round(float(run.figures['specimen_cycles']), 1),
            'peak_before_n': round(peak, 1),
            'travel_mm': round(float(np.max(np.abs(after - zb))) * 1e3, 4),
            'bound_mm': round(break_travel(p, peak, 1e-3) * 1e3, 4),
            'end_stop_distance_mm': round((stroke - float(np.max(np.abs(after)))) * 1e3, 3),
            'trips': trips, 'mode_after': run.figures['control_mode']}


def _protect(p: Params) -> dict:
    limit, move, speed, t0 = 2.0e3, 5.0e-3, 1.0e-2, 0.5
    p = p.replace(control_mode='displacement_force_limited', protect_force=limit)

    def ref(t):
        s = min(max(t - t0, 0.0) * speed, move)
        return s, (speed if 0.0 < s < move else 0.0), math.nan

    run = run_axis(p, t0 + move / speed + 1.0, ref)
    peak = float(np.max(np.abs(run.load)))
    return {'max_force_n': round(peak, 1),
            'max_force_over_limit': round(max(0.0, peak - limit) / limit * 100, 3),
            'held_at_n': round(float(run.load[-1]), 1),
            'travel_mm': round(float(run.z[-1]) * 1e3, 4)}


def _tune(p: Params) -> dict:
    r = gains(p)
    period = 2 * max(0.5, 4 * r.settling_s)
    measured, _ = square_wave(p.replace(**r.values()), 'force', SQUARE, period=period,
                              cycles=2)
    return {'predicted_overshoot_pct': round(r.overshoot_pct, 3),
            'measured_overshoot_pct': round(measured, 3),
            'bandwidth_hz': round(r.bandwidth_hz, 3),
            'phase_margin_deg': round(r.phase_margin_deg, 2),
            'gain_margin_db': round(r.gain_margin_db, 2),
            'force_kp': float(f'{r.gains.kp:.4g}'), 'force_ki': float(f'{r.gains.ki:.4g}'),
            'note': r.note}


def main(argv=None) -> int:
    """Run the benchmark and print its figures."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks force',
                                 description=__doc__.strip().splitlines()[0])
    ap.add_argument('--frequencies', type=positives, default=list(FREQUENCIES),
                    help='the force sines, comma-separated [Hz]')
    ap.add_argument('--cycles', type=count, default=30, help="each sine's cycles")
    ap.add_argument('--specimens', default=','.join(SPECIMENS),
                    help=f'comma-separated, of {list(SPECIMENS)}')
    a = ap.parse_args(argv)
    names = [s for s in a.specimens.split(',') if s]
    unknown = set(names) - set(SPECIMENS)
    if unknown or not names:
        ap.error(f'--specimens: unknown {sorted(unknown)}; known {list(SPECIMENS)}')
    fq = [int(f) if f == int(f) else f for f in a.frequencies]
    figures = {'sine': {}, 'switch': {}, 'break': {}, 'protect': {}, 'tune': {},
               'table1_friction': {}}
    for name in names:
        k = SPECIMENS[name]
        t = _tune(rig(k))
        p = rig(k, force_kp=t['force_kp'], force_ki=t['force_ki'])
        figures['tune'][name] = t
        figures['sine'][name] = _sines(p, fq, a.cycles)
        figures['switch'][name] = _switch(p)
        figures['break'][name] = _break(p)
        figures['break'][name + '_without_detector'] = _break(p, detector=False)
        friction = rig(k, 'table1_estimated', force_kp=t['force_kp'], force_ki=t['force_ki'])
        f10 = 10 if 10 in fq else fq[-1]
        figures['table1_friction'][name] = {str(f10): _sine(friction, f10, a.cycles, True)}
    if 'stiff' in names:
        k = SPECIMENS['stiff']
        t = figures['tune']['stiff']
        figures['protect'] = _protect(rig(k, force_kp=t['force_kp'], force_ki=t['force_ki']))
    sw = figures['switch'].values()
    figures['switch'].update(
        to_force_pct=max(v['to_force_pct'] for v in sw),
        to_displacement_pct=max(v['to_displacement_pct'] for v in sw),
        current_step_pct=max(v['current_step_pct'] for v in sw))
    br = [v for n, v in figures['break'].items() if not n.endswith('_without_detector')]
    if all(v.get('broke') for v in br):
        figures['break'].update(travel_mm=max(v['travel_mm'] for v in br),
                                end_stop_distance_mm=min(v['end_stop_distance_mm']
                                                         for v in br))
    _print(figures)
    return report(figures)


def _print(fig: dict) -> None:
    print('force sines, 10 kN: amplitude ratio, phase [deg], RMS error [%], cycles')
    for name, per in fig['sine'].items():
        for f, d in per.items():
            print(f'  {name:9s} {f:>4s} Hz: ' + '; '.join(
                f"{k} {v['amp_ratio']:.4f} {v['phase_deg']:+.3f} {v['rms_err_pct']:.3f} "
                f"{v['cycles']}" for k, v in d.items()))
