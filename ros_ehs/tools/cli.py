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
import math
import sys
from typing import Sequence

import numpy as np
from ros_ehs.core.errors import EhsError, InputError
from ros_ehs.core.options import CLI_OPTIONS, CLI_POSITIONAL, CONTROLLER_SPECS
from ros_ehs.core.settings import parse_assignment, parse_value, Setting


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
    from ros_ehs.core.identify.verdict import why_adequate
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
        print(f'  verdict: adequate: {why_adequate(result.halves, result.jackknife)}')
    else:
        print('  verdict: NOT ADEQUATE; do not trust these values:')
        for w in result.inadequacy:
            print(f'    - {w}')
        for a in result.advice:
            print(f'    advice: {a}')
    for k, p in files.items():
        print(f'wrote {p}')


def _cmd_identify(args) -> int:
    from ros_ehs.data.identification import run_options

    def progress(e):
        print(f'  iteration {e["iteration"]:3d}  cost {e["cost"]:.6g}', flush=True)

    result, files, held = run_options(vars(args), 'the command line',
                                      progress=None if args.quiet else progress)
    _print_identification(result, files, held)
    return 0 if result.success and result.adequate else 1


def _cmd_drive(args) -> int:
    from ros_ehs.data.drive_files import InProcessPlayer, iterate, load_drive
    from ros_ehs.nodes.drive_bench import BenchPlayer
    from ros_ehs.core.params import PLANT_SPECS, preset
    t, z = load_drive(args.target)
    rig = preset(args.plant)
    ctrl = preset(args.controller).replace(**dict(parse_assignment(a, CONTROLLER_SPECS)
                                                  for a in args.set))
    if args.bench != 'none':
        rt = {'rt_priority': args.rt_priority} if args.rt_priority else {}
        play = BenchPlayer(args.out, mode=args.bench,
                           domain_id=None if args.domain_id < 0 else args.domain_id,
                           max_trips=args.max_trips,
                           plant={'model': args.model, **rt,
                                  **{s.name: rig[s.name] for s in PLANT_SPECS}},
                           controller={**rt, **ctrl})
    else:
        play = InProcessPlayer(rig, args.out, controller_params=ctrl, model=args.model)

    def progress(k, e):
        print(f'  iteration {k}: RMS error {e:.3f} %' if isinstance(k, int) else
              f'  {k} played again: {e}', flush=True)

    band = None
    if args.band == ['auto']:
        band = 'auto'
    elif args.band:
        try:
            band = tuple(float(x) for x in args.band)
        except ValueError:
            band = ()
        if len(band) != 2:
            raise InputError(f'--band: give F_LO F_HI [Hz] or auto, got {args.band}')
    res = iterate(play, t, z, args.out, iterations=args.iterations, rms_target_pct=args.rms,
                  frf_bag=args.frf_bag or None, progress=progress, band=band)
    for w in res['warnings']:
        print(f'warning: {w}')
    if args.bench != 'none':
        print('watchdog trips per run: ' + ', '.join(f'{k} {v}' for k, v in play.trips.items()))
    lo, hi = res['band_hz']
    print(f"first pass {res['rms_err_pct'][0]:.3f} %, best {res['best_pct']:.3f} % overall, "
          f"{res['band_rms_err_pct']:.3f} % in the FRF's band {lo:g}-{hi:g} Hz "
          f"({res['uncovered_pct']:.3g} % of the target outside what the FRF covers); last "
          f"response/target within {res['band_db_max']:.3f} dB, {res['band_deg_max']:.2f} "
          f"deg; drive {res['drive']} (the reference node plays it: kind:=csv csv_path:=...)")
    return 0 if res['best_pct'] <= args.rms else 1


def _cmd_tune(args) -> int:
    from ros_ehs.core.control.tuning import tune
    from ros_ehs.core.params import save_yaml
    from ros_ehs.core.sim.specimen_runs import square_wave

    p = _rig(args, CONTROLLER_SPECS)
    loops = ('displacement', 'force') if args.loop == 'both' else (args.loop,)
    if 'force' in loops and not p['k_L'] > 0:
        if args.loop == 'force':
            raise InputError('a force loop needs the specimen: set k_L (--set k_L=5e7, or a '
                             '--params file with the fitted k_L)')
        loops = ('displacement',)
        print('no specimen (k_L = 0): the displacement loop only')
    gains: dict[str, float] = {}
    worst = 0.0
    for loop in loops:
        step = args.step or (4.0e3 if loop == 'force' else 2.0e-3)
        unit = 'N' if loop == 'force' else 'm'
        r = tune(p, loop, bandwidth_hz=args.bandwidth, phase_margin_deg=args.phase_margin,
                 gain_margin_db=args.gain_margin, model=args.model, step=step)
        gains.update(r.values())
        print(f'{loop} loop ({args.model} model, k_L {p["k_L"]:g} N/m, steps of {step:g} '
              f'{unit}):')
        print('  gains: ' + ', '.join(f'{k} {v:.4g}' for k, v in r.values().items()))
        print(f'  predicted: crossover {r.crossover_hz:.3g} Hz, bandwidth {r.bandwidth_hz:.3g} '
              f'Hz, phase margin {r.phase_margin_deg:.1f} deg, gain margin '
              f'{r.gain_margin_db:.1f} dB')
        n = r.step.size
        marks = [k for k in (10, 20, 50, 100, 200, 500, 1000, 2000) if k < n]
        print(f'  predicted step: overshoot {r.overshoot_pct:.2f} %, settles (2 %) in '
              f'{r.settling_s * 1e3:.0f} ms; ' + ', '.join(
                  f'{k} ms {r.step[k]:.3f}' for k in marks))
        if r.note:
            print(f'  note: {r.note}')
        if args.check:
            period = 2 * max(0.5, 4 * r.settling_s)
            measured, _ = square_wave(p.replace(**r.values()), loop, step / 2, period=period,
                                      cycles=2)
            gap = abs(measured - r.overshoot_pct)
            worst = max(worst, gap if measured <= 10.0 else math.inf)
            print(f'  square wave +-{step / 2:g} {unit}, {period:g} s, full model: overshoot '
                  f'{measured:.2f} % ({gap:.2f} points from the prediction)')
    if args.out:
        path = save_yaml(args.out, gains, node_name='controller')
        print(f'wrote {path}')
    return 0 if worst <= 3.0 else 1


def _rig(args, settable=None):
    """Return the model of ``--preset``, ``--params`` and ``--set`` (of ``settable``)."""
    from ros_ehs.core.params import ALL_SPECS, load_yaml, preset
    p = preset(args.preset)
    if args.params:
        p = load_yaml(args.params, p)
    return p.replace(**dict(parse_assignment(a, settable or ALL_SPECS) for a in args.set))


def _cmd_procedure(args) -> int:
    from ros_ehs.core.procedure.spec import load_procedure
    from ros_ehs.core.sim.virtual_test import run_procedure

    proc = load_procedure(args.file)
    p = _rig(args)
    print(f'virtual test of {proc.name!r} ({len(proc.steps)} steps) on the {args.model} model '
          f'at {args.rate_hz:g} Hz, specimen k_L {p["k_L"]:g} N/m, life '
          f'{p["specimen_life"]:g} cycles at {p["specimen_life_range"]:g} N')

    def progress(sim_s: float, cycles: int, state: str) -> None:
        print(f'  ... {sim_s:.6g} s simulated, {cycles} cycles, {state}', file=sys.stderr,
              flush=True)
    from ros_ehs.core.sim.jumps import CycleJumps
    r = run_procedure(proc, p, model=args.model, rate_hz=args.rate_hz,
                      max_seconds=args.max_time, observe=args.observe, progress=progress,
                      jumps=None if args.exact else CycleJumps())
    for who, kind, what, message in ((e[0], e[1], e[2], e[-1]) for e in r.events):
        if kind in ('step', 'step_end', 'failure', 'detector', 'run_out', 'trip', 'mode',
                    'interrupted', 'finished'):
            print(f'  {who:10s} {kind:11s} {message}')
    jumped = (f' ({r.jumped} of them jumped: {r.rig_s:.6g} s on the rig, '
              f'{r.rig_speed:.1f}x)') if r.jumped else ''
    print(f'result: {r.result} ({r.reason}); {r.total_cycles} cycles, {r.sim_s:.6g} s '
          f'simulated in {r.wall_s:.3g} s ({r.speed:.1f}x real time){jumped}')
    for kind, n in sorted(r.tripped.items()):
        print(f'  {kind} would trip at cycle {n}')
    if proc.ends_on('fitted_stiffness_drop'):
        print('  fitted_stiffness_drop: not judged in a virtual test (it judges the live '
              "identification's fits on the rig)")
    if r.fractured_at is not None:
        print(f'  the specimen fractured at cycle {r.fractured_at:g}')
    if args.out:
        import numpy as np
        from ros_ehs.core.procedure.detectors import CYCLE_COLUMNS
        np.savetxt(args.out, r.cycles, delimiter=',', fmt='%.10g', comments='',
                   header=','.join(CYCLE_COLUMNS))
        print(f'wrote {args.out}')
    return 0


def _cmd_fatigue_report(args) -> int:
    from ros_ehs.data.fatigue import write_fatigue_report
    rep = write_fatigue_report(args.bags, args.out)
    print(f'{rep.cycles} cycles' + (f'; {rep.reason}' if rep.reason else '; no end recorded'))
    for kind, what, n, message in rep.failures:
        print(f'  {kind} {what} at cycle {n}: {message}')
    for f in rep.files:
        print(f'wrote {f}')
    return 0


def _cmd_campaign(args) -> int:
    from ros_ehs.core.campaign.spec import load_campaign
    from ros_ehs.data.campaign import campaign_hash, run_campaign, virtual_specimen
    from ros_ehs.data.store import ResultStore
    c = load_campaign(args.file)
    p = _rig(args)
    store = ResultStore(args.store)
    print(f"campaign {c.name!r} ({c.plan['method']}, run-out {c.run_out:g} cycles) into "
          f'{args.store}: virtual coupons on the {args.model} model, seed {args.seed}')

    def test(nxt):
        print(f'  {nxt.specimen} at {nxt.level:g} ...', end='', flush=True)
        return virtual_specimen(c, nxt, p, seed=args.seed, model=args.model,
                                rate_hz=args.rate_hz, exact=args.exact)

    def progress(rec, verdict):
        t = verdict.target
        print(f' {rec.result}, {rec.cycles} cycles ({rec.duration_s / 3600:.3g} rig h)'
              + (f'; target +-{t["width"]:.3g}' if t else '')
              + (f': {rec.reason}' if rec.result == 'invalid' else ''), flush=True)
    try:
        out = run_campaign(c, store, test, file_hash=campaign_hash(args.file),
                           max_specimens=args.max_specimens or None, progress=progress)
    finally:
        store.close()
    v = out.verdict
    print(f'{len(out.records)} specimens in the store ({out.tested} tested now): '
          + (v.reason if v.done else 'not ended (--max-specimens); next '
             f'{v.next_specimen.specimen} at {v.next_specimen.level:g}'))
    if v.fit is not None:
        print(f'  fit: log10 N = {v.fit.a:.4g} - {v.fit.k:.4g} log10 S, scatter '
              f'{v.fit.s:.3g} decades; slope interval {v.fit.k_interval[0]:.4g} .. '
              f'{v.fit.k_interval[1]:.4g}')
    return 0


def _cmd_campaign_rehearse(args) -> int:
    import json
    import os
    from ros_ehs.core.campaign.spec import load_campaign
    from ros_ehs.data.rehearsal import rehearse
    c = load_campaign(args.file)
    p = _rig(args)
    workers = 0 if args.in_process else (args.workers or os.cpu_count() or 1)
    where = ('in this process' if args.in_process else
             f'on the scheduler {args.scheduler}' if args.scheduler else
             f'on a local cluster of {workers} workers')
    print(f'rehearsing {c.name!r}: {args.replicates} replicates per plan ({args.plans}), '
          f'coupons by the {args.lives}, {where}', flush=True)

    def progress(done, total):
        bar = '#' * (30 * done // total)
        print(f'\r  [{bar:30s}] {done}/{total}', end='' if done < total else '\n',
              file=sys.stderr, flush=True)
    r = rehearse(c, p, args.replicates, seed=args.seed, lives=args.lives, plans=args.plans,
                 scheduler=args.scheduler or None, workers=None if args.scheduler else workers,
                 progress=progress)
    t = r.truth
    print(f"truth (the specimen law): slope {t['k']:g}, scatter {t['scatter']:g} decades"
          + (f", target {t['target']:.6g}" if 'target' in t else ''))
    print(f"{'plan':22s} {'rig h (p10/50/90)':>24s} {'run-outs':>9s} {'width p50/p90':>15s} "
          f"{'met':>5s} {'slope/target covered':>21s}")
    for name, s in r.plans.items():
        h, w, cov = s['rig_h'], s['target_width'], s['coverage']
        hs = f"{h['p10']:.3g}/{h['median']:.3g}/{h['p90']:.3g}" if h else '-'
        ws = f"{w['median']:.3g}/{w['p90']:.3g}" if w else '-'
        cs = '/'.join(f"{cov[q]['covered']:.2f}" if cov[q] else '-' for q in ('slope', 'target'))
        met = f"{s['target_met']:.2f}" if s['target_met'] is not None else '-'
        print(f"{name:22s} {hs:>24s} {s['run_out_fraction']:9.2f} {ws:>15s} {met:>5s} "
              f'{cs:>21s}')
    print(f'{r.wall_s:.3g} s on {r.workers or "no"} workers')
    if args.out:
        with open(args.out, 'w') as fh:
            json.dump({'truth': r.truth, 'plans': r.plans, 'replicates': r.replicates,
                       'workers': r.workers, 'wall_s': r.wall_s}, fh, indent=1, default=float)
        print(f'wrote {args.out}')
    return 0


def _cmd_campaign_report(args) -> int:
    from ros_ehs.data.campaign_report import write_campaign_report
    from ros_ehs.data.store import ResultStore
    store = ResultStore(args.store)
    try:
        rep = write_campaign_report(store, args.out, args.campaign, args.confidence)
    finally:
        store.close()
    print(f'{rep.campaign}: {rep.specimens} specimens ({rep.failed} failed, {rep.run_out} '
          f'run out, {rep.invalid} invalid)')
    for f in rep.files:
        print(f'wrote {f}')
    return 0


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
    if not args.out:
        raise InputError('ehs_sim record needs --out: the bag directory to create')
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


def _cli_type(s: Setting, item: bool = False):
    """Return the argparse ``type`` of setting ``s`` (one item of a list when ``item``)."""
    def convert(text: str):
        try:
            if item or s.kind in ('str', 'choice'):
                return text if item else s.check(text)
            return s.check(parse_value(text))
        except EhsError as err:
            raise argparse.ArgumentTypeError(str(err)) from None
    convert.__name__ = s.name
    return convert


def add_settings(parser: argparse.ArgumentParser, settings: Sequence[Setting],
                 positional: Sequence[str] = ()) -> None:
    """
    Add an option for each setting, derived from it: ``--name-with-dashes``, its type checked.

    A flag takes ``--name`` / ``--no-name``; a list takes several values or one
    comma-separated one (``--free d_c,F_cc``); ``positional`` settings take no flag.
    """
    for s in settings:
        helptext = s.describe().replace('%', '%%').replace('; *live*', '')
        if s.name in positional:
            if s.kind == 'list':
                parser.add_argument(s.name, nargs='+', type=_cli_type(s, True), help=helptext)
            else:
                parser.add_argument(s.name, type=_cli_type(s), help=helptext)
            continue
        flag = '--' + s.name.replace('_', '-')
        same = [f for f in s.flags if not f.startswith('--no-')]
        if s.kind == 'bool':
            parser.add_argument(flag, *same, dest=s.name, default=s.default, help=helptext,
                                action=argparse.BooleanOptionalAction)
            for f in s.flags:
                if f.startswith('--no-'):
                    parser.add_argument(f, dest=s.name, action='store_false',
                                        help=f'the same as --no-{s.name.replace("_", "-")}')
        elif s.kind == 'list':
            parser.add_argument(flag, *same, dest=s.name, nargs='+', action='extend',
                                type=_cli_type(s, True), default=None, metavar=s.name.upper(),
                                help=helptext)
        else:
            parser.add_argument(flag, *same, dest=s.name, type=_cli_type(s), default=s.default,
                                metavar=s.name.upper(), help=helptext)


def _lists(args: argparse.Namespace, settings: Sequence[Setting]) -> None:
    """Give every list option its default when absent, and split comma-separated values."""
    for s in settings:
        if s.kind == 'list' and s.name != 'set':
            v = getattr(args, s.name)
            v = list(s.default) if v is None else [x for a in v for x in a.split(',') if x]
            setattr(args, s.name, v)
        elif s.kind == 'list':
            setattr(args, s.name, getattr(args, s.name) or [])


#: each command: its handler and its help
COMMANDS = {
    'main': (_cmd_main, 'the paper test in closed loop, summarised'),
    'figures': (_cmd_figures, "the paper's Figs. 5-7 as PNG, from simulation"),
    'params-doc': (_cmd_params_doc, 'write docs/parameters.md from the parameter table'),
    'record': (_cmd_record, 'in-process bench run (plant + controller + sensor noise) '
               'recorded to a rosbag2 MCAP bag: a synthetic experiment'),
    'drive': (_cmd_drive, 'drive-file iteration, in process or on the bench: a drive that '
              'makes the axis reproduce a target time history (each run a bag)'),
    'identify': (_cmd_identify, "refit Table 1's parameters from bags (report folder)"),
    'tune': (_cmd_tune, 'displacement and force gains from a model and its specimen for a '
             'bandwidth and stability margins; predicted margins and step, checked with a '
             'square wave in process'),
    'procedure': (_cmd_procedure, 'a virtual test: a procedure file run in process on the '
                  'model faster than real time: its cycles, time, and when each failure '
                  'detector would trip'),
    'fatigue-report': (_cmd_fatigue_report, "a fatigue test's cycle table, captured cycles "
                       'and events from its bags as CSV, and plots'),
    'campaign': (_cmd_campaign, 'a fatigue campaign of virtual coupons, run in process into '
                 'its results store (docs/campaigns.md): each specimen, the fit, why it ended'),
    'campaign-rehearse': (_cmd_campaign_rehearse, 'a campaign rehearsed on the model: its '
                          'plan and the others at its specimen count, each drawn many times '
                          '(Dask: a local cluster or a scheduler), their rig hours, run-outs, '
                          "target widths and their intervals' coverage of the truth"),
    'campaign-report': (_cmd_campaign_report, "a campaign's report from its store: S-N plot, "
                        "specimens as CSV (also in pyLife's layout), the fit, one HTML page"),
    'trend': (_cmd_trend, 'the live estimates of a long run over time, from its bag (topic '
              'parameter_estimates)'),
}


def parser() -> argparse.ArgumentParser:
    """Return the ``ehs_sim`` parser, its options derived from the settings."""
    ap = argparse.ArgumentParser(prog='ehs_sim', description=__doc__.strip().splitlines()[0])
    sub = ap.add_subparsers(dest='cmd', required=True)
    for name, (func, helptext) in COMMANDS.items():
        p = sub.add_parser(name, help=helptext, description=helptext)
        add_settings(p, CLI_OPTIONS[name], CLI_POSITIONAL.get(name, ()))
        p.set_defaults(func=func)
    return ap


def main(argv=None) -> int:
    """Parse arguments and run; core errors become one clear line and exit code 2."""
    args = parser().parse_args(argv)
    _lists(args, CLI_OPTIONS[args.cmd])
    try:
        return args.func(args)
    except EhsError as err:
        print(f'ehs_sim: error: {err}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
