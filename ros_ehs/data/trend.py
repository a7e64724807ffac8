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
The trend of the live estimates over a long run, from its bag (``ehs_sim trend``).

:func:`read_estimates` takes the ``parameter_estimates`` messages the recorder kept;
:func:`plot_trend` draws each parameter's estimate against time with its band of
``sigmas`` standard errors, adequate fits filled, the others hollow, and each push marked;
:func:`trend_table` gives the same as text.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Sequence

from ros_ehs.core.errors import BagError, DataError
from ros_ehs.core.params import spec
from ros_ehs.data.bag.reader import open_bag
from ros_ehs.data.experiments import resolve_topic
import ros_ehs_msgs_py as contract

__all__ = ['plot_trend', 'read_estimates', 'trend_table']


def read_estimates(path: str | os.PathLike) -> list[contract.ParameterEstimate]:
    """Return the live estimates of the bag at ``path`` in stamp order (BagError if none)."""
    bag = open_bag(path)
    topic = resolve_topic(bag, contract.ESTIMATES.name)
    out = []
    for m, msg in bag.decoded([topic]):
        try:
            out.append(contract.estimate_from_msg(msg))
        except ValueError as err:
            raise BagError(f'{topic} at {m.log_time_ns} ns: {err}') from None
    return sorted(out, key=lambda e: e.stamp_ns)


def trend_table(estimates: Sequence[contract.ParameterEstimate]) -> str:
    """Return one line per refit: time from the first, each value +- its stderr, verdict."""
    fits = [e for e in estimates if e.values]
    if not fits:
        return 'no fit in the recording'
    names = list(fits[0].values)
    t0 = estimates[0].stamp_ns
    lines = ['  t [s]  ' + '  '.join(f'{n:>22}' for n in names) + '  adequate  pushed']
    for e in estimates:
        t = (e.stamp_ns - t0) * 1e-9
        if not e.values:
            lines.append(f'{t:7.1f}  {e.verdict}')
            continue
        cells = '  '.join(f'{e.values.get(n, math.nan):11.5g} +- {e.stderr.get(n, math.nan):7.2g}'
                          for n in names)
        lines.append(f'{t:7.1f}  {cells}  {str(e.adequate):>8}  {str(e.pushed):>6}')
    return '\n'.join(lines)


def plot_trend(estimates: Sequence[contract.ParameterEstimate], out: str | os.PathLike,
               names: Sequence[str] | None = None, sigmas: float = 3.0) -> Path:
    """Plot each parameter's estimate over time with its band into the PNG ``out``."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import numpy as np

    fits = [e for e in estimates if e.values]
    if not fits:
        raise DataError('no fit among the estimates: nothing to plot (see their verdicts)')
    names = list(names or fits[0].values)
    t0 = estimates[0].stamp_ns
    t = np.array([(e.stamp_ns - t0) * 1e-9 for e in fits])
    ok = np.array([e.adequate for e in fits])
    pushed = np.array([e.pushed for e in fits])
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 1.9 * len(names) + 0.6), sharex=True,
                             squeeze=False)
    for ax, n in zip(axes[:, 0], names):
        v = np.array([e.values.get(n, np.nan) for e in fits])
        se = np.array([e.stderr.get(n, np.nan) for e in fits])
        band = np.where(ok, sigmas * se, np.nan)
        ax.fill_between(t, v - band, v + band, color='C0', alpha=0.25, lw=0,
                        label=f'+-{sigmas:g} stderr')
        ax.plot(t[ok], v[ok], 'o', ms=3, color='C0', label='adequate')
        ax.plot(t[~ok], v[~ok], 'o', ms=3, mfc='none', color='C3', label='not adequate')
        for tp in t[pushed]:
            ax.axvline(tp, color='C2', lw=0.8, alpha=0.6)
        ax.set_ylabel(f'{n} [{spec(n).unit}]')
        ax.grid(alpha=0.3)
    axes[0, 0].plot([], [], color='C2', lw=0.8, label='pushed')
    axes[0, 0].legend(loc='best', fontsize=7, ncol=4)
    axes[-1, 0].set_xlabel('time from the first refit [s]')
    fig.suptitle('live estimates')
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
