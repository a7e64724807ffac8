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
A rig whose parameters drift: oil warming up, seals wearing in.

Each :class:`DriftStage` changes some parameters by a relative amount along a smooth
warm-up curve (a quintic step: no jump in the value, its rate or its acceleration) from
``start`` to ``start + duration`` [s]; the stages add up. :meth:`Drift.at` gives the
parameter set at a time, validated like any other.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Sequence

from ros_ehs.core.errors import ParameterError
from ros_ehs.core.params import Params, spec

__all__ = ['Drift', 'DriftStage', 'smoothstep']


def smoothstep(tau: float) -> float:
    """Return the quintic step ``10 tau^3 - 15 tau^4 + 6 tau^5`` on [0, 1], clamped."""
    tau = min(max(tau, 0.0), 1.0)
    return tau * tau * tau * (10.0 + tau * (-15.0 + 6.0 * tau))


@dataclass(frozen=True)
class DriftStage:
    """``changes``: parameter -> relative change at the end (-0.3: 30 % lower)."""

    start: float
    duration: float
    changes: dict = field(default_factory=dict)

    @property
    def settled(self) -> float:
        """Time at which this stage's change is complete [s]."""
        return self.start + self.duration


class Drift:
    """Stages of parameter drift (see the module docstring)."""

    def __init__(self, stages: Sequence[DriftStage]) -> None:
        for k, st in enumerate(stages):
            if not (math.isfinite(st.start) and st.start >= 0):
                raise ParameterError(f'drift stage {k}: `start` = {st.start!r} s must be >= 0')
            if not (math.isfinite(st.duration) and st.duration > 0):
                raise ParameterError(f'drift stage {k}: `duration` = {st.duration!r} s must be '
                                     '> 0')
            for n, r in st.changes.items():
                spec(n)       # an unknown name raises, naming the known ones
                if not (math.isfinite(r) and r > -1.0):
                    raise ParameterError(f'drift stage {k}: {n} change {r!r} must be a '
                                         'finite fraction > -1')
        self.stages = tuple(stages)

    @property
    def names(self) -> tuple[str, ...]:
        """Return the parameters that drift."""
        return tuple(dict.fromkeys(n for st in self.stages for n in st.changes))

    def factors(self, t: float) -> dict[str, float]:
        """Return each drifting parameter's factor on its base value at time ``t`` [s]."""
        out = dict.fromkeys(self.names, 1.0)
        for st in self.stages:
            s = smoothstep((t - st.start) / st.duration)
            for n, r in st.changes.items():
                out[n] += r * s
        return out

    def at(self, base: Params, t: float) -> Params:
        """Return ``base`` drifted to time ``t`` [s]."""
        return base.replace(**{n: base[n] * f for n, f in self.factors(t).items()})
