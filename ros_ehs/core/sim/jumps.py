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
Cycle jumping: a long virtual test simulates the cycles that tell something, and jumps the rest.

Most of a long constant-amplitude step repeats one settled cycle while the specimen's crack
creeps. A virtual test with :class:`CycleJumps` simulates every period until the step has
run ``settle`` cycles and its last ``between`` cycles' controlled levels are within
``levels`` of their range of the specified ones (the loop and its compensation have
converged: a position loop 1 um off its levels after a jump left the load it carries 0.1 %
off, and a peak/valley-change trip 1 % late); then it **jumps**:
the specimen carries ``n`` cycles at once at the range its last half cycles carried (their
power mean with Paris' exponent: the range that grows the crack as they did; its own law
integrated over the jump, :meth:`~ros_ehs.core.model.specimen.Specimen.advance`), the
counts advance by ``n`` (:meth:`~ros_ehs.core.procedure.runner.ProcedureRunner.jump`), and
``between`` cycles are simulated again before the next jump. The jump ``n`` is the largest
that keeps, by the specimen's law:

* its stiffness within ``stiffness`` (a fraction) of the stiffness now, and its crack within
  ``crack`` of the crack now (what every cycle-watched quantity follows);
* half the cycles to the fracture, and half the cycles to each failure detector's predicted
  trip (``stiffness_drop`` and ``peak_valley_change``: their value now carried along the
  stiffness the law predicts): the jumps shorten as a trip nears, and the trip itself, and
  the fracture, happen in simulated cycles;
* the step's end and the run-out ``JUMP_MARGIN`` cycles away (simulated).

A **block program** (a cyclic step of several levels repeated) jumps whole sequences (``n`` a
multiple of its cycles a sequence, at most :data:`MAX_SEQUENCE`), once each of its last
sequence's cycles repeats the one a sequence before within ``levels``; its range is the power
mean over the last sequence's half cycles. In displacement control the specimen's force
range falls with its stiffness: a jump is carried at the mean of the range now and the one
its end's stiffness gives. No jump is made shorter than ``min_jump``, before every failure
detector has its reference, or in a sweep (simulated whole). A **drive** step jumps whole
passes, each carrying the half cycles a pass carried (the specimen's reversals counted over
the last passes), at their power-mean range. The jumped cycles
are in the cycle table with the levels of the last simulated cycle and the flag
:data:`EXTRAPOLATED`; their time is the rig's (each table row's end is the simulated time
plus the time jumped before it).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math

from ros_ehs.core.errors import InputError
from ros_ehs.core.procedure.detectors import Cycle, EXTRAPOLATED, TAPERED

__all__ = ['CycleJumps', 'EXTRAPOLATED', 'Jumper', 'MAX_SEQUENCE']

#: the longest block sequence jumped (cycles); a longer one is simulated whole
MAX_SEQUENCE = 200


@dataclass(frozen=True)
class CycleJumps:
    """When a virtual test jumps, and how far (module docstring)."""

    stiffness: float = 0.002
    crack: float = 0.05
    settle: int = 20
    between: int = 5
    levels: float = 0.0005
    min_jump: int = 10

    def __post_init__(self) -> None:
        for name, lo, hi in (('stiffness', 0.0, 0.5), ('crack', 0.0, 10.0),
                             ('levels', 0.0, 1.0)):
            v = getattr(self, name)
            if not (math.isfinite(v) and lo < v <= hi):
                raise InputError(f'CycleJumps `{name}` = {v!r} must be in ({lo:g}, {hi:g}]')
        for name in ('settle', 'between', 'min_jump'):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise InputError(f'CycleJumps `{name}` = {v!r} must be a whole number >= 1')


def _first(pred, hi: int) -> float:
    """Return the smallest n in [1, hi] with pred(n) (monotone), or inf when none."""
    if hi < 1 or not pred(hi):
        return math.inf
    lo = 0                                     # pred(lo) False, pred(hi) True
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if pred(mid):
            hi = mid
        else:
            lo = mid
    return float(hi)


class Jumper:
    """One virtual test's jumps: it watches the cycles and sizes each jump."""

    def __init__(self, policy: CycleJumps) -> None:
        self.policy = policy
        self.recent: deque[Cycle] = deque(maxlen=2 * MAX_SEQUENCE + policy.between)
        self.step = -1
        self.in_step = 0                 # cycles simulated in the step
        self.since = 0                   # cycles simulated since the last jump
        self.jumps = 0
        self.force_range = math.nan      # the range the last jump was carried at [N]
        #: the specimen's cycles (half its reversals) a step cycle carries: 1 for a sine, a
        #: drive pass's own count for a drive
        self.per_cycle = 1.0
        self.marks: deque[int] = deque(maxlen=self.recent.maxlen)   # its half cycles then

    def saw(self, cycles, half_cycles: int = 0) -> None:
        """Take the cycles the runner closed this period, and the specimen's half cycles."""
        for c in cycles:
            if c.step != self.step:
                self.step, self.in_step, self.since = c.step, 0, 0
                self.recent.clear()
                self.marks.clear()
            self.recent.append(c)
            self.marks.append(int(half_cycles))
            self.in_step += 1
            self.since += 1

    def jumped(self, n: int) -> None:
        """Note a jump of ``n`` cycles made: ``between`` cycles are simulated before the next."""
        self.jumps += 1
        self.since = 0
        self.recent.clear()
        self.marks.clear()

    def size(self, runner, specimen, step) -> int:
        """
        Return the jump to make now (0: none), in the running ``step`` (the runner's).

        A block program's jump is whole sequences; a one-level cyclic step's last cycles must
        be within ``levels`` of its specified peak and valley (the compensation converged).
        """
        p = self.policy
        mode = step.control_mode
        blocks = step['blocks'] if step.type == 'cyclic' else ((0.0, 0.0, 1),)
        per = sum(b[2] for b in blocks)
        specified = (blocks[0][0], blocks[0][1]) if per == 1 and step.type == 'cyclic' \
            else None
        need = max(p.between, per)
        if per > MAX_SEQUENCE or self.in_step < max(p.settle, 2 * per) or \
                self.since < need or len(self.recent) < need + per:
            return 0
        room = runner.jump_room()
        if room < max(p.min_jump, per):
            return 0
        cs = list(self.recent)[-(need + per):]
        if any(c.flags & TAPERED or not c.finite() for c in cs):
            return 0
        hi = [c.f_hi if mode == 'force' else c.z_hi for c in cs]
        lo = [c.f_lo if mode == 'force' else c.z_lo for c in cs]
        span = max(hi) - min(lo)
        # each of the last cycles repeats the one a sequence before (settled)
        if not span > 0 or any(abs(hi[j] - hi[j - per]) > p.levels * span or
                               abs(lo[j] - lo[j - per]) > p.levels * span
                               for j in range(per, len(cs))):
            return 0
        if specified is not None and per == 1:
            tol = p.levels * (specified[0] - specified[1])
            if any(abs(h - specified[0]) > tol or abs(v - specified[1]) > tol
                   for h, v in zip(hi[-p.between:], lo[-p.between:])):
                return 0
        dets = runner.step_detectors()
        if any(d.kind != 'fitted_stiffness_drop' and d.kind != 'underpeak' and
               d.reference is None for d in dets):
            return 0
        n = min(room, 10 ** 12)
        self.per_cycle = 0.0
        if specimen is not None and specimen.present:
            # the half cycles the last `need` cycles carried: their range, and how many a cycle
            half = self.marks[-1] - self.marks[-1 - need]
            if half > 0:
                rng = specimen.recent_range(half)
                if not math.isfinite(rng):
                    return 0
                self.per_cycle = half / (2.0 * need)
                n = min(n, self._specimen_room(specimen, rng, cs[-per:], dets, mode, n))
                self.force_range = rng
                if mode != 'force':      # the range falls with the stiffness over the jump
                    k_now = specimen.stiffness
                    a = specimen.grown(int(n) * self.per_cycle, rng)
                    k_end = specimen.k0 / (1.0 + specimen.lam * a * a)
                    self.force_range = 0.5 * rng * (1.0 + k_end / k_now)
        n = int(n) // per * per
        return n if n >= p.min_jump else 0

    def _specimen_room(self, sp, rng: float, last: list, dets, mode: str, cap: int) -> float:
        p = self.policy
        spc = self.per_cycle                   # the specimen's cycles a step cycle
        left = sp.cycles_left(rng) / spc
        if math.isinf(left):
            return cap                         # below its fatigue limit: nothing changes
        hi = int(min(cap, max(1.0, 0.5 * left)))
        k_now = sp.stiffness
        a_now = sp.a

        def grown(n):
            return sp.grown(n * spc, rng)

        def stiff(n):
            a = grown(n)
            return sp.k0 / (1.0 + sp.lam * a * a)
        room = float(hi)
        room = min(room, _first(lambda n: grown(n) > a_now * (1.0 + p.crack), hi) - 1)
        room = min(room, _first(lambda n: stiff(n) < k_now * (1.0 - p.stiffness), hi) - 1)
        for d in dets:
            for c in last:                       # each cycle of the last sequence
                trip = self._trip(d, c, mode, sp, stiff, k_now)
                if trip is not None:
                    room = min(room, 0.5 * (_first(lambda n: trip(n), hi) - 1))
        return room

    @staticmethod
    def _trip(d, last: Cycle, mode: str, sp, stiff, k_now):
        """Return n -> whether detector ``d`` would have tripped after n more cycles."""
        v, ref = d.values, d.reference
        if ref is None or d.tripped_at is not None:     # tripped (observed): judged no more
            return None
        if d.kind == 'stiffness_drop' and math.isfinite(d.last_value):
            now = 1.0 - d.last_value
            return lambda n: now * stiff(n) / k_now < 1.0 - v['drop']
        if d.kind == 'peak_valley_change':
            rng = ref['hi'] - ref['lo']
            if not rng > 0:
                return None
            if mode == 'force':        # the position: the load over the stiffness
                hi0, lo0, base = last.z_hi, last.z_lo, sp.z0

                def moved(n):
                    r = k_now / stiff(n)
                    return (base + (hi0 - base) * r, base + (lo0 - base) * r)
            else:                      # the load: the position times the stiffness
                hi0, lo0 = last.f_hi, last.f_lo

                def moved(n):
                    r = stiff(n) / k_now
                    return (hi0 * r, lo0 * r)

            def trip(n):
                h, lo = moved(n)
                return max(abs(h - ref['hi']), abs(lo - ref['lo'])) / rng > v['tolerance']
            return trip
        return None
