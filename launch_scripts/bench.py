#!/usr/bin/env python3
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
Start a bench: plant + controller + reference + recorder, each its own process.

    python launch_scripts/bench.py --duration 10 --out bags/my_run
    python launch_scripts/bench.py --mode lockstep --duration 10     # deterministic, fast
    python launch_scripts/bench.py --mode lockstep --duration 60 --no-cpu-affinity
    python launch_scripts/bench.py --mode lockstep --duration 600 --procedure test.yaml
    python launch_scripts/bench.py --mode lockstep --duration 600 --station 8080 \
        --plant-param real_time_factor=1      # a virtual rig at the rig's speed, to watch

``--procedure FILE`` runs a test (docs/procedures.md): the procedure node takes the
reference's place, starts at once (``--no-autostart``: wait for ``~/start``) and the bench
ends when the test has finished (or after ``--duration``); it then prints the test's events
and cycle count from the bag (``ehs_sim fatigue-report BAG`` writes the rest).

``--controller-param NAME=VALUE`` and ``--plant-param NAME=VALUE`` (repeatable) set one node's
parameters, e.g. the safety limits (docs/safety.md) or a plant fault to inject. After the run
the bench prints, read from the bag, what it holds, the safety events (topic ``events``) and,
with ``--live-identify``, the live refits (``parameter_estimates``).

It runs for ``--duration`` seconds (real time: wall seconds after the loop closes; lock-step:
sim seconds, as fast as DDS goes, or at most ``real_time_factor`` sim seconds per wall second)
or until Ctrl-C, then stops every child cleanly: the
recorder first (so the bag closes with the loop intact), then reference, plant, controller.
In real time the plant and the controller run on SCHED_FIFO 50 unless told otherwise
(``--rt-priority N``, 0: the default scheduler; lock-step takes it only when told; where the
process may not, the bench says so once and what that risks, and they run on), and the nodes
then get the Fast DDS profile ``fastdds_rt.xml`` beside this
script (unless ``FASTRTPS_DEFAULT_PROFILES_FILE`` names a profile other than the
package's): under SCHED_FIFO a node joining the network could block the plant's publish for
333 ms (docs/nodes.md).
The bag goes to ``--out`` (default ``bags/ehs_<UTC time>``), the node logs to
``out/logs/<bag name>/``. ``--params-file`` is passed to every node (a ``/**`` section
reaches them all, ``plant:`` only the plant). Exit code 0 when every node ran and stopped
cleanly, 1 otherwise (their logs say why).

With ``--machine-probe`` (real time), beside the nodes a probe runs on each CPU
(``ros_ehs.benchmarks.sleeper``: a 1 kHz sleep loop without ROS, at the same ``--rt-priority``),
a diagnostic for a machine you do not trust: the summary says how many of the plant's late
commands (over 3 periods old) fell in a stall of the machine that a probe saw in the same run
(a gap over 2 ms), and how many more in a shorter hiccup of the machine
(``ros_ehs.benchmarks.sleeper.hiccups``).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import signal
import sys
import time

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # a source checkout works too

from ros_ehs.benchmarks.sleeper import coincident, HICCUP_MS, hiccups, STALL_MS  # noqa: E402
from ros_ehs.benchmarks.sleeper import command as probe_command  # noqa: E402
from ros_ehs.core.errors import EhsError  # noqa: E402
from ros_ehs.core.options import NODE_OPTIONS, NODE_PARAMS  # noqa: E402
from ros_ehs.core.settings import parse_assignment  # noqa: E402
from ros_ehs.data.synthetic_bag import SensorNoise  # noqa: E402
from ros_ehs.nodes.fastdds_profile import ENV, PROFILE  # noqa: E402
from ros_ehs.nodes.processes import NodeProcesses, StartupError  # noqa: E402
from ros_ehs.nodes.recorder import default_bag_path  # noqa: E402
from ros_ehs.nodes.scheduling import (BENCH_PRIORITY, realtime_allowed,  # noqa: E402
                                      RISK, rtprio_limit, setpoint_priority)
import ros_ehs_msgs_py as contract  # noqa: E402

#: at most this many CPUs get a probe (one each); a larger machine gets none
PROBE_MAX_CPUS = 4
#: the Fast DDS profile a bench under SCHED_FIFO needs (see the file's comment)
RT_PROFILE = Path(__file__).resolve().with_name('fastdds_rt.xml')


def _start_probes(procs: NodeProcesses, rt_priority: int) -> list[str]:
    """Start one machine probe per CPU this process may use; return their names."""
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) > PROBE_MAX_CPUS:
        print(f'bench: no machine probes ({len(cpus)} CPUs, more than {PROBE_MAX_CPUS})')
        return []
    for cpu in cpus:
        procs.start(f'probe{cpu}', cmd=probe_command(cpu, HICCUP_MS, rt_priority))
    return [f'probe{cpu}' for cpu in cpus]


def _probe_lines(procs: NodeProcesses, probes: list[str], trip_log: list) -> None:
    """Print what the probes saw, and how many late commands fell in a stall they saw."""
    gaps, top = [], 0.0
    for name in probes:
        try:
            f = json.loads(procs[name].output().strip().splitlines()[-1])
        except (IndexError, ValueError):
            print(f'bench: machine probe {name} left no figures (see its log)', file=sys.stderr)
            return
        gaps += f['gaps']
        top = max(top, f['max_gap_ms'])
        for said in f.get('not_applied', []):
            print(f'bench: machine probe {name}: {said}', file=sys.stderr)
    # each late command's span without a fresh one, [t - age, t]: did a probe stall over 2 ms
    # in it (held a period or more: what makes a command late with a round trip of zero)?
    spans = [(t, age) for t, _, age, _ in trip_log]
    hit = coincident(spans, [(g[0], g[1]) for g in gaps if g[1] > STALL_MS])
    alone = sum(h for h, (*_, a) in zip(hit, trip_log) if a)
    # the rest, against the shorter hiccups the machine made (not threads queued on the CPU)
    hic = sum(h and not s for h, s in zip(coincident(spans, hiccups(gaps)), hit))
    print(f'bench: machine probes ({len(probes)}, a 1 kHz sleep loop without ROS on each CPU, '
          f'same priority, same run): {len(gaps)} gaps over {HICCUP_MS:g} ms, longest '
          f'{top:.2f} ms; {sum(hit)} of the {len(trip_log)} late commands fell in a gap over '
          f'{STALL_MS:g} ms ({alone} of them at late plant ticks alone), {hic} more in a '
          f'hiccup (a probe the machine woke {HICCUP_MS - 1:.1f} ms late or more)')


def _node_param(node: str):
    """Return the argparse type of ``--<node>-param NAME=VALUE``: checked against the node."""
    settings = NODE_OPTIONS[node] + NODE_PARAMS[node]

    def parse(text: str) -> tuple[str, object]:
        try:
            return parse_assignment(text, settings)
        except EhsError as err:
            raise argparse.ArgumentTypeError(str(err)) from None
    return parse


def _bag_lines(bag: Path, live: bool, error: str = '') -> None:
    """
    Print what the bag holds, read from the bag: topics, safety events, live refits.

    ``error``: why the recorder stopped recording (its status, or its exit), printed as one
    line with what stays readable.
    """
    from ros_ehs.data.bag import open_bag
    from ros_ehs.core.errors import BagError
    from ros_ehs.data.trend import trend_table

    def decoded(topic, convert):
        topic = '/' + topic.name
        return [convert(m) for _, m in b.decoded([topic])] if topic in b.topics else []
    try:
        b = open_bag(bag)
        events = decoded(contract.EVENTS, contract.event_from_msg)
        estimates = decoded(contract.ESTIMATES, contract.estimate_from_msg) if live else []
    except (BagError, ValueError) as err:
        print(f'bench: cannot read the bag {bag}: {err}', file=sys.stderr)
        return
    files = f'{len(b.files)} file' + ('s' if len(b.files) > 1 else '')
    counts = ', '.join(f'{t.name} {t.count}' for t in b.topics.values())
    if error:
        meta = ('metadata.yaml written for them' if (bag / 'metadata.yaml').is_file() else
                'no metadata.yaml (the files read without it)')
        print(f'bench: recorder error: {error}; {b.message_count} messages readable in {bag} '
              f'({files}); {meta}', file=sys.stderr)
    print(f'bench: bag {bag}: {b.message_count} messages in {files} ({counts})')
    print(f'bench: safety events: {len(events)}')
    for e in events:
        print(f'bench:   {(e.stamp_ns - b.start_ns) * 1e-9:9.3f} s  {e.kind} {e.detector} '
              f'({e.action}): {e.message}')
    if live:
        print(f'bench: live refits: {len(estimates)}')
        for line in trend_table(sorted(estimates, key=lambda e: e.stamp_ns)).splitlines():
            print('bench:   ' + line)


def _test_lines(bag: Path) -> None:
    """Print the test's events and cycle count, read from the bag."""
    from ros_ehs.core.errors import BagError
    from ros_ehs.data.fatigue import read_cycles, read_procedure_events
    try:
        events = read_procedure_events(bag)
        table = read_cycles(bag)
    except (BagError, ValueError) as err:
        print(f'bench: cannot read the test from the bag {bag}: {err}', file=sys.stderr)
        return
    print(f'bench: test: {len(table)} cycles recorded, {len(events)} events')
    for e in events:
        print(f"bench:   cycle {e['total_cycles']:>8}  {e['kind']}: {e['message']}")


def _campaign(a) -> int:
    """Run ``--campaign`` on the lock-step bench into ``--store``; write its report."""
    from ros_ehs.core.campaign.spec import load_campaign
    from ros_ehs.core.params import ALL_SPECS, preset
    from ros_ehs.data.campaign import campaign_hash, run_campaign
    from ros_ehs.data.campaign_report import write_campaign_report
    from ros_ehs.data.store import ResultStore
    from ros_ehs.nodes.campaign_bench import BenchCoupons
    try:
        c = load_campaign(a.campaign)
        rig = preset(a.preset).replace(**dict(parse_assignment(x, ALL_SPECS) for x in a.set))
    except EhsError as err:
        print(f'bench: {err}', file=sys.stderr)
        return 2
    out = Path(a.out) if a.out else Path('out') / 'campaigns' / c.name.replace(' ', '_')
    out.mkdir(parents=True, exist_ok=True)
    url = a.store or str(out / 'campaign.db')
    store = ResultStore(url)
    coupons = BenchCoupons(c, rig, out, seed=a.seed, model=a.model, domain_id=a.domain_id,
                           say=lambda line: print(line, flush=True))
    print(f"bench: campaign {c.name!r} ({c.plan['method']}, run-out {c.run_out:g}) on the "
          f'lock-step bench into {url}; coupons in {out}', flush=True)

    def test(nxt):
        print(f'bench: {nxt.specimen} at {nxt.level:g} ...', flush=True)
        return coupons(nxt)

    def progress(rec, verdict):
        print(f'bench: {rec.specimen} {rec.result}, {rec.cycles} cycles'
              + (f': {rec.reason}' if rec.result == 'invalid' else ''), flush=True)
    try:
        end = run_campaign(c, store, test, file_hash=campaign_hash(a.campaign),
                           progress=progress)
        report = write_campaign_report(store, out / 'report', c.name)
    finally:
        coupons.close()
        store.close()
    print(f'bench: {len(end.records)} specimens in the store ({end.tested} tested now): '
          f"{end.verdict.reason}; report {out / 'report' / 'report.html'} "
          f'({report.specimens} specimens)', flush=True)
    return 0


def main(argv=None) -> int:
    """Run the bench; see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument('--duration', type=float, default=10.0, help='seconds (0: until Ctrl-C)')
    ap.add_argument('--out', default=None, help='bag directory (default bags/ehs_<time>)')
    ap.add_argument('--mode', choices=('realtime', 'lockstep'), default='realtime')
    ap.add_argument('--model', choices=('simplified', 'reduced', 'full'), default='simplified')
    ap.add_argument('--reference', choices=('sine', 'step', 'chirp', 'csv'), default='sine')
    ap.add_argument('--no-noise', action='store_true',
                    help='publish exact states (default: 5 um, 1 mm/s, 0.2 bar sensor noise)')
    ap.add_argument('--params-file', default=None, help='ROS 2 parameters YAML for all nodes')
    ap.add_argument('--domain-id', type=int, default=None, help='ROS_DOMAIN_ID')
    ap.add_argument('--log-dir', default=None,
                    help="the nodes' logs and the plant's figures.json (default "
                         'out/logs/<bag name>)')
    ap.add_argument('--cpu-affinity', action=argparse.BooleanOptionalAction, default=None,
                    help='plant and controller on one CPU, the reference on another (their '
                    'cpu_affinity option; default: yes, on a machine with two CPUs or more): '
                    'the loop then skips the cross-core wake-up (docs/nodes.md, "CPU '
                    'placement")')
    ap.add_argument('--rt-priority', type=int, default=None,
                    help=f'SCHED_FIFO priority of the plant and controller (their rt_priority '
                    f'option; default {BENCH_PRIORITY} in real time, none in lock-step, where '
                    'nothing has a deadline; needs CAP_SYS_NICE or ulimit -r, else the bench '
                    'says so once and they run on at normal priority; the reference or '
                    'procedure node 10 under it, at most 40); the nodes then get '
                    'the Fast DDS profile fastdds_rt.xml beside this script; 0: the default '
                    'scheduler')
    ap.add_argument('--machine-probe', action=argparse.BooleanOptionalAction, default=False,
                    help='real time: also a 1 kHz sleep loop without ROS on each CPU beside the '
                    "nodes, to tell the machine's stalls from the loop's (a diagnostic for a "
                    'machine you do not trust; off by default)')
    ap.add_argument('--controller-param', type=_node_param('controller'), action='append',
                    default=[],
                    metavar='NAME=VALUE', help='a controller parameter (repeatable), e.g. '
                    'limit_position_max=0.03')
    ap.add_argument('--plant-param', type=_node_param('plant'), action='append', default=[],
                    metavar='NAME=VALUE', help='a plant parameter (repeatable), e.g. '
                    'fault=frozen_sensor')
    ap.add_argument('--procedure', default=None, metavar='FILE',
                    help='run a test: the procedure node (this file) instead of the reference')
    ap.add_argument('--autostart', action=argparse.BooleanOptionalAction, default=True,
                    help='--procedure: start the test at once (else call ~/start)')
    ap.add_argument('--live-identify', action='store_true',
                    help='also run the identify node in live mode: refit the last 10 s every '
                    '5 s and push significant fits to the controller; its estimates go into '
                    'the bag (ehs_sim trend BAG; docs/identification.md, "Live mode")')
    ap.add_argument('--station', type=int, default=None, metavar='PORT',
                    help="the operator's station beside the bench: the page on "
                         'http://HOST:PORT/ (docs/station.md; 0: a free port)')
    ap.add_argument('--station-host', default='127.0.0.1',
                    help="the station's address (another interface: read-only to other "
                         'machines without --station-token)')
    ap.add_argument('--station-token', default='',
                    help='the token a page from another machine must give to act')
    camp = ap.add_argument_group('a campaign on the lock-step bench (docs/campaigns.md)')
    camp.add_argument('--campaign', default=None, metavar='FILE',
                      help='run this campaign file specimen after specimen, each a virtual '
                      'coupon through the nodes (one lock-step bench a coupon) into --store; '
                      'run again after a crash: it goes on from the store')
    camp.add_argument('--store', default=None, metavar='URL',
                      help='--campaign: the results store (a SQLite file or a postgresql:// '
                      'URL; default <out>/campaign.db)')
    camp.add_argument('--seed', type=int, default=1, help="--campaign: the coupons' seed")
    camp.add_argument('--preset', default='table1_estimated',
                      help="--campaign: the rig model's parameter preset")
    camp.add_argument('--set', action='append', default=[], metavar='NAME=VALUE',
                      help='--campaign: a rig or coupon value over the preset (repeatable), '
                      'e.g. k_L=1e7 specimen_life=300')
    rec = ap.add_argument_group('recording: the recorder node options (docs/recording.md)')
    rec.add_argument('--max-bag-size', type=int, default=None,
                     help='split once a file holds this many bytes (0: never)')
    rec.add_argument('--max-bag-duration', type=float, default=None,
                     help='split once a file spans this many seconds (0: never; default 600)')
    rec.add_argument('--compression', choices=('zstd', 'lz4', 'none'), default=None,
                     help='MCAP chunk compression (default zstd)')
    rec.add_argument('--min-free-space', type=int, default=None,
                     help='bytes: refuse to start, and stop recording, below this')
    a = ap.parse_args(argv)
    if a.campaign:
        return _campaign(a)
    out = Path(a.out) if a.out else default_bag_path()
    if out.exists():
        print(f'bench: {out} exists; choose another --out', file=sys.stderr)
        return 2
    lock = a.mode == 'lockstep'
    logs = Path(a.log_dir) if a.log_dir else Path('out/logs') / out.name
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    pf = a.params_file
    env = {}
    if a.rt_priority is None:             # lock-step has no deadline to take priority for
        a.rt_priority = 0 if lock else BENCH_PRIORITY
    if a.rt_priority and not realtime_allowed(a.rt_priority):
        print(f'bench: SCHED_FIFO {a.rt_priority} is not allowed here (no CAP_SYS_NICE, '
              f'ulimit -r {rtprio_limit()}): {RISK}', file=sys.stderr, flush=True)
        a.rt_priority = 0
    # the real-time profile, unless a profile of the user's own is named (the package's
    # default one is not: the real-time profile holds its settings too)
    if a.rt_priority and os.environ.get(ENV, '') in ('', str(PROFILE)):
        env[ENV] = str(RT_PROFILE)
        print(f'bench: Fast DDS profile {RT_PROFILE} (shared-memory healthy check 30 ms)',
              flush=True)
    with NodeProcesses(a.domain_id, logs, env=env) as procs:
        if procs.shm_cleanup is not None and procs.shm_cleanup.removed:
            # left by processes that did not exit cleanly; reused, they carry the timeouts
            # of whoever created them (a 333 ms stall under SCHED_FIFO): ros_ehs.nodes.fastdds_shm
            print(f'bench: {procs.shm_cleanup.summary()}', flush=True)
        plant = {'model': a.model}
        loop = {'rt_priority': a.rt_priority} if a.rt_priority else {}
        plant.update(loop)
        if not a.no_noise:
            noise = SensorNoise()
            plant.update(noise_z=noise.z, noise_v=noise.v, noise_p=noise.p)
        if lock:
            plant['duration'] = float(a.duration)
        plant.update(a.plant_param)
        controller = {**loop, **dict(a.controller_param)}
        # the setpoint's source under the loop's priority, above the station and a browser
        setpoint = {'rt_priority': setpoint_priority(a.rt_priority)} if a.rt_priority else {}
        # in real time the reference runs at 250 Hz (the controller extrapolates it with its
        # velocity): a 1 kHz reference costs a quarter of a core for nothing
        recorder = {k: v for k, v in (('max_bag_size', a.max_bag_size),
                                      ('max_bag_duration', a.max_bag_duration),
                                      ('compression', a.compression),
                                      ('min_free_space', a.min_free_space)) if v is not None}
        probes = _start_probes(procs, a.rt_priority) if a.machine_probe and not lock else []
        try:
            procs.start_loop(a.mode, bag=out, plant=plant, controller=controller,
                             params_file=pf,
                             recorder=recorder, pin=a.cpu_affinity,
                             reference={'kind': a.reference,
                                        'rate_hz': 1000.0 if lock else 250.0, **setpoint},
                             procedure={'file': str(Path(a.procedure).resolve()),
                                        'autostart': a.autostart, **setpoint}
                             if a.procedure else None)
        except StartupError as err:
            print(f'bench: {err}', file=sys.stderr)
            return 1
        live = []
        if a.live_identify:
            ref_cpu = -1 if procs.placement is None else procs.placement[1]
            procs.start('identify', {'live': True, 'push': True, 'cpu_affinity': ref_cpu,
                                     'use_sim_time': lock}, params_file=pf)
            live = ['identify']
        if a.station is not None:
            ref_cpu = -1 if procs.placement is None else procs.placement[1]
            procs.start('station', {'port': a.station, 'host': a.station_host,
                                    'token': a.station_token, 'cpu_affinity': ref_cpu},
                        params_file=pf)
            live.append('station')
            ok = procs.wait_status(contract.STATION_STATUS, lambda st: 'url' in st.values, 30.0)
            st = procs.status(contract.STATION_STATUS)
            if not ok or st is None:
                print(f"bench: the station did not start (its log: {logs / 'station.log'})",
                      file=sys.stderr)
            else:
                url = st.values['url']
                pin = ('' if procs.placement is None else
                       f' (a browser on this machine: `taskset -c {procs.placement[1]} chromium '
                       f"{url}` keeps it off the loop's CPU; docs/station.md)")
                print(f'bench: station on {url}{pin}', flush=True)
        where = ('' if procs.placement is None else
                 '; plant and controller on CPU {}, reference on CPU {}'.format(
                     *procs.placement))
        print(f'bench: {a.mode} loop running ({a.model} model{where}); recording to {out}',
              flush=True)
        t0 = time.monotonic()
        while not stop and all(p.alive() for p in procs.procs.values()):
            done = procs.status(contract.PLANT_STATUS)
            if lock and done is not None and done.message == 'lock-step run complete':
                break
            test = procs.status(contract.PROCEDURE_STATUS) if a.procedure else None
            if test is not None and test.values.get('state') == 'finished':
                break
            if not lock and a.duration > 0 and time.monotonic() - t0 >= a.duration:
                break
            time.sleep(0.05)
        died = [n for n, p in procs.procs.items() if not p.alive()]
        print(f'bench: stopping after {time.monotonic() - t0:.1f} s', flush=True)
        # the recorder first (it drains while the writers still run), then the plant before
        # its controller: a plant outliving the controller would count every period until
        # its own exit as stale, with a watchdog trip (the summary's figures are the plant's)
        first = ['procedure'] if a.procedure else []      # its last records reach the bag
        order = [*first, 'recorder', *live, 'reference', 'plant', 'controller', *probes]
        codes = procs.stop([n for n in order if n in procs.procs])
        if codes.get('recorder', 0) != 0:
            # a recorder that stops on an error says why in its status before it exits (and
            # waits until readers have it); the watch's thread may not have taken it in yet
            procs.wait_status(contract.RECORDER_STATUS, lambda st: st.level == 2, 5.0)
        recorder = procs.status(contract.RECORDER_STATUS)
    error = ''
    if recorder is not None and recorder.level == 2:
        error = recorder.message
    elif codes.get('recorder', 0) != 0:
        error = f"it exited with code {codes['recorder']} (its log: {logs / 'recorder.log'})"
    _bag_lines(out, bool(live), error)
    if a.procedure:
        _test_lines(out)
    try:
        f = procs['plant'].figures()
        span = max(f['sim_time_s'], 1e-9)
        late = f['late_commands_late_tick']
        print(f"bench: late commands (over 3 periods) {f['late_commands']} in {span:.1f} s of "
              f"loop ({f['late_commands'] / span:.2f}/s): {f['late_commands'] - late} from a "
              f'late controller, {late} from late plant ticks alone; watchdog trips (the valve '
              f"zeroed) {f['watchdog_trips']}; fresh cycles "
              f"{f['fresh_cycle_fraction']:.4f}, longest period {f['period_max_ms']:.2f} ms")
        if probes:
            _probe_lines(procs, probes, f['late_log'])
    except (RuntimeError, KeyError, ValueError):
        print('bench: the plant left no figures (see its log)', file=sys.stderr)
    bad = {n: c for n, c in codes.items() if c != 0}
    if died or bad:
        print(f'bench: stopped early {died}, exit codes {codes}; logs in {logs}',
              file=sys.stderr)
        return 1
    print(f'bench: done; bag {out}, logs {logs}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
