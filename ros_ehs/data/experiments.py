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
Extract identification experiments (arrays on one uniform time grid) from a bag.

Where the signals are comes from a :class:`~ros_ehs.data.mapping.TopicMap`: by default this
package's contract (``state``, ``servo_current``, the chamber pressures), or a rig driver's
topics (``/joint_states`` with a named joint, ``Float64MultiArray`` commands, pressures in
bar, ...). Messages are read from their CDR bytes (:mod:`ros_ehs_msgs_py.wire`), not decoded
into message objects.

Time policy:

* the time base is the ``state`` topic's header stamps (its receive times when the driver
  does not stamp them); states, commands, pressures and load readings are sorted by stamp,
  a repeated stamp (a lock-step resend) kept once, and a state closer than 0.45 of the
  median period to the one before it (a stray publisher, another clock) is dropped, the
  experiment's name says how many (a driver's jitter of a quarter period either way brings
  two states within 0.5 of it: kept);
* a run goes on over one or two missed samples (:data:`BRIDGE
  <ros_ehs.core.identify.experiment.BRIDGE>`); a longer gap splits the recording into runs
  (:func:`load_experiments`), and runs too short to fit are dropped;
* a run whose stamps jitter (a driver's timestamps: up to a quarter of the period) is
  resampled onto a uniform grid at its mean period by cubic splines through the samples;
* messages without a header (``Float64``, ``Float64MultiArray``) carry their receive time,
  moved onto the state's clock by the median difference between the states' stamps and their
  receive times (the driver's clock against the recorder's).

Signals:

* the current of each period is, when the state reports it (our plant's joint
  ``servo_valve``: what the valve really got, watchdog and late commands included), that
  current; otherwise the command in force, averaged over the period, ``input_delay`` later
  than its stamp (or receive time), counted along the driver's cycles where its stamps
  jitter (a driver acts on a command at a cycle:
  :func:`ros_ehs.core.identify.experiment.takeover_times`) - with ``input_delay`` unknown,
  the fit estimates it (:func:`ros_ehs.data.identification.run_identification`);
* the velocity is the state's when it has one; otherwise it is derived from the position by a
  Savitzky-Golay derivative (quadratic, about 5 ms wide, at least 3 samples) and its noise,
  which the fit's verdict compares the residual with, is the position's noise times that
  filter's gain (``Experiment.noise``), not estimated from the derived signal itself;
* chamber pressures (or one load pressure) are interpolated onto the grid (cubic splines)
  when mapped, and so is the load cell (``load_cell``, a WrenchStamped's ``load_axis``) when
  the bag has it and it reads a load (a plant without a specimen publishes a load cell that
  reads 0).
"""

from __future__ import annotations

import os

import numpy as np

from ros_ehs.core.errors import BagError, DataError
from ros_ehs.core.identify.experiment import (cut_experiment, Experiment, MIN_SAMPLES,
                                              on_grid, run_bounds, Series, sorted_by_time,
                                              split_runs)
from ros_ehs.data.bag.reader import Bag, open_bag
from ros_ehs.data.mapping import (COMMAND_TYPES, decoder, LOAD_TYPES, PRESSURE_TYPES,
                                  STATE_TYPES, TopicDecoder, TopicMap)
import ros_ehs_msgs_py as contract

__all__ = ['load_experiment', 'load_experiments', 'resolve_topic']


def resolve_topic(bag: Bag, name: str, required: bool = True) -> str | None:
    """
    Find topic ``name`` in ``bag``, in any namespace (``/axis1/state``).

    A missing topic raises :class:`BagError` listing the bag's topics, or gives None when
    not ``required``; an ambiguous one always raises.
    """
    if name in bag.topics:
        return name
    rel = name.lstrip('/')
    hits = [t for t in bag.topics if t == '/' + rel or t.endswith('/' + rel)]
    if len(hits) == 1:
        return hits[0]
    if not hits:
        if not required:
            return None
        raise BagError(f'bag {str(bag.path)!r} has no topic {name!r}; it has: '
                       f'{bag.describe() or "no topics"}')
    raise BagError(f'topic {name!r} is ambiguous in {str(bag.path)!r}: {hits} '
                   '(pass the full name)')


def _check_type(bag: Bag, topic: str, allowed: tuple[str, ...], role: str) -> str:
    got = bag.topics[topic].msg_type
    if got not in allowed:
        want = allowed[0] if len(allowed) == 1 else f'one of {list(allowed)}'
        raise BagError(f'{role} topic {topic!r} in {str(bag.path)!r} has type {got}, '
                       f'expected {want}; the bag has: {bag.describe()}')
    return got


def _series(bag: Bag, topic: str, dec: TopicDecoder) -> tuple[list, list]:
    """
    Return each message's signal and its receive time [ns] (the messages with it only).

    A payload that will not decode is a :class:`BagError` naming the topic and the time.
    """
    out, recv = [], []
    for m in bag.messages([topic]):
        try:
            got = dec(m.data)
        except ValueError as err:
            raise BagError(f'malformed message on {topic!r} at {m.log_time_ns} ns: {err}') \
                from None
        if got is not None:
            out.append(got)
            recv.append(m.log_time_ns)
    if not out and dec.seen:
        option = 'joint' if dec.role == 'state' else 'command_joint'
        effort = '' if dec.role == 'state' else ' with an effort'
        raise BagError(f'{dec.role} topic {topic!r} in {str(bag.path)!r} has no joint '
                       f'{dec.joint!r}{effort}; its joints: {sorted(dec.seen)} (set '
                       f'`{option}`)')
    return out, recv


def _times(rows: list, recv: list) -> tuple[np.ndarray, np.ndarray]:
    """Return (stamps or receive times [ns], values) of (stamp, value) rows."""
    ts = np.array([r[0] if r[0] is not None else rv for r, rv in zip(rows, recv)],
                  dtype=np.int64)
    return ts, np.array([r[1] for r in rows], dtype=float)


def _read(path, tmap: TopicMap, bag: Bag | None, start=None, end=None) -> Series:
    """Read the mapped series of the bag at ``path`` (see the module docstring)."""
    bag = bag or open_bag(path, start=start, end=end)
    name = os.path.basename(os.path.normpath(str(path)))
    if start is not None or end is not None:
        name += f' [{start or 0:g}-{"" if end is None else f"{end:g}"} s]'
    if bag.message_count == 0 and (start is not None or end is not None):
        raise DataError(f'{name}: the window holds no message (is it past the end of the '
                        'bag?)')
    st = resolve_topic(bag, tmap.state)
    cm = resolve_topic(bag, tmap.command)
    _check_type(bag, st, STATE_TYPES, 'state')
    ctype = _check_type(bag, cm, COMMAND_TYPES, 'command')
    sdec = decoder(tmap, 'state', bag.topics[st].msg_type)
    rows, rx = _series(bag, st, sdec)
    ts = np.array([r[0] for r in rows], dtype=np.int64)
    recv = np.array(rx, dtype=np.int64)
    z, v, applied = (np.array([r[k] for r in rows], dtype=float) for k in (1, 2, 3))
    cdec = decoder(tmap, 'command', ctype)
    tc, vc = _times(*_series(bag, cm, cdec))
    stamped = cdec.stamped
    if ts.size == 0 or tc.size == 0:
        raise DataError(f'{name}: too little data: {ts.size} state and {tc.size} command '
                        'messages')
    if not np.any(ts):         # a driver that does not stamp: its receive times
        ts = recv.copy()
    # the driver's clock against the recorder's: receive times onto the state's clock
    offset = int(np.median(ts - recv))
    if not stamped:
        tc = tc + offset
    ts, recv, z, v, applied = sorted_by_time(ts, recv, z, v, applied)
    keep = on_grid(ts)
    if not keep.all():
        name += f' ({int(keep.size - keep.sum())} off-grid states dropped)'
        ts, z, v, applied = ts[keep], z[keep], v[keep], applied[keep]
    tc, vc = sorted_by_time(tc, vc)
    pressures = []
    defaults = (contract.PRESSURE_P.name, contract.PRESSURE_T.name)
    wanted = [tmap.pressure_load] if tmap.pressure_load else \
        [p for p in (tmap.pressure_p, tmap.pressure_t) if p]
    # the contract's own pressure topics are optional (a bag may lack them); a rig's are not
    found = [resolve_topic(bag, p, required=p not in defaults) for p in wanted]
    if found and all(found):
        for top in found:
            ptype = _check_type(bag, top, PRESSURE_TYPES, 'pressure')
            pdec = decoder(tmap, 'pressure_p', ptype)
            rows, rx = _series(bag, top, pdec)
            tp, pv = _times(rows, rx)
            if not pdec.stamped:
                tp = tp + offset
            pressures.append(sorted_by_time(tp, pv))
    cell = None
    if tmap.load_cell:    # the contract's load_cell is optional (no specimen); a rig's is not
        top = resolve_topic(bag, tmap.load_cell,
                            required=tmap.load_cell != contract.LOAD_CELL.name)
        if top is not None:
            _check_type(bag, top, LOAD_TYPES, 'load_cell')
            rows, rx = _series(bag, top, decoder(tmap, 'load_cell', bag.topics[top].msg_type))
            tl, fl = _times(rows, rx)
            if tl.size and np.ptp(fl) > 0:     # a load cell that reads: a specimen
                cell = sorted_by_time(tl, fl)
    if bag.truncated:
        name += ' (truncated)'
    delay = 0.0 if tmap.input_delay is None else float(tmap.input_delay)
    return Series(name, ts, z, v, applied, tc, vc, pressures, bool(tmap.pressure_load), delay,
                  cell)


def _topic_map(topics: TopicMap | None, state, command, pressure_p, pressure_t) -> TopicMap:
    if topics is not None:
        if not isinstance(topics, TopicMap):
            raise DataError(f'`topics` must be a TopicMap, got {type(topics).__name__}')
        return topics
    if (pressure_p is None) != (pressure_t is None):
        pressure_p = pressure_t = None
    return TopicMap(state=state, command=command, pressure_p=pressure_p,
                    pressure_t=pressure_t)


def load_experiment(path: str | os.PathLike, *, topics: TopicMap | None = None,
                    state: str = contract.STATE.name,
                    command: str = contract.COMMAND.name,
                    pressure_p: str | None = contract.PRESSURE_P.name,
                    pressure_t: str | None = contract.PRESSURE_T.name,
                    bag: Bag | None = None, start: float | None = None,
                    end: float | None = None) -> Experiment:
    """
    Read one experiment from the bag at ``path``: the whole recording, on one grid.

    The recording must have no gap of more than :data:`BRIDGE
    <ros_ehs.core.identify.experiment.BRIDGE>` missed samples.

    ``topics`` says where the signals are (default: the contract; ``state``, ``command``,
    ``pressure_p``, ``pressure_t`` are shorthands for a contract-like map). Pressures are
    optional (pass None to ignore them); a bag without the contract's pressure topics gives
    an experiment without pressures. ``start``/``end`` [s from the bag's first message] take
    a window of the recording (a split bag reads only the files it needs). Raises
    :class:`BagError` / :class:`DataError` naming the problem (missing topics with the topics
    the bag has, wrong types, missing joints with the joints the topic has, too little data,
    no excitation, samples missing from the grid: see :func:`load_experiments` for those).
    """
    rec = _read(path, _topic_map(topics, state, command, pressure_p, pressure_t), bag, start,
                end)
    if rec.ts.size < 2:
        raise DataError(f'{rec.name}: too little data: {rec.ts.size} samples (need at least '
                        f'{MIN_SAMPLES})')
    runs, cuts = run_bounds(rec.ts)
    if cuts:
        d = np.diff(rec.ts)
        k = cuts[0] - 1
        raise DataError(f'{rec.name}: samples are not on a uniform grid (period '
                        f'{np.median(d) * 1e-9:g} s, but {d[k] * 1e-9:g} s between t = '
                        f'{(rec.ts[k] - rec.ts[0]) * 1e-9:g} and '
                        f'{(rec.ts[k + 1] - rec.ts[0]) * 1e-9:g} s); load_experiments splits '
                        'such a recording into its runs')
    return cut_experiment(rec, 0, rec.ts.size, rec.name)


def load_experiments(path: str | os.PathLike, *, topics: TopicMap | None = None,
                     state: str = contract.STATE.name,
                     command: str = contract.COMMAND.name,
                     pressure_p: str | None = contract.PRESSURE_P.name,
                     pressure_t: str | None = contract.PRESSURE_T.name,
                     bag: Bag | None = None, start: float | None = None,
                     end: float | None = None) -> list[Experiment]:
    """
    Read the contiguous runs of the bag at ``path``: one experiment per run.

    A best-effort recorder can miss states (a busy machine, a full queue), which leaves a gap
    in the sample grid; a run goes on over one or two missed states (:data:`BRIDGE
    <ros_ehs.core.identify.experiment.BRIDGE>`), a longer gap splits the recording, and runs
    shorter than :data:`MIN_SAMPLES` are dropped, as are runs in which the piston does not
    move (a hold before the trajectory started) when another run does. Names get ``[k/n]``
    when there is more than one run. ``topics``, ``start``/``end``: as in
    :func:`load_experiment`.
    """
    rec = _read(path, _topic_map(topics, state, command, pressure_p, pressure_t), bag, start,
                end)
    return split_runs(rec)
