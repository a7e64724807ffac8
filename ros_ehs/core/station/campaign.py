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
The station's campaign panel: the S-N plot, the specimens and the next level.

:class:`CampaignPanel` takes the campaign node's messages as plain values (no ROS types):
its status (``ros_ehs/campaign`` in ``diagnostics``) and each record on ``campaign/results``,
and answers :meth:`CampaignPanel.snapshot`: None until a campaign is heard; then its state,
the specimens' table, the S-N points by result (``failed``, ``run_out``; ``invalid`` ones
are listed, never plotted: their lives say nothing of the level), the median curve with
its 10 % and 90 % curves, the next level and the verdict.

The curves are the campaign node's own fit, carried in its status (``fit_a``, ``fit_k``,
``fit_s``: Basquin, ``log10 N = a - k log10 S``, log-normal scatter ``s`` decades): the
station draws what the campaign decides on, it does not fit again. They span the levels
tested, widened by a tenth each way.

A record heard twice (a transient-local topic replays its history to a station that starts
or reconnects) is one row: the newest. A campaign node not heard for ``lost_after`` seconds
(``now`` passed in, a monotonic clock) is said in ``lost``: the page then offers no next
specimen. Bounded: at most ``max_specimens`` rows, the newest
kept (the count of all stays); 24 specimens make a design campaign.
"""

from __future__ import annotations

import math
from typing import Any

from ros_ehs_msgs_py.values import NodeStatus

__all__ = ['CampaignPanel', 'CURVE_POINTS', 'RESULT_KEYS', 'Z90']

#: the points of each drawn curve
CURVE_POINTS = 24
#: the standard normal's 90 % quantile: the 10 % and 90 % curves lie this many scatters from
#: the median
Z90 = 1.2815515655446004
#: what a specimen's row carries, from its record on ``campaign/results``
RESULT_KEYS = ('specimen', 'level', 'result', 'cycles', 'reason', 'mean', 'amplitude',
               'r_ratio', 'peak', 'valley', 'started', 'ended')
_NUMBERS = ('level', 'cycles', 'mean', 'amplitude', 'r_ratio', 'peak', 'valley')
_RESULTS = ('failed', 'run_out', 'invalid')


def _num(text: Any) -> float | None:
    """Return a status value as a finite float, or None (missing, 'nan', not a number)."""
    try:
        x = float(text)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


class CampaignPanel:
    """The campaign as the page shows it (see the module docstring)."""

    def __init__(self, max_specimens: int = 1000, lost_after: float = 3.0) -> None:
        if not (isinstance(max_specimens, int) and max_specimens >= 1):
            raise ValueError(f'`max_specimens` = {max_specimens!r} must be an int >= 1')
        if not (math.isfinite(lost_after) and lost_after > 0):
            raise ValueError(f'`lost_after` = {lost_after!r} s must be finite and > 0')
        self.max_specimens = max_specimens
        self.lost_after = float(lost_after)
        self.status: NodeStatus | None = None
        self.heard = math.nan                  # when the status came [s, the caller's clock]
        self.records = 0                       # records taken, repeats included
        self._rows: dict[str, dict] = {}       # by specimen id, in the order last heard

    def take_status(self, status: NodeStatus, now: float) -> None:
        """Take the campaign node's status, heard at ``now`` [s]."""
        self.status = status
        self.heard = float(now)

    def take_result(self, record: NodeStatus) -> None:
        """
        Take one specimen's record (its values: :data:`RESULT_KEYS`).

        A record without a specimen id or with a result that is not one of ``failed``,
        ``run_out``, ``invalid`` raises ValueError naming it (the node logs and drops it).
        """
        v = record.values
        sid = str(v.get('specimen', '')).strip()
        if not sid:
            raise ValueError(f'campaign record {record.name!r} names no specimen')
        if v.get('result') not in _RESULTS:
            raise ValueError(f'campaign record of {sid}: result {v.get("result")!r} is not '
                             f'one of {list(_RESULTS)}')
        row = {k: (_num(v.get(k)) if k in _NUMBERS else str(v.get(k, '')))
               for k in RESULT_KEYS}
        row['specimen'] = sid
        self.records += 1
        self._rows.pop(sid, None)
        self._rows[sid] = row
        while len(self._rows) > self.max_specimens:
            del self._rows[next(iter(self._rows))]

    def snapshot(self, now: float) -> dict | None:
        """Return what the page draws at ``now`` [s], JSON-able (None: no campaign heard)."""
        if self.status is None and not self._rows:
            return None
        st = self.status
        v = st.values if st is not None else {}
        age = now - self.heard
        out: dict[str, Any] = {
            'lost': (f'no status from the campaign node for {age:.1f} s' if age > self.lost_after
                     else '') if st is not None else 'no status from the campaign node yet',
            'heard': st is not None, 'level': st.level if st else None,
            'message': st.message if st else 'no campaign status yet (its results only)',
            **{k: str(v.get(k, '')) for k in ('state', 'specimen', 'verdict', 'unit', 'name',
                                              'store')},
            **{k: _num(v.get(k)) for k in ('next_level', 'run_out_cycles')},
            'under_way_level': _num(v.get('level')),
            'specimens': list(self._rows.values()), 'records': self.records}
        points: dict[str, list] = {'failed': [[], []], 'run_out': [[], []]}
        for r in self._rows.values():
            if r['result'] in points and r['level'] and r['cycles'] and \
                    r['level'] > 0 and r['cycles'] > 0:
                points[r['result']][0].append(r['cycles'])
                points[r['result']][1].append(r['level'])
        out['points'] = points
        out['counts'] = {k: sum(r['result'] == k for r in self._rows.values())
                         for k in _RESULTS}
        fit = {k: _num(v.get('fit_' + k)) for k in ('a', 'k', 's')}
        ok = all(x is not None for x in fit.values()) and fit['k'] > 0 and fit['s'] >= 0
        out['fit'] = fit if ok else None
        out['curves'] = self._curves(fit) if ok else None
        return out

    def _curves(self, fit: dict) -> dict | None:
        """Return the 10/50/90 % curves over the levels tested: loads and each curve's lives."""
        levels = [r['level'] for r in self._rows.values()
                  if r['result'] in ('failed', 'run_out') and r['level'] and r['level'] > 0]
        if not levels:
            return None
        lo, hi = min(levels) / 1.1, max(levels) * 1.1
        loads = [lo * (hi / lo) ** (j / (CURVE_POINTS - 1)) for j in range(CURVE_POINTS)]
        a, k, s = fit['a'], fit['k'], fit['s']
        curves: dict[str, list] = {'load': loads}
        for name, z in (('p10', -Z90), ('p50', 0.0), ('p90', Z90)):
            exps = [a - k * math.log10(x) + z * s for x in loads]
            if not all(-300.0 < e < 300.0 for e in exps):
                return None                    # a fit no page can draw (and JSON cannot say)
            curves[name] = [10.0 ** e for e in exps]
        return curves
