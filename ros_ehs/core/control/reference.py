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
The reference generator the reference node runs: when which samples go out, and corrections.

:class:`ReferenceGenerator` samples a waveform (:mod:`ros_ehs.core.control.waveforms`),
corrected cycle by cycle by amplitude/phase or peak/valley control where asked
(:func:`correction_for`), and decides everything the reference node does between a message
and the next; the node converts messages, calls it and publishes. The clocks are passed in:
``now`` [s] the node's monotonic clock, stamps [ns] its ROS clock (real time) or ``/clock``'s
(sim time). Each rule is tested in ``test/test_reference_generator.py`` without DDS.

* **Time zero** is the first sample's stamp. In real time (:meth:`~ReferenceGenerator.tick`)
  it waits for ``wait_subscribers`` subscribers on ``reference`` and, with ``wait_loop``, for
  the plant's diagnostics to report its loop closed (:meth:`~ReferenceGenerator.loop_closed`);
  nothing is published until then. After ``duration`` (0: never) the last position is held
  with zero velocity.
* **Sim time** (lock-step): each ``/clock`` t is answered with the samples at t, t + 1 /
  ``rate_hz``, ... up to t + ``preview`` (:meth:`~ReferenceGenerator.clock`), so a resend or a
  reordered clock gets the same samples and needs no special case; a clock more than
  ``EPOCH_PERIODS`` periods back starts a new run (a lock-step plant started again, a replayed
  bag): the waveform restarts from its beginning there, and its corrections from scratch.
* **Force control** (``control_mode`` force): the waveform is a force [N], sent as each
  reference's ``f_ref`` with no position; the corrections learn from the load cell's reading
  (the node passes it to :meth:`~ReferenceGenerator.state`). A displacement waveform's
  amplitude and offset stay within ``POSITION_RANGE``.
* **Corrections** (APC, PVC) learn from the measured position of each state
  (:meth:`~ReferenceGenerator.state`), once per stamp, in order. A correction starts
  ``preview`` after the end of the cycle it was learnt from, so no sample already sent
  changes; under sim time a clock whose preview holds a correction is answered only once the
  state that ends its cycle has been measured (the preview waits: the loop is then the
  in-process loop's to 1e-9 m). States before time zero are kept (``EARLY_STATES``) and taken
  when it comes. The corrections freeze, keeping the command's last amplitude and phase,
  while a safety trip that acts is latched (:meth:`~ReferenceGenerator.event`: hold, stop,
  power off) and, in real time, while no state has come for ``STATES_LOST`` s
  (:meth:`~ReferenceGenerator.watch`); they resume after a reset or when states return,
  without a jump. No cycle that overlaps the controller's ramp-on (``ramp_time``, from time
  zero and after a reset) is learnt from.

What the node should log is left in :attr:`ReferenceGenerator.notes` as ``(level, text)``.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from ros_ehs.core.control.apc import AmplitudePhaseControl
from ros_ehs.core.control.cycles import CycleCorrection
from ros_ehs.core.control.loop import EPOCH_PERIODS, NOTE_PERIOD
from ros_ehs.core.control.pvc import PeakValleyControl
from ros_ehs.core.control.waveforms import cyclic_blocks, make
from ros_ehs.core.errors import InputError, ParameterError
from ros_ehs_msgs_py import Reference

__all__ = ['EARLY_STATES', 'POSITION_RANGE', 'ReferenceGenerator', 'STATES_LOST',
           'correction_for']

#: Real time: no state for this long freezes the corrections [s].
STATES_LOST = 0.2
#: Sim time: states kept from before time zero (time zero's own).
EARLY_STATES = 100
#: A position waveform's amplitude and offset stay within this [m].
POSITION_RANGE = 2.0


def correction_for(values: Mapping[str, Any], options: Mapping[str, Any]
                   ) -> CycleCorrection | None:
    """
    Return the cycle-by-cycle correction the reference options ask for (APC, PVC), or None.

    ``values``: the waveform's (:data:`~ros_ehs.core.control.waveforms.WAVEFORM`);
    ``options``: ``amplitude_phase_control``, ``peak_valley_control``, ``preview``,
    ``ramp_time``, ``apc_harmonics``, ``blocks``. Raises :class:`ParameterError` naming what
    cannot be corrected (both asked for, the wrong kind of waveform, a preview too long).
    """
    apc, pvc = options['amplitude_phase_control'], options['peak_valley_control']
    if not (apc or pvc):
        return None
    if apc and pvc:
        raise ParameterError('amplitude_phase_control corrects a sine, peak_valley_control a '
                             'triangle or haversine: choose one')
    kinds = ('sine', 'chirp') if apc else ('triangle', 'haversine')
    name = 'amplitude_phase_control' if apc else 'peak_valley_control'
    kind = values['kind']
    if kind not in kinds:
        raise ParameterError(f'{name} corrects a {" or ".join(kinds)}: `kind` is {kind!r}')
    preview = float(options['preview'])
    f = float(values['frequency'])
    if kind == 'chirp':         # the sweep's shortest period bounds the preview
        f = max(float(values['f0']), float(values['f1']))
    share = 1.0 if apc else 0.5
    if preview * f >= share:
        raise ParameterError(f'{name}: `preview` = {preview:g} s must be under '
                             f'{"the" if apc else "half the"} period ({1 / f:g} s)')
    # a correction starts `preview` after the cycle it was learnt from: every sample already
    # sent stays as it was sent, and under sim time each preview can wait for the states it
    # depends on (in process: the same latency gives the same numbers)
    ramp = float(options['ramp_time'])
    if apc:
        if kind == 'chirp':         # a sweep: the fundamental only (docs/controller.md)
            return AmplitudePhaseControl(float(values['amplitude']), float(values['f0']), 0.0,
                                         sweep_to=float(values['f1']),
                                         sweep_time=float(values['chirp_duration']),
                                         latency=preview, learn_from=ramp)
        return AmplitudePhaseControl(float(values['amplitude']), float(values['frequency']),
                                     float(values['offset']),
                                     harmonics=int(options['apc_harmonics']),
                                     latency=preview, learn_from=ramp)
    return PeakValleyControl(cyclic_blocks(values, options['blocks']), f, values['kind'],
                             latency=preview, learn_from=ramp)


class ReferenceGenerator:
    """
    The reference node's rules (see the module docstring).

    ``values``: the waveform's settings; ``options``: the reference node's (``rate_hz``,
    ``preview``, ``duration``, ``csv_path``, ``blocks``, ``wait_subscribers``, ``wait_loop``
    and the corrections'); ``sim_time``: answer ``/clock`` with previews (lock-step) instead of
    ticking in real time.
    """

    def __init__(self, values: Mapping[str, Any], options: Mapping[str, Any], *,
                 sim_time: bool = False) -> None:
        self.options = dict(options)
        rate = float(self.options['rate_hz'])
        if not (math.isfinite(rate) and rate > 0):
            raise InputError(f'`rate_hz` = {rate!r} must be a positive number of Hz')
        self.dt_ns = int(round(1e9 / rate))
        self.sim_time = bool(sim_time)
        self.force = self.options.get('control_mode', 'displacement') == 'force'
        self.values: dict[str, Any] = {}
        self.traj = None
        self.correction: CycleCorrection | None = None
        self.set_waveform(values)
        self.frozen_by: set[str] = set()
        self.clipped = False            #: the controller clips its command (its events)
        self.t_first: int | None = None    # time zero [ns]
        self.last_ns = -1                  # the newest sample's (or clock's) stamp
        self.count = 0                     # samples (real time) or previews (sim time) sent
        self.bad = 0                       # malformed clocks
        self.runs = 1
        self.closed = not (self.options['wait_loop'] and not self.sim_time)
        self.notes: list[tuple[str, str]] = []
        self._last_state = math.nan        # when the newest state arrived [s]
        self._measured_ns = -1             # the newest state stamp a correction has taken
        self._early: list[tuple[int, float]] = []
        self._waiting: list[int] = []      # clock stamps whose preview waits for states
        self._noted = -math.inf

    # -- the waveform ------------------------------------------------------------------------
    def set_waveform(self, values: Mapping[str, Any]) -> None:
        """
        Take new waveform settings (checked, as a whole); a correction starts again.

        Raises :class:`ParameterError` (or :class:`~ros_ehs.core.errors.DataError` for a
        drive file) naming the problem; nothing changes then.
        """
        merged = {**self.values, **values}
        if not self.force:
            for name in ('amplitude', 'offset'):
                v = merged.get(name, 0.0)
                if isinstance(v, (int, float)) and abs(v) > POSITION_RANGE:
                    raise ParameterError(f'`{name}` = {v!r} m is beyond +-{POSITION_RANGE:g} m '
                                         '(a force? set control_mode force)')
        traj = make(merged, self.options['csv_path'], self.options['blocks'])
        corr = correction_for(merged, self.options)
        self.traj, self.values, self.correction = traj, merged, corr
        self._measured_ns, self._waiting = -1, []

    @property
    def started(self) -> bool:
        """Return True from time zero on."""
        return self.t_first is not None

    def samples(self, stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return z_ref [m] and v_ref [m/s] at ``stamps_ns`` (held after ``duration``)."""
        t = (stamps_ns - self.t_first) * 1e-9
        dur = float(self.options['duration'])
        traj = self.traj if self.correction is None else self._corrected
        if dur <= 0:
            return traj(t)
        hold = t > dur
        z, v = traj(np.minimum(t, dur))
        return z, np.where(hold, 0.0, v)

    def _corrected(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        zv = [self.correction.reference(float(x)) for x in np.atleast_1d(t)]
        return np.array([a for a, _ in zv]), np.array([b for _, b in zv])

    # -- real time ---------------------------------------------------------------------------
    def loop_closed(self) -> None:
        """Take the plant's word that its loop is closed (``wait_loop``)."""
        self.closed = True

    def tick(self, stamp_ns: int, subscribers: int) -> Reference | None:
        """
        Real time: return the sample at ``stamp_ns`` to publish, or None before time zero.

        ``subscribers``: those of ``reference`` now.
        """
        if self.t_first is None:
            need = int(self.options['wait_subscribers'])
            if subscribers < need or not self.closed:
                return None
            if need or self.options['wait_loop']:
                self.notes.append(('info', f'time zero: {subscribers} subscriber(s) on '
                                   'reference' + (', the plant reports its loop closed'
                                                  if self.options['wait_loop'] else '')))
            self.t_first = stamp_ns
        z, v = self.samples(np.array([stamp_ns], dtype=np.int64))
        self.last_ns = stamp_ns
        self.count += 1
        return self._reference(stamp_ns, float(z[0]), float(v[0]))

    def _reference(self, stamp_ns: int, value: float, rate: float) -> Reference:
        """Return the sample as a position and its velocity, or as a force."""
        if self.force:
            return Reference(stamp_ns, math.nan, math.nan, value)
        return Reference(stamp_ns, value, rate)

    # -- sim time ----------------------------------------------------------------------------
    def malformed_clock(self) -> None:
        """Count a ``/clock`` that did not decode (answered with nothing)."""
        self.bad += 1

    def clock(self, t_ns: int, now: float = math.nan) -> list[Reference] | None:
        """
        Sim time: return the preview that answers ``/clock`` ``t_ns``, or None: it waits.

        A waiting preview is returned by :meth:`state` once the states it depends on came.
        """
        if t_ns < self.last_ns - EPOCH_PERIODS * self.dt_ns:     # /clock went back
            self.runs += 1
            if not (now - self._noted < NOTE_PERIOD):
                self._noted = now
                self.notes.append(('info', f'new run: /clock jumped back '
                                   f'{(self.last_ns - t_ns) * 1e-9:.6g} s; trajectory from its '
                                   f'start (run {self.runs})'))
            self.t_first = None
            if self.correction is not None:       # a new run: its corrections start again
                self.correction = correction_for(self.values, self.options)
                self._measured_ns, self._waiting = -1, []
        if self.t_first is None or t_ns < self.t_first:
            self.t_first = t_ns
            if self.correction is not None:
                early, self._early = self._early, []
                for stamp, z in sorted(early):
                    self._measure(stamp, z)
        self.last_ns = t_ns
        if not self._ready(t_ns):         # the states it depends on are on their way
            if t_ns not in self._waiting:
                self._waiting.append(t_ns)
            return None
        return self.preview(t_ns)

    def preview(self, t_ns: int) -> list[Reference]:
        """Return the samples from ``t_ns`` to ``t_ns`` + ``preview`` (one period at least)."""
        n = max(1, int(float(self.options['preview']) * 1e9 // self.dt_ns))
        stamps = np.arange(n + 1, dtype=np.int64) * self.dt_ns + t_ns
        z, v = self.samples(stamps)
        self.count += 1
        return [self._reference(int(st), float(zz), float(vv)) for st, zz, vv in
                zip(stamps, z, v)]

    def _ready(self, t_ns: int) -> bool:
        """Whether a correction has measured every state the preview of ``t_ns`` depends on."""
        if self.correction is None:
            return True
        # the samples up to t + preview use corrections from the cycles that ended by
        # t + preview - latency = t: their ends must have been measured
        end = (t_ns - self.t_first) * 1e-9
        boundary = self.correction.cycle_start(self.correction.cycle_of(end))
        return boundary <= 0.0 or self._measured_ns >= self.t_first + int(
            round(boundary * 1e9)) - 1000

    # -- corrections -------------------------------------------------------------------------
    def state(self, stamp_ns: int, z: float, now: float) -> list[list[Reference]]:
        """
        Take a measured position [m] stamped ``stamp_ns`` that arrived at ``now`` [s].

        Returns the previews that waited for it (sim time), in order.
        """
        if self.correction is None:
            return []
        self._last_state = now
        self._freeze('states lost', False)
        if self.t_first is None:
            if self.sim_time and len(self._early) < EARLY_STATES:    # time zero's own state
                self._early.append((stamp_ns, z))
            return []
        self._measure(stamp_ns, z)
        out = []
        while self._waiting and self._ready(self._waiting[0]):
            out.append(self.preview(self._waiting.pop(0)))
        return out

    def _measure(self, stamp_ns: int, z: float) -> None:
        # once per stamp, in order: a lock-step resend is the same state again
        if stamp_ns <= self._measured_ns or stamp_ns < self.t_first:
            return
        self._measured_ns = stamp_ns
        if self.clipped:
            self.correction.clip()        # learn from it only what asks less of the rig
        self.correction.measure((stamp_ns - self.t_first) * 1e-9, z)

    def watch(self, now: float) -> None:
        """Real time: freeze the corrections when no state has come for ``STATES_LOST``."""
        if math.isnan(self._last_state):       # the lost time counts from the first watch
            self._last_state = now
        if self.correction is not None and self.t_first is not None and \
                now - self._last_state > STATES_LOST:
            self._freeze('states lost', True)

    def event(self, kind: str, action: str) -> None:
        """Take a safety event of the controller (its ``kind`` and ``action``)."""
        if self.correction is None:
            return
        if kind in ('clipped', 'unclipped'):    # the command not applied as asked
            self.clipped = kind == 'clipped'
        elif kind == 'trip' and action in ('hold', 'stop', 'power_off'):
            self._freeze('safety trip', True)
        elif kind in ('reset', 'enabled'):
            if 'safety trip' in self.frozen_by and self.t_first is not None:
                # the controller ramps onto the trajectory again: not learnt from
                self.correction.learn_from = (self.last_ns - self.t_first) * 1e-9 + float(
                    self.options['ramp_time'])
            self._freeze('safety trip', False)

    def _freeze(self, reason: str, on: bool) -> None:
        was = bool(self.frozen_by)
        (self.frozen_by.add if on else self.frozen_by.discard)(reason)
        if bool(self.frozen_by) != was:
            self.correction.freeze(bool(self.frozen_by))
            self.notes.append(('info', ('APC frozen: ' if self.frozen_by else 'APC resumed: ')
                               + reason))

    # -- figures -----------------------------------------------------------------------------
    def figures(self) -> dict:
        """Return the figures the diagnostics report."""
        t = 0.0 if self.t_first is None else (self.last_ns - self.t_first) * 1e-9
        f = {'started': self.t_first is not None, 'published': self.count, 'time_s': t,
             'bad_clocks': self.bad}
        c = self.correction
        last = c.history[-1] if c is not None and c.history else {}
        if isinstance(c, PeakValleyControl):
            f.update(pvc_cycles=c.judged, pvc_error=float(last.get('error', math.nan)),
                     pvc_converged=c.converged_at is not None,
                     pvc_frozen=','.join(sorted(self.frozen_by)))
        elif c is not None:
            f.update(apc_cycles=c.cycles, apc_amp_ratio=float(last.get('amp_ratio', math.nan)),
                     apc_phase_deg=float(last.get('phase_deg', math.nan)),
                     apc_harmonics_pct=float(last.get('harmonics_pct', math.nan)),
                     apc_converged=c.converged_at is not None,
                     apc_frozen=','.join(sorted(self.frozen_by)))
        return f

    def describe(self) -> str:
        """Return what it generates, as the node's start-up line says."""
        corr = {type(None): '', AmplitudePhaseControl: ', amplitude/phase control',
                PeakValleyControl: ', peak/valley control'}[type(self.correction)]
        return f'{self.values["kind"]} reference{corr}'
