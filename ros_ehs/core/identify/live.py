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
Live re-identification: refit a sliding window of the running loop; push what is significant.

The ROS-free core of the identify node's live mode (docs/identification.md, "Live mode"):

* :class:`SampleWindow` keeps the last seconds of states, commands and pressures in bounded
  buffers (a week-long test holds one window, never the week); a state stamped more than a
  second before the last one starts a new run (a restarted plant, a replayed bag) and clears
  it; a non-finite state is dropped and counted.
* :class:`RefitSchedule` says when a refit is due: once the first ``window`` of the state
  clock has come, then every ``period`` of it; one refit at a time (a state that finds one
  running does not queue another); a new run starts the wait over.
* :class:`ReceiveClock` puts a message without a header (a ros2_control driver's
  ``Float64MultiArray`` commands, ``Float64`` pressures) on the states' clock: its receive
  time plus the median of the newest states' stamp minus receive time.
* :class:`RefitThread` runs the refits on one thread, woken per due refit, and never starts
  one after a stop (the stop's wake-up ends it); a stop waits a bound for a parked thread to
  end and says whether it did, since a thread left in compiled code must not see the
  interpreter's teardown.
* :class:`LiveIdentifier` refits a window, warm-started from its last *adequate* estimate
  (cold from the base set until there is one), and decides whether to push the result to
  the controller: only an adequate fit, every value strictly inside its bounds, a change
  beyond both ``sigmas`` standard errors and ``rel_change`` of the controller's value for at
  least one pushed parameter, and at most once per ``push_period`` of the state clock.
  Each refit gives a :class:`~ros_ehs_msgs_py.ParameterEstimate` saying what was decided
  and why.
"""

from __future__ import annotations

from collections import deque
import math
import threading
import time
from typing import Callable, Sequence
import warnings

import numpy as np
from ros_ehs.core.errors import DataError, IdentificationWarning, InputError
from ros_ehs.core.identify.estimator import fit_bounds, IdentificationResult, identify
from ros_ehs.core.identify.experiment import experiments_from_series
from ros_ehs.core.identify.verdict import why_adequate
from ros_ehs.core.params import Params, spec
from ros_ehs_msgs_py import ParameterEstimate

__all__ = ['LiveIdentifier', 'ReceiveClock', 'RefitSchedule', 'RefitThread', 'SampleWindow']

#: A state this much older than the last one starts a new run [ns].
NEW_RUN_NS = 1_000_000_000


def _columns(rows) -> tuple[np.ndarray, ...]:
    """Return the columns of (stamp [ns], value, ...) rows: int64 stamps, float values."""
    cols = list(zip(*rows))
    return (np.array(cols[0], dtype=np.int64),) + tuple(np.array(c, dtype=float)
                                                        for c in cols[1:])


class SampleWindow:
    """The last ``seconds`` of the loop's signals, in buffers of at most ``capacity`` samples."""

    def __init__(self, seconds: float, capacity: int) -> None:
        if not (math.isfinite(seconds) and seconds > 0):
            raise InputError(f'`seconds` = {seconds!r} must be a positive number')
        if not (isinstance(capacity, int) and capacity >= 2):
            raise InputError(f'`capacity` = {capacity!r} must be an integer >= 2')
        self.seconds = float(seconds)
        self.capacity = capacity
        self.dropped = 0        #: non-finite states
        self.runs = 1           #: runs seen (a stamp that jumped back starts one)
        self._states: deque = deque(maxlen=capacity)
        self._commands: deque = deque(maxlen=capacity)
        self._pressures = (deque(maxlen=capacity), deque(maxlen=capacity))
        self._cell: deque = deque(maxlen=capacity)
        self._last = -1

    def add_state(self, stamp_ns: int, z: float, z_dot: float, i: float = math.nan) -> None:
        """Add a state: position [m], velocity [m/s] (NaN: derive it), applied current [A]."""
        if not math.isfinite(z):
            self.dropped += 1
            return
        if self._last >= 0 and stamp_ns < self._last - NEW_RUN_NS:
            self.clear()
            self.runs += 1
        self._last = max(self._last, stamp_ns)
        self._states.append((stamp_ns, z, z_dot, i))

    def add_command(self, stamp_ns: int, i: float) -> None:
        """Add a command [A] stamped on the states' clock."""
        if math.isfinite(i):
            self._commands.append((stamp_ns, i))

    def add_pressure(self, chamber: int, stamp_ns: int, p: float) -> None:
        """Add a chamber pressure [Pa]: ``chamber`` 0 is P, 1 is T."""
        if math.isfinite(p):
            self._pressures[chamber].append((stamp_ns, p))

    def add_load(self, stamp_ns: int, force: float) -> None:
        """Add a load cell reading [N]."""
        if math.isfinite(force):
            self._cell.append((stamp_ns, force))

    def clear(self) -> None:
        """Forget every sample."""
        self._states.clear()
        self._commands.clear()
        self._cell.clear()
        for q in self._pressures:
            q.clear()
        self._last = -1

    @property
    def last_stamp_ns(self) -> int:
        """Stamp of the newest state [ns] (-1 when empty)."""
        return self._last

    def span(self) -> float:
        """Time the held states cover [s]."""
        if len(self._states) < 2:
            return 0.0
        return (self._states[-1][0] - self._states[0][0]) * 1e-9

    def experiments(self, name: str = 'live') -> list:
        """
        Return the experiments of the last ``seconds`` (its contiguous runs).

        Raises :class:`DataError` when they cannot be fitted (too little data, a piston that
        does not move).
        """
        if not self._states:
            raise DataError(f'{name}: no state received yet')
        ts, z, v, i = _columns(self._states)
        m = ts >= ts[-1] - int(self.seconds * 1e9)
        cmd = _columns(self._commands) if self._commands else None
        press = ([_columns(q) for q in self._pressures]
                 if self._pressures[0] and self._pressures[1] else [])
        cell = _columns(self._cell) if len(self._cell) >= 2 else None
        if cell is not None and not np.ptp(cell[1]) > 0:
            cell = None                  # a load cell that reads nothing: no specimen
        return experiments_from_series(name, ts[m], z[m], v[m], i[m], cmd, press, cell=cell)


class RefitSchedule:
    """
    When the live identifier refits (see the module docstring).

    ``window_s`` [s] of states first, then every ``period_s`` [s] of the state clock.
    """

    def __init__(self, window_s: float, period_s: float) -> None:
        for name, v in (('window_s', window_s), ('period_s', period_s)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f'`{name}` = {v!r} must be a positive number of seconds')
        self.window_ns = int(window_s * 1e9)
        self.period_ns = int(period_s * 1e9)
        self.busy = False           #: a refit runs
        self._next: int | None = None

    def state(self, stamp_ns: int, new_run: bool = False) -> bool:
        """Take a state's stamp [ns]; return True when a refit is due now (it is then busy)."""
        if new_run:
            self._next = None
        if self._next is None:
            self._next = stamp_ns + self.window_ns
        if stamp_ns >= self._next and not self.busy:
            self._next = stamp_ns + self.period_ns
            self.busy = True
            return True
        return False

    def done(self) -> None:
        """Say that the running refit has ended."""
        self.busy = False


class RefitThread:
    """
    Run ``job`` on one thread each time :meth:`wake` is called; never after :meth:`stop`.

    ``setup`` runs first on the thread (its priority); an exception from ``job`` goes to
    ``failed`` and the thread waits for the next wake-up; ``finished`` runs after each job,
    also after a failed one. Wake-ups while a job runs fold into one.
    """

    def __init__(self, job: Callable[[], None], failed: Callable[[Exception], None],
                 finished: Callable[[], None] = lambda: None,
                 setup: Callable[[], None] = lambda: None, name: str = 'ehs-refit') -> None:
        self._job, self._failed, self._finished, self._setup = job, failed, finished, setup
        self._todo = threading.Event()
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name=name)
        self._thread.start()

    def wake(self) -> None:
        """Ask for one run of the job (ignored after :meth:`stop`)."""
        self._todo.set()

    @property
    def stopping(self) -> bool:
        """Say if :meth:`stop` was called (a job under way then keeps its result to itself)."""
        return self._stopping.is_set()

    @property
    def alive(self) -> bool:
        """Say if the thread has not ended (it may be inside a job, in compiled code)."""
        return self._thread.is_alive()

    def stop(self, wait: float) -> bool:
        """Stop: no job starts after this; wait up to ``wait`` [s]; return True if it ended."""
        self._stopping.set()
        self._todo.set()
        self._thread.join(wait)
        return not self._thread.is_alive()

    def _run(self) -> None:
        self._setup()
        while True:
            self._todo.wait()
            self._todo.clear()
            if self._stopping.is_set():
                return
            try:
                self._job()
            except Exception as err:      # a refit must never end the live node
                self._failed(err)
            finally:
                self._finished()


class ReceiveClock:
    """Receive times onto the states' clock (see the module docstring); ``keep`` states."""

    def __init__(self, keep: int = 101) -> None:
        self._offsets: deque[int] = deque(maxlen=keep)

    def state(self, stamp_ns: int, received_ns: int) -> None:
        """Take a state stamped ``stamp_ns`` that arrived at ``received_ns`` [ns]."""
        self._offsets.append(stamp_ns - received_ns)

    def stamp(self, received_ns: int) -> int:
        """Return the states' clock at ``received_ns`` [ns] (no state yet: unchanged)."""
        if not self._offsets:
            return received_ns
        return received_ns + int(sorted(self._offsets)[len(self._offsets) // 2])


class LiveIdentifier:
    """
    Refit windows, warm-started, and decide what to push (see the module docstring).

    ``base``: the starting values and the fixed ones; ``pushable``: the fitted parameters the
    controller takes; ``controller``: the values it has now (None until known: no push).
    """

    def __init__(self, base: Params, *, free: Sequence[str], pushable: Sequence[str],
                 model: str, sigmas: float, rel_change: float, push_period: float,
                 max_nfev: int = 100) -> None:
        for name, v, lo in (('sigmas', sigmas, 0.0), ('rel_change', rel_change, 0.0),
                            ('push_period', push_period, 0.0)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= lo):
                raise InputError(f'`{name}` = {v!r} must be a number >= {lo:g}')
        self.base = base
        self.free = tuple(free)
        self.pushable = tuple(n for n in pushable if n in self.free)
        self.model = model
        self.sigmas = float(sigmas)
        self.rel_change = float(rel_change)
        self.push_period = float(push_period)
        self.max_nfev = max_nfev
        self.estimate: dict[str, float] | None = None    #: the last adequate fit's values
        self.controller: dict[str, float] | None = None
        self.last_push_ns: int | None = None
        self.refits = 0
        self.pushes = 0

    def refit(self, experiments, stamp_ns: int, window_s: float
              ) -> tuple[ParameterEstimate, IdentificationResult | None]:
        """Refit ``experiments`` (warm when there is an estimate); return the estimate."""
        self.refits += 1
        warm = self.estimate is not None
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', IdentificationWarning)
            r = identify(experiments, free=self.free, model=self.model, base=self.base,
                         x0=self.estimate, warm=warm, workers=1, max_nfev=self.max_nfev)
        wall = time.perf_counter() - t0
        ok = r.adequate and r.success and r.params is not None
        if r.adequate:
            verdict = f'adequate: {why_adequate(r.halves, r.jackknife)}'
        else:
            verdict = 'not adequate: ' + '; '.join(r.inadequacy)
        if r.adequate and not ok:
            verdict += f' but {r.message}' if not r.success else ' but not a valid set'
        if ok:
            self.estimate = dict(r.x)
        push, reason = self.decide(r, stamp_ns) if ok else (False, verdict)
        est = ParameterEstimate(stamp_ns, dict(r.x), dict(r.stderr), bool(ok), verdict,
                                push, reason, window_s, wall, r.iterations, tuple(r.failed))
        return est, r

    def decide(self, r: IdentificationResult, stamp_ns: int) -> tuple[bool, str]:
        """Return whether to push the adequate fit ``r`` now, and why (or why not)."""
        for n in self.free:
            lo, hi = fit_bounds(n)
            if not lo < r.x[n] < hi:
                return False, (f'{n} = {r.x[n]:.6g} {spec(n).unit} is on its bound '
                               f'[{lo:g}, {hi:g}]')
        if not self.pushable:
            return False, 'the controller takes none of the fitted values'
        if self.controller is None:
            return False, "the controller's values are not known yet"
        changed = []
        for n in self.pushable:
            cur, new, se = self.controller[n], r.x[n], r.stderr[n]
            step = abs(new - cur)
            if step > self.sigmas * se and step > self.rel_change * abs(cur):
                changed.append(f'{n} {cur:.6g} -> {new:.6g} ({100 * (new - cur) / cur:+.1f} %, '
                               f'{step / se:.0f} stderr)' if cur and se else f'{n} -> {new:.6g}')
        if not changed:
            return False, (f'no significant change (beyond {self.sigmas:g} stderr and '
                           f'{100 * self.rel_change:g} %)')
        if self.last_push_ns is not None:
            since = (stamp_ns - self.last_push_ns) * 1e-9
            if since < self.push_period:
                return False, (f'last push {since:.1f} s ago (push_period '
                               f'{self.push_period:g} s): ' + ', '.join(changed))
        return True, ', '.join(changed)

    def pushed(self, values: dict[str, float], stamp_ns: int) -> None:
        """Record that the controller took ``values`` at ``stamp_ns``."""
        if self.controller is None:
            self.controller = {}
        self.controller.update(values)
        self.last_push_ns = stamp_ns
        self.pushes += 1
