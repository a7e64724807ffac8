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
``python -m ros_ehs.benchmarks paper``: the paper's experiments, with numbers.

Dead zone, plateau and lag are per half cycle (see ros_ehs.core.metrics); RMS error per run after
the first period. ``*_ffpid_*`` is the default feedforward; ``*_ffpid_paper_*`` the law as
printed (tau 0.016 s), ``*_ffpid_paper_tau_*`` with tau = the measured PID loop delay.
``controller_step_us`` is the mean cost of one ``Controller.step`` (PID + feedforward).
"""

import time

from ros_ehs.benchmarks import positive, report
from ros_ehs.core.control import Controller
from ros_ehs.core.params import preset
from ros_ehs.core.sim.paper_runs import paper_runs


def run(duration: float = 4.0) -> dict:
    """Run both models and return the figures."""
    out = {}
    for model in ('simplified', 'full'):
        runs = paper_runs(model, duration)
        sfx = '' if model == 'simplified' else '_full'
        for name, key in (('pid', 'pid'), ('ffpid', 'ffpid'), ('ffpid_paper', 'ffpid_paper'),
                          ('ffpid_paper_tau', 'ffpid_paper_tau'),
                          ('pid_initial_params', 'pid_initial')):
            m = runs[key][1]
            out[f'deadzone_{name}_s{sfx}'] = round(m.deadzone_s, 4)
            out[f'rms_err_{name}_m{sfx}'] = float(f'{m.rms_err_m:.4g}')
            out[f'plateau_{name}_s{sfx}'] = round(m.plateau_s, 4)
            out[f'lag_{name}_s{sfx}'] = round(m.lag_s, 4)
        out[f'deadzone_cut_ffpid{sfx}'] = round(1 - out[f'deadzone_ffpid_s{sfx}']
                                                / out[f'deadzone_pid_s{sfx}'], 3)
        out[f'rms_cut_ffpid{sfx}'] = round(1 - out[f'rms_err_ffpid_m{sfx}']
                                           / out[f'rms_err_pid_m{sfx}'], 3)
    c = Controller(preset('table1_estimated'))
    n = 20000
    t0 = time.perf_counter()
    for k in range(n):
        c.step(0.01, 0.1, 0.009)
    out['controller_step_us'] = round((time.perf_counter() - t0) / n * 1e6, 2)
    out['duration_s'] = duration
    return out


def main(argv=None) -> int:
    """Print the figures; the last line is one JSON object."""
    import argparse
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks paper')
    ap.add_argument('--duration', type=positive, default=4.0, help='each run [s]')
    return report(run(ap.parse_args(argv).duration))
