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
Procedure files: a test as steps, each with its end conditions and data, validated whole.

A procedure is a YAML mapping (docs/procedures.md shows one, the tables there are generated
from the declarations here)::

    name: coupon R=0.1 at 10 Hz
    control_mode: force             # the steps' default: displacement or force
    run_out: 2000000                # the test ends when this many cycles are done
    steps:
      - {name: preload, type: ramp, to: 5500.0, rate: 2000.0}
      - {name: settle, type: dwell, time: 2.0}
      - name: fatigue
        type: cyclic
        waveform: sine
        mean: 5500.0
        amplitude: 4500.0
        frequency: 10.0
        end:
          - {stiffness_drop: {drop: 0.10}}
          - {peak_valley_change: {tolerance: 0.05}}

Steps (``type``): ``ramp`` to a level at a rate; ``dwell`` for a time; ``cyclic`` (sine,
triangle or haversine between ``mean -+ amplitude``, ``peak``/``valley``, or a block-loading
sequence ``blocks`` of ``[peak, valley, cycles]``; a ``count`` of cycles, or until an end
condition); ``sweep`` (a sine sweep from ``f0`` to ``f1`` over ``duration``); ``drive`` (a
drive file, ``t,z`` CSV, played ``repeats`` times: iterate it first with ``ehs_sim
drive``). Levels are in the step's control mode's unit: m in displacement, N in force.

End conditions (``end``, any of them ends the step; a ``count`` and a ``time`` are end
conditions too): ``time`` [s]; ``level`` (``signal`` position or load crossing ``above`` or
``below`` a value); and the failure detectors of :mod:`ros_ehs.core.procedure.detectors`:
``stiffness_drop``, ``peak_valley_change``, ``underpeak`` (each cycle's extremes) and
``fitted_stiffness_drop`` (the specimen stiffness ``k_L`` live identification fits, with its
standard error). A failure detector that trips ends the test (the specimen has failed); the
others end the step.

Every key is declared once, with its unit, range and meaning (:data:`STEP_KEYS`,
:data:`END_KEYS`, :data:`TEST_KEYS`); :func:`parse_procedure` checks a whole file before
anything moves, and every error names the step (its number and name) and the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Any, Mapping

from ros_ehs.core.errors import InputError, ParameterError
from ros_ehs.core.settings import Setting

__all__ = ['CAPTURES', 'COMPENSATIONS', 'DETECTORS', 'END_KEYS', 'EndCondition',
           'POSITION_RANGE', 'Procedure', 'STEP_KEYS', 'STEP_TYPES', 'Step', 'TEST_KEYS',
           'PACING_KEYS', 'TRANSITION_KEYS',
           'WAVEFORMS', 'load_procedure', 'parse_procedure']

STEP_TYPES = ('ramp', 'dwell', 'cyclic', 'sweep', 'drive')
WAVEFORMS = ('sine', 'triangle', 'haversine')
COMPENSATIONS = ('auto', 'apc', 'pvc', 'none')
#: full cycles kept: at log-spaced counts (1, 2, 5, 10, 20, 50, ...), or none
CAPTURES = ('log', 'none')
#: the failure detectors (they end the test)
DETECTORS = ('stiffness_drop', 'peak_valley_change', 'underpeak', 'fitted_stiffness_drop')
MODES = ('displacement', 'force')
#: a displacement level stays within this [m]
POSITION_RANGE = 2.0

_LEVEL = 1.0e7     # a level's range in either unit
_S = Setting

#: The test's own keys.
TEST_KEYS: tuple[Setting, ...] = (
    _S('name', '', 'test', meaning='what the test is called (in the status, the bag, the '
       'report)'),
    _S('control_mode', '', 'displacement', meaning="the steps' control mode unless a step "
       'says otherwise', choices=MODES),
    _S('run_out', '1', 0, 0, 10**12, 'the test ends (run-out) when this many cycles are done '
       'in all (0: no limit)'),
    _S('stop_level', 'm or N', 0.0, -_LEVEL, _LEVEL, '~/stop and the end: ramp the command '
       "to this level (in the last step's mode: 0 N unloads a specimen), then hold"),
    _S('stop_rate', 'm/s or N/s', 0.0, 0.0, 1.0e9, 'the rate of that ramp (0: the last ramp '
       "step's rate, or 1 mm/s or 1 kN/s)"),
    _S('steps', '', [], meaning='the steps, in order (a list of mappings)'),
)

#: How a waveform step (cyclic, sweep, drive) starts and resumes: the mean, then the taper.
TRANSITION_KEYS: tuple[Setting, ...] = (
    _S('taper', '1', 3, 1, 1000, 'cycles over which the amplitude grows from zero at the '
       "step's start and at each resume (after the mean is reached); they count, flagged "
       'tapered, and are neither learnt from nor judged by the failure detectors'),
    _S('mean_rate', 'm/s or N/s', 0.0, 0.0, 1.0e9, 'the fastest the command moves to the '
       "cycle's mean before the taper, from where the axis is (0: the test's stop_rate, or "
       '1 mm/s or 1 kN/s)'),
)
#: How far a step's compensation may move the command (cyclic and sweep steps).
LIMIT_KEYS: tuple[Setting, ...] = (
    _S('compensation_limit', '1', 1.0, 0.0, 10.0, 'the most the compensation may move the '
       'command from the specified one, as a fraction of the specified amplitude (the '
       'amplitude, the mean and, for APC, the harmonics); when it is met for '
       '`limit_cycles` learnt cycles in a row, the levels cannot be reached and the test is '
       'interrupted, the limit named'),
    _S('limit_cycles', '1', 5, 1, 1000, 'see compensation_limit'),
    _S('compensation_gain', '1', 0.7, 0.05, 1.0, "the fraction of a learnt cycle's error "
       'the compensation corrects at once (peak/valley control: of the range and mean; '
       'amplitude/phase control: of each harmonic); lower for a rig whose response changes '
       'from cycle to cycle'),
)

#: When a cycle counts (cyclic steps): null pacing.
PACING_KEYS: tuple[Setting, ...] = (
    _S('count_tolerance', '1', 0.0, 0.0, 0.5, 'a cycle counts only when the controlled '
       "signal's peak and valley (the cycle's fit) are each within this fraction of the "
       "specified range of the step's levels (0: every whole cycle counts); a cycle outside "
       'it (the taper, a level not yet reached) is carried but not counted: the count '
       'waits, the step runs on, and the cycles and time spent are reported (null pacing)'),
    _S('null_cycles', '1', 100, 1, 10**6, 'so many cycles in a row outside count_tolerance '
       'interrupt the test: its levels are not reached'),
    _S('frequency_min', 'Hz', 0.0, 0.0, 500.0, 'with count_tolerance, the frequency backs '
       'off: backoff_cycles cycles in a row outside it lower the frequency by a fifth, down to '
       'this, and the step goes on at it from where the axis is (the mean, then the taper, as '
       'a resume); 0: the frequency stays and only the count waits'),
    _S('backoff_cycles', '1', 10, 1, 10**6, 'see frequency_min'),
    _S('level_error', '1', 0.05, 0.0, 1.0, 'the levels detector: a cycle past its taper whose '
       'fitted peak or valley is further than this fraction of the specified range from its '
       'level is off; `level_cycles` off in a row interrupt the test, the levels named (0: '
       'off)'),
    _S('level_cycles', '1', 100, 1, 10**6, 'see level_error'),
)
#: Each step type's keys (besides ``name``, ``type``, ``control_mode``, ``end``, ``capture``).
STEP_KEYS: dict[str, tuple[Setting, ...]] = {
    'ramp': (_S('to', 'm or N', 0.0, -_LEVEL, _LEVEL, 'the level to ramp to'),
             _S('rate', 'm/s or N/s', 1.0, 1.0e-9, 1.0e9, 'how fast')),
    'dwell': (_S('time', 's', 1.0, 0.0, 1.0e9, 'how long to hold the level'),),
    'cyclic': (_S('waveform', '', 'sine', meaning="the cycle's shape", choices=WAVEFORMS),
               _S('mean', 'm or N', 0.0, -_LEVEL, _LEVEL, 'the mean (with amplitude)'),
               _S('amplitude', 'm or N', 0.0, 0.0, _LEVEL, 'the amplitude (with mean)'),
               _S('peak', 'm or N', 0.0, -_LEVEL, _LEVEL, 'the peak (with valley)'),
               _S('valley', 'm or N', 0.0, -_LEVEL, _LEVEL, 'the valley (with peak)'),
               _S('blocks', '', [], meaning='block loading: [peak, valley, cycles] each, '
                  'repeated in turn (instead of the levels)'),
               _S('frequency', 'Hz', 1.0, 1.0e-3, 200.0, 'cycles a second'),
               _S('count', '1', 0, 0, 10**12, 'the step ends after this many cycles (0: at an '
                  'end condition, or the run-out)'),
               _S('compensation', '', 'auto', meaning='peak/valley control (pvc: each '
                  "cycle's peak and valley reach the levels, what a fatigue test is specified "
                  'by) or amplitude/phase control (apc, sines only: the fundamental and its '
                  'harmonics), learnt from the measured signal; auto: pvc; none: the waveform '
                  'as specified', choices=COMPENSATIONS)) + TRANSITION_KEYS + LIMIT_KEYS
    + PACING_KEYS,
    'sweep': (_S('mean', 'm or N', 0.0, -_LEVEL, _LEVEL, 'the mean'),
              _S('amplitude', 'm or N', 0.0, 0.0, _LEVEL, 'the amplitude'),
              _S('f0', 'Hz', 1.0, 1.0e-3, 200.0, 'the start frequency'),
              _S('f1', 'Hz', 20.0, 1.0e-3, 200.0, 'the end frequency'),
              _S('duration', 's', 10.0, 1.0e-3, 1.0e7, 'the sweep time (linear)'),
              _S('compensation', '', 'auto', meaning='amplitude/phase control of the '
                 'fundamental (auto, apc) or none', choices=COMPENSATIONS)) + TRANSITION_KEYS
    + LIMIT_KEYS,
    'drive': (_S('file', '', '', meaning='the drive file: CSV with columns t [s] and the '
                 'level (z [m], or F [N] in force), as `ehs_sim drive` writes it'),
              _S('repeats', '1', 1, 1, 10**9, 'how many times to play it (each pass a cycle)'))
    + TRANSITION_KEYS,
}
#: The keys every step may have.
COMMON_KEYS: tuple[Setting, ...] = (
    _S('name', '', '', meaning='what the step is called (default: its type and number)'),
    _S('type', '', 'ramp', meaning='what the step does', choices=STEP_TYPES),
    _S('control_mode', '', 'displacement', meaning='the loop the step drives (default: the '
       "test's)", choices=MODES),
    _S('end', '', [], meaning='end conditions (a list; any of them ends the step)'),
    _S('capture', '', 'log', meaning="full cycles kept besides every cycle's peaks and "
       'valleys: at log-spaced counts, or none', choices=CAPTURES),
)

#: Each end condition's keys.
END_KEYS: dict[str, tuple[Setting, ...]] = {
    'time': (_S('time', 's', 0.0, 0.0, 1.0e9, 'the step ends after this long'),),
    'level': (_S('signal', '', 'load', meaning='what crosses', choices=('position', 'load')),
              _S('above', 'm or N', math.nan, -_LEVEL, _LEVEL, 'ends when it rises above '
                 'this'),
              _S('below', 'm or N', math.nan, -_LEVEL, _LEVEL, 'ends when it falls below '
                 'this')),
    'stiffness_drop': (
        _S('drop', '1', 0.1, 1.0e-3, 0.99, "the specimen has failed when each cycle's stiffness "
           '(load range over displacement range) has fallen this fraction under the '
           "reference cycle's"),
        _S('settling', '1', 20, 0, 10**9, 'cycles before the reference (the loop and the '
           'compensation settle)'),
        _S('reference', '1', 10, 1, 10**6, 'cycles averaged for the reference'),
        _S('persist', '1', 2, 1, 10**6, 'consecutive cycles beyond it')),
    'peak_valley_change': (
        _S('tolerance', '1', 0.05, 1.0e-4, 10.0, 'the specimen has failed when the uncontrolled '
           "signal's peak or valley (displacement in force control, load in displacement "
           "control) has moved this fraction of the reference cycle's range"),
        _S('settling', '1', 20, 0, 10**9, 'cycles before the reference'),
        _S('reference', '1', 10, 1, 10**6, 'cycles averaged for the reference'),
        _S('persist', '1', 2, 1, 10**6, 'consecutive cycles beyond it')),
    'underpeak': (
        _S('fraction', '1', 0.9, 0.01, 1.0, 'the specimen has failed when the controlled '
           "signal's range falls under this fraction of the specified one (a crack that "
           'opens, a fracture)'),
        _S('settling', '1', 20, 0, 10**9, 'cycles before it is judged'),
        _S('persist', '1', 1, 1, 10**6, 'consecutive cycles under it')),
    'fitted_stiffness_drop': (
        _S('drop', '1', 0.1, 1.0e-3, 0.99, 'the specimen has failed when the specimen '
           'stiffness k_L that live identification fits has fallen this fraction under its '
           'reference (the identify node must fit k_L: its `free` holds it)'),
        _S('sigmas', '1', 2.0, 0.0, 10.0, 'and is under that limit by this many of its '
           'standard errors (a fit too uncertain to tell does not trip it)'),
        _S('settling', '1', 20, 0, 10**9, "the step's cycles before an estimate counts"),
        _S('reference', '1', 2, 1, 1000, 'adequate estimates averaged for the reference'),
        _S('persist', '1', 2, 1, 1000, 'consecutive adequate estimates beyond it')),
}


@dataclass(frozen=True)
class EndCondition:
    """One end condition: its kind (a key of :data:`END_KEYS`) and its checked values."""

    kind: str
    values: Mapping[str, Any]

    @property
    def failure(self) -> bool:
        """Return True for a failure detector (it ends the test, not just the step)."""
        return self.kind in DETECTORS


@dataclass(frozen=True)
class Step:
    """One step: its kind, its values (checked), its end conditions and its capture."""

    index: int
    name: str
    type: str                    # noqa: A003 the file's key
    control_mode: str
    values: Mapping[str, Any]
    end: tuple[EndCondition, ...] = ()
    capture: str = 'log'

    def __getitem__(self, key: str) -> Any:
        """Return the step's value of ``key``."""
        return self.values[key]

    @property
    def cyclic(self) -> bool:
        """Return True for a step that counts cycles (cyclic, sweep, drive)."""
        return self.type in ('cyclic', 'sweep', 'drive')

    @property
    def label(self) -> str:
        """Return how errors and events name it: its number and name."""
        return f'step {self.index + 1} ({self.name})'


@dataclass(frozen=True)
class Procedure:
    """A checked procedure: the test's values and its steps."""

    name: str
    steps: tuple[Step, ...]
    run_out: int = 0
    stop_level: float = 0.0
    stop_rate: float = 0.0
    source: str = ''
    text: str = field(default='', repr=False)    #: the file's text (kept with the test)

    def ends_on(self, kind: str) -> bool:
        """Say if any step has an end condition of ``kind``."""
        return any(e.kind == kind for s in self.steps for e in s.end)


def _check(setting: Setting, value: Any, where: str) -> Any:
    try:
        return setting.check(value)
    except ParameterError as err:
        raise InputError(f'{where}: {str(err).replace("parameter ", "", 1)}') from None


def _mapping(doc: Any, where: str) -> Mapping:
    if not isinstance(doc, Mapping):
        raise InputError(f'{where}: expected a mapping, got {type(doc).__name__}')
    return doc


def _unknown(doc: Mapping, known, where: str) -> None:
    bad = sorted(set(doc) - set(known))
    if bad:
        raise InputError(f'{where}: unknown keys {bad}; known: {sorted(known)}')


def _level(v: float, mode: str, key: str, where: str) -> None:
    if mode == 'displacement' and abs(v) > POSITION_RANGE:
        raise InputError(f'{where}: `{key}` = {v!r} m is beyond +-{POSITION_RANGE:g} m in '
                         'displacement control (a force? give the step control_mode force)')


def _end(doc: Any, mode: str, where: str) -> EndCondition:
    doc = _mapping(doc, where)
    if len(doc) != 1:
        raise InputError(f'{where}: an end condition is one of {sorted(END_KEYS)} with its '
                         f'values, e.g. {{stiffness_drop: {{drop: 0.1}}}}; got {sorted(doc)}')
    kind, body = next(iter(doc.items()))
    if kind not in END_KEYS:
        raise InputError(f'{where}: unknown end condition `{kind}`; known: {sorted(END_KEYS)}')
    keys = END_KEYS[kind]
    if kind == 'time' and not isinstance(body, Mapping):
        body = {'time': body}
    body = _mapping(body, f'{where} `{kind}`')
    _unknown(body, [s.name for s in keys], f'{where} `{kind}`')
    values = {s.name: _check(s, body[s.name], f'{where} `{kind}`') if s.name in body else
              s.default for s in keys}
    if kind == 'level':
        given = [k for k in ('above', 'below') if k in body]
        if len(given) != 1:
            raise InputError(f'{where} `level`: give `above` or `below` (one of them)')
        _level(values[given[0]], mode if values['signal'] == 'load' or mode == 'force'
               else 'displacement', given[0], f'{where} `level`')
    return EndCondition(kind, values)


def _step(k: int, doc: Any, default_mode: str) -> Step:
    where = f'step {k + 1}'
    doc = _mapping(doc, where)
    if 'type' not in doc:
        raise InputError(f'{where}: no `type`; one of {list(STEP_TYPES)}')
    kind = _check(COMMON_KEYS[1], doc['type'], where)
    name = doc.get('name') or f'{kind} {k + 1}'
    if not isinstance(name, str):
        raise InputError(f'{where}: `name` = {name!r} must be a string')
    where = f'step {k + 1} ({name})'
    keys = STEP_KEYS[kind]
    _unknown(doc, [s.name for s in COMMON_KEYS + keys], where)
    mode = _check(COMMON_KEYS[2], doc.get('control_mode', default_mode), where)
    capture = _check(COMMON_KEYS[4], doc.get('capture', 'log'), where)
    values = {}
    for s in keys:
        if s.name in doc:
            values[s.name] = (doc[s.name] if s.name == 'blocks' else
                              _check(s, doc[s.name], where))
        else:
            values[s.name] = s.default
    if kind == 'ramp':
        if 'to' not in doc or 'rate' not in doc:
            raise InputError(f'{where}: a ramp needs `to` and `rate`')
        _level(values['to'], mode, 'to', where)
    elif kind == 'dwell':
        if 'time' not in doc:
            raise InputError(f'{where}: a dwell needs `time`')
    elif kind == 'cyclic':
        values['blocks'] = _blocks(doc, values, mode, where)
        if values['count_tolerance'] > 0 and len(values['blocks']) > 1:
            raise InputError(f'{where}: `count_tolerance` paces a step of one level; a block '
                             'program would skip the blocks of the cycles it does not count')
        if 'frequency' not in doc:
            raise InputError(f'{where}: a cyclic step needs `frequency`')
        if values['frequency_min'] > 0 and not (
                values['count_tolerance'] > 0
                and values['frequency_min'] < values['frequency']):
            raise InputError(f"{where}: `frequency_min` = {values['frequency_min']!r} Hz backs "
                             'the frequency off while cycles are outside `count_tolerance`: '
                             'give count_tolerance > 0 and frequency_min under `frequency` = '
                             f"{values['frequency']!r} Hz")
        comp = values['compensation']
        if comp == 'apc' and (values['waveform'] != 'sine' or len(values['blocks']) > 1):
            raise InputError(f'{where}: `compensation` apc corrects a sine of one level; use '
                             'pvc for triangles, haversines and blocks')
    elif kind == 'sweep':
        for key in ('amplitude', 'f0', 'f1', 'duration'):
            if key not in doc:
                raise InputError(f'{where}: a sweep needs `{key}`')
        if values['amplitude'] <= 0:
            raise InputError(f'{where}: `amplitude` = {values["amplitude"]!r} must be > 0')
        if values['compensation'] == 'pvc':
            raise InputError(f'{where}: a sweep takes apc (its fundamental) or none, not pvc')
        for key in ('mean', 'amplitude'):
            _level(values[key], mode, key, where)
    elif kind == 'drive':
        if not values['file']:
            raise InputError(f'{where}: a drive step needs `file` (a t,z CSV)')
    end = doc.get('end', [])
    if not isinstance(end, list):
        raise InputError(f'{where}: `end` must be a list of end conditions')
    ends = tuple(_end(e, mode, f'{where} end {j + 1}') for j, e in enumerate(end))
    if any(e.failure for e in ends) and kind != 'cyclic':
        raise InputError(f'{where}: failure detectors judge cycles: they go on a cyclic step')
    if kind == 'cyclic' and not values['count'] and not ends:
        pass    # until the run-out (checked by the procedure)
    return Step(k, name, kind, mode, values, ends, capture)


def _blocks(doc: Mapping, values: dict, mode: str, where: str) -> tuple:
    """Return the cyclic step's blocks as ((peak, valley, cycles), ...), checked."""
    levels = [g for g in (('mean', 'amplitude'), ('peak', 'valley'), ('blocks',))
              if any(k in doc for k in g)]
    if len(levels) != 1:
        raise InputError(f'{where}: give the levels one way: `mean` and `amplitude`, `peak` '
                         'and `valley`, or `blocks`')
    if levels[0] == ('blocks',):
        raw = doc['blocks']
        if not isinstance(raw, list) or not raw:
            raise InputError(f'{where}: `blocks` must be a list of [peak, valley, cycles]')
        out = []
        for j, b in enumerate(raw):
            ok = isinstance(b, (list, tuple)) and len(b) == 3 and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                for x in b)
            if not ok or not b[0] > b[1] or b[2] < 1 or b[2] != int(b[2]):
                raise InputError(f'{where}: block {j + 1} = {b!r} must be [peak, valley, '
                                 'cycles] with peak above valley and a whole number of '
                                 'cycles >= 1')
            _level(b[0], mode, f'blocks[{j + 1}] peak', where)
            _level(b[1], mode, f'blocks[{j + 1}] valley', where)
            out.append((float(b[0]), float(b[1]), int(b[2])))
        return tuple(out)
    missing = [k for k in levels[0] if k not in doc]
    if missing:
        raise InputError(f'{where}: `{levels[0][0]}` needs `{missing[0]}`')
    if levels[0] == ('mean', 'amplitude'):
        mean, amp = values['mean'], values['amplitude']
        if not amp > 0:
            raise InputError(f'{where}: `amplitude` = {amp!r} must be > 0')
        peak, valley = mean + amp, mean - amp
    else:
        peak, valley = values['peak'], values['valley']
        if not peak > valley:
            raise InputError(f'{where}: `peak` = {peak!r} must be above `valley` = '
                             f'{valley!r}')
    for key, v in (('peak', peak), ('valley', valley)):
        _level(v, mode, key, where)
    return ((float(peak), float(valley), 1),)


def parse_procedure(doc: Any, source: str = 'the procedure', text: str = '') -> Procedure:
    """Check a whole procedure (a YAML document's mapping); return it, or raise naming why."""
    doc = _mapping(doc, source)
    _unknown(doc, [s.name for s in TEST_KEYS], source)
    top = {s.name: _check(s, doc[s.name], source) if s.name in doc and s.name != 'steps'
           else s.default for s in TEST_KEYS}
    steps = doc.get('steps')
    if not isinstance(steps, list) or not steps:
        raise InputError(f'{source}: `steps` must be a non-empty list of steps')
    out = []
    for k, s in enumerate(steps):
        try:
            out.append(_step(k, s, top['control_mode']))
        except InputError as err:
            raise InputError(f'{source}: {err}') from None
    last = out[-1]
    if last.type == 'cyclic' and not last['count'] and not last.end and not top['run_out']:
        raise InputError(f'{source}: {last.label} never ends: give it a `count`, an end '
                         'condition, or the test a `run_out`')
    names = [s.name for s in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f'{source}: step names must differ; {dup} repeat')
    return Procedure(top['name'], tuple(out), int(top['run_out']), float(top['stop_level']),
                     float(top['stop_rate']), source, text)


def load_procedure(path: str | Path) -> Procedure:
    """Read and check a procedure file (YAML); errors name the file, the step and the key."""
    import yaml
    p = Path(path)
    try:
        text = p.read_text()
        doc = yaml.safe_load(text)
    except OSError as err:
        raise InputError(f'cannot read the procedure {str(p)!r}: {err}') from None
    except yaml.YAMLError as err:
        raise InputError(f'procedure {str(p)!r} is not YAML: {err}') from None
    return parse_procedure(doc, f'procedure {str(p)!r}', text)
