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
r"""
A specimen in the load string: the force it carries, and a crack that grows until it breaks.

The specimen is a spring and a damper between the piston and the frame, installed at the
piston position ``z_L`` (where it carries no load): it carries

.. math:: F = k(a) (z - z_L) + c_L \dot z

which the load cell reads (with ``load_cell_noise``), and which acts on the piston (the
models' load string, :mod:`ros_ehs.core.model.kernels`).

**Damage law.** A crack of size ``a`` (a fraction of the crack at which the specimen
fractures) grows with each half cycle of the force it carries, by Paris' law in the force
range (the stress intensity range goes with the force range and the root of the crack):

.. math:: \frac{da}{dN} = A \left(\frac{\Delta F}{\Delta F_{ref}}\right)^m a^{m/2}

counted on the force's reversals (a half cycle between one reversal and the next: its range
``|F_n - F_{n-1}|``, half a cycle's growth, integrated exactly over it, so a constant-range
test lives exactly its closed form). A **fatigue limit** (``specimen_fatigue_limit``, a force
range, times :math:`10^{s_l \xi_l}` with ``specimen_limit_scatter`` and a second draw from
the seed) is a threshold of the stress intensity range: a half cycle whose range is at or
below ``limit sqrt(a_0 / a)`` does not grow the crack, so a specimen loaded below the limit
runs out, and one above it lives as without it. ``A`` is set so that at the constant range
``specimen_life_range`` = :math:`\Delta F_{ref}` the crack grows from ``specimen_crack0`` =
:math:`a_0` to 1 in ``specimen_life`` cycles :math:`N_f` (times a scatter factor
:math:`10^{s \xi}`, :math:`\xi` a standard normal drawn from ``specimen_seed``, :math:`s` =
``specimen_scatter``):

.. math:: A = \frac{a_0^{1 - m/2} - 1}{(m/2 - 1) N_f}\ (m \ne 2), \qquad
          A = \frac{\ln(1/a_0)}{N_f}\ (m = 2)

The crack makes the specimen more compliant: :math:`k(a) = k_L / (1 + \lambda a^2)`
(``specimen_compliance`` = :math:`\lambda`, a centre crack's compliance growing with its
square). When ``a`` has reached 1 the specimen **fractures** at the next peak of the force
(the reversal from rising to falling: it breaks in tension, at the load cycle's maximum):
from the next period it carries nothing (``k`` and ``c_L`` are 0), the force path is lost
within the cycle. At constant range the cycles to a crack ``a`` are, in closed form,
:meth:`Specimen.cycles_to`, and to a stiffness drop :meth:`Specimen.cycles_to_drop`: what a
test's failure criteria are judged against.

Reversals are found on the force the model computes (no noise), with a hysteresis of
``REVERSAL_FRACTION`` of the life's force range, so a ripple is no cycle. Everything is
deterministic from the parameters and the seed.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np
from ros_ehs.core.errors import InputError

__all__ = ['REVERSAL_FRACTION', 'Specimen']

#: A reversal is a turn of the force by more than this fraction of ``specimen_life_range``.
REVERSAL_FRACTION = 0.02
#: the half cycles :meth:`Specimen.recent_range` is the range of, by default
RECENT = 10
#: the half cycles' ranges kept (at least; a list trimmed by half when twice as long)
RANGES_KEPT = 1000


class Specimen:
    """
    The specimen of ``params`` (a :class:`~ros_ehs.core.params.Params`; see the module docstring).

    ``k_L`` = 0 is no specimen: it carries nothing and never breaks.
    """

    def __init__(self, params: Mapping[str, float]) -> None:
        self.k0 = float(params['k_L'])
        self.c0 = float(params['c_L'])
        self.z0 = float(params['z_L'])
        self.m = float(params['specimen_paris_m'])
        self.a0 = float(params['specimen_crack0'])
        self.lam = float(params['specimen_compliance'])
        self.range_ref = float(params['specimen_life_range'])
        scatter = float(params['specimen_scatter'])
        rng = np.random.default_rng(int(params['specimen_seed']))
        xi = rng.standard_normal()
        self.life = float(params['specimen_life']) * 10.0 ** (scatter * xi)
        limit = float(params['specimen_fatigue_limit'])
        xi_limit = rng.standard_normal()            # after the life's: its draw is unchanged
        #: the force range below which the initial crack does not grow [N] (0: none)
        self.limit = limit * 10.0 ** (float(params['specimen_limit_scatter']) * xi_limit) \
            if limit > 0 else 0.0
        if not (self.life > 0 and math.isfinite(self.life)):
            raise InputError(f'specimen life {self.life!r} cycles must be a positive number')
        h = self.m / 2.0
        if abs(h - 1.0) < 1e-12:
            self.A = math.log(1.0 / self.a0) / self.life
        else:
            self.A = (self.a0 ** (1.0 - h) - 1.0) / ((h - 1.0) * self.life)
        self.a = self.a0
        self.half_cycles = 0
        self.broken = False
        self._hyst = REVERSAL_FRACTION * self.range_ref
        self._last_rev = 0.0         # the force at the last reversal [N]
        self._ext = 0.0              # the running extreme since it [N]
        self._dir = 0                # +1 rising, -1 falling, 0 not yet moving
        self._ranges: list[float] = []   # the last RECENT half cycles' ranges [N]

    @property
    def present(self) -> bool:
        """Return True when there is a specimen (``k_L`` > 0)."""
        return self.k0 > 0.0

    @property
    def cycles(self) -> float:
        """Return the cycles it has carried (half cycles / 2)."""
        return self.half_cycles / 2.0

    @property
    def stiffness(self) -> float:
        """Return its stiffness now [N/m] (0 when broken)."""
        return 0.0 if self.broken else self.k0 / (1.0 + self.lam * self.a * self.a)

    @property
    def damping(self) -> float:
        """Return its damping now [N s/m] (0 when broken)."""
        return 0.0 if self.broken else self.c0

    def force(self, z: float, z_dot: float) -> float:
        """Return the force it carries at piston position ``z`` [m] and speed [m/s] [N]."""
        if self.broken or not self.present:
            return 0.0
        return self.stiffness * (z - self.z0) + self.c0 * z_dot

    def update(self, force: float) -> bool:
        """
        Take this period's force [N]; return True when its stiffness changed (a reversal).

        At a reversal the half cycle just ended grows the crack; a crack of 1 breaks it.
        """
        if self.broken or not self.present or not math.isfinite(force):
            return False
        if self._dir >= 0 and force > self._ext:
            self._ext = force
        elif self._dir <= 0 and force < self._ext:
            self._ext = force
        if self._dir == 0:
            if abs(force - self._last_rev) > self._hyst:
                self._dir = 1 if force > self._last_rev else -1
                self._ext = force
            return False
        if self._dir * (self._ext - force) <= self._hyst:
            return False
        # a reversal at the extreme: the half cycle from the last one ends there
        rng = abs(self._ext - self._last_rev)
        self._ranges.append(rng)
        if len(self._ranges) > 2 * RANGES_KEPT:
            del self._ranges[:RANGES_KEPT]
        at_peak = self._dir > 0
        self._last_rev, self._ext, self._dir = self._ext, force, -self._dir
        return self._grow(rng, at_peak)

    # -- Paris' law, integrated in closed form (every growth and count below uses these) -----
    def _below(self, force_range: float, a: float) -> bool:
        """Return True when ``force_range`` is at or under the fatigue limit at crack ``a``."""
        return self.limit > 0.0 and force_range <= self.limit * math.sqrt(self.a0 / a)

    def _grown_from(self, a: float, g: float) -> float:
        """Return the crack from ``a`` after a growth ``g`` = A dN (range/ref)^m (1: broken)."""
        h = self.m / 2.0
        if abs(h - 1.0) < 1e-12:
            return min(1.0, a * math.exp(g))
        w = a ** (1.0 - h) - (h - 1.0) * g
        return min(1.0, w ** (1.0 / (1.0 - h))) if w > 0.0 else 1.0

    def _cycles_between(self, a_from: float, a_to: float, force_range: float) -> float:
        """Return the cycles from crack ``a_from`` to ``a_to`` at a constant range [N]."""
        h = self.m / 2.0
        if abs(h - 1.0) < 1e-12:
            n = math.log(a_to / a_from) / self.A
        else:
            n = (a_from ** (1.0 - h) - a_to ** (1.0 - h)) / ((h - 1.0) * self.A)
        return n / (force_range / self.range_ref) ** self.m

    def _grow(self, force_range: float, at_peak: bool) -> bool:
        self.half_cycles += 1
        if self._below(force_range, self.a):
            return False             # below the threshold: the crack does not grow
        # the growth law integrated exactly over the half cycle (a constant range in it)
        self.a = self._grown_from(self.a, 0.5 * self.A * (force_range / self.range_ref)
                                  ** self.m)
        if self.a >= 1.0 and at_peak:
            self.broken = True
        return True

    def recent_range(self, half_cycles: int | None = None) -> float:
        """
        Return the constant range that grows the crack as the last half cycles did [N].

        The power mean, with Paris' exponent, of the last ``half_cycles`` half cycles' ranges
        (default :data:`RECENT`, at most :data:`RANGES_KEPT`); NaN before as many.
        """
        n = RECENT if half_cycles is None else int(half_cycles)
        if not 0 < n <= len(self._ranges):
            return math.nan
        m = self.m
        rs = self._ranges[-n:]
        return (sum(r ** m for r in rs) / n) ** (1.0 / m)

    def grown(self, n: float, force_range: float) -> float:
        """Return the crack that ``n`` more cycles at ``force_range`` [N] leave (1: fracture)."""
        if self.broken:
            return 1.0
        if self._below(force_range, self.a):
            return self.a              # below the threshold: no growth
        return self._grown_from(self.a, self.A * n * (force_range / self.range_ref) ** self.m)

    def advance(self, n: float, force_range: float) -> None:
        """
        Carry ``n`` whole cycles at ``force_range`` [N] at once (a virtual test's jump).

        The crack grows as the half cycles would grow it one by one (the law integrated over
        them: exact at a constant range); a jump never fractures it (the caller sizes it so:
        a crack that would reach 1 is refused).
        """
        if n < 0 or not math.isfinite(force_range):
            raise InputError(f'a jump of {n!r} cycles at {force_range!r} N')
        a = self.grown(n, force_range)
        if a >= 1.0:
            raise InputError(f'a jump of {n} cycles at {force_range:.6g} N would fracture '
                             'the specimen: the fracture is simulated')
        self.a = a
        self.half_cycles += int(round(2.0 * n))

    def cycles_left(self, force_range: float) -> float:
        """Return the whole cycles from the crack now to fracture at ``force_range`` [N]."""
        if self.broken:
            return 0.0
        if self._below(force_range, self.a):
            return math.inf
        return self._cycles_between(self.a, 1.0, force_range)

    def cycles_to(self, a: float, force_range: float | None = None) -> float:
        """
        Return the cycles from ``specimen_crack0`` to crack ``a`` at a constant range [N].

        Infinite at a range the fatigue limit stops (the threshold only falls as the crack
        grows: above it at the initial crack, the crack grows as without it).
        """
        rng = force_range or self.range_ref
        if self._below(rng, self.a0) and a > self.a0:
            return math.inf
        return self._cycles_between(self.a0, a, rng)

    def crack_after(self, n: float, force_range: float | None = None) -> float:
        """Return the crack after ``n`` cycles at a constant range [N] (1: it fractures)."""
        rng = force_range or self.range_ref
        if self._below(rng, self.a0):
            return self.a0
        return self._grown_from(self.a0, self.A * n * (rng / self.range_ref) ** self.m)

    def aged(self, params: Mapping[str, float], n: float, force_range: float) -> dict:
        """
        Return the parameters that install this coupon as it is after ``n`` cycles at a range.

        ``params``: those it was made from. Its crack then is the new ``specimen_crack0`` and
        ``specimen_life`` is rescaled so that the growth law (and the scatter the same seed
        draws) is unchanged: a :class:`Specimen` of them has the cycles left that this one has
        after ``n`` cycles at ``force_range`` [N]. What a restarted virtual coupon needs (a
        plant started again mid-test: the real coupon kept its crack). The fatigue limit's
        threshold is taken at the new initial crack.
        """
        a = self.crack_after(n, force_range)
        if a >= 1.0:
            raise InputError(f'the coupon fractures within {n:g} cycles at {force_range:g} N: '
                             'nothing is left to install')
        h = self.m / 2.0
        if abs(h - 1.0) < 1e-12:
            scale = math.log(1.0 / a) / math.log(1.0 / self.a0)
        else:
            scale = (a ** (1.0 - h) - 1.0) / (self.a0 ** (1.0 - h) - 1.0)
        return {'specimen_crack0': a,
                'specimen_life': float(params['specimen_life']) * scale}

    def stiffness_after(self, n: float, force_range: float | None = None) -> float:
        """Return the stiffness after ``n`` cycles at a constant range [N/m] (before fracture)."""
        a = self.crack_after(n, force_range)
        return self.k0 / (1.0 + self.lam * a * a)

    def cycles_to_drop(self, drop: float, force_range: float | None = None) -> float:
        """
        Return the cycles to a stiffness drop ``drop`` (0.1: 10 %) at a constant range.

        The drop is against the stiffness as installed (with the initial crack).
        """
        if not 0.0 < drop < 1.0 or self.lam <= 0.0:
            raise InputError(f'`drop` = {drop!r} must be in (0, 1) with a compliance that grows')
        # against the stiffness as installed, with its initial crack
        a = math.sqrt(((1.0 + self.lam * self.a0 ** 2) / (1.0 - drop) - 1.0) / self.lam)
        if a > 1.0:
            return math.inf          # it breaks first
        return self.cycles_to(max(a, self.a0), force_range)

    def figures(self) -> dict:
        """Return its state: cycles, crack, stiffness, broken."""
        return {'specimen_cycles': self.cycles, 'specimen_crack': self.a,
                'specimen_stiffness_n_per_m': self.stiffness, 'specimen_broken': self.broken}
