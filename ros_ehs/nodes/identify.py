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
The identify node: ``ros2 run ros_ehs identify --ros-args -p bags:=[bags/run1]``.

A thin wrapper over :func:`ros_ehs.identify.run.run_identification` (what ``ehs_sim identify``
runs): it reads the bags, refits the free parameters, logs each iteration and writes the
report folder ``out`` (``identified_params.yaml``, ``summary.json``, figures). With
``push: true`` it then sets the fitted values the controller declares (friction, damping and
valve values its feedforward uses) on the running controller ``controller`` through its
``set_parameters_atomically`` service, so the cross-checks (F_cc <= F_sc) see the whole set,
and logs what the controller accepted or why it refused. The node exits when done: 0 on
success, 1 if the fit or the push failed, 2 for bad input (missing bag, foreign topics...).
"""

from __future__ import annotations

import threading

from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.task import Future
from ros_ehs.bag.mapping import topic_map, TopicMap
from ros_ehs.control.feedforward import MODEL_PARAMS
from ros_ehs.errors import EhsError
from ros_ehs.identify.run import run_identification
from ros_ehs.nodes.ros_common import declare_options, Option, run
from ros_ehs.params import CONTROL_SPECS, ESTIMATED
import ros_ehs_msgs_py as contract

__all__ = ['OPTIONS', 'IdentifyNode', 'main', 'pushable']

OPTIONS = (
    Option('bags', [], 'bags to fit jointly (directories, split or not, or .mcap/.db3 files)'),
    Option('holdout', [], 'bags scored with the fitted values, not fitted'),
    Option('out', 'out/identification', 'report folder'),
    Option('free', list(ESTIMATED), 'parameters to fit (default the seven of Table 1)'),
    Option('model', 'simplified', 'model to fit: simplified (the paper), reduced (with the '
           "full model's valve dynamics: for a real rig) or full",
           choices=('simplified', 'reduced', 'full')),
    Option('cost', 'sae', 'sae (the paper) or sse', choices=('sae', 'sse')),
    Option('initial', '', 'parameters YAML for the start (default Table 1 initial values)'),
    Option('state_topic', contract.STATE.name, 'state topic in the bags'),
    Option('command_topic', contract.COMMAND.name, 'command topic in the bags'),
    Option('pressure_p_topic', contract.PRESSURE_P.name, 'chamber P pressure topic'),
    Option('pressure_t_topic', contract.PRESSURE_T.name, 'chamber T pressure topic'),
    Option('use_pressures', True, 'fit the chamber pressures when the bags have them'),
    Option('topic_map', '', "a rig's topic map (YAML: docs/identification.md); when given, "
           'the four topic options above are not used'),
    Option('joint', '', "the axis's joint in the state (default: the map's, or piston)"),
    Option('input_delay', -1.0, 'from a command to the valve acting on it [s]; -1: the map '
           'says, or estimated where the bags record commands (auto)', -1.0, 0.5),
    Option('max_nfev', 100, 'most model evaluations', 1, 100000),
    Option('starts', 0, 'also refit from this many seeded random starts and report how many '
           'reach the same optimum', 0, 1000),
    Option('seed', 0, 'seed of the random starts', 0, 2**31 - 1),
    Option('advise', True, 'name the parameters the bags do not pin down and the reference '
           'trajectory that would'),
    Option('start', 0.0, "fit from this time on [s from each bag's first message]", 0.0, 1e9),
    Option('end', 0.0, 'fit up to this time (0: to the end) [s from the first message '
           'of each bag]', 0.0, 1e9),
    Option('figures', True, 'write the PNG figures'),
    Option('push', False, 'set the fitted values on the running controller'),
    Option('controller', 'controller', 'name of the controller node to push to'),
    Option('push_timeout', 10.0, 'wait this long for the controller [s]', 0.1, 600.0),
)


def pushable(names) -> list[str]:
    """Return those of ``names`` that the controller node declares (in that order)."""
    declared = {s.name for s in CONTROL_SPECS} | set(MODEL_PARAMS)
    return [n for n in names if n in declared]


class IdentifyNode(Node):
    """Identification job as a node (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('identify', **kwargs)
        self.opt = declare_options(self, OPTIONS)
        if not self.opt['bags']:
            raise EhsError('parameter `bags` is empty: give the bags to fit '
                           '(-p bags:=[bags/sample_sine_1hz])')
        self.done = Future()
        self.result = None
        threading.Thread(target=self._job, daemon=True).start()

    def bag_topics(self) -> TopicMap:
        """Return where the signals are in the bags, from the options."""
        o = self.opt
        topics = {} if o['topic_map'] else {      # a map file replaces the topic options
            'state': o['state_topic'], 'command': o['command_topic'],
            'pressure_p': o['pressure_p_topic'], 'pressure_t': o['pressure_t_topic']}
        tmap = topic_map(o['topic_map'] or None, 'the options', joint=o['joint'] or None,
                         input_delay=o['input_delay'] if o['input_delay'] >= 0 else None,
                         **topics)
        return tmap if o['use_pressures'] else tmap.without_pressures()

    def _job(self) -> None:
        log = self.get_logger()
        o = self.opt
        try:
            result, files, _ = run_identification(
                o['bags'], o['out'], free=o['free'], model=o['model'], cost=o['cost'],
                holdout=o['holdout'], initial=o['initial'] or None,
                topics=self.bag_topics(),
                max_nfev=int(o['max_nfev']), figures=bool(o['figures']),
                start=float(o['start']) or None, end=float(o['end']) or None,
                starts=int(o['starts']), seed=int(o['seed']), advise=bool(o['advise']),
                progress=lambda e: log.info(f'iteration {e["iteration"]:3d}  '
                                            f'cost {e["cost"]:.6g}'))
        except EhsError as err:
            log.error(str(err))
            self.done.set_result(2)
            return
        self.result = result
        log.info(f'{result.message} after {result.iterations} iterations, {result.nfev} '
                 f'evaluations, {result.wall_s:.1f} s')
        for n in result.free:
            log.info(f'{n:>7} = {result.x[n]:.6g} +- {result.stderr[n]:.3g}')
        for w in result.warnings:
            log.warning(w)
        if result.starts:
            log.info(f'robustness: {result.starts["message"]}')
        if result.excitation:
            weak = result.excitation.get('recommended') is not None
            (log.warning if weak else log.info)(f'excitation: {result.excitation["message"]}')
        if result.adequate:
            log.info('verdict: adequate (the sensor noise explains the residuals)')
        else:
            log.error('verdict: NOT ADEQUATE: ' + '; '.join(result.inadequacy))
            for a in result.advice:
                log.warning(f'advice: {a}')
        log.info(f'wrote {o["out"]}: ' + ', '.join(sorted(p.name for p in files.values())))
        rc = 0 if result.success and result.adequate else 1
        if o['push'] and result.params is not None:
            rc = max(rc, self._push(result))
        self.done.set_result(rc)

    def _push(self, result) -> int:
        log = self.get_logger()
        names = pushable(result.free)
        if not names:
            log.warning('nothing to push: the controller declares none of the fitted values')
            return 0
        params = [Parameter(n, Parameter.Type.DOUBLE, float(result.params[n])) for n in names]
        client = AsyncParameterClient(self, self.opt['controller'])
        if not client.wait_for_services(timeout_sec=float(self.opt['push_timeout'])):
            log.error(f'push: no parameter services of `{self.opt["controller"]}` within '
                      f'{self.opt["push_timeout"]:g} s')
            return 1
        fut = client.set_parameters_atomically(params)
        ev = threading.Event()
        fut.add_done_callback(lambda f: ev.set())
        if not ev.wait(float(self.opt['push_timeout'])) or fut.result() is None:
            log.error('push: the controller did not answer')
            return 1
        res = fut.result().result
        if not res.successful:
            log.error(f'push refused by `{self.opt["controller"]}`: {res.reason}')
            return 1
        log.info(f'pushed to `{self.opt["controller"]}`: ' + ', '.join(
            f'{p.name}={p.value:.6g}' for p in params))
        return 0


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs identify``."""
    return run(IdentifyNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
