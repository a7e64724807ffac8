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
Campaign files: a fatigue campaign's plan, checked whole before anything moves.

A campaign (YAML) is a procedure template, the way a load level becomes its cyclic step's
levels, a plan of levels and specimens, the run-out, and an optional target::

    name: 6082-T6 coupons
    procedure: coupon.yaml          # a procedure file (or `template:`, the mapping itself)
    level_step: fatigue             # the cyclic step the level sets (default: the first)
    level: {kind: max_load, R: 0.1} # peak = S, valley = R S (or amplitude: mean +- S)
    run_out: 1.0e7                  # cycles: a specimen this far unbroken is a run-out
    plan: {method: levels, levels: [9000, 8000, 7000, 6000], specimens: 3}
    target: {kind: load_at_life, life: 1.0e6, confidence: 0.9, width: 0.05}

Plans (``plan.method``): ``levels`` (the horizons method: ``specimens`` at each of
``levels``), ``pearl_string`` (one specimen at each level from ``start`` down by ``step``,
``specimens`` in all), ``staircase`` (from ``start``, ``step`` down after a failure and up
after a run-out, ISO 12107 / Dixon-Mood, ``specimens`` in all), ``adaptive`` (the next level
chosen from the data so far between ``low`` and ``high``, ``specimens`` in all). Every level
the plan can give is rendered into the template and checked as a procedure
(:func:`~ros_ehs.core.procedure.spec.parse_procedure`): every error names the campaign's
file and key, or the rendered level and the procedure's step and key.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
import math
from pathlib import Path
import re
from typing import Any, Mapping, Sequence

from ros_ehs.core.errors import InputError
# the procedure file's checks: a campaign file's errors read as a procedure file's
from ros_ehs.core.procedure.spec import _check, _mapping, _unknown, parse_procedure, Procedure
from ros_ehs.core.settings import Setting

__all__ = ['CAMPAIGN_KEYS', 'Campaign', 'LEVEL_KINDS', 'PLANS', 'SPECIMEN_ID', 'SPECIMEN_MAX',
           'TARGETS', 'load_campaign', 'parse_campaign']

#: the longest specimen id (it names a folder)
SPECIMEN_MAX = 64
#: what a specimen id may be: letters, digits, ``_ . -``, at most :data:`SPECIMEN_MAX`
SPECIMEN_ID = re.compile(rf'^[A-Za-z0-9][A-Za-z0-9_.-]{{0,{SPECIMEN_MAX - 1}}}$')

#: how a level S sets the cyclic step: max_load (peak S, valley R S), amplitude (mean +- S)
LEVEL_KINDS = ('max_load', 'amplitude')
PLANS = ('levels', 'pearl_string', 'staircase', 'adaptive')
#: a target: the load whose median life is `life`, or the median life at `load`
TARGETS = ('load_at_life', 'life_at_load')
#: the valid specimens before a target may end a campaign (ASTM E739's least for exploratory
#: data): a handful of lucky specimens can make an interval look narrow
MIN_SPECIMENS = 6
_BIG = 1.0e9
_S = Setting

CAMPAIGN_KEYS: tuple[Setting, ...] = (
    _S('name', '', 'campaign', meaning='what the campaign is called'),
    _S('procedure', '', '', meaning='the procedure file the specimens run (relative to the '
       'campaign file), its level set by `level`'),
    _S('template', '', {}, meaning='the procedure itself (a mapping), instead of `procedure`'),
    _S('level_step', '', '', meaning='the cyclic step the level sets (default: the '
       "procedure's first cyclic step)"),
    _S('level', '', {}, meaning='how a level S [N or m] sets that step: {kind: max_load, R} '
       '(peak S, valley R S) or {kind: amplitude, mean} (mean +- S)'),
    _S('run_out', '1', 1.0e7, 1.0, 1.0e12, 'a specimen unbroken after this many cycles is a '
       'run-out (its life right-censored)'),
    _S('plan', '', {}, meaning='which levels, in what order: {method, ...}, the method one of '
       'levels, pearl_string, staircase and adaptive (their keys below)'),
    _S('level_tolerance', '1', 0.02, 0.0, 0.5, 'a specimen whose achieved peak or valley '
       'is further than this fraction of the specified range from the specified one is '
       'invalid (its point would sit where it was not loaded)'),
    _S('target', '', {}, meaning='optional: what the campaign aims for, where it may stop: '
       '{kind: load_at_life, life, confidence, width} or {kind: life_at_load, load, '
       'confidence, width} (width: the half-width of the interval, a fraction), and '
       'min_specimens (default 6): the valid specimens before it may end the campaign'),
)
#: each plan's keys
PLAN_KEYS: dict[str, tuple[Setting, ...]] = {
    'levels': (_S('levels', 'N or m', [], meaning='the load levels'),
               _S('specimens', '1', 3, 1, 1000, 'specimens at each level')),
    'pearl_string': (_S('start', 'N or m', 0.0, 0.0, _BIG, 'the first level'),
                     _S('step', 'N or m', 0.0, 0.0, _BIG, 'each next level this much lower'),
                     _S('specimens', '1', 6, 2, 1000, 'specimens in all')),
    'staircase': (_S('start', 'N or m', 0.0, 0.0, _BIG, 'the first level'),
                  _S('step', 'N or m', 0.0, 0.0, _BIG, 'down after a failure, up after a '
                     'run-out'),
                  _S('specimens', '1', 15, 2, 1000, 'specimens in all')),
    'adaptive': (_S('low', 'N or m', 0.0, 0.0, _BIG, 'the lowest level it may choose'),
                 _S('high', 'N or m', 0.0, 0.0, _BIG, 'the highest'),
                 _S('specimens', '1', 12, 3, 1000, 'specimens in all')),
}


@dataclass(frozen=True)
class Campaign:
    """A checked campaign: its template and how levels become procedures."""

    name: str
    template: Mapping[str, Any]
    level_step: str
    level_kind: str
    level_value: float            #: R (max_load) or the mean (amplitude)
    run_out: float
    plan: Mapping[str, Any]
    target: Mapping[str, Any] | None
    source: str
    level_tolerance: float = 0.02

    @property
    def unit(self) -> str:
        """Return the levels' unit: N when the level's step is in force control, else m."""
        step = self.level_step_of(self.procedure(max(self.planned_levels())))
        return 'N' if step.control_mode == 'force' else 'm'

    def procedure(self, level: float, specimen: str = '') -> Procedure:
        """Return the procedure of one specimen at ``level`` (checked)."""
        return parse_procedure(self.procedure_doc(level, specimen),
                               f'{self.source} at level {level:g}')

    def level_step_of(self, procedure: Procedure):
        """Return the step of a rendered procedure that the level sets."""
        return next(s for s in procedure.steps if s.name == self.level_step)

    def procedure_doc(self, level: float, specimen: str = '') -> dict:
        """Return the procedure of one specimen at ``level`` as a procedure file's mapping."""
        doc = copy.deepcopy(dict(self.template))
        doc['name'] = f'{self.name}: {specimen or "specimen"} at {level:g}'
        doc['run_out'] = int(self.run_out)
        for step in doc['steps']:
            if step.get('name') == self.level_step:
                for k in ('peak', 'valley', 'mean', 'amplitude', 'blocks'):
                    step.pop(k, None)
                if self.level_kind == 'max_load':
                    step['peak'], step['valley'] = float(level), float(self.level_value * level)
                else:
                    step['mean'], step['amplitude'] = float(self.level_value), float(level)
        return doc

    def next_level(self, results: Sequence[tuple[float, bool]]) -> float | None:
        """
        Return the next specimen's level, or None when the plan is done.

        ``results``: each specimen so far, in order, as (level, failed). ``levels``: each
        level in turn, ``specimens`` at each; ``pearl_string``: one at each level from
        ``start`` down by ``step``; ``staircase``: ``start``, then a ``step`` down after a
        failure and up after a run-out. An ``adaptive`` plan chooses from the fit: refused
        here, named (:func:`ros_ehs.core.campaign.runner.judge` chooses it).
        """
        p, n = self.plan, len(results)
        m = p['method']
        if m == 'levels':
            per = int(p['specimens'])
            return float(p['levels'][n // per]) if n < per * len(p['levels']) else None
        if n >= int(p['specimens']):
            return None
        if m == 'pearl_string':
            return float(p['start'] - n * p['step'])
        if m == 'staircase':
            if not n:
                return float(p['start'])
            level, failed = results[-1]
            nxt = level - p['step'] if failed else level + p['step']
            return float(nxt) if nxt > 0 else float(level)
        raise InputError(f'{self.source}: an adaptive plan chooses its next level from the '
                         'fit so far: ask ros_ehs.core.campaign.runner.judge')

    def planned_levels(self) -> list[float]:
        """Return every level the plan can give (a staircase's and an adaptive plan's range)."""
        p = self.plan
        m = p['method']
        if m == 'levels':
            return [float(v) for v in p['levels']]
        if m == 'pearl_string':
            return [p['start'] - j * p['step'] for j in range(int(p['specimens']))]
        if m == 'staircase':
            n = int(p['specimens'])
            return [p['start'] + j * p['step'] for j in range(-n + 1, n)
                    if p['start'] + j * p['step'] > 0]
        return [p['low'], 0.5 * (p['low'] + p['high']), p['high']]


def _number(doc: Mapping, key: str, where: str, lo: float = 0.0, hi: float = math.inf,
            strict_lo: bool = True) -> float:
    v = doc.get(key)
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and \
        (v > lo if strict_lo else v >= lo) and v < hi
    if not ok:
        raise InputError(f'{where}: `{key}` = {v!r} must be a number '
                         f'{">" if strict_lo else ">="} {lo:g}' +
                         (f' and < {hi:g}' if math.isfinite(hi) else ''))
    return float(v)


def _plan(doc: Any, where: str) -> dict:
    doc = _mapping(doc, where)
    method = doc.get('method')
    if method not in PLANS:
        raise InputError(f'{where}: `method` = {method!r} must be one of {list(PLANS)}')
    keys = PLAN_KEYS[method]
    _unknown(doc, ['method'] + [s.name for s in keys], where)
    out: dict[str, Any] = {'method': method}
    for s in keys:
        if s.name not in doc and s.name not in ('specimens',):
            raise InputError(f'{where}: a {method} plan needs `{s.name}`')
        if s.name == 'levels':                    # a list: checked below
            out[s.name] = doc[s.name]
        else:
            out[s.name] = _check(s, doc[s.name], where) if s.name in doc else s.default
    if method == 'levels':
        lv = out['levels']
        if not isinstance(lv, list) or len(lv) < 2 or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and v > 0 for v in lv):
            raise InputError(f'{where}: `levels` = {lv!r} must be a list of two levels or '
                             'more, each > 0')
        if len(set(lv)) != len(lv):
            raise InputError(f'{where}: `levels` repeat: {lv!r}')
    for key in ('start', 'step', 'low', 'high'):
        if key in out and not out[key] > 0:
            raise InputError(f'{where}: `{key}` = {out[key]!r} must be > 0')
    if method == 'pearl_string' and not out['start'] - (out['specimens'] - 1) * out['step'] > 0:
        raise InputError(f'{where}: {out["specimens"]} levels from {out["start"]:g} down by '
                         f'{out["step"]:g} reach zero')
    if method == 'adaptive' and not out['low'] < out['high']:
        raise InputError(f'{where}: `low` = {out["low"]:g} must be below `high` = '
                         f'{out["high"]:g}')
    return out


def _target(doc: Any, where: str) -> dict | None:
    if doc in (None, {}):
        return None
    doc = _mapping(doc, where)
    kind = doc.get('kind')
    if kind not in TARGETS:
        raise InputError(f'{where}: `kind` = {kind!r} must be one of {list(TARGETS)}')
    at = 'life' if kind == 'load_at_life' else 'load'
    _unknown(doc, ['kind', at, 'confidence', 'width', 'min_specimens'], where)
    out = {'kind': kind, at: _number(doc, at, where),
           'confidence': _number(doc, 'confidence', where, 0.5, 1.0),
           'width': _number(doc, 'width', where, 0.0, 1.0), 'min_specimens': MIN_SPECIMENS}
    if 'min_specimens' in doc:
        v = doc['min_specimens']
        if not (isinstance(v, int) and not isinstance(v, bool) and 3 <= v <= 1000):
            raise InputError(f'{where}: `min_specimens` = {v!r} must be a whole number from 3 '
                             'to 1000')
        out['min_specimens'] = v
    return out


def parse_campaign(doc: Any, source: str = 'the campaign', base: Path | None = None
                   ) -> Campaign:
    """Check a whole campaign (a YAML document's mapping); return it, or raise naming why."""
    import yaml
    doc = _mapping(doc, source)
    _unknown(doc, [s.name for s in CAMPAIGN_KEYS], source)
    if ('procedure' in doc) == ('template' in doc):
        raise InputError(f'{source}: give the procedure of the specimens one way: `procedure` (a '
                         'file) or `template` (the mapping)')
    for key in ('level', 'plan'):
        if key not in doc:
            raise InputError(f'{source}: a campaign needs `{key}`')
    name = _check(CAMPAIGN_KEYS[0], doc.get('name', 'campaign'), source)
    if 'procedure' in doc:
        path = Path(str(doc['procedure']))
        if base is not None and not path.is_absolute():
            path = base / path
        try:
            template = yaml.safe_load(path.read_text())
        except OSError as err:
            raise InputError(f'{source}: `procedure`: cannot read {str(path)!r}: {err}') \
                from None
        except yaml.YAMLError as err:
            raise InputError(f'{source}: `procedure` {str(path)!r} is not YAML: {err}') \
                from None
        where = f'{source}: procedure {str(path)!r}'
    else:
        template, where = doc['template'], f'{source}: `template`'
    template = _mapping(template, where)
    steps = template.get('steps')
    if not isinstance(steps, list):
        raise InputError(f'{where}: `steps` must be a list of steps')
    cyclic = [s.get('name') for s in steps if isinstance(s, Mapping) and
              s.get('type') == 'cyclic']
    if not cyclic:
        raise InputError(f'{where}: no cyclic step for the level to set')
    level_step = doc.get('level_step') or cyclic[0]
    if level_step not in cyclic:
        raise InputError(f'{source}: `level_step` = {level_step!r} is not a cyclic step of the '
                         f'procedure (its cyclic steps: {cyclic}; a cyclic step needs a '
                         '`name` to be set)')
    lv = _mapping(doc['level'], f'{source}: `level`')
    kind = lv.get('kind')
    if kind not in LEVEL_KINDS:
        raise InputError(f'{source}: `level`: `kind` = {kind!r} must be one of '
                         f'{list(LEVEL_KINDS)}')
    if kind == 'max_load':
        _unknown(lv, ['kind', 'R'], f'{source}: `level`')
        value = _number(lv, 'R', f'{source}: `level`', -_BIG, 1.0, strict_lo=False)
    else:
        _unknown(lv, ['kind', 'mean'], f'{source}: `level`')
        v = lv.get('mean')
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)):
            raise InputError(f'{source}: `level`: `mean` = {v!r} must be a number')
        value = float(v)
    run_out = _check(CAMPAIGN_KEYS[5], doc.get('run_out', CAMPAIGN_KEYS[5].default), source)
    plan = _plan(doc['plan'], f'{source}: `plan`')
    target = _target(doc.get('target'), f'{source}: `target`')
    tol_key = next(s for s in CAMPAIGN_KEYS if s.name == 'level_tolerance')
    tol = _check(tol_key, doc.get('level_tolerance', tol_key.default), source)
    c = Campaign(name, template, level_step, kind, value, float(run_out), plan, target, source,
                 float(tol))
    for level in c.planned_levels():           # every level the plan can give, as a procedure
        c.procedure(level)
    return c


def load_campaign(path: str | Path) -> Campaign:
    """Read and check a campaign file (YAML); errors name the file and the key."""
    import yaml
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
    except OSError as err:
        raise InputError(f'cannot read the campaign {str(p)!r}: {err}') from None
    except yaml.YAMLError as err:
        raise InputError(f'campaign {str(p)!r} is not YAML: {err}') from None
    return parse_campaign(doc, f'campaign {str(p)!r}', p.parent)
