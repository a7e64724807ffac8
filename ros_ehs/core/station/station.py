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
The station: scope, meters and board together, fed from one thread and read from another.

:class:`Station` is what the station node holds: it takes each state and reference (their
own stamps, no clock of its own), the nodes' statuses and events (with ``now`` passed in),
the campaign node's status and records, and answers :meth:`Station.frame`, one page update:
the scope's envelope for the page's time base, every meter, the board and the campaign
panel. The node's executor writes and the web server's thread reads:
one lock guards both, held for a copy, never for a wait.

The scope's reference and error take the newest reference carried to the state's stamp with
its velocity (first-order hold, as the controller extrapolates a reference that comes slower
than the states: a 250 Hz reference drawn as it is showed a 100 um sawtooth of error that the
loop does not have), when it is at most ``HOLD_NS`` older than the state; its force is
the load cell where the state has one, else the piston's hydraulic force
(``force_source`` says which).
"""

from __future__ import annotations

import math
import threading
from typing import Any

from ros_ehs.core.station.board import Board
from ros_ehs.core.station.campaign import CampaignPanel
from ros_ehs.core.station.meters import Meter
from ros_ehs.core.station.scope import CHANNELS, Scope, TIME_BASES
from ros_ehs_msgs_py.values import AxisState, NodeStatus, ParameterEstimate, Reference

__all__ = ['FLOORS', 'HOLD_NS', 'Station']

#: a reference older than this [ns] is not carried to a state's stamp: drawn as it is
HOLD_NS = 50_000_000

#: each meter's band floor [SI]: above a bench's noise peak to peak (5 um: 8 sigma is 40 um), so
#: a held axis makes no cycles
FLOORS = {'position': 5e-5, 'reference': 1e-6, 'error': 5e-5, 'force': 50.0, 'current': 1e-4}


class Station:
    """The station's state (see the module docstring)."""

    def __init__(self, scope_samples: int = 131072, buckets: int = 400,
                 lost_after: float = 3.0) -> None:
        if not (isinstance(buckets, int) and buckets >= 1):
            raise ValueError(f'`buckets` = {buckets!r} must be an int >= 1')
        self.scope = Scope(scope_samples)
        self.meters = {name: Meter(FLOORS[name]) for name, _ in CHANNELS}
        self.board = Board(lost_after)
        self.campaign = CampaignPanel(lost_after=lost_after)
        self.buckets = buckets
        self.force_source = 'none'
        self.states = 0
        self.frames = 0
        self._ref = Reference(0, math.nan, math.nan)
        self._lock = threading.Lock()
        self._t0: int | None = None

    # -- the loop's signals ------------------------------------------------------------------
    def take_reference(self, r: Reference) -> None:
        """Take the newest reference."""
        with self._lock:
            self._ref = r

    def take_state(self, s: AxisState) -> None:
        """Take one state: a scope sample and every meter."""
        force, source = (s.load, 'load cell') if math.isfinite(s.load) else (s.force, 'hydraulic')
        with self._lock:
            if self._t0 is None or s.stamp_ns < self._t0:
                self._t0 = s.stamp_ns             # a new run (stamps start again)
                self.scope.clear()
            r = self._ref
            dt = s.stamp_ns - r.stamp_ns
            ref = r.z_ref + r.v_ref * dt * 1e-9 if 0 <= dt <= HOLD_NS and \
                math.isfinite(r.v_ref) else r.z_ref
            values = {'position': s.z, 'reference': ref, 'error': ref - s.z,
                      'force': force, 'current': s.i}
            self.scope.add((s.stamp_ns - self._t0) * 1e-9, values)
            for name, m in self.meters.items():
                m.add(values[name])
            if math.isfinite(force):
                self.force_source = source
            self.states += 1

    def reset_meters(self) -> None:
        """Forget every meter's min/max and cycles (the page's meter reset: no axis action)."""
        with self._lock:
            for m in self.meters.values():
                m.reset()

    # -- the nodes' word ---------------------------------------------------------------------
    def take_status(self, source: str, now: float, status: NodeStatus) -> None:
        """Take a node's status (see :meth:`Board.take_status`)."""
        with self._lock:
            self.board.take_status(source, now, status)

    def take_event(self, now_wall: float, source: str, kind: str, level: int, message: str,
                   **extra: Any) -> None:
        """Take an event for the log (see :meth:`Board.take_event`)."""
        with self._lock:
            self.board.take_event(now_wall, source, kind, level, message, **extra)

    def take_estimate(self, now: float, e: ParameterEstimate) -> None:
        """Take a live refit (see :meth:`Board.take_estimate`)."""
        with self._lock:
            self.board.take_estimate(now, e)

    def take_campaign_status(self, now: float, status: NodeStatus) -> None:
        """Take the campaign node's status (see :meth:`CampaignPanel.take_status`)."""
        with self._lock:
            self.campaign.take_status(status, now)

    def take_campaign_result(self, record: NodeStatus) -> None:
        """Take one specimen's record (see :meth:`CampaignPanel.take_result`)."""
        with self._lock:
            self.campaign.take_result(record)

    # -- the page ----------------------------------------------------------------------------
    def frame(self, now: float, span: float, board: bool = True) -> dict:
        """
        Return one page update for time base ``span`` [s] (one of :data:`TIME_BASES`).

        The scope (:meth:`Scope.packed`) and the meters always; the board (statuses,
        detectors, events, estimates) and the campaign panel (None without a campaign) when
        ``board`` (a page takes them a few times a second).
        """
        if span not in TIME_BASES:
            raise ValueError(f'time base {span!r} s is not one of {TIME_BASES}')
        with self._lock:
            self.frames += 1
            out = {'scope': self.scope.packed(span, self.buckets), 'span': span,
                   'units': dict(CHANNELS), 'force_source': self.force_source,
                   'meters': {k: m.as_dict() for k, m in self.meters.items()},
                   'states': self.states}
            if board:
                out['board'] = {**self.board.snapshot(now),
                                'campaign': self.campaign.snapshot(now)}
            return out
