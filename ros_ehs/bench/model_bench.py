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
``python -m ros_ehs.bench model``: speed and accuracy of the plant integrators.

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

from ros_ehs.bench import report
from ros_ehs.closed_loop import reference_step, run_closed_loop
from ros_ehs.model.plant import DEFAULT_H, Plant
from ros_ehs.params import preset
from ros_ehs.reference import Sine


def _best_of(fn, repeat=3):
    best = float('inf')
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def run(duration_err: float = 1.0, duration_rtf: float = 4.0) -> dict:
    """Run the benchmark and return the figures."""
    p = preset('table1_estimated', ff_enable=0.0)
    out = {'h_full_s': DEFAULT_H['full'], 'h_simplified_s': DEFAULT_H['simplified'],
           'control_period_s': 1e-3}
    cl = run_closed_loop(p, Sine(), duration_rtf, model='full')
    u = np.column_stack([cl.i[:-1], np.zeros(cl.i.size - 1)])
    for model in ('full', 'simplified'):
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
    n = 500
    x = plant.equilibrium()
    t0 = time.perf_counter()
    for k in range(n):
        x = reference_step(plant, x, u[k], 1e-3, rtol=1e-6, method='LSODA', atol_scale=1e-6)
    out['rtf_solve_ivp_full'] = round(n * 1e-3 / (time.perf_counter() - t0), 2)
    out['rtf_ratio_full_vs_solve_ivp'] = round(out['rtf_full'] / out['rtf_solve_ivp_full'], 1)

    for model in ('full', 'simplified'):
        fast = run_closed_loop(p, Sine(), duration_err, model=model)
        ref = run_closed_loop(p, Sine(), duration_err, model=model, stepper='reference')
        out[f'max_pos_err_{model}_m'] = float(f'{np.abs(fast.z - ref.z).max():.3g}')
    out['err_horizon_s'] = duration_err
    return out


def main(argv=None) -> int:
    """Print the figures; the last line is one JSON object."""
    return report(run())
