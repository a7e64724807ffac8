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
The identification report: parameters YAML, JSON summary and PNG figures in one folder.

* ``identified_params.yaml``: a ROS 2 parameters file (``/**: ros__parameters:``) with the
  fitted values, which plant and controller load with ``--params-file``;
* ``summary.json``: values, standard errors, correlation, fit metrics (with each signal's
  residual against the sensor noise), the adequacy verdict and advice, history, warnings;
* ``fit_<experiment>.png``: measured vs fitted position and velocity, and the velocity
  residual beside the estimated sensor noise;
* ``history.png``: cost and parameters per iteration (the paper's Fig. 3);
* ``correlation.png``: the parameter correlation matrix.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
import re
import textwrap

from ros_ehs.core.identify.estimator import IdentificationResult
from ros_ehs.core.params import save_yaml

__all__ = ['write_report']


def _safe(name: str) -> str:
    return re.sub(r'[^A-Za-z0-9_.-]+', '_', name).strip('_') or 'experiment'


def write_report(result: IdentificationResult, experiments, out: str | os.PathLike, *,
                 figures: bool = True) -> dict[str, Path]:
    """
    Write the report of ``result`` on ``experiments`` (the ones it was fitted on) to ``out``.

    The fit figures plot ``result.fitted``, the model traces the fit itself computed.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    summary = result.summary()
    files['summary'] = out / 'summary.json'
    files['summary'].write_text(json.dumps(summary, indent=2, default=float) + '\n')
    if result.params is not None:
        files['params'] = save_yaml(out / 'identified_params.yaml', result.params,
                                    names=list(result.free))
    if not figures:
        return files
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    if isinstance(experiments, (list, tuple)):
        exps = list(experiments)
    else:
        exps = [experiments]
    for e, (name, fit) in zip(exps, result.fitted.items()):
        fig, ax = plt.subplots(3, 1, figsize=(9, 8), sharex=True,
                               gridspec_kw={'height_ratios': [3, 3, 2]})
        ax[0].plot(e.t, e.z * 1e3, lw=0.8, label='measured')
        ax[0].plot(e.t, fit['z'] * 1e3, lw=0.8, ls='--', label='fitted model')
        ax[0].set_ylabel('position z [mm]')
        ax[1].plot(e.t, e.v, lw=0.6, label='measured')
        ax[1].plot(e.t, fit['z_dot'], lw=0.8, ls='--', label='fitted model')
        ax[1].set_ylabel('velocity [m/s]')
        # the residual beside the sensor noise the fit estimated: an honest fit stays in it
        # except at the stick-slip reversals
        ax[2].plot(e.t, (fit['z_dot'] - e.v) * 1e3, lw=0.6, color='C3', label='fit - measured')
        sig = result.sigma.get(name, {}).get('z_dot')
        if sig:
            ax[2].axhspan(-2e3 * sig, 2e3 * sig, color='0.85', label='+-2 sigma sensor noise')
        ax[2].set_ylabel('residual [mm/s]')
        ax[2].set_xlabel('time [s]')
        m = result.metrics.get(name, {})
        title = ', '.join(f'{k}: R2 {v["r2"]:.4f}, {v["noise_ratio"]:.2f}x noise'
                          for k, v in m.items() if k in ('z_dot', 'z'))
        ax[0].set_title(f'{name}: {title}')
        if not result.adequate:
            first = textwrap.shorten(result.inadequacy[0], 110, placeholder=' ...')
            fig.suptitle(f'NOT ADEQUATE: {first} (summary.json: why, and what to run instead)',
                         color='C3', fontsize=8)
        for a in ax:
            a.grid(True, alpha=0.3)
            a.legend(loc='upper right')
        fig.tight_layout()
        p = out / f'fit_{_safe(name)}.png'
        fig.savefig(p, dpi=100)
        plt.close(fig)
        files[f'fit_{name}'] = p
    h = result.history
    if h:
        names = list(result.free)
        fig, axes = plt.subplots(len(names) + 1, 1, figsize=(7, 1.6 * (len(names) + 1)),
                                 sharex=True)
        it = [e['iteration'] for e in h]
        axes[0].semilogy(it, [max(e['cost'], 1e-300) for e in h], 'o-')
        axes[0].set_ylabel(f'{result.cost_kind.upper()}')
        for a, n in zip(axes[1:], names):
            a.plot(it, [e['x'][n] for e in h], 'o-', ms=3)
            a.set_ylabel(n, rotation=0, ha='right')
        axes[-1].set_xlabel('iteration')
        axes[0].set_title('identification history')
        fig.tight_layout()
        files['history'] = out / 'history.png'
        fig.savefig(files['history'], dpi=90)
        plt.close(fig)
    c = result.correlation
    if c.size:
        fig, ax = plt.subplots(figsize=(5.5, 4.8))
        im = ax.imshow(c, vmin=-1, vmax=1, cmap='coolwarm')
        ax.set_xticks(range(len(result.free)), result.free, rotation=45)
        ax.set_yticks(range(len(result.free)), result.free)
        for a in range(c.shape[0]):
            for b in range(c.shape[1]):
                if math.isfinite(c[a, b]):
                    ax.text(b, a, f'{c[a, b]:.2f}', ha='center', va='center', fontsize=7)
        fig.colorbar(im)
        ax.set_title('parameter correlation')
        fig.tight_layout()
        files['correlation'] = out / 'correlation.png'
        fig.savefig(files['correlation'], dpi=90)
        plt.close(fig)
    return files
