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
One setting, declared once: name, unit, default, range or choices, live or not, meaning.

A :class:`Setting` is what every knob of ros_ehs is: a model or controller parameter
(:class:`ros_ehs.core.params.ParamSpec`, a Setting with its provenance), a node's option or an
``ehs_sim`` option (:mod:`ros_ehs.core.options`). Everything else is derived from it: the ROS
parameter declarations with their ranges and descriptions (:mod:`ros_ehs.nodes.parameters`),
the command-line options (:func:`ros_ehs.tools.cli.add_settings`), the tables of
``docs/parameters.md``, ``docs/nodes.md`` and ``docs/cli.md`` (``python -m
ros_ehs.tools.docs``), and every check of a value (:meth:`Setting.check`).

Its kind follows from its default: ``bool``, ``int``, ``float`` (an int is taken for a float,
as a ROS parameters file may write ``1`` for ``1.0``), ``str`` (``choice`` when it has
``choices``) or ``list`` (of strings). :func:`parse_assignment` is the one ``NAME=VALUE``
parser (the value read as YAML, as ``ros2 run ... -p name:=value`` reads it).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Iterable, Mapping, Sequence

from ros_ehs.core.errors import ParameterError

__all__ = ['KINDS', 'Setting', 'by_name', 'check_values', 'parse_assignment', 'parse_value']

#: The kinds a setting can be.
KINDS = ('bool', 'int', 'float', 'str', 'choice', 'list')


@dataclass(frozen=True)
class Setting:
    """
    One setting (see the module docstring).

    ``lo``/``hi`` is the valid range of a number (inclusive); ``live``: it may change while a
    node runs (a read-only ROS parameter otherwise); ``flags``: further command-line
    spellings (``--topics`` besides ``--topic-map``; for a flag, ``--no-...`` sets it false);
    ``words``: words that stand for a value (``('auto', -1.0)``), taken by :meth:`check`.
    """

    name: str
    unit: str
    default: Any
    lo: float = -math.inf
    hi: float = math.inf
    meaning: str = ''
    choices: tuple[str, ...] = ()
    live: bool = False
    flags: tuple[str, ...] = ()
    words: tuple[tuple[str, Any], ...] = ()

    @property
    def kind(self) -> str:
        """Return what values it takes: one of :data:`KINDS`."""
        d = self.default
        if self.choices:
            return 'choice'
        if isinstance(d, bool):
            return 'bool'
        if isinstance(d, int):
            return 'int'
        if isinstance(d, float):
            return 'float'
        if isinstance(d, (list, tuple)):
            return 'list'
        return 'str'

    @property
    def is_choice(self) -> bool:
        """Return True for a string with a fixed set of choices."""
        return bool(self.choices)

    @property
    def ranged(self) -> bool:
        """Return True for a number with a finite range."""
        return self.kind in ('int', 'float') and math.isfinite(self.lo) and \
            math.isfinite(self.hi)

    def check(self, value: Any) -> Any:
        """Return ``value`` converted to this setting's kind, or raise ParameterError naming it."""
        kind, name = self.kind, self.name
        if isinstance(value, str) and self.words:
            value = dict(self.words).get(value, value)
        if kind == 'choice':
            if not isinstance(value, str) or value not in self.choices:
                raise ParameterError(f'parameter `{name}` = {value!r} is not one of '
                                     f'{list(self.choices)}')
            return value
        if kind == 'bool':
            if not isinstance(value, bool):
                raise ParameterError(f'parameter `{name}` = {value!r} must be true or false')
            return value
        if kind == 'str':
            if not isinstance(value, str):
                raise ParameterError(f'parameter `{name}` = {value!r} must be a string')
            return value
        if kind == 'list':
            if not isinstance(value, (list, tuple)) or not all(isinstance(v, str)
                                                               for v in value):
                raise ParameterError(f'parameter `{name}` = {value!r} must be a list of strings')
            return list(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(f'parameter `{name}` = {value!r} must be a number'
                                 + (f' [{self.unit}]' if self.unit else '')
                                 + ''.join(f' or {w}' for w, _ in self.words))
        if kind == 'int':
            if float(value) != int(value):
                raise ParameterError(f'parameter `{name}` = {value!r} must be a whole number')
            v: float | int = int(value)
        else:
            v = float(value)
            if not math.isfinite(v):
                raise ParameterError(f'parameter `{name}` = {v!r} is not finite')
        if not self.lo <= v <= self.hi:
            unit = f' {self.unit}' if self.unit else ''
            raise ParameterError(f'parameter `{name}` = {v!r}{unit} is outside its valid range '
                                 f'[{self.lo!r}, {self.hi!r}] ({self.meaning})')
        return v

    def describe(self) -> str:
        """Return the meaning with the unit, the range or choices, and live: a docs cell."""
        out = self.meaning
        if self.unit:
            out += f' [{self.unit}]'
        if self.choices:
            out += f' (one of: {", ".join(self.choices)})'
        elif self.ranged:
            out += f' (range {self.lo:g} to {self.hi:g})'
        if self.words:
            out += ''.join(f'; {w}: {v!r}' for w, v in self.words)
        if self.live:
            out += '; *live*'
        return out


def by_name(settings: Iterable[Setting]) -> dict[str, Setting]:
    """Return ``{name: setting}``; a name declared twice raises ParameterError naming it."""
    out: dict[str, Setting] = {}
    for s in settings:
        if s.name in out:
            raise ParameterError(f'setting `{s.name}` is declared twice')
        out[s.name] = s
    return out


def parse_value(text: str) -> Any:
    """Return ``text`` read as one YAML value (``1e-3``, ``true``, ``[a, b]``, ``hold``)."""
    import yaml
    try:
        v = yaml.safe_load(text) if text.strip() else ''
    except yaml.YAMLError as err:
        raise ParameterError(f'{text!r} is not a value: {err}') from None
    if isinstance(v, str):       # YAML 1.1 reads 1e3, nan and inf as words: numbers here
        try:
            return float(v)
        except ValueError:
            pass
    return v


def parse_assignment(text: str, settings: Sequence[Setting] | None = None
                     ) -> tuple[str, Any]:
    """
    Return ``(name, value)`` of ``NAME=VALUE`` (the value as YAML, see :func:`parse_value`).

    With ``settings``, the name must be one of them and the value is checked against it; a
    float setting takes an integer (``kp=1``).
    """
    name, sep, value = text.partition('=')
    name = name.strip()
    if not sep or not name:
        raise ParameterError(f'{text!r} is not NAME=VALUE')
    v = parse_value(value)
    if settings is not None:
        known = by_name(settings)
        if name not in known:
            raise ParameterError(f'unknown parameter `{name}`; known: {sorted(known)}')
        v = known[name].check(v)
    return name, v


def check_values(values: Mapping[str, Any], settings: Sequence[Setting]) -> dict[str, Any]:
    """Return ``values`` checked against ``settings`` (unknown names raise, naming them)."""
    known = by_name(settings)
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ParameterError(f'unknown settings {unknown}; known: {sorted(known)}')
    return {k: known[k].check(v) for k, v in values.items()}
