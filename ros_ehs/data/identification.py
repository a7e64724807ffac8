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
"""One identification job, from bag paths to a report folder (the command and node)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence
import warnings

from ros_ehs.core.errors import IdentificationWarning, InputError
from ros_ehs.core.identify.delay import estimate_delay, with_delay
from ros_ehs.core.identify.design import identifiability, recommend
from ros_ehs.core.identify.estimator import (IdentificationResult, identify, judge,
                                             multistart, score)
from ros_ehs.core.identify.problem import SIGNALS
from ros_ehs.core.params import ESTIMATED, load_yaml, preset
from ros_ehs.data.experiments import load_experiments
from ros_ehs.data.mapping import topic_map_of, TopicMap
from ros_ehs.data.report import write_report
import ros_ehs_msgs_py as contract

__all__ = ['run_identification']


def _contract_commands(topics: TopicMap) -> bool:
    """Return True for the contract's commands: stamped with the state they answer."""
    return (topics.command.lstrip('/').split('/')[-1] == contract.COMMAND.name
            and topics.command_joint == contract.JOINT_VALVE)


def run_identification(bags: Sequence[str | os.PathLike], out: str | os.PathLike, *,
                       free: Sequence[str] = ESTIMATED, model: str = 'simplified',
                       cost: str = 'sae', signals: Sequence[str] = SIGNALS,
                       holdout: Sequence[str | os.PathLike] = (),
                       initial: str | os.PathLike | None = None,
                       state_topic: str = contract.STATE.name,
                       command_topic: str = contract.COMMAND.name,
                       pressure_topics: tuple[str, str] | None = (
                           contract.PRESSURE_P.name, contract.PRESSURE_T.name),
                       topics: TopicMap | None = None,
                       segment: float | None = 1.0, workers: int | None = None,
                       max_nfev: int = 100,
                       start: float | None = None, end: float | None = None,
                       starts: int = 0, seed: int = 0,
                       advise: bool = True, figures: bool = True,
                       progress: Callable[[dict], None] | None = None
                       ) -> tuple[IdentificationResult, dict[str, Path], dict]:
    """
    Load ``bags``, fit them jointly, score ``holdout`` bags and write the report to ``out``.

    ``initial``: a parameters YAML for the starting point (default Table 1's initial values).
    ``start``/``end``: fit only that window of each bag [s from its first message].
    ``starts``: also refit from that many seeded random starts and report how many reach the
    same optimum (``result.starts``, ``summary.json``).
    ``advise``: name the parameters the bags do not pin down and the excitation that would
    (:func:`ros_ehs.core.identify.design.recommend`; ``result.excitation``): an adequate fit only,
    since the standard errors of another mean little; 5-10 s when some parameter is weak.
    ``topics``: where the signals are in the bags (:class:`~ros_ehs.data.mapping.TopicMap`: a
    rig driver's topics, joint, message types, units); default the contract, named by
    ``state_topic``, ``command_topic`` and ``pressure_topics``. When the bags record
    commands, not the current the valve got, and the map gives no ``input_delay``, the fit
    estimates it (:mod:`ros_ehs.core.identify.delay`): a fit at no delay, the delay that best
    replays it, a warm refit there, and the delay again with its standard error
    (``result.input_delay``).
    Returns the result, the written files and the hold-out metrics.
    """
    if not bags:
        raise InputError('`bags`: give at least one bag to identify from')
    if topics is None:
        pp, pt = pressure_topics or (None, None)
        topics = TopicMap(state=state_topic, command=command_topic, pressure_p=pp,
                          pressure_t=pt)

    def load(b):
        return load_experiments(b, topics=topics, start=start, end=end)

    exps = [e for b in bags for e in load(b)]      # a bag with gaps gives several runs
    held = [e for b in holdout for e in load(b)]
    base = load_yaml(initial, preset('table1_initial')) if initial else preset('table1_initial')
    commanded = any(e.commands is not None for e in exps)
    kw = {'free': free, 'model': model, 'cost': cost, 'signals': signals,
          'segment': segment, 'workers': workers, 'max_nfev': max_nfev}
    estimate = commanded and topics.input_delay is None and not _contract_commands(topics)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)   # kept in result.warnings
        # a fit the delay's estimate refits is judged once, at the end
        result = identify(exps, base=base, progress=progress, verdict=not estimate, **kw)
        delay = {}
        if estimate:
            first = estimate_delay(exps, result.params or base, model=model,
                                   signals=signals, segment=segment, n_free=len(free))
            exps = with_delay(exps, first.value)
            result = identify(exps, base=base, x0=dict(result.x), progress=progress,
                              verdict=False, **kw)
            est = estimate_delay(exps, result.params or base, model=model, signals=signals,
                                 segment=segment, n_free=len(free),
                                 widening=result.stderr_widening)
            if abs(est.value - first.value) > 0.5 * est.stderr:
                exps = with_delay(exps, est.value)
                result = identify(exps, base=base, x0=dict(result.x), progress=progress,
                                  verdict=False, **kw)
            result = judge(result, exps, signals=signals, segment=segment, workers=workers,
                           max_nfev=max_nfev)
            delay = est.as_dict()
        elif commanded and topics.input_delay is None:    # the contract's own commands
            delay = {'value_s': 0.0, 'estimated': False,
                     'why': 'the contract: each command answers the state it is stamped with'}
        elif commanded:
            delay = {'value_s': float(topics.input_delay), 'estimated': False}
        result.input_delay = delay
        held = with_delay(held, delay['value_s']) if delay else held
    if starts:
        result.starts = multistart(exps, result, starts=starts, seed=seed, free=free,
                                   model=model, cost=cost, signals=signals, base=base,
                                   segment=segment, workers=workers, max_nfev=max_nfev)
    if advise and result.adequate and result.params is not None:
        result.excitation = recommend(result, exps, signals=signals, segment=segment)
    elif advise:
        result.excitation = {'identifiability': identifiability(result), 'recommended': None,
                             'message': 'no excitation advice: the fit is not adequate'}
    held_metrics = {}
    if held and result.params is not None:
        held_metrics = score(result.params, held, model=model, signals=signals,
                             segment=segment)
        result.metrics.update({f'held-out {k}': v for k, v in held_metrics.items()})
    files = write_report(result, exps, out, figures=figures)
    return result, files, held_metrics


def run_options(options: Mapping[str, Any], where: str = 'the options',
                progress: Callable[[dict], None] | None = None
                ) -> tuple[IdentificationResult, dict[str, Path], dict]:
    """
    Run :func:`run_identification` as the identify options say.

    ``options``: the values of :data:`ros_ehs.core.options.IDENTIFY` (the identify node's and
    ``ehs_sim identify``'s); ``where`` names them in errors.
    """
    o = options
    return run_identification(
        o['bags'], o['out'], free=o['free'], model=o['model'], cost=o['cost'],
        holdout=o['holdout'], initial=o['initial'] or None, topics=topic_map_of(o, where),
        workers=o['workers'] or None, max_nfev=int(o['max_nfev']), figures=bool(o['figures']),
        start=float(o['start']) or None, end=float(o['end']) or None,
        starts=int(o['starts']), seed=int(o['seed']), advise=bool(o['advise']),
        progress=progress)
