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
A fatigue test's data read back from its bags: the cycle table, the captured cycles, events.

The procedure node records every counted cycle's extremes on ``procedure/cycles`` (40-byte
records), full cycles at log-spaced counts on ``procedure/captures`` and its events on
``procedure/events`` (the contract, :mod:`ros_ehs_msgs_py.topics`). A test that was
restarted spans several bags: :func:`read_cycles` takes them in order and keeps each count
once (the first record of it). Truncated bags (a power cut) read up to their last whole
chunk.
"""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np
from ros_ehs.data.bag import open_bag
import ros_ehs_msgs_py as contract

__all__ = ['CYCLE_COLUMNS', 'read_captures', 'read_cycles', 'read_procedure_events']

#: the cycle table's columns
CYCLE_COLUMNS = ('count', 'step', 'end_s', 'cmd_hi', 'cmd_lo', 'z_hi', 'z_lo', 'load_hi',
                 'load_lo')
_CYCLES = '/' + contract.CYCLES.name
_CAPTURES = '/' + contract.CAPTURES.name
_EVENTS = '/' + contract.PROCEDURE_EVENTS.name


def _bags(bags) -> list:
    return [bags] if isinstance(bags, (str, os.PathLike)) else list(bags)


def read_cycles(bags: str | os.PathLike | Sequence) -> np.ndarray:
    """Return the cycle table of ``bags`` (n x 9, :data:`CYCLE_COLUMNS`), each count once."""
    rows: dict[int, tuple] = {}
    for path in _bags(bags):
        b = open_bag(path)
        if _CYCLES not in b.topics:
            continue
        for _, msg in b.decoded([_CYCLES]):
            for r in contract.cycles_from_bytes(bytes(msg.data)):
                rows.setdefault(r[0], r)
    out = np.array([rows[k] for k in sorted(rows)], float).reshape(-1, 9)
    out[:, 2] *= 1e-9
    return out


def read_captures(bags: str | os.PathLike | Sequence) -> list[dict]:
    """Return the captured full cycles: count, t [s], command, z [m], load [N] each."""
    out = []
    for path in _bags(bags):
        b = open_bag(path)
        if _CAPTURES not in b.topics:
            continue
        for _, msg in b.decoded([_CAPTURES]):
            label = msg.layout.dim[0].label
            n = msg.layout.dim[1].size
            d = np.asarray(msg.data, float).reshape(4, n)
            out.append({'count': int(label.split()[-1]), 't': d[0], 'cmd': d[1], 'z': d[2],
                        'load': d[3]})
    return out


def read_procedure_events(bags: str | os.PathLike | Sequence) -> list[dict]:
    """Return the procedure's events (kind, what, value, total_cycles, step, message...)."""
    out = []
    for path in _bags(bags):
        b = open_bag(path)
        if _EVENTS not in b.topics:
            continue
        out.extend(contract.procedure_event_from_msg(msg) for _, msg in b.decoded([_EVENTS]))
    return out
