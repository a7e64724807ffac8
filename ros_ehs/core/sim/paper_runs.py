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
The paper's section 5 experiments in simulation (no ROS): runs, metrics and figures.

Runs on the 1 Hz / 0.04 m sine (``duration`` s, first period skipped by the metrics):

* ``pid_initial``: PID on the plant with Table 1 initial parameters (Figs. 5, 6);
* ``pid``: PID on the plant with Table 1 estimated parameters (Figs. 5, 6, 7);
* ``ffpid_paper``: + feedforward of eqs. (9)-(20) as printed (tau = 0.016 s, no velocity term);
* ``ffpid_paper_tau``: the same with tau = the measured loop delay of the PID run;
* ``ffpid``: + the default feedforward (friction/damping of eq. 20 and velocity feedforward).
"""

from __future__ import annotations

from pathlib import Path

from ros_ehs.core.control.waveforms import Sine
from ros_ehs.core.metrics import tracking_metrics
from ros_ehs.core.params import preset
from ros_ehs.core.sim.closed_loop import run_closed_loop

__all__ = ['paper_runs', 'plot_runs']


def paper_runs(model: str = 'simplified', duration: float = 4.0) -> dict:
    """Return ``{name: (ClosedLoopResult, TrackingMetrics)}`` for the five runs above."""
    ini = preset('table1_initial', ff_enable=0.0)
    est = preset('table1_estimated', ff_enable=0.0)
    out = {}

    def run(name, plant, ctrl):
        r = run_closed_loop(plant, Sine(), duration, model=model, controller_params=ctrl)
        out[name] = (r, tracking_metrics(r.t, r.z_ref, r.v_ref, r.z, r.z_dot))

    run('pid_initial', ini, ini)
    run('pid', est, est)
    paper_ff = est.replace(ff_enable=1.0, ff_velocity=0.0, tau_delay=0.016)
    run('ffpid_paper', est, paper_ff)
    run('ffpid_paper_tau', est, paper_ff.replace(tau_delay=round(out['pid'][1].lag_s, 3)))
    run('ffpid', est, preset('table1_estimated'))
    return out


def plot_runs(runs: dict, out_dir: str | Path, model: str) -> list[Path]:
    """Write the displacement and velocity comparisons as PNG files; return their paths."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    figs = [('fig5_6_initial_vs_estimated', ['pid_initial', 'pid'],
             'PID: Table 1 initial vs estimated plant parameters'),
            ('fig7_pid_vs_ffpid', ['pid', 'ffpid_paper_tau', 'ffpid'],
             'Estimated plant: PID vs feedforward PID')]
    paths = []
    for stem, names, title in figs:
        fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
        r0 = runs[names[0]][0]
        ax1.plot(r0.t, r0.z_ref * 1e3, 'k--', lw=1, label='reference')
        ax2.plot(r0.t, r0.v_ref, 'k--', lw=1, label='reference')
        for n in names:
            r, m = runs[n]
            lab = f'{n} (dead zone {m.deadzone_s * 1e3:.0f} ms, rms {m.rms_err_m * 1e3:.2f} mm)'
            ax1.plot(r.t, r.z * 1e3, lw=1.2, label=lab)
            ax2.plot(r.t, r.z_dot, lw=1.2, label=n)
        ax1.set_ylabel('displacement z [mm]')
        ax2.set_ylabel('velocity z_dot [m/s]')
        ax2.set_xlabel('time [s]')
        ax1.set_title(f'{title} ({model} model, 1 Hz / 0.04 m sine)')
        ax1.legend(fontsize=8, loc='lower left')
        ax2.legend(fontsize=8, loc='lower left')
        for ax in (ax1, ax2):
            ax.grid(alpha=0.3)
            ax.set_xlim(1.0, min(3.0, r0.t[-1]))
        fig.tight_layout()
        path = out_dir / f'{stem}_{model}.png'
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths
