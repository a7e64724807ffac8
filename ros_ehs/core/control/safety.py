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
Limit and error detectors with latched actions, hydraulics on/off and ramp-on (ROS-free).

A :class:`Supervisor` sits between the trajectory and the position controller, as the limit
detectors of a servo-hydraulic test controller do. Every control period
:meth:`Supervisor.update` takes the measurement and the trajectory's reference and returns
the reference the controller must track, or that the valve current must be zero.

Detectors (``ros_ehs.core.params.SAFETY_SPECS`` holds their limits and actions):

=====================  ======================================================================
``limit_position_max``  ``z > limit_position_max``
``limit_position_min``  ``z < limit_position_min``
``limit_velocity``      ``|z_dot| > limit_velocity`` (z_dot measured, or differenced)
``limit_force``         ``|force| > limit_force`` (when the state carries the force)
``limit_error``         ``|z_ref - z| > limit_error`` for longer than ``limit_error_time``
``feedback``            position non-finite, lost (:meth:`Supervisor.feedback_lost`), or
                        frozen: bit-identical for ``frozen_periods`` periods with
                        ``|i| >= frozen_current`` (periods without neither count nor clear)
``saturation``          the command at ``u_max`` for longer than ``limit_saturation_time``
``limit_load_max``      the load cell above ``limit_load_max`` (when there is a reading), or
                        the load ``limit_load_lead`` ahead at its rate
``limit_load_min``      the load cell, or the load ahead, below ``limit_load_min``
``limit_specimen_max``  the specimen's displacement ``z - z_L`` above ``limit_specimen_max``
``limit_specimen_min``  ``z - z_L`` below ``limit_specimen_min``
``limit_force_error``   force control: ``|F_ref - F| > limit_force_error`` for longer than
                        ``limit_error_time`` (:meth:`Supervisor.judge_force_error`)
``specimen_break``      within ``break_window`` the load's magnitude fell by more than
                        ``break_drop`` while the piston moved more than ``break_travel`` the
                        way that would have loaded the specimen more: its force path is lost
``load_feedback``       force control or specimen protect (``needs_load``): the load cell
                        non-finite, missing or stale; or frozen: its reading repeated while
                        the piston moved far enough to change the load by more than
                        ``load_frozen_force`` (``k_L`` times the travel since the reading last
                        changed; a reading of exactly 0 N is not judged: a simulated broken
                        specimen's); a hold then holds the position where it last changed
``hold_error``          a hold the axis does not obey: the piston more than
                        ``hold_error_position`` plus the braking distance at the speed the
                        hold began at from the held position (or, held in force control, the
                        load more than ``hold_error_force`` from the held load) for longer
                        than ``hold_error_time`` (:meth:`Supervisor.judge_hold`)
``loop_timing``         real time: the valve held one command more than ``loop_timing_late``:
                        a state answered that long after its stamp, or that long after the
                        one answered before it (the states between never answered)
                        (:meth:`Supervisor.judge_timing`): the machine is too busy to run the
                        loop on time
=====================  ======================================================================

Edge-case policy (each branch tested in ``test/test_safety.py``):

* a value exactly at its limit does not trip (the break detector: a drop and a travel
  exactly at theirs do not). A load limit also judges the load ``limit_load_lead`` ahead:
  the reading plus the lead times its rate (differenced stamp to stamp, smoothed over the
  lead, started again after a missing reading): the axis stops a moving load that much after
  the command that holds it, so a limit judged on the reading is passed by the rate times
  it. A time-qualified detector trips when the
  condition has held for *longer* than its time (``n`` periods with ``n dt > T``);
* a trip is **latched** (and reported once, as an :class:`Event`) until :meth:`reset`
  succeeds; the action applies from the command that answers the state on which the
  condition became true: the period after it;
* several latched detectors: the most severe action rules
  (``indicate < hold < stop < power_off``);
* ``hold`` freezes the reference at the measured position of the trip (in force control
  the force loop holds the load of the trip; a load limit tripped ahead of its reading:
  the limit, :attr:`Supervisor.load_trip`); ``stop`` ramps it
  from there to ``safe_position`` at ``safe_velocity``, then holds; ``power_off`` zeroes the
  valve current; from ``hold`` or ``stop`` a more severe action starts from the measured
  position again;
* :meth:`reset` is refused, naming the detectors, while a latched limit is still beyond its
  limit less the hysteresis (``limit_hysteresis`` of the limit, of the span between the pair
  for the position and the specimen limits), or the feedback is still non-finite or lost.
  The tracking-error, saturation and frozen conditions cannot be judged while the axis is
  held or off: they count as clear, and are judged again from the ramp-on;
* **ramp-on** at the start, on :meth:`enable` and after a reset: the reference starts at the
  measured position ``z0`` and blends into the trajectory,
  ``z_ref = z0 + w (z_traj - z0)``, ``v_ref = w v_traj + w' (z_traj - z0)`` with the quintic
  ``w(s) = 10 s^3 - 15 s^4 + 6 s^5``, ``s = t / ramp_time``: the reference's position,
  velocity and acceleration are continuous, so the command does not jump. A ramp waits for
  the first finite position (0 A until then);
* disabled (hydraulics off): 0 A; :meth:`enable` is refused while a hold, stop or power-off
  is latched ("reset first");
* non-finite velocity or force in a state: the velocity is differenced from the position,
  the force detector skips the sample; a non-finite trajectory is passed on (the PID's
  policy: 0 A and ``fault``). A non-finite load skips the load limits and the break
  detector (its window restarts), and trips ``load_feedback`` where the load is needed;
* the position's tracking error is judged only while the displacement loop drives the valve
  (``track_position``) and not while specimen protect limits its command (``limited``: the
  force limit, not a fault, keeps the position from its reference);
* :meth:`blend_from` starts a ramp like the ramp-on, from a given position over a given time:
  the displacement loop taking over from the force loop (a mode switch) starts there.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
import math
from typing import Mapping, NamedTuple

from ros_ehs.core.errors import InputError
from ros_ehs.core.model.coefficients import flow_gain_kq
from ros_ehs.core.params import ACTIONS, spec
from ros_ehs_msgs_py.values import SafetyEvent as Event

__all__ = ['ACTIONS', 'DETECTORS', 'Demand', 'Event', 'LIMITS_OF', 'SafetyConfig', 'Supervisor',
           'UNITS', 'break_travel', 'braking_distance', 'ramp_weight', 'unprotected']

#: The detectors, in the order they are checked and reported.
DETECTORS = ('limit_position_max', 'limit_position_min', 'limit_velocity', 'limit_force',
             'limit_error', 'feedback', 'saturation', 'limit_load_max', 'limit_load_min',
             'limit_specimen_max', 'limit_specimen_min', 'limit_force_error', 'specimen_break',
             'load_feedback', 'hold_error', 'loop_timing')
_SEVERITY = {a: k for k, a in enumerate(ACTIONS)}
UNITS = {'limit_position_max': 'm', 'limit_position_min': 'm', 'limit_velocity': 'm/s',
         'limit_force': 'N', 'limit_error': 'm', 'feedback': '', 'saturation': 's',
         'limit_load_max': 'N', 'limit_load_min': 'N', 'limit_specimen_max': 'm',
         'limit_specimen_min': 'm', 'limit_force_error': 'N', 'specimen_break': 'N',
         'load_feedback': '', 'hold_error': '', 'loop_timing': 's'}
_NUMBERS = ('limit_position_max', 'limit_position_min', 'limit_velocity', 'limit_force',
            'limit_error', 'limit_error_time', 'feedback_timeout', 'frozen_periods',
            'frozen_current', 'limit_saturation_time', 'limit_hysteresis', 'safe_position',
            'safe_velocity', 'ramp_time', 'limit_load_max', 'limit_load_min',
            'limit_load_lead', 'limit_specimen_max', 'limit_specimen_min', 'limit_force_error',
            'break_drop', 'break_travel', 'break_window', 'z_L', 'k_L', 'load_frozen_force',
            'hold_error_position', 'hold_error_force', 'hold_error_time', 'load_check_window',
            'load_check_force', 'load_drift_force', 'loop_timing_late')
#: the pairs of limits whose hysteresis is a fraction of their span
_PAIRS = {'limit_position_max': ('limit_position_min', 'limit_position_max', 1),
          'limit_position_min': ('limit_position_min', 'limit_position_max', -1),
          'limit_load_max': ('limit_load_min', 'limit_load_max', 1),
          'limit_load_min': ('limit_load_min', 'limit_load_max', -1),
          'limit_specimen_max': ('limit_specimen_min', 'limit_specimen_max', 1),
          'limit_specimen_min': ('limit_specimen_min', 'limit_specimen_max', -1)}


#: The load cell's fit against the position takes every period's sample and is judged every
#: this many periods (a drift or a wrong gain is slow)
LOAD_CHECK_EVERY = 10
#: The load check's zero-load position: its reference is the mean of the judged windows'
#: over this long from the first [s]...
LOAD_ZERO_TIME = 2.0
#: ...and it is compared smoothed over this long [s] (a first-order filter: it lags a steady
#: drift by this long; with 100 N of white noise on the cell and 10 um on the position, the
#: smoothed zero stays within 37 N of its reference over 1200 cycles of the fatigue rig, the
#: reason for ``load_drift_force``'s 100 N)
LOAD_ZERO_SMOOTH = 0.25
#: The values a user sets to tune each detector (a value set while the action is off protects
#: nothing: :func:`unprotected`).
LIMITS_OF = {'limit_position_max': ('limit_position_max',),
             'limit_position_min': ('limit_position_min',),
             'limit_velocity': ('limit_velocity',), 'limit_force': ('limit_force',),
             'limit_error': ('limit_error', 'limit_error_time'),
             'feedback': ('feedback_timeout', 'frozen_periods', 'frozen_current'),
             'saturation': ('limit_saturation_time',),
             'limit_load_max': ('limit_load_max', 'limit_load_lead'),
             'limit_load_min': ('limit_load_min', 'limit_load_lead'),
             'limit_specimen_max': ('limit_specimen_max',),
             'limit_specimen_min': ('limit_specimen_min',),
             'limit_force_error': ('limit_force_error',),
             'specimen_break': ('break_drop', 'break_travel', 'break_window'),
             'load_feedback': ('load_frozen_force', 'load_check_window', 'load_check_force',
                               'load_drift_force'),
             'hold_error': ('hold_error_position', 'hold_error_force', 'hold_error_time'),
             'loop_timing': ('loop_timing_late',)}


def unprotected(params: Mapping[str, object]) -> list[str]:
    """
    Return a sentence for each detector whose limit is set but whose action is ``off``.

    A value changed from its default says the user meant the detector to act; with its
    action ``off`` it never will. The controller says each once at its start.
    """
    out = []
    for det in DETECTORS:
        if str(params[det + '_action']) != 'off':
            continue
        set_ = [n for n in LIMITS_OF[det] if float(params[n]) != float(spec(n).default)]
        if set_:
            vals = ', '.join(f'{n} = {float(params[n]):g} {spec(n).unit}'.rstrip() for n in set_)
            out.append(f'{vals} set, but {det}_action is off: the {det} detector will not act '
                       f'(give it an action: indicate, hold, stop or power_off)')
    return out


def _default(name: str) -> float:
    """Return a parameter's declared default (ros_ehs.core.params: declared once)."""
    return float(spec(name).default)


@dataclass(frozen=True)
class SafetyConfig:
    """The detectors' limits [SI] and actions; build with :meth:`from_params`."""

    limit_position_max: float = _default('limit_position_max')
    limit_position_min: float = _default('limit_position_min')
    limit_velocity: float = _default('limit_velocity')
    limit_force: float = _default('limit_force')
    limit_error: float = _default('limit_error')
    limit_error_time: float = _default('limit_error_time')
    feedback_timeout: float = _default('feedback_timeout')
    frozen_periods: float = _default('frozen_periods')
    frozen_current: float = _default('frozen_current')
    limit_saturation_time: float = _default('limit_saturation_time')
    limit_hysteresis: float = _default('limit_hysteresis')
    safe_position: float = _default('safe_position')
    safe_velocity: float = _default('safe_velocity')
    ramp_time: float = _default('ramp_time')
    limit_load_max: float = _default('limit_load_max')
    limit_load_min: float = _default('limit_load_min')
    limit_load_lead: float = _default('limit_load_lead')
    limit_specimen_max: float = _default('limit_specimen_max')
    limit_specimen_min: float = _default('limit_specimen_min')
    limit_force_error: float = _default('limit_force_error')
    break_drop: float = _default('break_drop')
    break_travel: float = _default('break_travel')
    break_window: float = _default('break_window')
    z_L: float = _default('z_L')
    k_L: float = _default('k_L')
    load_frozen_force: float = _default('load_frozen_force')
    hold_error_position: float = _default('hold_error_position')
    hold_error_force: float = _default('hold_error_force')
    hold_error_time: float = _default('hold_error_time')
    load_check_window: float = _default('load_check_window')
    load_check_force: float = _default('load_check_force')
    load_drift_force: float = _default('load_drift_force')
    loop_timing_late: float = _default('loop_timing_late')
    actions: Mapping[str, str] = field(default_factory=lambda: {
        d: spec(d + '_action').default for d in DETECTORS})
    #: the rig's braking distance per unit of speed, the detection's periods left out [s]
    #: (:func:`braking_distance` at 1 m/s and dt 0, from the rig's parameters; 0 without them)
    braking_time: float = 0.0

    def __post_init__(self) -> None:
        """Validate every value against its declaration in ros_ehs.core.params."""
        for name in _NUMBERS:
            spec(name).check(getattr(self, name))
        for d in DETECTORS:
            spec(d + '_action').check(self.actions.get(d, 'off'))
        unknown = set(self.actions) - set(DETECTORS)
        if unknown:
            raise InputError(f'`actions` names unknown detectors {sorted(unknown)}; '
                             f'known: {list(DETECTORS)}')
        for lo, hi, unit in (('limit_position_min', 'limit_position_max', 'm'),
                             ('limit_load_min', 'limit_load_max', 'N'),
                             ('limit_specimen_min', 'limit_specimen_max', 'm')):
            if not getattr(self, lo) < getattr(self, hi):
                raise InputError(f'`{lo}` = {getattr(self, lo)!r} {unit} must be below `{hi}` '
                                 f'= {getattr(self, hi)!r} {unit}')

    @classmethod
    def from_params(cls, params: Mapping[str, object]) -> 'SafetyConfig':
        """Build from a :class:`~ros_ehs.core.params.Params` (or any mapping with the names)."""
        rig = ('beta_e', 'A_p', 'l_iac', 'm_p', 'm_s', 'K_w')
        braking = braking_distance(params, 1.0, 0.0) if all(k in params for k in rig) else 0.0
        return cls(**{n: float(params[n]) for n in _NUMBERS},
                   actions={d: str(params[d + '_action']) for d in DETECTORS},
                   braking_time=braking)

    def action(self, detector: str) -> str:
        """Return what ``detector`` does when it trips."""
        return self.actions.get(detector, 'off')

    def limit(self, detector: str) -> float:
        """Return the limit a detector compares with, in its unit (feedback: the timeout)."""
        return {'limit_error': self.limit_error, 'feedback': self.feedback_timeout,
                'saturation': self.limit_saturation_time, 'specimen_break': self.break_drop,
                'load_feedback': math.nan, 'hold_error': self.hold_error_time,
                'loop_timing': self.loop_timing_late,
                }.get(detector, getattr(self, detector, math.nan))


class Demand(NamedTuple):
    """What the controller must do this period."""

    mode: str        #: 'run', 'ramp', 'hold', 'stop', 'power_off', 'disabled', 'waiting'
    z_ref: float     #: reference position [m] (NaN when the current must be zero)
    v_ref: float     #: reference velocity [m/s]
    power: bool      #: False: valve current 0 A


def ramp_weight(s: float) -> tuple[float, float]:
    """Return the quintic blend ``w(s)`` and ``dw/ds`` for ``s`` in [0, 1] (clipped)."""
    if s <= 0.0:
        return 0.0, 0.0
    if s >= 1.0:
        return 1.0, 0.0
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s)), 30.0 * s * s * (1.0 - s) ** 2


def braking_distance(params: Mapping[str, object], v: float, dt: float,
                     periods: float = 2.0) -> float:
    """
    Return how far the piston runs past a position limit it crosses at speed ``v`` [m].

    ``d = |v| (periods dt + tau_v) + |v| / omega_h``: the detection and action take
    ``periods`` control periods (the action applies to the command answering the state that
    tripped: one period in lock-step, at most two in real time); the valve closes with the
    time constant ``tau_v`` of its spool (``sqrt(m_s / K_w)``, the spool's own natural
    period, at least 2 ms for a G761-class valve); then the oil column's stiffness
    ``k_h = 2 beta_e A_p / l_iac`` against the moving mass ``m_p`` stops the piston within
    ``|v| / omega_h`` (``omega_h = sqrt(k_h / m_p)``, the hydraulic natural frequency at
    mid-stroke, where the chambers are softest together). Friction and the specimen only
    shorten it. ``test/test_safety.py`` checks it against the full model.
    """
    beta, a_p, l_iac, m_p = (float(params[k]) for k in ('beta_e', 'A_p', 'l_iac', 'm_p'))
    tau_v = max(2.0e-3, math.sqrt(float(params['m_s']) / float(params['K_w'])))
    omega_h = math.sqrt(2.0 * beta * a_p / l_iac / m_p)
    return abs(v) * (periods * dt + tau_v) + abs(v) / omega_h


def break_travel(params: Mapping[str, object], force: float, dt: float) -> float:
    """
    Return how far the piston can travel after its specimen breaks at ``force`` [N] [m].

    The bound the ``specimen_break`` detector with a hold keeps (docs/safety.md):

    * the oil column lets go: the chambers held ``force`` against the specimen, and released
      they drive the piston until their pressure difference is spent, at most ``2 |F| /
      k_h`` (a mass on a spring released from its preload; ``k_h = 2 beta_e A_p / l_iac``);
    * the valve keeps flowing while the break is detected and acted on: the piston must run
      ``break_travel``, accelerating at ``|F| / m_p`` from rest (``t_d = sqrt(2 break_travel
      m_p / |F|)``), the hold acts a period or two later and the spool closes in ``tau_v``;
      at the most the valve is open at ``u_max``, a speed of ``u_max K_q K_x / A_p``.

    Friction and the displacement loop pulling back only shorten it.
    """
    beta, a_p, l_iac, m_p = (float(params[k]) for k in ('beta_e', 'A_p', 'l_iac', 'm_p'))
    k_h = 2.0 * beta * a_p / l_iac
    f = abs(float(force))
    if f <= 0:
        return 0.0
    tau_v = max(2.0e-3, math.sqrt(float(params['m_s']) / float(params['K_w'])))
    t_d = math.sqrt(2.0 * float(params['break_travel']) * m_p / f)
    v_max = float(params['u_max']) * flow_gain_kq(params) * float(params['K_x']) / a_p
    return 2.0 * f / k_h + v_max * (t_d + 2.0 * dt + tau_v)


class _Latch:
    """One detector's state: latched, the periods its condition has held and for how long."""

    __slots__ = ('tripped', 'count', 'ns', 'since', 'last')

    def __init__(self) -> None:
        self.tripped = False
        self.count = 0
        self.ns = 0          # the states' stamps' time over those periods [ns]
        self.since = 0       # _held: the stamp its condition began at [ns]
        self.last = 0        # ... and the last stamp it held at [ns]


class Supervisor:
    """Detectors, latched actions, hydraulics on/off and ramp-on (see the module docstring)."""

    def __init__(self, config: SafetyConfig | None = None, dt: float = 1e-3,
                 enabled: bool = True) -> None:
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise InputError(f'`dt` = {dt!r} s must be finite and > 0')
        if config is not None and not isinstance(config, SafetyConfig):
            raise InputError(f'`config` must be SafetyConfig, got {type(config).__name__}')
        self.config = config or SafetyConfig()
        self.dt = float(dt)
        self._win_cfg: SafetyConfig | None = None     # the config _win_n is of
        self._win_n = 1
        self.latches = {d: _Latch() for d in DETECTORS}
        self.enabled = bool(enabled)
        self.counts = dict.fromkeys(DETECTORS, 0)
        self._window: deque[tuple[int, float, float]] = deque()   # the break window: (n, F, z)
        self._win_max: deque[tuple[int, float]] = deque()         # its maxima of |F|, falling
        self._win_zlo: deque[tuple[int, float]] = deque()    # minima of z where F >= 0, rising
        self._win_zhi: deque[tuple[int, float]] = deque()    # maxima of z where F < 0, falling
        self._win_seq = 0
        self._lc_zero_clear()
        self._restart()

    # -- state -------------------------------------------------------------------------------
    def _restart(self) -> None:
        self._ramp_pending = True       # a ramp-on starts at the next finite position
        self._ramp_t0 = 0
        self._ramp_z0 = math.nan
        self._ramp_from = math.nan      # ramp_again: from the last demand, not the measurement
        self._ramp_time = math.nan      # blend_from: this ramp's own time (NaN: ramp_time)
        self._ramp_T = 0.0              # the running ramp's time [s]
        self.ramp = 0.0                 #: the ramp-on's progress: 0 waiting/off, 1 on
        self._mode = 'run'              # 'run' | 'hold' | 'stop' | 'power_off'
        self._hold_z = math.nan
        self._hold_speed = math.nan     # the piston's speed as the hold began (judge_hold)
        self._last_z = math.nan
        self._z_dot = math.nan          # the newest state's velocity (measured or differenced)
        self._last_stamp: int | None = None
        self._same = 0
        self._last_ref = math.nan
        self._load_last = math.nan      # the load cell's last reading [N]
        self._load_same = 0             # periods it has repeated
        self._z_load = math.nan         # the position when it last changed [m]
        self._hold_at = math.nan        # where a hold holds instead of the measured position
        self.load_trip: tuple[float, float] | None = None   #: a load limit's trip (update())
        self._rate_clear()
        self._lc_clear()

    def _load_limit(self, det: str, stamp_ns: int, load: float, ahead: float, h: float,
                    events: list[Event]) -> None:
        """
        Trip a load limit the reading or the load ahead passed; set :attr:`load_trip`.

        ``load_trip`` is (the load to hold, the brake's share): a trip ahead of the reading
        holds the limit (the load is still on its way there) and brakes by the share of a
        period it came late (how far the load ahead passed the limit over what the load
        changes in a period ``h`` [s]); a trip by the reading holds the reading with the whole
        brake (it came the axis's stopping time late).
        """
        cfg = self.config
        lim = getattr(cfg, det)
        side = 1.0 if det == 'limit_load_max' else -1.0
        if side * (load - lim) > 0:          # the reading itself
            value, held, share, why = load, load, 1.0, ''
        else:
            step = abs(self._rate) * h
            value, held, share = ahead, lim, min(1.0, side * (ahead - lim) / step)
            why = (f'{det}: the load {load:.6g} N moving at {self._rate:.4g} N/s is '
                   f'{ahead:.6g} N {cfg.limit_load_lead * 1e3:g} ms ahead, '
                   f'{"above" if side > 0 else "below"} {lim:g} N')
        if self._check(det, True, stamp_ns, value, why, events):
            self.load_trip = (held, share)

    def _rate_clear(self) -> None:
        """Forget the load's rate (the load limits' lead)."""
        self._rate = 0.0                # the load's rate, smoothed over the lead [N/s]
        self._rate_load = math.nan      # the reading it was differenced from [N]
        self._rate_stamp = 0            # ... and its stamp [ns]

    def _lc_clear(self) -> None:
        """Forget the load check's window (its zero-load reference stays)."""
        self._lc_sums = [0.0, 0.0, 0.0, 0.0, 0.0]  # weighted sums of 1, z, F, z^2, z F
        self._lc_bad = 0                            # periods in a row it has disagreed
        self._lc_k = 0                              # periods since the window began

    def _lc_zero_clear(self) -> None:
        """Forget the load check's zero-load reference (a reset: a new installation)."""
        self._lc_z0 = math.nan          # the reference zero-load position [m]
        self._lc_ref = [0.0, 0]         # its sum and samples while it is made
        self._lc_zs = math.nan          # the zero-load position, smoothed [m]

    def _load_check(self, stamp_ns: int, z: float, load: float, events: list[Event]) -> None:
        """Fit the window's load against the position: a cell that does not follow, or drifted."""
        cfg = self.config
        s = self._lc_sums
        # the window: every period's sample, weighted exp(-age / load_check_window) (no
        # samples kept; each sample averages the sensors' noise down)
        lam = max(0.0, 1.0 - self.dt / cfg.load_check_window)
        s[0] = lam * s[0] + 1.0
        s[1] = lam * s[1] + z
        s[2] = lam * s[2] + load
        s[3] = lam * s[3] + z * z
        s[4] = lam * s[4] + z * load
        self._lc_k += 1
        if self._lc_k % LOAD_CHECK_EVERY:
            return          # judged every LOAD_CHECK_EVERY periods: the faults are slow
        k = cfg.k_L
        n = max(2, int(round(cfg.load_check_window / self.dt)))
        if self._lc_k < n:
            return
        w = s[0]
        zm, fm = s[1] / w, s[2] / w
        vz = s[3] / w - zm * zm
        if not vz * k * k > 4.0 * cfg.load_check_force ** 2:
            self._lc_bad = 0
            return                   # the piston did not move enough to judge the cell by
        k_fit = (s[4] / w - zm * fm) / vz
        z0 = zm - fm / k_fit if k_fit else math.nan
        follows = 0.25 * k <= k_fit <= 4.0 * k
        # the zero-load position is judged on a swing of twice that at least: the position's
        # noise biases the fitted k low by its share of the swing's variance, and the zero
        # with it (10 um on a 0.1 mm swing: 1 %, 55 N of a 5.5 kN mean)
        judged = follows and vz * k * k > 16.0 * cfg.load_check_force ** 2
        drift = 0.0
        if judged:
            a = min(1.0, LOAD_CHECK_EVERY * self.dt / LOAD_ZERO_SMOOTH)
            self._lc_zs = z0 if not math.isfinite(self._lc_zs) else \
                self._lc_zs + a * (z0 - self._lc_zs)
            ref = self._lc_ref
            if not math.isfinite(self._lc_z0):
                ref[0] += z0
                ref[1] += 1
                if ref[1] * LOAD_CHECK_EVERY * self.dt >= LOAD_ZERO_TIME:
                    self._lc_z0 = ref[0] / ref[1]
            else:
                drift = k * (self._lc_zs - self._lc_z0)
        bad = not follows or abs(drift) > cfg.load_drift_force
        # a disagreement that lasts a whole window (a transient, a break, is not one)
        self._lc_bad = self._lc_bad + LOAD_CHECK_EVERY if bad else 0
        if self._lc_bad < n:
            return
        if not follows:
            why = (f'load_feedback: the load cell does not follow the piston: over '
                   f'{cfg.load_check_window:g} s its readings make {k_fit:.4g} N/m of the '
                   f'travel, k_L is {k:.4g} N/m')
        else:
            why = (f'load_feedback: the load cell drifted: it reads zero with the piston '
                   f'{(self._lc_zs - self._lc_z0) * 1e3:.4g} mm from where it did (k_L times '
                   f'it: '
                   f'{drift:.4g} N, above {cfg.load_drift_force:g} N)')
        self._check('load_feedback', True, stamp_ns, load, why, events)

    def restart(self) -> None:
        """Forget the run (a new epoch): ramp on again at the next state; latches stay."""
        self._restart()

    def ramp_again(self) -> None:
        """
        Ramp onto the trajectory again, from the last demanded position, over ``ramp_time``.

        For a trajectory that jumps: a reference that comes back after being held stale
        (the controller node) has moved on meanwhile, and following it at once would step
        the demand by all it moved.
        """
        if math.isfinite(self._last_ref):
            self._ramp_pending = True
            self._ramp_from = self._last_ref

    def blend_from(self, z: float, duration: float) -> None:
        """
        Ramp onto the trajectory from position ``z`` [m] over ``duration`` [s] (a mode switch).

        Only while running: a hold or a stop keeps its own demand.
        """
        if math.isfinite(z) and self._mode == 'run':
            self._ramp_pending = True
            self._ramp_from = float(z)
            self._ramp_time = float(duration)

    @property
    def mode(self) -> str:
        """Return what the axis does now (see :class:`Demand`)."""
        if not self.enabled:
            return 'disabled'
        return self._mode

    @property
    def action(self) -> str:
        """Return the most severe of the latched actions, or 'off' when nothing is latched."""
        acts = [self.config.action(d) for d, s in self.latches.items() if s.tripped]
        return max(acts, key=_SEVERITY.__getitem__, default='off')

    def tripped(self) -> list[str]:
        """Return the latched detectors."""
        return [d for d, s in self.latches.items() if s.tripped]

    def set_config(self, config: SafetyConfig) -> None:
        """Take new limits and actions; a latched detector stays latched."""
        if not isinstance(config, SafetyConfig):
            raise InputError(f'`config` must be SafetyConfig, got {type(config).__name__}')
        self.config = config

    # -- per period --------------------------------------------------------------------------
    def update(self, stamp_ns: int, z: float, z_dot: float, force: float,
               z_traj: float, v_traj: float, i_last: float,
               saturated: bool, *, load: float = math.nan, needs_load: bool = False,
               track_position: bool = True,
               limited: bool = False) -> tuple[Demand, list[Event]]:
        """
        Check the detectors on one state; return the demand for its command and the events.

        ``i_last`` is the command the controller sent for the previous state and
        ``saturated`` whether it was at the limit (the frozen and saturation detectors).
        ``load`` the load cell [N] (NaN: none); ``needs_load``: force control or specimen
        protect, which need it; ``track_position``: the displacement loop drives the valve
        (its tracking error is judged); ``limited``: specimen protect limited the previous
        command.
        """
        cfg = self.config
        events: list[Event] = []
        self.load_trip = None
        dt = self.dt
        dt_ns = round(dt * 1e9)
        if self._last_stamp is not None and stamp_ns > self._last_stamp:
            dt_ns = stamp_ns - self._last_stamp
            dt = dt_ns * 1e-9
        finite = math.isfinite(z)
        if not math.isfinite(z_dot) and finite and math.isfinite(self._last_z):
            z_dot = (z - self._last_z) / dt
        self._z_dot = z_dot
        powered = self.enabled and self._mode != 'power_off'
        # feedback: non-finite, or frozen while the command drives the valve. A period without
        # a command (|i| below frozen_current: a sine's zero crossing) neither counts nor
        # clears: the count restarts only when the position changes (a frozen sensor under a
        # sine tripped 385 periods late once, its count cleared at each crossing)
        if finite and z == self._last_z and powered:
            if abs(i_last) >= cfg.frozen_current:
                self._same += 1
        else:
            self._same = 0
        if not finite:
            self._check('feedback', True, stamp_ns, z, 'non-finite position', events)
        elif self._same >= cfg.frozen_periods:
            self._check('feedback', True, stamp_ns, float(self._same), 'position frozen for '
                        f'{self._same} periods at {z:.6g} m while |i| >= '
                        f'{cfg.frozen_current:g} A', events)
        # each detector is judged here and latched by _check only when it is beyond its limit
        # (a call per detector and period cost a tenth of the virtual test's time)
        if finite:
            if z > cfg.limit_position_max:
                self._check('limit_position_max', True, stamp_ns, z, '', events)
            if z < cfg.limit_position_min:
                self._check('limit_position_min', True, stamp_ns, z, '', events)
        if abs(z_dot) > cfg.limit_velocity and math.isfinite(z_dot):
            self._check('limit_velocity', True, stamp_ns, z_dot, '', events)
        if abs(force) > cfg.limit_force and math.isfinite(force):
            self._check('limit_force', True, stamp_ns, force, '', events)
        self._check_specimen(stamp_ns, z, load, needs_load, powered, events)
        # saturation: the previous command at its limit for longer than the time. Its time is
        # the gaps' before each state judged: the command a state answers for was applied all
        # that time (a state after a stall counts the stall, not a period)
        sat = self.latches['saturation']
        sat.count, sat.ns = (sat.count + 1, sat.ns + dt_ns) if (saturated and powered) else (0, 0)
        if sat.count and sat.ns > round(cfg.limit_saturation_time * 1e9):
            self._check('saturation', True, stamp_ns, sat.ns * 1e-9, '', events)
        self._last_z = z if finite else self._last_z
        self._last_stamp = stamp_ns
        demand = self._demand(stamp_ns, z, z_traj, v_traj)
        # tracking error against the reference this command will track
        err = self.latches['limit_error']
        e = demand.z_ref - z if (finite and demand.power) else math.nan
        bad = math.isfinite(e) and abs(e) > cfg.limit_error and demand.mode != 'waiting' and \
            (track_position or demand.mode in ('hold', 'stop')) and not limited
        t_ns = self._held(err, bad, stamp_ns)
        if bad and t_ns > round(cfg.limit_error_time * 1e9) and self._check(
                'limit_error', True, stamp_ns, e, f'|z_ref - z| = {abs(e):.6g} m above '
                f'{cfg.limit_error:g} m for {t_ns * 1e-9:.6g} s', events):
            demand = self._demand(stamp_ns, z, z_traj, v_traj)
        return demand, events

    def _check_specimen(self, stamp_ns: int, z: float, load: float, needs_load: bool,
                        powered: bool, events: list[Event]) -> None:
        """Check the load limits, the specimen's displacement limits, its break, the load."""
        cfg = self.config
        if math.isfinite(z):
            d = z - cfg.z_L
            if d > cfg.limit_specimen_max:
                self._check('limit_specimen_max', True, stamp_ns, d, '', events)
            if d < cfg.limit_specimen_min:
                self._check('limit_specimen_min', True, stamp_ns, d, '', events)
        win = self._window
        # a reading that repeats while the piston moves (exactly 0 N is what a simulated
        # specimen's cell reads once it has broken: left to the break detector)
        if load == self._load_last and load != 0.0:
            self._load_same += 1
            moved = cfg.k_L * abs(z - self._z_load)
            if needs_load and powered and self._mode == 'run' and self._load_same >= 2 and \
                    moved > cfg.load_frozen_force and self._check(
                        'load_feedback', True, stamp_ns, load,
                        f'load_feedback: the load cell read {load:.6g} N for {self._load_same} '
                        f'periods while the piston moved {abs(z - self._z_load) * 1e3:.4g} mm '
                        f'(k_L times it: {moved:.4g} N, above {cfg.load_frozen_force:g} N): '
                        'frozen', events):
                self._hold_at = self._z_load      # where the reading was last true
        else:
            self._load_same = 0
            self._load_last = load
            self._z_load = z
        if not (math.isfinite(load) and math.isfinite(z)):
            self._rate_clear()
            if self._lc_k:
                self._lc_clear()
            win.clear()
            self._win_max.clear()
            self._win_zlo.clear()
            self._win_zhi.clear()
            if needs_load and powered and self._mode in ('run',):
                self._check('load_feedback', True, stamp_ns, load,
                            'load_feedback: no valid load cell reading (non-finite, missing or '
                            'stale) under force control or specimen protect', events)
            return
        # the load limits: the reading, and the load limit_load_lead ahead at its rate
        lead = cfg.limit_load_lead
        ahead, h = load, self.dt
        if lead > 0:
            if math.isfinite(self._rate_load) and stamp_ns > self._rate_stamp:
                h = (stamp_ns - self._rate_stamp) * 1e-9
                self._rate += h / (lead + h) * ((load - self._rate_load) / h - self._rate)
            self._rate_load, self._rate_stamp = load, stamp_ns
            ahead = load + lead * self._rate
        if load > cfg.limit_load_max or ahead > cfg.limit_load_max:
            self._load_limit('limit_load_max', stamp_ns, load, ahead, h, events)
        if load < cfg.limit_load_min or ahead < cfg.limit_load_min:
            self._load_limit('limit_load_min', stamp_ns, load, ahead, h, events)
        # the break: against each reading in the window, the drop of |F| and the travel the
        # way that loaded it (sign of that reading's force); only when the window's largest
        # |F| is more than the drop above this one (the window's maxima kept in order)
        # (and only when some reading lies more than the travel the way its force loads: the
        # lowest z of the tensile readings, the highest of the compressive ones; the loop over
        # the window ran on every unloading period before)
        top, zlo, zhi = self._win_max, self._win_zlo, self._win_zhi
        bt = cfg.break_travel
        if top and top[0][1] - abs(load) > cfg.break_drop and (
                (zlo and z - zlo[0][1] > bt) or (zhi and -(z - zhi[0][1]) > bt)):
            for _, f0, z0 in win:
                drop = abs(f0) - abs(load)
                travel = math.copysign(1.0, f0) * (z - z0)
                if drop > cfg.break_drop and travel > cfg.break_travel:
                    self._check('specimen_break', True, stamp_ns, drop,
                                f'specimen_break: the load fell {drop:.6g} N (from {f0:.6g} N '
                                f'to {load:.6g} N) while the piston moved {travel * 1e3:.6g} mm '
                                'the way that loads it', events)
                    break
        # the load cell against the motion, once the break has had its say (a broken
        # specimen's cell reads nothing while the piston moves: that is the break's to name)
        if needs_load and powered and self._mode == 'run' and cfg.k_L > 0 and \
                not self.latches['specimen_break'].tripped:
            self._load_check(stamp_ns, z, load, events)
        elif self._lc_k:
            self._lc_clear()
        self._win_seq += 1
        win.append((self._win_seq, load, z))
        a = abs(load)
        while top and top[-1][1] <= a:
            top.pop()
        top.append((self._win_seq, a))
        if load >= 0.0:
            while zlo and zlo[-1][1] >= z:
                zlo.pop()
            zlo.append((self._win_seq, z))
        else:
            while zhi and zhi[-1][1] <= z:
                zhi.pop()
            zhi.append((self._win_seq, z))
        if cfg is not self._win_cfg:        # the window's length in periods, per config
            self._win_cfg = cfg
            self._win_n = max(1, int(math.ceil(cfg.break_window / self.dt - 1e-9)))
        n = self._win_n
        while len(win) > n:
            old = win.popleft()[0]
            if top and top[0][0] == old:
                top.popleft()
            if zlo and zlo[0][0] == old:
                zlo.popleft()
            if zhi and zhi[0][0] == old:
                zhi.popleft()

    def judge_force_error(self, stamp_ns: int, e: float, dt: float | None = None
                          ) -> list[Event]:
        """
        Judge the force loop's error ``e`` = F_ref - F [N] of this period; return its events.

        Call it once per period while the force loop drives the valve (a non-finite error
        clears the count).
        """
        cfg = self.config
        return self._timed('limit_force_error', stamp_ns, e, cfg.limit_force_error,
                           cfg.limit_error_time, self.dt if dt is None else dt,
                           lambda t: f'|F_ref - F| = {abs(e):.6g} N above '
                           f'{cfg.limit_force_error:g} N for {t:.6g} s')

    def _timed(self, det: str, stamp_ns: int, e: float, limit: float, time: float,
               dt: float, why, bridge: float = 0.0) -> list[Event]:
        """
        Latch ``det`` once ``|e|`` has been beyond ``limit`` for longer than ``time`` [s].

        The time is the states' stamps' (from the first state beyond, its own period ``dt``
        counted): a state late after a stall counts its gap, not a period. ``why(t)``: its
        message after ``t`` s; a non-finite ``e`` clears the count. ``bridge`` [s]: states
        within the limit up to this long after the last one beyond count on (a ringing
        error's troughs: beyond at each swing, it is beyond all along).
        """
        events: list[Event] = []
        bad = math.isfinite(e) and abs(e) > limit
        t_ns = self._held(self.latches[det], bad, stamp_ns, dt,
                          round(bridge * 1e9) if math.isfinite(e) else -1)
        if bad and t_ns > round(time * 1e9):
            self._check(det, True, stamp_ns, e, why(t_ns * 1e-9), events)
        return events

    def _held(self, lat: _Latch, bad: bool, stamp_ns: int, dt: float | None = None,
              bridge_ns: int = -1) -> int:
        """
        Return how long [ns] a sampled condition has held, ``bad`` at ``stamp_ns``.

        The stamps' span from the first state it held at, that state's own period ``dt``
        (the nominal one) counted: a later state counts the gap before it, but the first
        counts a period, not a stall before it (what the condition was before that state is
        not known). States where it does not hold within ``bridge_ns`` of the last one where
        it did count on (-1: none).
        """
        if bad:
            if not lat.count:
                lat.since = stamp_ns
            lat.count += 1
            lat.last = stamp_ns
        elif not (lat.count and stamp_ns - lat.last <= bridge_ns):
            lat.count = 0
            return 0
        return stamp_ns - lat.since + round((self.dt if dt is None else dt) * 1e9)

    def judge_hold(self, stamp_ns: int, e: float, force: bool,
                   travel: float = 0.0) -> list[Event]:
        """
        Judge a hold's error ``e`` of this period; return its events.

        ``e``: the held position less the measured [m], or, held in force control
        (``force``), the held load less the measured [N]; then ``travel``, how far the piston
        moved since the hold began [m], counts too: beyond ``hold_error_position`` plus the
        travel ``hold_error_force`` makes on the specimen (over ``k_L``) the load path is
        lost (a break the break detector did not name), whatever the load cell reads. Call
        it once per period while the axis holds; past its limit for longer than
        ``hold_error_time`` it latches ``hold_error`` (power off by default: a stuck valve),
        troughs within it up to half of that time counting on (a hold that rings).
        Held in position, the limit is ``hold_error_position`` plus the braking distance
        (:func:`braking_distance`, the rig's ``braking_time``) at the piston's speed in the
        hold's first period (the state's, measured or differenced): a piston that stops
        within it from that speed obeyed the hold.
        """
        cfg = self.config
        if not math.isfinite(self._hold_speed):
            v = self._z_dot
            self._hold_speed = abs(v) if math.isfinite(v) else 0.0
        limit = cfg.hold_error_force if force else cfg.hold_error_position + \
            self._hold_speed * (cfg.braking_time + 2.0 * self.dt)
        unit, what = ('N', 'load') if force else ('m', 'position')
        # judged as a fraction of its limit; held in force, the travel as one of its reach
        r = abs(e) / limit if math.isfinite(e) else 0.0
        reach = cfg.hold_error_position + cfg.hold_error_force / cfg.k_L if (
            force and cfg.k_L > 0) else math.inf
        if math.isfinite(travel) and abs(travel) / reach > r:
            return self._timed('hold_error', stamp_ns, abs(travel) / reach, 1.0,
                               cfg.hold_error_time, self.dt,
                               lambda t: f'hold_error: the load path is lost: the piston ran '
                               f'{abs(travel) * 1e3:.4g} mm from where the hold in force '
                               f'began (reach {reach * 1e3:.4g} mm: hold_error_position and '
                               f'hold_error_force over k_L) for {t:.6g} s')
        # a hold that rings past its limit at each swing does not hold either: troughs up
        # to half of hold_error_time count on (a 57 Hz oil column's swings are 9 ms apart);
        # one overshoot that comes back is not judged
        return self._timed('hold_error', stamp_ns, r if math.isfinite(e) else math.nan, 1.0,
                           cfg.hold_error_time, self.dt,
                           lambda t: f'hold_error: the axis does not hold: {abs(e):.6g} {unit} '
                           f'from the held {what} (limit {limit:g} {unit}) for {t:.6g} s',
                           bridge=0.5 * cfg.hold_error_time)

    def _check(self, det: str, cond: bool, stamp_ns: int, value: float, why: str,
               events: list[Event]) -> bool:
        """Latch ``det`` if ``cond`` and its action is not off; return True on a new trip."""
        if not cond:
            return False
        act = self.config.action(det)
        s = self.latches[det]
        if act == 'off' or s.tripped:
            return False
        s.tripped = True
        self.counts[det] += 1
        lim = self.config.limit(det)
        unit = UNITS[det]
        msg = why or f'{det}: {value:.6g} {unit} beyond {lim:.6g} {unit}'
        events.append(Event(stamp_ns, 'trip', det, float(value), lim, unit, act,
                            f'{msg}; action {act}'))
        self._escalate(act)
        return True

    def _escalate(self, act: str) -> None:
        """Enter the mode of a new trip's action if it is more severe than the present one."""
        if act in ('off', 'indicate'):
            return
        if _SEVERITY[act] > _SEVERITY.get(self._mode, 0):
            self._mode = act
            self._hold_z = math.nan       # set from the measured position in _demand
            self._hold_speed = math.nan   # set by the hold's first judge_hold

    def demand_for(self, stamp_ns: int, z: float, z_traj: float, v_traj: float) -> Demand:
        """Return this period's demand again (after a trip judged once the demand was made)."""
        return self._demand(stamp_ns, z, z_traj, v_traj)

    def _demand(self, stamp_ns: int, z: float, z_traj: float, v_traj: float) -> Demand:
        cfg = self.config
        if not self.enabled:
            self.ramp = 0.0
            return Demand('disabled', math.nan, 0.0, False)
        if self._mode == 'power_off':
            self.ramp = 0.0
            return Demand('power_off', math.nan, 0.0, False)
        if self._mode in ('hold', 'stop'):
            if not math.isfinite(self._hold_z):     # the period of the trip: start here
                self._hold_z = self._hold_at if math.isfinite(self._hold_at) else \
                    z if math.isfinite(z) else self._last_ref
                self._hold_at = math.nan
                self._ramp_pending = True           # after a reset: ramp on from there
            if self._mode == 'stop':
                step = cfg.safe_velocity * self.dt
                d = cfg.safe_position - self._hold_z
                if d:
                    self._hold_z += math.copysign(min(abs(d), step), d)
                    v = math.copysign(cfg.safe_velocity, d) if abs(d) > step else 0.0
                    self._last_ref = self._hold_z
                    return Demand('stop', self._hold_z, v, True)
            self._last_ref = self._hold_z
            return Demand(self._mode, self._hold_z, 0.0, True)
        if self._ramp_pending:
            if not math.isfinite(z):
                self.ramp = 0.0
                return Demand('waiting', math.nan, 0.0, False)
            self._ramp_pending = False
            self._ramp_t0 = stamp_ns
            self._ramp_z0 = self._ramp_from if math.isfinite(self._ramp_from) else z
            self._ramp_from = math.nan
            self._ramp_T = self._ramp_time if math.isfinite(self._ramp_time) else cfg.ramp_time
            self._ramp_time = math.nan
        t = (stamp_ns - self._ramp_t0) * 1e-9
        T = self._ramp_T
        if T > 0 and t < T:
            w, dw = ramp_weight(t / T)
            z0 = self._ramp_z0
            zr = z0 + w * (z_traj - z0)
            self._last_ref = zr
            self.ramp = t / T
            return Demand('ramp', zr, w * v_traj + dw / T * (z_traj - z0), True)
        self._last_ref = z_traj
        self.ramp = 1.0
        return Demand('run', z_traj, v_traj, True)

    # -- feedback lost (no state at all: the node's timer) -----------------------------------
    def feedback_lost(self, age_s: float, stamp_ns: int) -> list[Event]:
        """
        Report that the newest state is ``age_s`` old; latch ``feedback`` if over the timeout.

        The node calls it from a timer in real time (a lost sensor sends nothing to check).
        """
        if not (age_s > self.config.feedback_timeout):
            return []
        events: list[Event] = []
        self._check('feedback', True, stamp_ns, float(age_s),
                    f'no feedback for {age_s:.6g} s (timeout {self.config.feedback_timeout:g} '
                    's)', events)
        return events

    def judge_timing(self, late_s: float, stamp_ns: int, unanswered: int = 0) -> list[Event]:
        """
        Judge how late the loop is: ``late_s`` [s], how long the valve held its last command.

        The controller calls it in real time for every state it takes, stale ones too (a
        state that never comes is the feedback detector's): ``late_s`` is that state's age
        when answered, or more when ``unanswered`` states came between it and the one
        answered before (the loop's topics keep only the newest state, so a stalled loop
        wakes to a fresh one: the valve held the earlier answer all that time). Beyond
        ``loop_timing_late`` it latches ``loop_timing``. Nothing is left to judge at a reset:
        it counts as clear.
        """
        late = self.config.loop_timing_late
        if not (late_s > late):
            return []
        events: list[Event] = []
        why = (f'the valve held one command {late_s * 1e3:.4g} ms ({unanswered} states in '
               'between never answered)' if unanswered > 0 else
               f'a state answered {late_s * 1e3:.4g} ms after its stamp')
        self._check('loop_timing', True, stamp_ns, float(late_s),
                    f'loop_timing: {why} (limit {late * 1e3:g} ms): the machine is too busy '
                    'to run the loop on time', events)
        return events

    # -- operator ----------------------------------------------------------------------------
    def still_active(self, z: float, z_dot: float, force: float,
                     feedback_age_s: float = 0.0, load: float = math.nan) -> list[str]:
        """
        Return the latched detectors whose condition still holds, with the hysteresis.

        ``z``, ``z_dot``, ``force``, ``load``: the newest measurement; ``feedback_age_s``: its
        age (real time). The tracking-error, saturation, frozen, break and load-feedback
        conditions count as clear (see the module docstring).
        """
        cfg = self.config
        h = cfg.limit_hysteresis
        out = []
        for d, s in self.latches.items():
            if not s.tripped:
                continue
            if d in _PAIRS:
                lo, hi, side = _PAIRS[d]
                span = getattr(cfg, hi) - getattr(cfg, lo)
                if d.startswith('limit_load'):      # of the limit itself: loads are not
                    span = abs(getattr(cfg, d))     # symmetric about a centre
                x = {'limit_load_max': load, 'limit_load_min': load,
                     'limit_specimen_max': z - cfg.z_L,
                     'limit_specimen_min': z - cfg.z_L}.get(d, z)
                if d.startswith('limit_load') and not math.isfinite(x):
                    bad = False          # no reading: the load limits cannot hold it
                elif side > 0:
                    bad = not (x <= getattr(cfg, hi) - h * span)
                else:
                    bad = not (x >= getattr(cfg, lo) + h * span)
            elif d == 'limit_velocity':
                bad = math.isfinite(z_dot) and abs(z_dot) > (1.0 - h) * cfg.limit_velocity
            elif d == 'limit_force':
                bad = math.isfinite(force) and abs(force) > (1.0 - h) * cfg.limit_force
            elif d == 'feedback':
                bad = not math.isfinite(z) or feedback_age_s > cfg.feedback_timeout
            else:
                bad = False
            if bad:
                out.append(d)
        return out

    def reset(self, stamp_ns: int, z: float, z_dot: float = math.nan,
              force: float = math.nan, feedback_age_s: float = 0.0,
              load: float = math.nan) -> tuple[bool, str, Event]:
        """
        Clear every latch unless a latched condition still holds; return (ok, reason, event).

        On success the axis ramps on from the measured position (when enabled).
        """
        active = self.still_active(z, z_dot, force, feedback_age_s, load)
        if active:
            why = ('still tripping: ' + ', '.join(
                f'{d} ({self._describe(d, z, z_dot, force, feedback_age_s, load)})'
                for d in active))
            return False, why, Event(stamp_ns, 'reset_refused', ','.join(active), math.nan,
                                     math.nan, '', self.action, why)
        cleared = self.tripped()
        for s in self.latches.values():
            s.tripped = False
            s.count = s.ns = 0
        self._same = 0
        self._load_same = 0
        self._hold_at = math.nan
        self._rate_clear()
        self._lc_clear()
        self._lc_zero_clear()
        self._window.clear()
        self._win_max.clear()
        self._win_zlo.clear()
        self._win_zhi.clear()
        was = self._mode
        self._mode = 'run'
        if was != 'run' or cleared:
            self._ramp_pending = True
        why = ('cleared ' + ', '.join(cleared)) if cleared else 'nothing was latched'
        return True, why, Event(stamp_ns, 'reset', ','.join(cleared), math.nan, math.nan, '',
                                'off', why)

    def _describe(self, d: str, z: float, z_dot: float, force: float, age: float,
                  load: float = math.nan) -> str:
        cfg = self.config
        if d in ('limit_position_max', 'limit_position_min'):
            return f'z = {z:.6g} m, limit {cfg.limit(d):g} m'
        if d in ('limit_load_max', 'limit_load_min'):
            return f'load = {load:.6g} N, limit {cfg.limit(d):g} N'
        if d in ('limit_specimen_max', 'limit_specimen_min'):
            return f'z - z_L = {z - cfg.z_L:.6g} m, limit {cfg.limit(d):g} m'
        if d == 'limit_velocity':
            return f'z_dot = {z_dot:.6g} m/s, limit {cfg.limit_velocity:g} m/s'
        if d == 'limit_force':
            return f'force = {force:.6g} N, limit {cfg.limit_force:g} N'
        if not math.isfinite(z):
            return 'position non-finite'
        return f'no feedback for {age:.6g} s'

    def enable(self, on: bool, stamp_ns: int) -> tuple[bool, str, Event]:
        """Turn hydraulics on (ramp-on from the measured position) or off; (ok, why, event)."""
        if not on:
            self.enabled = False
            return True, 'hydraulics off: 0 A', Event(stamp_ns, 'disabled', '', math.nan,
                                                      math.nan, '', 'off', 'hydraulics off')
        if _SEVERITY[self.action] > _SEVERITY['indicate']:
            why = (f'interlock latched ({", ".join(self.tripped())}: {self.action}): reset '
                   'first')
            return False, why, Event(stamp_ns, 'enable_refused', ','.join(self.tripped()),
                                     math.nan, math.nan, '', self.action, why)
        if not self.enabled:
            self.enabled = True
            self._ramp_pending = True
            self._mode = 'run'
            return True, 'hydraulics on: ramping on', Event(
                stamp_ns, 'enabled', '', math.nan, math.nan, '', 'off',
                'hydraulics on: ramping on from the measured position')
        return True, 'already on', Event(stamp_ns, 'enabled', '', math.nan, math.nan, '',
                                         'off', 'already on')
