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
Tracking metrics for the paper's sine test, defined once here and in docs/controller.md.

* ``rms_err_m`` / ``peak_err_m``: RMS and peak of ``z_ref - z`` after the first period.
* ``deadzone_s``: velocity dead zone, mean time **per half cycle** during which the piston is
  stuck, ``|z_dot| < v_th``, while the reference moves, ``|v_ref| >= v_th``. ``v_th`` is 2 %
  of the reference velocity amplitude (5 mm/s for 0.04 m at 1 Hz).
* ``plateau_s``: displacement "ceiling", mean time per half cycle that the piston is stuck at
  all (``|z_dot| < v_th``): the flat top of the displacement curve.
* ``peak_shortfall_m``: reference amplitude minus reached amplitude (ceiling height).
* ``lag_s``: delay that best aligns ``z`` with ``z_ref`` (cross-correlation, 0.1 ms grid).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ros_ehs.core.errors import DataError

__all__ = ['TrackingMetrics', 'tracking_metrics']


@dataclass(frozen=True)
class TrackingMetrics:
    """Figures of one sine-tracking run (SI units, per half cycle where stated)."""

    rms_err_m: float
    peak_err_m: float
    deadzone_s: float
    plateau_s: float
    peak_shortfall_m: float
    lag_s: float
    v_th: float
    half_cycles: float

    def as_dict(self) -> dict:
        """Return the figures as a plain dict."""
        return asdict(self)


def tracking_metrics(t, z_ref, v_ref, z, z_dot, frequency: float = 1.0,
                     skip: float | None = None) -> TrackingMetrics:
    """Compute :class:`TrackingMetrics` for a sine run, ignoring the first ``skip`` s."""
    t, z_ref, v_ref, z, z_dot = (np.asarray(a, dtype=float) for a in (t, z_ref, v_ref, z,
                                                                      z_dot))
    if not (t.shape == z_ref.shape == v_ref.shape == z.shape == z_dot.shape) or t.size < 10:
        raise DataError('tracking_metrics: signals must have one common shape, >= 10 samples')
    skip = 1.0 / frequency if skip is None else skip
    m = t >= t[0] + skip
    if m.sum() < 10:
        raise DataError(f'tracking_metrics: nothing left after skipping {skip} s')
    t, z_ref, v_ref, z, z_dot = t[m], z_ref[m], v_ref[m], z[m], z_dot[m]
    dt = float(np.median(np.diff(t)))
    span = t[-1] - t[0] + dt
    half_cycles = 2.0 * frequency * span
    e = z_ref - z
    v_th = 0.02 * np.abs(v_ref).max()
    stuck = np.abs(z_dot) < v_th
    dead = stuck & (np.abs(v_ref) >= v_th)
    amp_ref = 0.5 * (z_ref.max() - z_ref.min())
    amp = 0.5 * (z.max() - z.min())
    # lag by cross-correlation on a 0.1 ms grid up to a quarter period
    lags = np.arange(0.0, 0.25 / frequency, 1e-4)
    tt = t[(t >= t[0] + lags[-1])]
    err = [np.mean((np.interp(tt - lag, t, z_ref) - np.interp(tt, t, z)) ** 2) for lag in lags]
    return TrackingMetrics(
        rms_err_m=float(np.sqrt(np.mean(e ** 2))),
        peak_err_m=float(np.abs(e).max()),
        deadzone_s=float(dead.sum() * dt / half_cycles),
        plateau_s=float(stuck.sum() * dt / half_cycles),
        peak_shortfall_m=float(amp_ref - amp),
        lag_s=float(lags[int(np.argmin(err))]),
        v_th=float(v_th),
        half_cycles=float(half_cycles),
    )
