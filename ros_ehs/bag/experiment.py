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

Where the signals are comes from a :class:`~ros_ehs.bag.mapping.TopicMap`: by default this
package's contract (``state``, ``servo_current``, the chamber pressures), or a rig driver's
topics (``/joint_states`` with a named joint, ``Float64MultiArray`` commands, pressures in
bar, ...). Messages are read from their CDR bytes (:mod:`ros_ehs_msgs_py.wire`), not decoded
into message objects.

Time policy:

* the time base is the ``state`` topic's header stamps (its receive times when the driver
  does not stamp them); states are sorted by stamp, a repeated stamp (a lock-step resend) is
  kept once, and a state closer than 0.45 of the median period to the one before it (a stray
  publisher, another clock) is dropped, the experiment's name says how many (a driver's
  jitter of a quarter period either way brings two states within 0.5 of it: kept);
* a gap (a missed sample: more than 1.5 periods) splits the record into runs
  (:func:`load_experiments`), and runs too short to fit are dropped;
* a run whose stamps jitter (a driver's timestamps: up to a quarter of the period) is
  resampled onto a uniform grid at its mean period, the position (and velocity) linearly;
* messages without a header (``Float64``, ``Float64MultiArray``) carry their receive time,
  moved onto the state's clock by the median difference between the states' stamps and their
  receive times (the driver's clock against the recorder's).

Signals:

* the current of each period is, when the state reports it (our plant's joint
  ``servo_valve``: what the valve really got, watchdog and late commands included), that
  current; otherwise the command in force, averaged over the period, ``input_delay`` later
  than its stamp (or receive time) - with ``input_delay`` unknown, the fit estimates it
  (:func:`ros_ehs.identify.run.run_identification`);
* the velocity is the state's when it has one; otherwise it is derived from the position by a
  Savitzky-Golay derivative (quadratic, about 5 ms wide, at least 3 samples) and its noise,
  which the fit's verdict compares the residual with, is the position's noise times that
  filter's gain (``Experiment.noise``), not estimated from the derived signal itself;
* chamber pressures (or one load pressure) are interpolated onto the grid when mapped.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import math
import os

import numpy as np

from ros_ehs.bag.mapping import (COMMAND_TYPES, FLOAT64, FLUID_PRESSURE, JOINT_STATE,
                                 PRESSURE_TYPES, PRESSURE_UNITS, STATE_TYPES,
                                 TopicMap)
from ros_ehs.bag.reader import Bag, open_bag
from ros_ehs.errors import BagError, DataError
from ros_ehs.noise import noise_sigma
import ros_ehs_msgs_py as contract

__all__ = ['Experiment', 'MIN_SAMPLES', 'experiment_from_arrays', 'experiments_from_series',
           'load_experiment', 'load_experiments', 'resolve_topic']

#: Fewer state samples than this is "too little data" for a 7-parameter fit.
MIN_SAMPLES = 500
#: Width of the Savitzky-Golay derivative that derives a missing velocity [s] (>= 5 samples).
DERIVATIVE_WIDTH = 5.0e-3


@dataclass(frozen=True)
class Experiment:
    """
    One recorded run on a uniform grid: ``t`` [s], ``i`` [A], ``z`` [m], ``v`` [m/s], ...

    ``noise`` holds a known noise level [unit] per signal (the derived velocity's), used
    instead of an estimate from the signal; ``derived`` names the signals computed rather
    than measured. ``commands`` (times [s] on ``t``'s clock, values [A]) is the command
    series ``i`` was built from with ``delay`` [s], kept so the fit can try another delay
    (:meth:`with_delay`); None when ``i`` is the current the valve got.
    """

    name: str
    t: np.ndarray
    i: np.ndarray
    z: np.ndarray
    v: np.ndarray
    p_a: np.ndarray | None = None
    p_b: np.ndarray | None = None
    noise: dict | None = None
    derived: tuple[str, ...] = ()
    commands: tuple[np.ndarray, np.ndarray] | None = None
    delay: float = 0.0
    p_load: np.ndarray | None = None
    t0_ns: int = 0      #: the state clock's stamp of ``t = 0`` [ns]
    #: the run starts after a gap in the record, mid-motion: the fit settles the valve's
    #: states for the first sample instead of starting them at rest
    after_gap: bool = False

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

    def with_delay(self, delay: float) -> 'Experiment':
        """Return this run with the current rebuilt from its commands ``delay`` [s] later."""
        if self.commands is None:
            raise DataError(f'{self.name}: the current is the one the valve got; it has no '
                            'command series to delay')
        tc, vc = self.commands
        return replace(self, i=_held_average(tc, vc, self.t, delay), delay=float(delay))


class _NoExcitation(DataError):
    """A run in which the piston did not move (a hold before the trajectory started)."""


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


def _held_average(tc: np.ndarray, vc: np.ndarray, t: np.ndarray, delay: float) -> np.ndarray:
    """
    Return the mean over each period ``[t_k, t_k+1]`` of the command ``delay`` earlier.

    ``tc`` (sorted) / ``vc``: when each command took over and its value; before the first
    command, the first value. The last sample repeats the last period's value.
    """
    if t.size < 2:
        return np.full(t.shape, vc[0] if vc.size else math.nan)
    # the cumulative integral of the held command: piecewise linear, exact under np.interp
    edges = np.concatenate([[min(tc[0], t[0] - delay) - 1.0], tc[1:],
                            [max(tc[-1], t[-1] - delay) + 1.0]])
    area = np.concatenate([[0.0], np.cumsum(vc * np.diff(edges))])
    a = np.interp(t - delay, edges, area)
    out = np.empty(t.shape)
    out[:-1] = np.diff(a) / np.diff(t)
    out[-1] = out[-2]
    return out


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

    A state closer than 0.45 of the median period to the one kept before it is a stranger (a
    stray publisher, another clock, a replay into a live bench) and is dropped.
    """
    keep = np.ones(ts.size, dtype=bool)
    d = np.diff(ts)
    if d.size == 0:
        return keep
    close = 0.45 * np.median(d)
    if not np.any(d < close):
        return keep
    last = ts[0]
    for j in range(1, ts.size):
        if ts[j] - last < close:
            keep[j] = False
        else:
            last = ts[j]
    return keep


def _joint_of(names: tuple[str, ...], joint: str, cache: dict) -> int:
    k = cache.get(names)
    if k is None:
        k = cache[names] = names.index(joint) if joint in names else -1
    return k


def _each(bag: Bag, topic: str, decode):
    """Yield ``(message, decode(its CDR bytes))``; a payload that will not decode is a BagError."""
    for m in bag.messages([topic]):
        try:
            d = decode(m.data)
        except ValueError as err:
            raise BagError(f'malformed message on {topic!r} at {m.log_time_ns} ns: {err}') \
                from None
        yield m, d


def _decode_states(bag: Bag, topic: str, joint: str):
    """Return stamps [ns], receive times [ns], z, v, applied current of the joint's states."""
    idx: dict = {}
    valve: dict = {}
    seen: set = set()
    stamps, recv, z, v, cur = [], [], [], [], []
    for m, d in _each(bag, topic, contract.decode_joint_state):
        k = _joint_of(d.name, joint, idx)
        if k < 0:
            if len(seen) < 20:
                seen.update(d.name)
            continue
        if k >= len(d.position):
            raise BagError(f'malformed message on {topic!r} at {m.log_time_ns} ns: joint '
                           f'{joint!r} has no position ({len(d.position)} positions for '
                           f'{len(d.name)} joints)')
        stamps.append(d.stamp_ns)
        recv.append(m.log_time_ns)
        z.append(d.position[k])
        v.append(d.velocity[k] if k < len(d.velocity) else math.nan)
        j = _joint_of(d.name, contract.JOINT_VALVE, valve)
        cur.append(d.effort[j] if 0 <= j < len(d.effort) else math.nan)
    if not stamps and seen:
        raise BagError(f'state topic {topic!r} in {str(bag.path)!r} has no joint {joint!r}; '
                       f'its joints: {sorted(seen)} (set `joint`)')
    return (np.asarray(stamps, dtype=np.int64), np.asarray(recv, dtype=np.int64),
            np.asarray(z, dtype=float), np.asarray(v, dtype=float),
            np.asarray(cur, dtype=float))


def _decode_commands(bag: Bag, topic: str, msg_type: str, tmap: TopicMap):
    """Return (times [ns], values [A], stamped): header stamps or receive times."""
    ts, vs = [], []
    if msg_type == JOINT_STATE:
        idx: dict = {}
        seen: set = set()
        for _, d in _each(bag, topic, contract.decode_joint_state):
            k = _joint_of(d.name, tmap.command_joint, idx)
            if k < 0 or k >= len(d.effort):
                seen.update(d.name)
                continue
            ts.append(d.stamp_ns)
            vs.append(d.effort[k])
        if not ts and seen:
            raise BagError(f'command topic {topic!r} in {str(bag.path)!r} has no joint '
                           f'{tmap.command_joint!r} with an effort; its joints: '
                           f'{sorted(seen)} (set `command_joint`)')
    elif msg_type == FLOAT64:
        for m, value in _each(bag, topic, contract.float64_from_cdr):
            ts.append(m.log_time_ns)
            vs.append(value)
    else:
        k = tmap.command_index
        for m, data in _each(bag, topic, contract.float64_array_from_cdr):
            if k >= len(data):
                raise BagError(f'command topic {topic!r}: `command_index` = {k} but its '
                               f'Float64MultiArray at {m.log_time_ns} ns has {len(data)} '
                               'values')
            ts.append(m.log_time_ns)
            vs.append(data[k])
    return (np.asarray(ts, dtype=np.int64),
            np.asarray(vs, dtype=float) * float(tmap.command_scale), msg_type == JOINT_STATE)


def _decode_pressure(bag: Bag, topic: str, msg_type: str, unit: str):
    """Return (times [ns], values [Pa], stamped)."""
    ts, vs = [], []
    if msg_type == FLUID_PRESSURE:
        for _, (st, p) in _each(bag, topic, contract.fluid_pressure_from_cdr):
            ts.append(st)
            vs.append(p)
    else:
        scale = PRESSURE_UNITS[unit]
        for m, p in _each(bag, topic, contract.float64_from_cdr):
            ts.append(m.log_time_ns)
            vs.append(p * scale)
    return np.asarray(ts, dtype=np.int64), np.asarray(vs, dtype=float), \
        msg_type == FLUID_PRESSURE


def _sorted(t: np.ndarray, *vals: np.ndarray):
    o = np.argsort(t, kind='stable')
    return (t[o],) + tuple(v[o] for v in vals)


@dataclass
class _Record:
    """A bag's series, on the state's clock [ns]: what the runs are cut from."""

    name: str
    ts: np.ndarray
    z: np.ndarray
    v: np.ndarray
    applied: np.ndarray
    tc: np.ndarray
    vc: np.ndarray
    pressures: list        # [(t [ns], Pa)] per chamber, one (load), or none
    load: bool
    delay: float


def _read(path, tmap: TopicMap, bag: Bag | None, start=None, end=None) -> _Record:
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
    ts, recv, z, v, applied = _decode_states(bag, st, tmap.joint)
    tc, vc, stamped = _decode_commands(bag, cm, ctype, tmap)
    if ts.size == 0 or tc.size == 0:
        raise DataError(f'{name}: too little data: {ts.size} state and {tc.size} command '
                        'messages')
    if not np.any(ts):         # a driver that does not stamp: its receive times
        ts = recv.copy()
    # the driver's clock against the recorder's: receive times onto the state's clock
    offset = int(np.median(ts - recv))
    if not stamped:
        tc = tc + offset
    ts, recv, z, v, applied = _sorted(ts, recv, z, v, applied)
    keep = np.concatenate([[True], np.diff(ts) > 0])
    ts, z, v, applied = ts[keep], z[keep], v[keep], applied[keep]
    keep = _on_grid(ts)
    if not keep.all():
        name += f' ({int(keep.size - keep.sum())} off-grid states dropped)'
        ts, z, v, applied = ts[keep], z[keep], v[keep], applied[keep]
    tc, vc = _sorted(tc, vc)
    pressures = []
    defaults = (contract.PRESSURE_P.name, contract.PRESSURE_T.name)
    wanted = [tmap.pressure_load] if tmap.pressure_load else \
        [p for p in (tmap.pressure_p, tmap.pressure_t) if p]
    # the contract's own pressure topics are optional (a bag may lack them); a rig's are not
    found = [resolve_topic(bag, p, required=p not in defaults) for p in wanted]
    if found and all(found):
        for top in found:
            ptype = _check_type(bag, top, PRESSURE_TYPES, 'pressure')
            tp, pv, pst = _decode_pressure(bag, top, ptype, tmap.pressure_unit)
            if not pst:
                tp = tp + offset
            pressures.append(_sorted(tp, pv))
    if bag.truncated:
        name += ' (truncated)'
    delay = 0.0 if tmap.input_delay is None else float(tmap.input_delay)
    return _Record(name, ts, z, v, applied, tc, vc, pressures, bool(tmap.pressure_load), delay)


def _savgol_width(dt: float) -> int:
    n = max(3, int(round(DERIVATIVE_WIDTH / dt)))
    return n + 1 - n % 2


def _experiment(rec: _Record, a: int, b: int, name: str) -> Experiment:
    """Build the experiment of samples ``a:b`` (one contiguous run)."""
    ts = rec.ts[a:b]
    span = (ts - ts[0]) * 1e-9
    dts = np.diff(span)
    dt = float(span[-1] / (span.size - 1)) if span.size > 1 else 1e-3
    z, v, applied = rec.z[a:b], rec.v[a:b], rec.applied[a:b]
    exact = dts.size == 0 or float(np.max(np.abs(dts - np.median(dts)))) <= 1e-6 * dt
    # each measured signal's noise, on its raw samples, before the grid averages neighbours
    noise = {'z': noise_sigma(z, span)}
    if np.all(np.isfinite(v)):
        noise['z_dot'] = noise_sigma(v, span)
    for key, (tp, pv) in zip(('p_CP', 'p_CT') if not rec.load else ('p_L',), rec.pressures):
        m = (tp >= ts[0]) & (tp <= ts[-1])
        if m.sum() >= 8:
            noise[key] = noise_sigma(pv[m], (tp[m] - ts[0]) * 1e-9)
    if exact:
        t = span
    else:        # a driver's jittered stamps: onto a uniform grid at the mean period
        t = np.arange(span.size) * dt
        z = np.interp(t, span, z)
        v = np.interp(t, span, v) if np.all(np.isfinite(v)) else np.full(t.shape, np.nan)
        applied = np.full(t.shape, np.nan)
    t0_ns = int(ts[0])
    commands = None
    if applied.size > 1 and np.all(np.isfinite(applied)):
        # state k reports the current of the period that ended at it: shift by one
        c = np.append(applied[1:], applied[-1])
    else:
        tc = (rec.tc - t0_ns) * 1e-9
        commands = (tc, rec.vc)
        first = tc[0] + rec.delay        # no command in force before this
        k0 = int(np.searchsorted(t, first - 1e-12))
        if k0 and t.size - k0 < MIN_SAMPLES:     # (nearly) all before the first command
            raise _NoExcitation(f'{name}: {k0} of its {t.size} samples come before the first '
                                'command; too few are left')
        if k0:
            t, z, v = t[k0:] - t[k0], z[k0:], v[k0:]
            t0_ns += int(round(span[k0] * 1e9)) if exact else int(round(k0 * dt * 1e9))
            commands = (tc - (t0_ns - int(ts[0])) * 1e-9, rec.vc)
        c = _held_average(commands[0], commands[1], t, rec.delay)
    derived = ()
    if not np.all(np.isfinite(v)) and np.all(np.isfinite(z)) and t.size >= 5:
        from scipy.signal import savgol_coeffs, savgol_filter
        w = min(_savgol_width(dt), t.size - (1 - t.size % 2))
        v = savgol_filter(z, w, 2, deriv=1, delta=dt, mode='interp')
        gain = float(np.sqrt(np.sum(savgol_coeffs(w, 2, deriv=1) ** 2))) / dt
        noise['z_dot'], derived = noise['z'] * gain, ('z_dot',)
    pa = pb = pl = None
    tt = t0_ns + np.round(t * 1e9).astype(np.int64)
    if rec.pressures:
        vals = [np.interp(tt, tp, pv) for tp, pv in rec.pressures]
        if rec.load:
            pl = vals[0]
        else:
            pa, pb = vals
    e = experiment_from_arrays(name, t, c, z, v, pa, pb)
    return replace(e, noise=noise, derived=derived, commands=commands, delay=rec.delay,
                   p_load=pl, t0_ns=t0_ns, after_gap=a > 0)


def _topic_map(topics: TopicMap | None, state, command, pressure_p, pressure_t) -> TopicMap:
    if topics is not None:
        if not isinstance(topics, TopicMap):
            raise DataError(f'`topics` must be a TopicMap, got {type(topics).__name__}')
        return topics
    if (pressure_p is None) != (pressure_t is None):
        pressure_p = pressure_t = None
    return TopicMap(state=state, command=command, pressure_p=pressure_p,
                    pressure_t=pressure_t)


def _runs(ts: np.ndarray) -> tuple[list[tuple[int, int]], list[int]]:
    d = np.diff(ts)
    cuts = np.flatnonzero(d > 1.5 * np.median(d)) + 1 if d.size else np.array([], int)
    edges = [0, *cuts.tolist(), ts.size]
    return list(zip(edges[:-1], edges[1:])), cuts.tolist()


def load_experiment(path: str | os.PathLike, *, topics: TopicMap | None = None,
                    state: str = contract.STATE.name,
                    command: str = contract.COMMAND.name,
                    pressure_p: str | None = contract.PRESSURE_P.name,
                    pressure_t: str | None = contract.PRESSURE_T.name,
                    bag: Bag | None = None, start: float | None = None,
                    end: float | None = None) -> Experiment:
    """
    Read one experiment from the bag at ``path`` (the whole record, which must have no gap).

    ``topics`` says where the signals are (default: the contract; ``state``, ``command``,
    ``pressure_p``, ``pressure_t`` are shorthands for a contract-like map). Pressures are
    optional (pass None to ignore them); a bag without the contract's pressure topics gives
    an experiment without pressures. ``start``/``end`` [s from the bag's first message] take
    a window of the record (a split bag reads only the files it needs). Raises
    :class:`BagError` / :class:`DataError` naming the problem (missing topics with the topics
    the bag has, wrong types, missing joints with the joints the topic has, too little data,
    no excitation, samples missing from the grid: see :func:`load_experiments` for those).
    """
    rec = _read(path, _topic_map(topics, state, command, pressure_p, pressure_t), bag, start,
                end)
    if rec.ts.size < 2:
        raise DataError(f'{rec.name}: too little data: {rec.ts.size} samples (need at least '
                        f'{MIN_SAMPLES})')
    runs, cuts = _runs(rec.ts)
    if cuts:
        d = np.diff(rec.ts)
        k = cuts[0] - 1
        raise DataError(f'{rec.name}: samples are not on a uniform grid (period '
                        f'{np.median(d) * 1e-9:g} s, but {d[k] * 1e-9:g} s between t = '
                        f'{(rec.ts[k] - rec.ts[0]) * 1e-9:g} and '
                        f'{(rec.ts[k + 1] - rec.ts[0]) * 1e-9:g} s); load_experiments splits '
                        'such a record into its runs')
    return _experiment(rec, 0, rec.ts.size, rec.name)


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
    in the sample grid; each gap splits the record, and runs shorter than
    :data:`MIN_SAMPLES` are dropped, as are runs in which the piston does not move (a hold
    before the trajectory started) when another run does. Names get ``[k/n]`` when there is
    more than one run. ``topics``, ``start``/``end``: as in :func:`load_experiment`.
    """
    rec = _read(path, _topic_map(topics, state, command, pressure_p, pressure_t), bag, start,
                end)
    return _split(rec)


def experiments_from_series(name: str, ts, z, v, applied=None, commands=None,
                            pressures=(), load: bool = False,
                            delay: float = 0.0) -> list[Experiment]:
    """
    Cut the contiguous runs of series held in memory, as :func:`load_experiments` cuts a bag's.

    What a live refit fits: ``ts`` [ns] are the states' stamps (sorted or not) with position
    ``z`` [m], velocity ``v`` [m/s] (NaN: derived from the position) and ``applied`` current
    [A] (NaN or None: unknown, then ``commands`` = (stamps [ns, the state's clock], currents
    [A]) held ``delay`` [s] later are used); ``pressures``: (stamps [ns], values [Pa]) per
    chamber, or one load pressure with ``load``. Raises :class:`DataError` as the bag path
    does (too little data, no excitation).
    """
    ts = np.asarray(ts, dtype=np.int64)
    z = np.asarray(z, dtype=float)
    v = np.asarray(v, dtype=float)
    applied = np.full(z.shape, np.nan) if applied is None else np.asarray(applied, float)
    order = np.argsort(ts, kind='stable')
    ts, z, v, applied = ts[order], z[order], v[order], applied[order]
    keep = np.concatenate([[True], np.diff(ts) > 0]) if ts.size else np.zeros(0, bool)
    ts, z, v, applied = ts[keep], z[keep], v[keep], applied[keep]
    tc, vc = (np.zeros(0, np.int64), np.zeros(0)) if commands is None else (
        np.asarray(commands[0], dtype=np.int64), np.asarray(commands[1], dtype=float))
    if ts.size < 2 or (tc.size == 0 and not np.all(np.isfinite(applied))):
        raise DataError(f'{name}: too little data: {ts.size} states and {tc.size} commands')
    tc, vc = _sorted(tc, vc)
    press = [_sorted(np.asarray(t, dtype=np.int64), np.asarray(p, dtype=float))
             for t, p in pressures]
    return _split(_Record(name, ts, z, v, applied, tc, vc, press, load, float(delay)))


def _split(rec: _Record) -> list[Experiment]:
    """Return the experiments of a record's contiguous runs (see :func:`load_experiments`)."""
    runs, cuts = _runs(rec.ts)
    long_ = [(a, b) for a, b in runs if b - a >= MIN_SAMPLES]
    if not long_:
        longest = max(b - a for a, b in runs)
        raise DataError(f'{rec.name}: too little data: the longest run without missing '
                        f'samples has {longest} samples (need at least {MIN_SAMPLES}); '
                        f'{len(cuts)} gaps')
    if len(long_) == 1:
        return [_experiment(rec, *long_[0], rec.name)]
    out, still = [], []
    for k, (a, b) in enumerate(long_):
        try:
            out.append(_experiment(rec, a, b, f'{rec.name} [{k + 1}/{len(long_)}]'))
        except _NoExcitation as err:      # e.g. the hold before the reference started
            still.append(str(err))
    if not out:
        raise DataError(f'{rec.name}: no run moves the piston: ' + '; '.join(still))
    return out
