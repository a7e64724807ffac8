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
The input delay of a rig: from a command's stamp (or receive time) to the valve acting on it.

A rig's bag records the commands, not the current the valve got: the driver applies a command
a cycle or two after it arrives, and a command without a header carries only the recorder's
receive time. :func:`delay_profile` replays the fitted model with the current rebuilt at
candidate delays (:meth:`~ros_ehs.data.experiments.Experiment.with_delay`: the command in force
``d`` earlier, averaged over each period, so the cost is continuous in ``d``) and returns the
sum of squared normalised residuals of each; :func:`estimate_delay` takes its minimum, and
its standard error from the profile's curvature, ``sqrt(2 s^2 / S'')`` with
``s^2 = S_min / (N - p)`` (the least-squares covariance of one more parameter), widened by the
fit's own widening for correlated residuals (``stderr_widening``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Sequence

import numpy as np

from ros_ehs.core.errors import DataError, InputError
from ros_ehs.core.identify.problem import FIT_H, Problem, SIGNALS
from ros_ehs.core.params import Params

__all__ = ['DelayEstimate', 'MAX_DELAY', 'delay_profile', 'estimate_delay', 'with_delay']

#: Delays searched [s]: a driver cycle or two and the network, with room to spare.
MAX_DELAY = 0.02


@dataclass(frozen=True)
class DelayEstimate:
    """The estimated input delay [s], its standard error [s] and the profile it came from."""

    value: float
    stderr: float
    delays: np.ndarray = field(repr=False)
    cost: np.ndarray = field(repr=False)

    def as_dict(self) -> dict:
        """Return the figures for a report (the profile as lists)."""
        return {'value_s': self.value, 'stderr_s': self.stderr, 'estimated': True,
                'profile_s': [float(d) for d in self.delays],
                'profile_cost': [float(c) for c in self.cost]}


def with_delay(experiments: Sequence, delay: float) -> list:
    """
    Return the runs with their current rebuilt ``delay`` [s] after the commands.

    Runs whose current is the one the valve got (no command series) are left as they are.
    """
    return [e.with_delay(delay) if e.commands is not None else e for e in experiments]


def delay_profile(experiments: Sequence, params: Params, delays: Sequence[float], *,
                  model: str = 'simplified', signals: Sequence[str] = SIGNALS,
                  segment: float | None = 1.0) -> np.ndarray:
    """Return the sum of squared normalised residuals of ``params`` at each delay [s]."""
    if not any(e.commands is not None for e in experiments):
        raise InputError('`experiments`: no run has a command series (a bag whose state '
                         'reports the applied current has no delay to estimate)')
    out = []
    for d in delays:
        exps = with_delay(experiments, float(d))
        prob = Problem(exps, params, ('c_c',), model, signals, segment, FIT_H[model])
        r = prob.residual(np.array([params['c_c']]) / prob.scale)
        out.append(float(r @ r))
    return np.asarray(out)


def estimate_delay(experiments: Sequence, params: Params, *, model: str = 'simplified',
                   signals: Sequence[str] = SIGNALS, segment: float | None = 1.0,
                   n_free: int = 7, widening: float = 1.0,
                   max_delay: float = MAX_DELAY) -> DelayEstimate:
    """
    Return the delay that minimises the replay cost of ``params``, with its standard error.

    A coarse scan in whole periods over ``[0, max_delay]``, then a scan in quarter periods
    around the best; the standard error from a parabola through the fine scan's minimum and
    its neighbours. ``n_free`` is the fit's number of free parameters (for ``N - p``).
    """
    if not experiments:
        raise InputError('`experiments`: give at least one run')
    dt = min(e.dt for e in experiments if e.commands is not None)
    coarse = np.arange(0.0, max_delay + 0.5 * dt, dt)
    c0 = delay_profile(experiments, params, coarse, model=model, signals=signals,
                       segment=segment)
    best = float(coarse[int(np.argmin(c0))])
    fine = best + np.arange(-4, 5) * 0.25 * dt
    fine = fine[fine >= 0.0]
    c1 = delay_profile(experiments, params, fine, model=model, signals=signals,
                       segment=segment)
    k = int(np.argmin(c1))
    value = float(fine[k])
    n = sum(e.t.size * len([s for s in signals if s in e.signals()]) for e in experiments)
    s2 = float(c1[k]) / max(1, n - n_free - 1)
    lo, hi = max(0, k - 2), min(fine.size, k + 3)
    stderr = math.nan
    if hi - lo >= 3:
        a2 = np.polyfit(fine[lo:hi] - value, c1[lo:hi], 2)[0]     # S ~ a2 (d - d*)^2 + ...
        if a2 > 0:
            stderr = math.sqrt(2.0 * s2 / (2.0 * a2)) * max(1.0, widening)
    if not math.isfinite(stderr):
        raise DataError('the input delay is not identifiable from these runs: the replay '
                        'cost has no minimum between 0 and '
                        f'{max_delay * 1e3:g} ms (give it: --input-delay)')
    delays = np.concatenate([coarse, fine])
    cost = np.concatenate([c0, c1])
    o = np.argsort(delays, kind='stable')
    return DelayEstimate(value, stderr, delays[o], cost[o])
