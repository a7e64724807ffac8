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
Extract an identification experiment (arrays on one time grid) from a bag's contract topics.

The time base is the ``state`` topic's header stamps. Stamp policy: states are sorted by
stamp and a repeated stamp (a lock-step resend) is kept once; a state closer than 3/4 of the
median period to the one before it (a stray publisher, another clock) is dropped and the
experiment's name says how many; a gap (missed samples, a stamp far ahead or behind) splits
the record into runs (:func:`load_experiments`), and runs too short to fit are dropped.
The servo current of each period is,
when the plant reports it, the current it applied (joint ``servo_valve`` of ``state``: what
the valve really got, watchdog and late commands included). Otherwise it is the latest
``servo_current`` command stamped at or before the state sample (the controller stamps its
answer with the state it answered, and the plant holds it for the period). Chamber pressures
are used when the bag has them.
"""

from __future__ import annotations

from dataclasses import dataclass
import os

import numpy as np

from ros_ehs.bag.reader import Bag, open_bag
from ros_ehs.errors import BagError, DataError
import ros_ehs_msgs_py as contract

__all__ = ['Experiment', 'MIN_SAMPLES', 'experiment_from_arrays', 'load_experiment',
           'load_experiments', 'resolve_topic']

#: Fewer state samples than this is "too little data" for a 7-parameter fit.
MIN_SAMPLES = 500


@dataclass(frozen=True)
class Experiment:
    """One recorded run on a uniform grid: ``t`` [s], ``i`` [A], ``z`` [m], ``v`` [m/s], ..."""

    name: str
    t: np.ndarray
    i: np.ndarray
    z: np.ndarray
    v: np.ndarray
    p_a: np.ndarray | None = None
    p_b: np.ndarray | None = None

    @property
    def dt(self) -> float:
        """Sample period [s]."""
        return float(self.t[1] - self.t[0])

    @property
    def duration(self) -> float:
        """Length of the record [s]."""
        return float(self.t[-1] - self.t[0])

    def signals(self) -> dict[str, np.ndarray]:
        """Measured outputs by name: ``z_dot``, ``z`` and, when recorded, ``p_CP``, ``p_CT``."""
        out = {'z_dot': self.v, 'z': self.z}
        if self.p_a is not None and self.p_b is not None:
            out['p_CP'] = self.p_a
            out['p_CT'] = self.p_b
        return out


class _NoExcitation(DataError):
    """A run in which the piston did not move (a hold before the trajectory started)."""


def resolve_topic(bag: Bag, name: str, required: bool = True) -> str | None:
    """
    Find contract topic ``name`` in ``bag``, in any namespace (``/axis1/state``).

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


def _check_type(bag: Bag, topic: str, expected: str) -> None:
    got = bag.topics[topic].msg_type
    if got != expected:
        raise BagError(f'topic {topic!r} in {str(bag.path)!r} has type {got}, '
                       f'expected {expected}')


def _series(bag: Bag, topic: str, read) -> tuple[np.ndarray, np.ndarray]:
    ts, vs = [], []
    for m, msg in bag.decoded([topic]):
        try:
            rec = read(msg)
        except (ValueError, AttributeError, KeyError, IndexError) as e:
            raise BagError(f'malformed message on {topic!r} at {m.log_time_ns} ns: {e}') \
                from None
        ts.append(rec[0])
        vs.append(rec[1:])
    return np.asarray(ts, dtype=np.int64), np.asarray(vs, dtype=float)


def experiment_from_arrays(name: str, t, i, z, v, p_a=None, p_b=None) -> Experiment:
    """Build and check an :class:`Experiment` from arrays (``t`` uniform, seconds)."""
    t = np.asarray(t, dtype=float)
    arrs = {'i': np.asarray(i, dtype=float), 'z': np.asarray(z, dtype=float),
            'v': np.asarray(v, dtype=float)}
    for k, a in arrs.items():
        if a.shape != t.shape:
            raise DataError(f'{name}: `{k}` has shape {a.shape}, `t` has {t.shape}')
    n = t.size
    if n < MIN_SAMPLES:
        raise DataError(f'{name}: too little data: {n} samples (need at least {MIN_SAMPLES}, '
                        f'e.g. {MIN_SAMPLES / 1000:g} s at 1 kHz)')
    dts = np.diff(t)
    dt = float(np.median(dts))
    if not dt > 0 or np.max(np.abs(dts - dt)) > 0.25 * dt:
        k = int(np.argmax(np.abs(dts - dt)))
        raise DataError(f'{name}: samples are not on a uniform grid (period {dt:g} s, but '
                        f'{dts[k]:g} s between t = {t[k]:g} and {t[k + 1]:g} s)')
    for k, a in arrs.items():
        if not np.all(np.isfinite(a)):
            j = int(np.flatnonzero(~np.isfinite(a))[0])
            raise DataError(f'{name}: `{k}` is not finite at t = {t[j]:g} s')
    if np.ptp(arrs['i']) < 1e-5 or np.ptp(arrs['z']) < 1e-4:
        raise _NoExcitation(
            f'{name}: no excitation: the current spans {np.ptp(arrs["i"]):.3g} A and the '
            f'piston {np.ptp(arrs["z"]):.3g} m (need a moving piston, e.g. a 1 Hz sine of a '
            'few cm)')
    pa = None if p_a is None else np.asarray(p_a, dtype=float)
    pb = None if p_b is None else np.asarray(p_b, dtype=float)
    return Experiment(name, t - t[0], arrs['i'], arrs['z'], arrs['v'], pa, pb)


def _on_grid(ts: np.ndarray) -> np.ndarray:
    """
    Mask of the states on the record's sample grid (sorted, distinct stamps [ns]).

    A state closer than 3/4 of the median period to the one kept before it is a stranger (a
    stray publisher, another clock, a replay into a live bench) and is dropped.
    """
    keep = np.ones(ts.size, dtype=bool)
    d = np.diff(ts)
    if d.size == 0:
        return keep
    close = 0.75 * np.median(d)
    if not np.any(d < close):
        return keep
    last = ts[0]
    for j in range(1, ts.size):
        if ts[j] - last < close:
            keep[j] = False
        else:
            last = ts[j]
    return keep


def _read(path, state, command, pressure_p, pressure_t, bag, start=None, end=None):
    """Return the bag's series on the state stamps: name, ts [ns], command, state, pressures."""
    bag = bag or open_bag(path, start=start, end=end)
    name = os.path.basename(os.path.normpath(str(path)))
    if start is not None or end is not None:
        name += f' [{start or 0:g}-{"" if end is None else f"{end:g}"} s]'
    if bag.message_count == 0 and (start is not None or end is not None):
        raise DataError(f'{name}: the window holds no message (is it past the end of the '
                        'bag?)')
    st = resolve_topic(bag, state)
    cm = resolve_topic(bag, command)
    _check_type(bag, st, contract.STATE.msg_type)
    _check_type(bag, cm, contract.COMMAND.msg_type)
    ts, sv = _series(bag, st, lambda m: (lambda s: (s.stamp_ns, s.z, s.z_dot, s.i))(
        contract.state_from_msg(m)))
    tc, cv = _series(bag, cm, lambda m: tuple(contract.command_from_msg(m)))
    if ts.size == 0 or tc.size == 0:
        raise DataError(f'{name}: too little data: {ts.size} state and {tc.size} command '
                        'messages')
    order = np.argsort(ts, kind='stable')
    ts, sv = ts[order], sv[order]
    keep = np.concatenate([[True], np.diff(ts) > 0])
    ts, sv = ts[keep], sv[keep]
    keep = _on_grid(ts)
    if not keep.all():
        name += f' ({int(keep.size - keep.sum())} off-grid states dropped)'
        ts, sv = ts[keep], sv[keep]
    oc = np.argsort(tc, kind='stable')
    tc, cv = tc[oc], cv[oc]
    k = np.searchsorted(tc, ts, side='right') - 1
    ok = k >= 0
    ts, sv, k = ts[ok], sv[ok], k[ok]
    cur = cv[k, 0]
    pa = pb = None
    have = [resolve_topic(bag, p, required=False) if p else None
            for p in (pressure_p, pressure_t)]
    if have[0] and have[1]:
        for top, tp in zip(have, (contract.PRESSURE_P, contract.PRESSURE_T)):
            _check_type(bag, top, tp.msg_type)
        series = [_series(bag, top, lambda m: tuple(contract.pressure_from_msg(m)))
                  for top in have]
        vals = []
        for tp, pv in series:
            o = np.argsort(tp, kind='stable')
            tp, pv = tp[o], pv[o, 0]
            j = np.clip(np.searchsorted(tp, ts, side='right') - 1, 0, tp.size - 1)
            vals.append(pv[j])
        pa, pb = vals
    if bag.truncated:
        name += ' (truncated)'
    return name, ts, cur, sv, pa, pb


def _experiment(name, ts, cur, sv, pa, pb, a: int, b: int) -> Experiment:
    """Build the experiment of samples ``a:b`` (one contiguous run)."""
    c = cur[a:b]
    applied = sv[a:b, 2]
    if applied.size > 1 and np.all(np.isfinite(applied)):
        # state k reports the current of the period that ended at it: shift by one
        c = np.append(applied[1:], applied[-1])
    return experiment_from_arrays(name, (ts[a:b] - ts[a]) * 1e-9, c, sv[a:b, 0], sv[a:b, 1],
                                  None if pa is None else pa[a:b],
                                  None if pb is None else pb[a:b])


def load_experiment(path: str | os.PathLike, *, state: str = contract.STATE.name,
                    command: str = contract.COMMAND.name,
                    pressure_p: str | None = contract.PRESSURE_P.name,
                    pressure_t: str | None = contract.PRESSURE_T.name,
                    bag: Bag | None = None, start: float | None = None,
                    end: float | None = None) -> Experiment:
    """
    Read an experiment from the bag at ``path`` using the contract topic names.

    Pressures are optional (pass None to ignore them); a bag without them gives an
    experiment without pressures. ``start``/``end`` [s from the bag's first message] take a
    window of the record (a split bag reads only the files it needs). Raises
    :class:`BagError` / :class:`DataError` naming the problem (missing topics with the topics
    the bag has, wrong types, too little data, no excitation, samples missing from the grid:
    see :func:`load_experiments` for those).
    """
    data = _read(path, state, command, pressure_p, pressure_t, bag, start, end)
    return _experiment(*data, 0, data[1].size)


def load_experiments(path: str | os.PathLike, *, state: str = contract.STATE.name,
                     command: str = contract.COMMAND.name,
                     pressure_p: str | None = contract.PRESSURE_P.name,
                     pressure_t: str | None = contract.PRESSURE_T.name,
                     bag: Bag | None = None, start: float | None = None,
                     end: float | None = None) -> list[Experiment]:
    """
    Read the contiguous runs of the bag at ``path``: one experiment per run.

    A best-effort recorder can miss states (a busy machine, a full queue), which leaves a gap
    in the sample grid; each gap splits the record, and runs shorter than
    :data:`MIN_SAMPLES` are dropped, as are runs in which the piston does not move (a hold
    before the trajectory started) when another run does. Names get ``[k/n]`` when there is
    more than one run.
    Irregular timing that is not a gap still raises, as :func:`load_experiment` does.
    ``start``/``end``: a window of the bag, as in :func:`load_experiment`.
    """
    name, ts, cur, sv, pa, pb = _read(path, state, command, pressure_p, pressure_t, bag,
                                      start, end)
    d = np.diff(ts)
    cuts = np.flatnonzero(d > 1.5 * np.median(d)) + 1 if d.size else np.array([], int)
    edges = [0, *cuts.tolist(), ts.size]
    runs = [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b - a >= MIN_SAMPLES]
    if not runs:
        longest = max(b - a for a, b in zip(edges[:-1], edges[1:]))
        raise DataError(f'{name}: too little data: the longest run without missing samples '
                        f'has {longest} samples (need at least {MIN_SAMPLES}); '
                        f'{len(cuts)} gaps')
    if len(runs) == 1:
        return [_experiment(name, ts, cur, sv, pa, pb, *runs[0])]
    out, still = [], []
    for k, (a, b) in enumerate(runs):
        try:
            out.append(_experiment(f'{name} [{k + 1}/{len(runs)}]', ts, cur, sv, pa, pb, a, b))
        except _NoExcitation as err:      # e.g. the hold before the reference started
            still.append(str(err))
    if not out:
        raise DataError(f'{name}: no run moves the piston: ' + '; '.join(still))
    return out
