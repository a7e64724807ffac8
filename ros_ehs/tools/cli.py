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
``ehs_sim``: command-line entry to the core (no ROS needed).

``ehs_sim main`` runs the paper's test (1 Hz / 0.04 m sine, PID) on the full model with the
Table 1 estimated parameters and prints a summary.
"""

import argparse
import sys

import numpy as np

from ros_ehs.core.errors import EhsError
from ros_ehs.core.params import ESTIMATED


def _cmd_main(args) -> int:
    from ros_ehs.core.sim.closed_loop import run_closed_loop
    from ros_ehs.core.params import preset
    from ros_ehs.core.control.waveforms import Sine

    p = preset(args.preset, ff_enable=0.0)
    r = run_closed_loop(p, Sine(args.amplitude, args.frequency), args.duration, model=args.model)
    half = r.t >= min(1.0, args.duration / 2)
    e = (r.z_ref - r.z)[half]
    print(f'closed loop, {args.model} model, preset {args.preset}: sine {args.amplitude} m at '
          f'{args.frequency} Hz for {args.duration} s, PID {p["kp"]}/{p["ki"]}/{p["kd"]}')
    print(f'  rms error {np.sqrt(np.mean(e ** 2)) * 1e3:.3f} mm, peak error '
          f'{np.abs(e).max() * 1e3:.3f} mm, peak current {np.abs(r.i).max() * 1e3:.2f} mA')
    print(f'  chamber P {r.signal("p_CP").min() / 1e6:.2f}..{r.signal("p_CP").max() / 1e6:.2f}'
          f' MPa, peak speed {np.abs(r.z_dot).max():.3f} m/s')
    return 0


def _cmd_figures(args) -> int:
    from ros_ehs.core.sim.paper_runs import paper_runs, plot_runs

    runs = paper_runs(args.model, args.duration)
    for name, (_, m) in runs.items():
        print(f'{name:>16}: dead zone {m.deadzone_s * 1e3:5.1f} ms/half cycle, rms error '
              f'{m.rms_err_m * 1e3:6.3f} mm, lag {m.lag_s * 1e3:5.1f} ms')
    for path in plot_runs(runs, args.out, args.model):
        print(f'wrote {path}')
    return 0


def _cmd_params_doc(args) -> int:
    from pathlib import Path

    from ros_ehs.core.params import markdown_table
    Path(args.out).write_text(markdown_table() + '\n')
    print(f'wrote {args.out}')
    return 0


def _print_identification(result, files, held) -> None:
    from ros_ehs.core.identify.verdict import worst_noise_ratio
    print(f'identification ({result.model} model, {result.cost_kind.upper()}): '
          f'{result.message} after {result.iterations} iterations, {result.nfev} evaluations, '
          f'{result.wall_s:.1f} s')
    for n in result.free:
        v, se, v0 = result.x[n], result.stderr[n], result.x0[n]
        print(f'  {n:>7} = {v:12.6g} +- {se:9.3g}  (start {v0:g})')
    d = result.input_delay
    if d:
        how = (f'+- {d["stderr_s"] * 1e3:.3g} ms (estimated)' if d.get('estimated')
               else f'({d["why"]})' if 'why' in d else '(given)')
        print(f'  input delay = {d["value_s"] * 1e3:.4g} ms {how}')
    for name, sig in result.metrics.items():
        fits = [f'{k} R2 {m["r2"]:.5f} NRMSE {m["nrmse"]:.4f}' for k, m in sig.items()]
        print(f'  {name}: ' + ', '.join(fits))
    for w in result.warnings:
        print(f'  warning: {w}')
    if result.starts:
        print(f'  robustness: {result.starts["message"]}')
    if result.excitation:
        print(f'  excitation: {result.excitation["message"]}')
    if result.adequate:
        print('  verdict: adequate: the residuals are within '
              f'{worst_noise_ratio(result.metrics):.2f}x the sensor noise')
    else:
        print('  verdict: NOT ADEQUATE; do not trust these values:')
        for w in result.inadequacy:
            print(f'    - {w}')
        for a in result.advice:
            print(f'    advice: {a}')
    for k, p in files.items():
        print(f'wrote {p}')


def _topic_map(args):
    """Return the bags' topic map: --topics FILE (or the contract), then the options."""
    from ros_ehs.data.mapping import topic_map
    from ros_ehs.core.errors import InputError
    delay = args.input_delay
    if delay is not None and delay.strip().lower() != 'auto':
        try:
            delay = float(delay)
        except ValueError:
            raise InputError(f'--input-delay {args.input_delay!r}: give seconds or auto') \
                from None
    tmap = topic_map(args.topics, 'the command line', state=args.state_topic,
                     joint=args.joint, command=args.command_topic,
                     command_index=args.command_index, pressure_p=args.pressure_p,
                     pressure_t=args.pressure_t, input_delay=delay)
    return tmap.without_pressures() if args.no_pressures else tmap


def _cmd_identify(args) -> int:
    from ros_ehs.data.identification import run_identification

    def progress(e):
        print(f'  iteration {e["iteration"]:3d}  cost {e["cost"]:.6g}', flush=True)

    result, files, held = run_identification(
        args.bags, args.out, free=[f for f in args.free.split(',') if f], model=args.model,
        cost=args.cost, holdout=args.holdout or (), initial=args.initial,
        topics=_topic_map(args), workers=args.workers, figures=not args.no_figures,
        start=args.start, end=args.end,
        starts=args.starts, seed=args.seed, advise=not args.no_advice,
        progress=None if args.quiet else progress)
    _print_identification(result, files, held)
    return 0 if result.success and result.adequate else 1


def _cmd_drive(args) -> int:
    from ros_ehs.data.drive_files import InProcessPlayer, iterate, load_drive
    from ros_ehs.nodes.drive_bench import BenchPlayer
    from ros_ehs.core.params import PLANT_SPECS, preset
    t, z = load_drive(args.target)
    rig, ctrl = preset(args.plant), preset(args.controller).replace(**dict(args.set))
    if args.bench:
        rt = {'rt_priority': args.rt_priority} if args.rt_priority else {}
        play = BenchPlayer(args.out, mode=args.bench, domain_id=args.domain_id,
                           max_trips=args.max_trips,
                           plant={'model': args.model, **rt,
                                  **{s.name: rig[s.name] for s in PLANT_SPECS}},
                           controller={**rt, **ctrl})
    else:
        play = InProcessPlayer(rig, args.out, controller_params=ctrl, model=args.model)

    def progress(k, e):
        print(f'  iteration {k}: RMS error {e:.3f} %' if isinstance(k, int) else
              f'  {k} played again: {e}', flush=True)

    res = iterate(play, t, z, args.out, iterations=args.iterations, rms_target_pct=args.rms,
                  frf_bag=args.frf_bag, progress=progress)
    if args.bench:
        print('watchdog trips per run: ' + ', '.join(f'{k} {v}' for k, v in play.trips.items()))
    print(f"first pass {res['rms_err_pct'][0]:.3f} %, best {res['best_pct']:.3f} %; last "
          f"response/target within {res['band_db_max']:.3f} dB, {res['band_deg_max']:.2f} "
          f"deg; drive {res['drive']} (the reference node plays it: kind:=csv csv_path:=...)")
    return 0 if res['best_pct'] <= args.rms else 1


def _cmd_trend(args) -> int:
    from ros_ehs.data.trend import plot_trend, read_estimates, trend_table
    est = read_estimates(args.bag)
    print(trend_table(est))
    pushed = sum(e.pushed for e in est)
    print(f'{len(est)} refits, {sum(e.adequate for e in est)} adequate, {pushed} pushed')
    if args.out:
        print(f'wrote {plot_trend(est, args.out, sigmas=args.sigmas)}')
    return 0


def _cmd_record(args) -> int:
    from ros_ehs.core.params import preset
    from ros_ehs.core.control.waveforms import Sine
    from ros_ehs.data.synthetic_bag import record_synthetic_bag, SensorNoise

    noise = SensorNoise() if args.noise else SensorNoise(0.0, 0.0, 0.0)
    s = record_synthetic_bag(args.out, plant_params=preset(args.plant),
                             controller_params=preset(args.controller),
                             reference=Sine(args.amplitude, args.frequency),
                             duration=args.duration, model=args.model, noise=noise,
                             seed=args.seed)
    print(f'recorded {args.out}: {int(s["samples"])} samples, {args.model} plant '
          f'({args.plant}), rms tracking error {s["rms_error_m"] * 1e3:.3f} mm (synthetic)')
    return 0


def _name_value(text: str) -> tuple[str, float | str]:
    name, eq, value = text.partition('=')
    if not (eq and name):
        raise argparse.ArgumentTypeError(f'{text!r} is not NAME=VALUE')
    try:
        return name, float(value)
    except ValueError:
        return name, value


def main(argv=None) -> int:
    """Parse arguments and run; core errors become one clear line and exit code 2."""
    ap = argparse.ArgumentParser(prog='ehs_sim', description=__doc__.strip().splitlines()[0])
    sub = ap.add_subparsers(dest='cmd', required=True)
    m = sub.add_parser('main', help='the paper test in closed loop, summarised')
    m.add_argument('--model', choices=['full', 'reduced', 'simplified'], default='full')
    m.add_argument('--preset', default='table1_estimated')
    m.add_argument('--duration', type=float, default=3.0)
    m.add_argument('--amplitude', type=float, default=0.04)
    m.add_argument('--frequency', type=float, default=1.0)
    m.set_defaults(func=_cmd_main)
    f = sub.add_parser('figures', help="the paper's Figs. 5-7 as PNG, from simulation")
    f.add_argument('--out', default='out/figures')
    f.add_argument('--model', choices=['full', 'reduced', 'simplified'], default='simplified')
    f.add_argument('--duration', type=float, default=3.0)
    f.set_defaults(func=_cmd_figures)
    d = sub.add_parser('params-doc', help='write docs/parameters.md from the parameter table')
    d.add_argument('--out', default='docs/parameters.md')
    d.set_defaults(func=_cmd_params_doc)
    r = sub.add_parser('record', help='in-process bench run (plant + controller + sensor '
                       'noise) recorded to a rosbag2 MCAP bag: a synthetic experiment')
    r.add_argument('--out', required=True, help='bag directory to create')
    r.add_argument('--plant', default='table1_estimated', help='plant parameter preset')
    r.add_argument('--controller', default='table1_initial', help='controller preset')
    r.add_argument('--model', choices=['full', 'reduced', 'simplified'], default='simplified')
    r.add_argument('--duration', type=float, default=10.0)
    r.add_argument('--amplitude', type=float, default=0.04)
    r.add_argument('--frequency', type=float, default=1.0)
    r.add_argument('--seed', type=int, default=0)
    r.add_argument('--no-noise', dest='noise', action='store_false')
    r.set_defaults(func=_cmd_record)
    dv = sub.add_parser('drive', help='drive-file iteration, in process or on the bench: a drive '
                        'that makes the axis reproduce a target time history (each run a bag)')
    dv.add_argument('target', help='target CSV (header t,z; seconds, metres)')
    dv.add_argument('--out', default='out/drive', help='folder for the bags and drive files')
    dv.add_argument('--frf-bag', default=None, help='a recorded broadband run (reference and '
                    'state) to take the FRF from (default: play and record one)')
    dv.add_argument('--iterations', type=int, default=6)
    dv.add_argument('--rms', type=float, default=1.0, help='stop at this RMS error [%%]')
    dv.add_argument('--plant', default='table1_estimated', help='the rig: a parameter preset')
    dv.add_argument('--controller', default='table1_estimated', help='controller preset')
    dv.add_argument('--set', action='append', type=_name_value, default=[],
                    metavar='NAME=VALUE', help='a controller value over its preset, e.g. '
                    'dp_gain=1.5e-7 (delta-P stabilisation); repeat for more')
    dv.add_argument('--model', choices=['full', 'reduced', 'simplified'], default='full')
    dv.add_argument('--bench', choices=['lockstep', 'realtime'], default=None,
                    help="play each run on the bench's nodes over DDS (default: in process)")
    dv.add_argument('--rt-priority', type=int, default=0, help='--bench realtime: the plant '
                    "and controller's SCHED_FIFO priority (0: none; needs CAP_SYS_NICE)")
    dv.add_argument('--max-trips', type=int, default=2, help='--bench: a run whose plant '
                    'watchdog zeroed the valve more often is played again (twice at most)')
    dv.add_argument('--domain-id', type=int, default=None,
                    help="ROS_DOMAIN_ID of the bench runs (default: the environment's)")
    dv.set_defaults(func=_cmd_drive)
    i = sub.add_parser('identify', help="refit Table 1's parameters from bags (report folder)")
    i.add_argument('bags', nargs='+', help='bag directories (split or not, mcap or sqlite3) '
                   'or .mcap/.db3 files, fitted jointly')
    i.add_argument('--out', default='out/identification', help='report folder')
    i.add_argument('--free', default=','.join(ESTIMATED),
                   help='comma-separated free parameters')
    i.add_argument('--model', choices=['full', 'reduced', 'simplified'], default='simplified')
    i.add_argument('--cost', choices=['sae', 'sse'], default='sae')
    i.add_argument('--holdout', nargs='*', help='bags scored with the fitted parameters')
    i.add_argument('--initial', help='parameters YAML to start from (default Table 1 initial)')
    i.add_argument('--topics', metavar='RIG.yaml', help='where the signals are in the bags: '
                   "a rig's topic map (docs/identification.md, section: your rig's bag); the "
                   'options below override its entries')
    i.add_argument('--state-topic', default=None, help='sensor_msgs/JointState (default state)')
    i.add_argument('--joint', default=None, help="the axis's joint in the state (default "
                   'piston)')
    i.add_argument('--command-topic', default=None, help='JointState, Float64 or '
                   'Float64MultiArray (default servo_current)')
    i.add_argument('--command-index', type=int, default=None,
                   help="Float64MultiArray commands: this axis's element (default 0)")
    i.add_argument('--pressure-p', default=None, help='chamber P pressure topic (default '
                   'pressure/chamber_p)')
    i.add_argument('--pressure-t', default=None, help='chamber T pressure topic (default '
                   'pressure/chamber_t)')
    i.add_argument('--no-pressures', action='store_true', help='fit without pressures')
    i.add_argument('--input-delay', default=None, metavar='SECONDS|auto',
                   help='from a command to the valve acting on it; auto (the default) '
                   'estimates it where the bags record commands, not the applied current')
    i.add_argument('--start', type=float, default=None,
                   help="fit from this time on [s from each bag's first message]")
    i.add_argument('--end', type=float, default=None,
                   help="fit up to this time [s from each bag's first message]")
    i.add_argument('--starts', type=int, default=0,
                   help='also refit from this many seeded random starts and report how many '
                   'reach the same optimum')
    i.add_argument('--seed', type=int, default=0, help='seed of the random starts')
    i.add_argument('--no-advice', action='store_true',
                   help='skip the excitation advice (which parameters the bags do not pin '
                   'down, and the reference trajectory that would)')
    i.add_argument('--workers', type=int, default=None,
                   help='threads for the Jacobian columns (default: 2 on a machine with 2 '
                   'or more CPUs)')
    i.add_argument('--no-figures', action='store_true')
    i.add_argument('--quiet', action='store_true')
    i.set_defaults(func=_cmd_identify)
    tr = sub.add_parser('trend', help='the live estimates of a long run over time, from its bag '
                        '(topic parameter_estimates)')
    tr.add_argument('bag', help='the bag (directory, .mcap or .db3)')
    tr.add_argument('--out', default='', help='PNG of each parameter against time, with its band')
    tr.add_argument('--sigmas', type=float, default=3.0, help='band width in standard errors')
    tr.set_defaults(func=_cmd_trend)
    args = ap.parse_args(argv)
    try:
        return args.func(args)
    except EhsError as err:
        print(f'ehs_sim: error: {err}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
