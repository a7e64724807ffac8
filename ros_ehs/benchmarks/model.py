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
``python -m ros_ehs.benchmarks model``: speed and accuracy of the plant integrators.

All figures come from one run on this machine, side by side:

* ``rtf_full`` / ``rtf_simplified``: simulated seconds per wall second of the batch kernel at
  the plant node's step sizes (1 ms zero-order hold, internal ``h`` of ``DEFAULT_H``), one core;
* ``rtf_*_step_api``: the same through the checked per-period ``Plant.step`` call the plant
  node makes (Python call overhead included);
* ``rtf_solve_ivp_full``: scipy LSODA (rtol 1e-6) on the same model and input, restarted
  every 1 ms period as a plant node would have to;
* ``max_pos_err_*_m``: closed loop 1 Hz / 0.04 m (paper PID), fast stepper against the
  Radau (rtol 1e-10) reference stepper.
"""

import time

import numpy as np

from ros_ehs.benchmarks import positive, report
from ros_ehs.core.control.waveforms import Chirp, Sine
from ros_ehs.core.model.plant import DEFAULT_H, Plant
from ros_ehs.core.params import preset
from ros_ehs.core.sim.closed_loop import model_difference, reference_step, run_closed_loop


def _best_of(fn, repeat=3):
    best = float('inf')
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def run(duration_err: float = 1.0, duration_rtf: float = 4.0,
        duration_fidelity: float = 10.0) -> dict:
    """Run the benchmark and return the figures."""
    p = preset('table1_estimated', ff_enable=0.0)
    out = {f'h_{m}_s': h for m, h in DEFAULT_H.items()}
    out['control_period_s'] = 1e-3
    cl = run_closed_loop(p, Sine(), duration_rtf, model='full')
    u = np.column_stack([cl.i[:-1], np.zeros(cl.i.size - 1)])
    for model in ('full', 'reduced', 'simplified'):
        plant = Plant(p, model)
        plant.simulate(1e-3, u[:5])
        wall = _best_of(lambda: plant.simulate(1e-3, u))
        out[f'rtf_{model}'] = round(duration_rtf / wall, 1)
        x0 = plant.equilibrium()
        n = min(u.shape[0], 2000)

        def stepping():
            x = x0
            for k in range(n):
                x = plant.step(x, u[k], 1e-3)
        out[f'rtf_{model}_step_api'] = round(n * 1e-3 / _best_of(stepping, 2), 1)

    plant = Plant(p, 'full')
    n = min(500, u.shape[0])
    x = plant.equilibrium()
    t0 = time.perf_counter()
    for k in range(n):
        x = reference_step(plant, x, u[k], 1e-3, rtol=1e-6, method='LSODA', atol_scale=1e-6)
    out['rtf_solve_ivp_full'] = round(n * 1e-3 / (time.perf_counter() - t0), 2)
    out['rtf_ratio_full_vs_solve_ivp'] = round(out['rtf_full'] / out['rtf_solve_ivp_full'], 1)

    for model in ('full', 'reduced', 'simplified'):
        fast = run_closed_loop(p, Sine(), duration_err, model=model)
        ref = run_closed_loop(p, Sine(), duration_err, model=model, stepper='reference')
        out[f'max_pos_err_{model}_m'] = float(f'{np.abs(fast.z - ref.z).max():.3g}')
    out['err_horizon_s'] = duration_err
    out['vs_full'] = fidelity(duration_fidelity)
    return out


#: The fidelity cases of docs/model.md: the paper's sine and 0.2-5 Hz chirps (10 s each).
FIDELITY_CASES = {'sine_1hz_40mm': Sine(0.04, 1.0)} | {
    f'chirp_0.2-5hz_{round(a * 1e3)}mm': Chirp(amplitude=a, f0=0.2, f1=5.0, duration=10.0)
    for a in (0.04, 0.02, 0.01, 0.005)}


def fidelity(duration: float = 10.0) -> dict:
    """
    Relative RMS differences [%] of the reduced and simplified models from the full one.

    Table 1's estimated values, the default controller, each case of ``FIDELITY_CASES``;
    ``full_h/2`` and ``full_F_sc+1%`` are the full model against itself, for scale: how much
    the response moves with the integration step and with 1 % more breakaway friction.
    """
    p = preset('table1_estimated')
    out = {}
    for case, ref in FIDELITY_CASES.items():
        rows = {m: model_difference(p, ref, duration, m) for m in ('reduced', 'simplified')}
        rows['full_h/2'] = model_difference(p, ref, duration, 'full', h=DEFAULT_H['full'] / 2)
        rows['full_F_sc+1%'] = model_difference(p.replace(F_sc=1.01 * p['F_sc']), ref, duration,
                                                'full', against_params=p)
        out[case] = {m: {k: round(100 * v, 2) for k, v in r.items() if k != 'current'}
                     for m, r in rows.items()}
    return out


def main(argv=None) -> int:
    """Print the figures; the last line is one JSON object."""
    import argparse
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks model')
    ap.add_argument('--seconds', type=positive, default=4.0,
                    help='simulated time of the real-time-factor runs [s]')
    ap.add_argument('--err-seconds', type=positive, default=1.0,
                    help='horizon of the integration error against solve_ivp [s]')
    ap.add_argument('--fidelity-seconds', type=positive, default=10.0,
                    help="each fidelity case's length [s]")
    a = ap.parse_args(argv)
    return report(run(a.err_seconds, a.seconds, a.fidelity_seconds))
