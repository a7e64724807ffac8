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
Loop timing statistics for the nodes' diagnostics and the benchmarks (no ROS import).

:class:`Ring` keeps the last ``n`` samples in a ring and answers percentiles;
:class:`LoopStats` counts periods, fresh cycles and round-trip times of a control loop.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ['LoopStats', 'Ring']


class Ring:
    """The last ``n`` float samples, a ring buffer, with their percentiles."""

    def __init__(self, n: int = 10000) -> None:
        self._a = np.zeros(int(n))
        self._k = 0
        self.total = 0

    def add(self, value: float) -> None:
        """Append one sample."""
        self._a[self._k] = value
        self._k = (self._k + 1) % self._a.size
        self.total += 1

    def values(self, last: int | None = None) -> np.ndarray:
        """
        Return the samples held, or the ``last`` newest of them (in no guaranteed order).

        ``last`` is what the once-a-second diagnostics use: the newest 2000 of a 20000-sample
        ring cost a tenth to rank (see :meth:`p50_p99_max`).
        """
        a, k = self._a, self._k
        n = min(self.total, a.size)
        if last is None or last >= n:
            return a[:n]
        last = max(int(last), 0)
        if last <= k:
            return a[k - last:k]
        return np.concatenate((a[a.size - (last - k):], a[:k]))     # across the wrap

    def pct(self, q: float) -> float:
        """
        Return the ``q``-th percentile (linear interpolation, as numpy's), NaN when empty.

        A partial sort, not ``np.percentile``: numpy's first percentile call in a process
        takes ~6 ms (its lazy imports), and it fell in the controller's first diagnostics,
        a period after the loop had closed (a watchdog trip per run).
        """
        v = self.values()
        if not v.size:
            return float('nan')
        n = v.size - 1
        k = n * q / 100.0
        lo = int(k)
        hi = min(lo + 1, n)
        w = np.partition(v, sorted({lo, hi}))
        return float(w[lo] + (w[hi] - w[lo]) * (k - lo))

    def p50_p99_max(self, last: int | None = None) -> tuple[float, float, float]:
        """
        Return the median, the 99th percentile and the largest sample (NaN when empty).

        Over the ``last`` newest samples if given. One partial sort for all three; still,
        ranking a 20000-sample ring costs ~0.2 ms, and the diagnostics take two of them
        once a second from the executor thread of a 1 kHz loop: that delayed the plant's tick
        by 0.7-0.9 ms, enough for the next tick to come before the command (measured under
        SCHED_FIFO). They now rank the newest 2000.
        """
        v = self.values(last)
        if not v.size:
            return (math.nan,) * 3
        n = v.size - 1
        k50, k99 = n * 0.5, n * 0.99
        idx = sorted({int(k50), min(int(k50) + 1, n), int(k99), min(int(k99) + 1, n), n})
        w = np.partition(v, idx)

        def at(k: float) -> float:       # linear interpolation, as np.percentile's default
            lo = int(k)
            return float(w[lo] + (w[min(lo + 1, n)] - w[lo]) * (k - lo))
        return at(k50), at(k99), float(w[n])

    def peak(self) -> float:
        """Return the largest sample held, NaN when empty."""
        v = self.values()
        return float(v.max()) if v.size else float('nan')


class LoopStats:
    """Periods [s], round-trip times [s] and the fraction of cycles with a fresh command."""

    def __init__(self, n: int = 20000) -> None:
        self.period = Ring(n)
        self.rtt = Ring(n)
        self.cycles = 0
        self.fresh = 0
        self._last: float | None = None

    def tick(self, now_s: float, fresh: bool) -> None:
        """Count one cycle at time ``now_s`` [s]; ``fresh`` if a new command came since."""
        if self._last is not None:
            self.period.add(now_s - self._last)
        self._last = now_s
        self.cycles += 1
        self.fresh += bool(fresh)

    @property
    def fresh_fraction(self) -> float:
        """Return the fraction of cycles that had a fresh command (NaN before any)."""
        return self.fresh / self.cycles if self.cycles else float('nan')

    def as_dict(self, last: int | None = None) -> dict[str, float]:
        """
        Return the figures in milliseconds, for diagnostics and benchmarks.

        Counts are over the whole run; percentiles and maxima over the ring, or over its
        ``last`` newest samples.
        """
        ms = 1e3
        p50, p99, top = self.period.p50_p99_max(last)
        r50, r99, rtop = self.rtt.p50_p99_max(last)
        return {'cycles': self.cycles, 'fresh_cycles': self.fresh,
                'fresh_cycle_fraction': self.fresh_fraction,
                'period_p50_ms': p50 * ms, 'period_p99_ms': p99 * ms, 'period_max_ms': top * ms,
                'rtt_p50_ms': r50 * ms, 'rtt_p99_ms': r99 * ms, 'rtt_max_ms': rtop * ms}
