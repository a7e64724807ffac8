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
Standard errors of a fit: the asymptotic covariance, widened where residuals are correlated.

:func:`_covariance` is the plain estimate from the Jacobian (scaled by pi/2 for the SAE
cost); where the residuals are correlated (a model error) the standard errors are the larger
of the AR(1)-widened and the block-robust (sandwich) ones (docs/identification.md,
"Uncertainty").
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ['BLOCK_S', 'standard_errors']


def _autocorrelation_factor(metrics: dict) -> float:
    """
    Return the variance inflation for correlated residuals, (1 + rho) / (1 - rho).

    rho is the largest lag-1 autocorrelation of any signal's residual (``acf1`` of
    :func:`_metrics`; AR(1): n samples carry the information of n (1 - rho) / (1 + rho)
    independent ones); 1 for white residuals, rho capped at 0.995.
    """
    rho = max((m['acf1'] for sig in metrics.values() for m in sig.values()
               if math.isfinite(m['acf1'])), default=0.0)
    rho = min(rho, 0.995)
    return (1.0 + rho) / (1.0 - rho) if rho > 0.05 else 1.0


#: Block length [s] of the block-robust standard errors: residuals 0.1 s apart are taken as
#: independent (the model-error patterns of a reduced fit decorrelate within ~20 ms).
BLOCK_S = 0.1


def _block_robust_variance(J, r, blocks, cost) -> np.ndarray:
    """
    Diagonal of the block-robust (sandwich) covariance, scaled units.

    ``(J'J)^-1 (sum_b J_b' r_b r_b' J_b) (J'J)^-1 G / (G - 1)`` over the G blocks of residuals
    ``blocks`` labels: it holds when residuals are correlated within a block, whatever the
    pattern (Liang & Zeger's cluster estimator). Scaled by pi/2 for the SAE cost, as the
    plain estimate is.
    """
    inv = np.linalg.pinv(J.T @ J)
    g = int(blocks.max()) + 1
    scores = np.zeros((g, J.shape[1]))
    np.add.at(scores, blocks, J * r[:, None])
    meat = scores.T @ scores
    var = np.diag(inv @ meat @ inv) * g / max(g - 1, 1)
    return var * (math.pi / 2.0 if cost == 'sae' else 1.0)


def _rescale(cov: np.ndarray, var: np.ndarray) -> np.ndarray:
    """``cov`` with its diagonal set to ``var``, the correlations kept."""
    d = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    with np.errstate(invalid='ignore'):
        s = np.sqrt(np.clip(var, 0, None)) / d
    s = np.where(np.isfinite(d) & np.isfinite(s), s, 1.0)    # unidentifiable: stays inf
    return cov * np.outer(s, s)


def _covariance(J, r, n, cost, free):
    """Asymptotic covariance (scaled units), correlation, and conditioning notes."""
    notes: list[str] = []
    m = r.size
    s2 = float(np.sum(r ** 2)) / max(m - n, 1)
    if cost == 'sae':
        s2 *= math.pi / 2.0   # L1 estimator variance under Gaussian noise (efficiency 2/pi)
    norms = np.linalg.norm(J, axis=0)
    dead = norms <= 1e-9 * max(float(norms.max()), 1e-300)
    for k in np.flatnonzero(dead):
        notes.append(f'{free[k]} is not identifiable: it has no effect on the fitted '
                     'signals with this model and data')
    JtJ = J.T @ J
    try:
        cov = np.linalg.inv(JtJ) * s2
        if not np.all(np.isfinite(cov)):
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(JtJ) * s2
        notes.append('the Jacobian is singular: some parameters have no effect on the fitted '
                     'signals')
    cov[dead, :] = np.nan
    cov[:, dead] = np.nan
    cov[dead, dead] = np.inf
    d = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    with np.errstate(invalid='ignore'):
        corr = cov / np.outer(d, d)
    corr[dead, dead] = 1.0
    for a in range(n):
        for b in range(a + 1, n):
            if abs(corr[a, b]) > 0.99:
                notes.append(f'{free[a]} and {free[b]} are correlated {corr[a, b]:+.3f}: '
                             'the data cannot tell them apart')
    return cov, corr, notes


def standard_errors(J: np.ndarray, r: np.ndarray, cost: str, free, metrics: dict,
                    blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str], float]:
    """
    Return the standard errors (scaled units), the correlations, notes and the widening.

    ``J`` and ``r``: the Jacobian and residuals at the optimum; ``metrics`` as
    :func:`ros_ehs.core.identify.verdict.fit_metrics` gives them (their lag-1 autocorrelations);
    ``blocks`` labels each residual with its :data:`BLOCK_S` block. With white residuals the
    plain estimate; with correlated ones the larger of the AR(1)-widened and block-robust
    ones, and the widening (the largest ratio to the plain one) is reported.
    """
    cov, corr, notes = _covariance(J, r, len(free), cost, free)
    widen = _autocorrelation_factor(metrics)
    se_white = np.sqrt(np.clip(np.diag(cov), 0, None))
    if widen > 1.0:
        # correlated residuals: the larger of the AR(1)-widened and the block-robust error
        robust = _block_robust_variance(J, r, blocks, cost)
        cov = _rescale(cov, np.maximum(widen * np.diag(cov), robust))
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid='ignore', divide='ignore'):
        ratio = se / se_white
    widening = float(np.nanmax(ratio)) if np.any(np.isfinite(ratio)) else 1.0
    if widening > 2.0:
        notes.append(f'the residuals are correlated: standard errors widened up to '
                     f'{widening:.1f}x for it (they assume independent samples)')
    return se, corr, notes, widening
