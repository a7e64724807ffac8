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

from dataclasses import dataclass
import os
from pathlib import Path
from typing import Sequence

import numpy as np
from ros_ehs.core.errors import DataError
from ros_ehs.core.procedure.detectors import CYCLE_COLUMNS
from ros_ehs.data.bag import open_bag
import ros_ehs_msgs_py as contract

__all__ = ['CYCLE_COLUMNS', 'FatigueReport', 'read_captures', 'read_cycles',
           'read_procedure_events', 'write_fatigue_report']

_CYCLES = '/' + contract.CYCLES.name
_CAPTURES = '/' + contract.CAPTURES.name
_EVENTS = '/' + contract.PROCEDURE_EVENTS.name


def _decoded(bags, topics) -> dict[str, list]:
    """Return each of ``topics``' decoded messages in ``bags``, in order; each bag read once."""
    paths = [bags] if isinstance(bags, (str, os.PathLike)) else list(bags)
    out: dict[str, list] = {t: [] for t in topics}
    for path in paths:
        b = open_bag(path)
        there = [t for t in topics if t in b.topics]
        if there:
            for m, msg in b.decoded(there):
                out[m.topic].append(msg)
    return out


def _cycles(msgs) -> np.ndarray:
    rows: dict[int, tuple] = {}
    for msg in msgs:
        for r in contract.cycles_from_bytes(bytes(msg.data)):
            rows.setdefault(r[0], r)
    out = np.array([rows[k] for k in sorted(rows)], float).reshape(-1, len(CYCLE_COLUMNS))
    out[:, 2] *= 1e-9
    return out


def _captures(msgs) -> list[dict]:
    out = []
    for msg in msgs:
        n = msg.layout.dim[1].size
        d = np.asarray(msg.data, float).reshape(4, n)
        out.append({'count': int(msg.layout.dim[0].label.split()[-1]), 't': d[0],
                    'cmd': d[1], 'z': d[2], 'load': d[3]})
    return out


def read_cycles(bags: str | os.PathLike | Sequence) -> np.ndarray:
    """Return the cycle table of ``bags`` (n x 10, :data:`CYCLE_COLUMNS`), each count once."""
    return _cycles(_decoded(bags, [_CYCLES])[_CYCLES])


def read_captures(bags: str | os.PathLike | Sequence) -> list[dict]:
    """Return the captured full cycles: count, t [s], command, z [m], load [N] each."""
    return _captures(_decoded(bags, [_CAPTURES])[_CAPTURES])


def read_procedure_events(bags: str | os.PathLike | Sequence) -> list[dict]:
    """Return the procedure's events (kind, what, value, total_cycles, step, message...)."""
    return [contract.procedure_event_from_msg(m) for m in _decoded(bags, [_EVENTS])[_EVENTS]]


@dataclass
class FatigueReport:
    """What :func:`write_fatigue_report` found and wrote."""

    cycles: int                  #: counted cycles in the bags
    result: str                  #: the test's end (the last ``finished`` event), '' if none
    reason: str
    failures: list               #: the failure and detector events (kind, what, cycle, message)
    files: list                  #: the files written


def write_fatigue_report(bags: str | os.PathLike | Sequence, out: str | os.PathLike
                         ) -> FatigueReport:
    """
    Write a test's cycle table and captured cycles as CSV, and its plots, into ``out``.

    ``cycles.csv`` (:data:`CYCLE_COLUMNS` and the stiffness [N/m]), ``captures.csv`` (count,
    t, command, z, load), ``events.csv``; ``peak_valley.png`` (the load's and the position's
    peaks and valleys against cycles, log scale), ``stiffness.png`` (load range over
    position range against cycles), ``hysteresis.png`` (load against position of each
    captured cycle).
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    got = _decoded(bags, [_CYCLES, _CAPTURES, _EVENTS])       # each bag read once
    table = _cycles(got[_CYCLES])
    if not len(table):
        raise DataError(f'no cycle on /{contract.CYCLES.name} in {bags!r}: not the recording '
                        'of a procedure (record that topic with the test)')
    caps = _captures(got[_CAPTURES])
    events = [contract.procedure_event_from_msg(m) for m in got[_EVENTS]]
    d = Path(out)
    d.mkdir(parents=True, exist_ok=True)
    dz = table[:, 5] - table[:, 6]
    with np.errstate(divide='ignore', invalid='ignore'):
        k = np.where(dz > 0, (table[:, 7] - table[:, 8]) / dz, np.nan)
    files = []
    path = d / 'cycles.csv'
    np.savetxt(path, np.column_stack([table, k]), delimiter=',', fmt='%.10g',
               header=','.join(CYCLE_COLUMNS + ('stiffness',)), comments='')
    files.append(path)
    path = d / 'captures.csv'
    with open(path, 'w') as fh:
        fh.write('count,t,cmd,z,load\n')
        for c in caps:
            for row in zip(c['t'], c['cmd'], c['z'], c['load']):
                fh.write(f"{c['count']}," + ','.join(f'{v:.10g}' for v in row) + '\n')
    files.append(path)
    path = d / 'events.csv'
    with open(path, 'w') as fh:
        fh.write('stamp_ns,kind,what,total_cycles,step,message\n')
        for e in events:
            msg = e['message'].replace('"', "'")
            fh.write(f"{e['stamp_ns']},{e['kind']},{e['what']},{e['total_cycles']},"
                     f'{e["step"]},"{msg}"\n')
    files.append(path)
    n = table[:, 0]
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for ax, (hi, lo, label) in zip(axes, ((7, 8, 'load [N]'), (5, 6, 'position [m]'))):
        ax.plot(n, table[:, hi], '-', lw=0.8, label='peak')
        ax.plot(n, table[:, lo], '-', lw=0.8, label='valley')
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend()
    axes[-1].set_xlabel('cycle')
    if n.max() > 10:
        axes[-1].set_xscale('log')
    fig.tight_layout()
    files.append(_save(fig, d / 'peak_valley.png'))
    fig, ax = plt.subplots(figsize=(9, 3.5))
    ax.plot(n, k, '-', lw=0.8)
    ax.set_xlabel('cycle')
    ax.set_ylabel('stiffness [N/m]')
    ax.grid(alpha=0.3)
    if n.max() > 10:
        ax.set_xscale('log')
    fig.tight_layout()
    files.append(_save(fig, d / 'stiffness.png'))
    if caps:
        fig, ax = plt.subplots(figsize=(6, 5))
        for c in caps:
            ax.plot(c['z'] * 1e3, c['load'], lw=0.8, label=f"cycle {c['count']}")
        ax.set_xlabel('position [mm]')
        ax.set_ylabel('load [N]')
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        fig.tight_layout()
        files.append(_save(fig, d / 'hysteresis.png'))
    fin = [e for e in events if e['kind'] == 'finished']
    result = fin[-1]['message'].split(':')[0] if fin else ''
    reason = fin[-1]['message'] if fin else ''
    fails = [(e['kind'], e['what'], e['total_cycles'], e['message']) for e in events
             if e['kind'] in ('failure', 'detector', 'run_out')]
    return FatigueReport(len(table), result, reason, fails, files)


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
