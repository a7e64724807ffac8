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

from ros_ehs.errors import EhsError


def _cmd_main(args) -> int:
    from ros_ehs.closed_loop import run_closed_loop
    from ros_ehs.params import preset
    from ros_ehs.reference import Sine

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
    from ros_ehs.experiments import paper_runs, plot_runs

    runs = paper_runs(args.model, args.duration)
    for name, (_, m) in runs.items():
        print(f'{name:>16}: dead zone {m.deadzone_s * 1e3:5.1f} ms/half cycle, rms error '
              f'{m.rms_err_m * 1e3:6.3f} mm, lag {m.lag_s * 1e3:5.1f} ms')
    for path in plot_runs(runs, args.out, args.model):
        print(f'wrote {path}')
    return 0


def _cmd_params_doc(args) -> int:
    from pathlib import Path

    from ros_ehs.params import markdown_table
    Path(args.out).write_text(markdown_table() + '\n')
    print(f'wrote {args.out}')
    return 0


def main(argv=None) -> int:
    """Parse arguments and run; core errors become one clear line and exit code 2."""
    ap = argparse.ArgumentParser(prog='ehs_sim', description=__doc__.strip().splitlines()[0])
    sub = ap.add_subparsers(dest='cmd', required=True)
    m = sub.add_parser('main', help='the paper test in closed loop, summarised')
    m.add_argument('--model', choices=['full', 'simplified'], default='full')
    m.add_argument('--preset', default='table1_estimated')
    m.add_argument('--duration', type=float, default=3.0)
    m.add_argument('--amplitude', type=float, default=0.04)
    m.add_argument('--frequency', type=float, default=1.0)
    m.set_defaults(func=_cmd_main)
    f = sub.add_parser('figures', help="the paper's Figs. 5-7 as PNG, from simulation")
    f.add_argument('--out', default='out/figures')
    f.add_argument('--model', choices=['full', 'simplified'], default='simplified')
    f.add_argument('--duration', type=float, default=3.0)
    f.set_defaults(func=_cmd_figures)
    d = sub.add_parser('params-doc', help='write docs/parameters.md from the parameter table')
    d.add_argument('--out', default='docs/parameters.md')
    d.set_defaults(func=_cmd_params_doc)
    args = ap.parse_args(argv)
    try:
        return args.func(args)
    except EhsError as err:
        print(f'ehs_sim: error: {err}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
