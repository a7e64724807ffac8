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
The station's board: what the page shows of the axis, built from the nodes' messages.

:class:`Board` takes decoded messages (plain values, no ROS types) with the time they came
(``now`` [s], a monotonic clock the caller passes in) and answers :meth:`Board.snapshot`:
the controller's state and every detector (limit, unit, action, latched, trips), hydraulics
and the ramp-on's progress, the control mode, the procedure's step, counts and time to go,
the live identification's newest estimates and their trend, the events log, and the graph:
which sources are heard and, when the controller has not been heard for ``lost_after``
seconds, ``lost`` with the reason (the page says so instead of showing a stale axis as live).

Bounded for a week-long test: the events log keeps the newest ``events`` entries (a count of
all stays), each parameter's trend the newest ``trend`` estimates.
"""

from __future__ import annotations

from collections import deque
import math
from typing import Any

from ros_ehs.core.control.safety import DETECTORS, UNITS
from ros_ehs_msgs_py.values import NodeStatus, ParameterEstimate

__all__ = ['Board', 'SOURCES']

#: the sources the board hears from, in the order the page lists them
SOURCES = ('controller', 'plant', 'procedure', 'identify')


def _num(text: Any) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


def _count(text: Any) -> int:
    """Return a count read from a status value (0 when missing or not a whole number)."""
    x = _num(text)
    return int(x) if math.isfinite(x) else 0


def _clean(v: Any) -> Any:
    """Return ``v`` JSON-able: NaN and infinities as None."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


class Board:
    """The station's picture of the axis (see the module docstring)."""

    def __init__(self, lost_after: float = 3.0, events: int = 200, trend: int = 50) -> None:
        if not (math.isfinite(lost_after) and lost_after > 0):
            raise ValueError(f'`lost_after` = {lost_after!r} s must be finite and > 0')
        self.lost_after = float(lost_after)
        self.heard: dict[str, float] = {}
        self.status: dict[str, NodeStatus] = {}
        self.events: deque[dict] = deque(maxlen=events)
        self.events_total = 0
        self.estimates: dict[str, deque[tuple[float, float]]] = {}
        self.estimate: dict | None = None
        self._trend = trend

    # -- input -------------------------------------------------------------------------------
    def take_status(self, source: str, now: float, status: NodeStatus) -> None:
        """Take a node's diagnostics status (``source`` one of :data:`SOURCES`)."""
        if source not in SOURCES:
            raise ValueError(f'`source` = {source!r} is not one of {SOURCES}')
        self.heard[source] = now
        self.status[source] = status

    def take_event(self, now_wall: float, source: str, kind: str, level: int, message: str,
                   **extra: Any) -> None:
        """Take one event (a safety event, a procedure's, an action of this station)."""
        self.events_total += 1
        self.events.append({'at': now_wall, 'source': source, 'kind': kind, 'level': int(level),
                            'message': message, **{k: _clean(v) for k, v in extra.items()}})

    def take_estimate(self, now: float, e: ParameterEstimate) -> None:
        """Take one live refit (``parameter_estimates``, decoded by the contract)."""
        self.heard['identify'] = now
        params = {}
        for k, x in e.values.items():
            if math.isfinite(x):
                params[k] = {'value': x, 'stderr': _clean(e.stderr.get(k, math.nan))}
                self.estimates.setdefault(k, deque(maxlen=self._trend)).append((now, x))
        self.estimate = {'adequate': bool(e.adequate), 'message': e.verdict, 'params': params,
                         'pushed': bool(e.pushed), 'reason': e.reason,
                         'failed': list(e.failed)}     # the verdict's rules, as tags

    # -- output ------------------------------------------------------------------------------
    def lost(self, now: float) -> str | None:
        """Return why the ROS graph counts as gone (no controller heard), or None."""
        t = self.heard.get('controller')
        if t is None:
            return 'waiting for the controller: no status heard yet'
        if now - t > self.lost_after:
            return f'no status from the controller for {now - t:.1f} s: the ROS graph is lost'
        return None

    def detectors(self) -> list[dict]:
        """Return every detector: limit, unit, action, latched, trips (from the controller)."""
        st = self.status.get('controller')
        values = st.values if st is not None else {}
        tripped = st.listed('tripped') if st is not None else set()
        return [{'name': d, 'limit': _clean(_num(values.get(f'{d}.limit'))), 'unit': UNITS[d],
                 'action': values.get(f'{d}.action', ''), 'latched': d in tripped,
                 'trips': _count(values.get(f'trips_{d}'))} for d in DETECTORS]

    def snapshot(self, now: float) -> dict:
        """Return what the page shows now (JSON-able)."""
        out: dict[str, Any] = {
            'lost': self.lost(now),
            'heard': {s: (_clean(round(now - self.heard[s], 3)) if s in self.heard else None)
                      for s in SOURCES},
            'events': list(self.events), 'events_total': self.events_total,
            'detectors': self.detectors()}
        for source in ('controller', 'plant', 'procedure'):
            st = self.status.get(source)
            out[source] = None if st is None else {
                'level': st.level, 'message': st.message,
                'values': {k: v for k, v in st.values.items() if '.' not in k}}
        out['estimate'] = self.estimate
        out['trend'] = {k: [[round(t - now, 3), x] for t, x in d]
                        for k, d in self.estimates.items()}
        return out
