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
Each cycle's extremes, and the detectors that decide from them that a specimen has failed.

A :class:`Cycle` is one cycle's peak and valley of the command, the position and the load
(and the cycle's number and end stamp). Its ``stiffness`` is the load's range over the
position's: the specimen's secant stiffness over the cycle.

The failure detectors (:data:`ros_ehs.core.procedure.spec.DETECTORS`) judge each whole cycle
of a cyclic step. Each first lets ``settling`` cycles pass (the loop and its compensation
settle), then averages ``reference`` cycles into a *reference cycle*, and from then on compares
each cycle with it; it trips when ``persist`` consecutive cycles are beyond its criterion:

* ``stiffness_drop``: the cycle's stiffness under ``(1 - drop)`` times the reference's;
* ``peak_valley_change``: the uncontrolled signal's peak or valley (the position in force
  control, the load in displacement control) moved more than ``tolerance`` of the reference
  cycle's range from the reference's;
* ``underpeak``: the controlled signal's range under ``fraction`` of the specified range (no
  reference: the procedure specifies it).

``fitted_stiffness_drop`` judges what live identification fits instead (:meth:`estimate`):
the specimen stiffness ``k_L`` of each adequate estimate (the verdict's: an estimate it calls
not adequate is not judged) once ``settling`` cycles of the step have passed; the mean of the
first ``reference`` of them is its reference; it trips when ``persist`` consecutive
estimates are under ``(1 - drop)`` times the reference by more than ``sigmas`` of their
standard errors (``k + sigmas se < (1 - drop) k_ref``), so a fit too uncertain to tell
waits for the next. It sees a crack that softens the specimen from the whole model of the
loop, load cell and pressures alike, where ``stiffness_drop`` sees it from two numbers a
cycle; it answers once a refit period.

A cycle with a non-finite extreme is not judged and breaks a run of ``persist``. A detector's
reference survives a restart: :meth:`FailureDetector.state` and :meth:`FailureDetector.restore`.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Mapping

from ros_ehs.core.errors import InputError
from ros_ehs.core.procedure.spec import DETECTORS

__all__ = ['CYCLE_COLUMNS', 'Cycle', 'EXTRAPOLATED', 'FailureDetector', 'TAPERED']

#: A cycle's flag: its amplitude was still tapering in (a start or a resume); it counts, and
#: neither the compensation nor the failure detectors learn from it.
TAPERED = 1
#: A cycle-table flag: the cycle was jumped by a virtual test (ros_ehs.core.sim.jumps), not
#: simulated; its record repeats the last simulated cycle's extremes.
EXTRAPOLATED = 2


#: a cycle table's columns, one row a cycle (the bag's records read back, a virtual test's
#: table, cycles.csv): :class:`Cycle`'s fields, the end in seconds
CYCLE_COLUMNS = ('count', 'step', 'end_s', 'cmd_hi', 'cmd_lo', 'z_hi', 'z_lo', 'load_hi',
                 'load_lo', 'flags')


@dataclass(frozen=True)
class Cycle:
    """One cycle's extremes [m, N; the command in its mode's unit] and where it ended."""

    count: int           #: the cycle's number in the test (the first is 1)
    step: int            #: the step it belongs to (its index)
    end_ns: int          #: the stamp of the state that ended it
    cmd_hi: float
    cmd_lo: float
    z_hi: float
    z_lo: float
    f_hi: float
    f_lo: float
    flags: int = 0       #: :data:`TAPERED` for a cycle of a start's or a resume's taper

    @property
    def stiffness(self) -> float:
        """Return the load's range over the position's [N/m] (NaN when the piston did not move)."""
        dz = self.z_hi - self.z_lo
        return (self.f_hi - self.f_lo) / dz if dz > 0 else math.nan

    def row(self) -> tuple:
        """Return the cycle as a row of a cycle table (:data:`CYCLE_COLUMNS`)."""
        return (self.count, self.step, self.end_ns * 1e-9, self.cmd_hi, self.cmd_lo,
                self.z_hi, self.z_lo, self.f_hi, self.f_lo, self.flags)

    def finite(self) -> bool:
        """Return True when every extreme is finite."""
        return all(math.isfinite(v) for v in (self.cmd_hi, self.cmd_lo, self.z_hi, self.z_lo,
                                              self.f_hi, self.f_lo))


class FailureDetector:
    """
    One failure detector of a step (see the module docstring).

    ``kind`` and ``values``: an end condition's; ``mode``: the step's control mode.
    """

    def __init__(self, kind: str, values: Mapping[str, Any], mode: str) -> None:
        if kind not in DETECTORS:
            raise InputError(f'`kind` = {kind!r} is not a failure detector')
        self.kind = kind
        self.values = dict(values)
        self.mode = mode
        self.judged = 0          #: cycles seen since the step (re)started
        self.reference: dict[str, float] | None = None
        self._acc: list[tuple[float, ...]] = []     # the reference's cycles or estimates
        self._beyond = 0
        self.tripped_at: int | None = None     #: the cycle count it tripped on
        self.last_value = math.nan             #: the newest cycle's judged value

    def state(self) -> dict:
        """Return what a restart needs: the reference cycle and the cycles judged."""
        return {'judged': self.judged, 'reference': self.reference}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Take a :meth:`state` back (a resumed test)."""
        self.judged = int(state.get('judged', 0))
        ref = state.get('reference')
        self.reference = dict(ref) if ref else None

    def _signals(self, c: Cycle) -> tuple[float, float, float, float]:
        """Return the controlled (hi, lo) and the uncontrolled (hi, lo) extremes."""
        if self.mode == 'force':
            return c.f_hi, c.f_lo, c.z_hi, c.z_lo
        return c.z_hi, c.z_lo, c.f_hi, c.f_lo

    def cycle(self, c: Cycle, specified: tuple[float, float] | None = None) -> str:
        """
        Judge a whole cycle; return why the specimen has failed ('' while it has not).

        ``specified``: the cycle's specified (peak, valley) of the controlled signal.
        """
        if self.tripped_at is not None:
            return ''
        self.judged += 1
        if self.kind == 'fitted_stiffness_drop':
            return ''                  # judged on each estimate (counted here for settling)
        v = self.values
        if not c.finite():
            self._beyond = 0
            return ''
        if self.judged <= v['settling']:
            return ''
        ctl_hi, ctl_lo, un_hi, un_lo = self._signals(c)
        if self.kind == 'underpeak':
            if specified is None:
                return ''
            want = specified[0] - specified[1]
            ratio = (ctl_hi - ctl_lo) / want if want > 0 else math.nan
            self.last_value = ratio
            bad = ratio < v['fraction']
            why = (f'underpeak: the controlled range is {ratio:.4g} of the specified '
                   f'{want:.6g} (under {v["fraction"]:g})')
        else:
            if self.reference is None:
                self._acc.append((c.stiffness, un_hi, un_lo))
                if len(self._acc) >= v['reference']:
                    n = len(self._acc)
                    self.reference = {'stiffness': sum(a[0] for a in self._acc) / n,
                                      'hi': sum(a[1] for a in self._acc) / n,
                                      'lo': sum(a[2] for a in self._acc) / n,
                                      'at': c.count}
                    self._acc = []
                return ''
            ref = self.reference
            if self.kind == 'stiffness_drop':
                # a reference without stiffness (its load did not move: a frozen load cell)
                # judges nothing
                ratio = c.stiffness / ref['stiffness'] if ref['stiffness'] > 0 else math.nan
                self.last_value = 1.0 - ratio
                bad = ratio < 1.0 - v['drop']
                why = (f'stiffness_drop: {c.stiffness:.6g} N/m is {(1.0 - ratio) * 100:.3g} % '
                       f"under the reference cycle's {ref['stiffness']:.6g} N/m (limit "
                       f'{v["drop"] * 100:g} %)')
            else:
                rng = ref['hi'] - ref['lo']
                moved = max(abs(un_hi - ref['hi']), abs(un_lo - ref['lo']))
                frac = moved / rng if rng > 0 else math.nan
                self.last_value = frac
                bad = frac > v['tolerance']
                which = 'position' if self.mode == 'force' else 'load'
                why = (f'peak_valley_change: the {which} peak/valley moved {frac * 100:.3g} % '
                       f"of the reference cycle's range (limit {v['tolerance'] * 100:g} %)")
        self._beyond = self._beyond + 1 if bad else 0
        if self._beyond >= v['persist']:
            self.tripped_at = c.count
            return why + f' for {self._beyond} cycle(s), at cycle {c.count}'
        return ''

    def estimate(self, k: float, stderr: float, adequate: bool, count: int) -> str:
        """
        Judge a live fit's specimen stiffness ``k`` [N/m] and its standard error ``stderr``.

        ``adequate``: the fit's verdict; ``count``: the test's cycle count now. Return why the
        specimen has failed ('' while it has not, and for every other kind).
        """
        if self.kind != 'fitted_stiffness_drop' or self.tripped_at is not None:
            return ''
        v = self.values
        if not (adequate and math.isfinite(k) and k > 0 and math.isfinite(stderr)
                and stderr >= 0) or self.judged <= v['settling']:
            return ''                  # not a fit to judge by: it neither counts nor clears
        if self.reference is None:
            self._acc.append((k, stderr))
            if len(self._acc) >= v['reference']:
                n = len(self._acc)
                self.reference = {'stiffness': sum(a[0] for a in self._acc) / n,
                                  'stderr': math.sqrt(sum(a[1] ** 2 for a in self._acc)) / n,
                                  'at': count}
                self._acc = []
            return ''
        k_ref = self.reference['stiffness']
        limit = (1.0 - v['drop']) * k_ref
        self.last_value = 1.0 - k / k_ref
        bad = k + v['sigmas'] * stderr < limit
        self._beyond = self._beyond + 1 if bad else 0
        if self._beyond >= v['persist']:
            self.tripped_at = count
            return (f'fitted_stiffness_drop: the fitted k_L {k:.6g} +- {stderr:.3g} N/m is '
                    f'{self.last_value * 100:.3g} % under its reference {k_ref:.6g} N/m '
                    f'(limit {v["drop"] * 100:g} %, by {v["sigmas"]:g} standard errors) for '
                    f'{self._beyond} estimate(s), at cycle {count}')
        return ''
