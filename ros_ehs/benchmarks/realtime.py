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
``python -m ros_ehs.benchmarks realtime``: what the nodes achieve in real time on this machine.

The tests check every rule deterministically (in process, and over DDS in lock-step, where a
run equals the in-process loop to 1e-9 m); what the machine's timing does to a run in real
time is measured here, each against a yardstick of the same run:

* ``apc``: the reference node's amplitude/phase control of a 4 mm, 10 Hz sine, on the bench
  in real time (plant and controller on SCHED_FIFO ``--rt-priority``): the complex error of
  the response's fundamental over the specified sine over the last 20 cycles, with APC and,
  as the yardstick, without (``err_apc``, ``err_pid``, their ``ratio``);
* ``rig``: the controller on a driver to ros2_control's conventions (driver and controller on
  SCHED_FIFO ``--rt-priority`` too, as controller_manager's update loop runs)
  (:mod:`ros_ehs.benchmarks.ros2_control_driver`, 500 Hz, its command written at its next
  cycle) and on our plant, the paper's sine: the tracking RMS of each against the same
  controller in process (a command a period late, and on arrival) at the same moments of the
  sine (what a run leaves out, after a watchdog trip, falls unevenly on the sine's phase),
  ``ratio_rig``, ``ratio_ours`` (1.0: the machine's timing cost nothing), and the states
  each counted (``counted_rig``, ``counted_ours``); our plant's piston over every state
  (``piston_ours``: :func:`ros_ehs.benchmarks.load.figures`, the worst error, the periods
  beyond 1 mm, the force's and the current's peaks).

The controllers' ``loop_timing`` only indicates here (``TIMING``): this benchmark measures
tracking, and a stall the plant's watchdog closed the valve in is left out (0.2 s
from the zeroing); what a stall does, held, is the ``load`` benchmark's. The indications are
counted (latched, a run says it once: ``loop_timing_rig``, ``loop_timing_ours``).

Last line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
import shutil
import sys
import tempfile

from domain_coordinator import domain_id
import numpy as np
from ros_ehs.benchmarks import BOUND, positive, report
from ros_ehs.benchmarks.load import piston, safety_events
from ros_ehs.core.control.waveforms import Sine
from ros_ehs.core.params import Params
from ros_ehs.core.sim.closed_loop import run_closed_loop
from ros_ehs.data.bag import open_bag, wait_for_counts
from ros_ehs.nodes.processes import NodeProcesses, recording, reference_started
import ros_ehs_msgs_py as contract

RATE = 500.0
#: the APC runs' sine [Hz]
APC_HZ = 10.0
#: what the tracking RMS leaves out of a run [s] (of a run shorter than twice that, its first
#: half), and the in-process yardstick's alike
SKIP = 2.0
#: the controllers' loop_timing: indicated, not acted on (the module docstring)
TIMING = {'loop_timing_action': 'indicate'}
#: the shortest run [s]: its first half still holds the ramp-on's second
SHORTEST = 2.0
#: the longest wait for a run's messages to reach its bag [s]
BAG_WAIT = 600.0
JOINT = 'actuator_z'


def fundamental(bag, frequency: float, cycles: int = 2) -> tuple[float, float]:
    """
    Return the measured position's amplitude [m] and phase [deg] at ``frequency``.

    Over the bag's last ``cycles``, against the reference's sine (time zero: its first sample).
    """
    b = open_bag(bag)
    states = sorted((s.stamp_ns, s.z) for s in
                    (contract.state_from_msg(m) for _, m in b.decoded(['/state'])))
    t0 = contract.reference_from_msg(next(b.decoded(['/reference']))[1]).stamp_ns
    t = np.array([(s - t0) * 1e-9 for s, _ in states])
    z = np.array([v for _, v in states])
    m = t >= t[-1] - cycles / frequency
    w = 2 * np.pi * frequency
    a, bb, _ = np.linalg.lstsq(np.column_stack([np.sin(w * t[m]), np.cos(w * t[m]),
                                                np.ones(m.sum())]), z[m], rcond=None)[0]
    return math.hypot(a, bb), math.degrees(math.atan2(bb, a))


def tracking(bag: Path, state: str, joint: str, skip: float = SKIP
             ) -> tuple[float, np.ndarray]:
    """
    RMS of z_ref - z [m] after ``skip`` s of the reference, and the moments it counted.

    A reference that went silent for more than the controller's reference_timeout (0.1 s) is
    held, then ramped back onto over ramp_time (1 s), by design: from the gap to a ramp_time
    after it is not tracking, and is left out. So is 0.2 s from a period our plant's watchdog
    zeroed the valve (the state's applied current exactly 0 A: a plant tick the machine made
    late). The moments are the counted states' times from the reference's first sample [s]:
    what is left out is not spread evenly over the sine's phase, whose error is not even
    either, so the yardstick is judged at the same moments (:func:`in_process`).
    """
    b = open_bag(bag)
    ref = sorted(contract.reference_from_cdr(m.data) for m in b.messages(['/reference']))
    tr = np.array([r.stamp_ns for r in ref])
    zr = np.array([r.z_ref for r in ref])
    vr = np.array([r.v_ref for r in ref])
    st = [contract.state_from_cdr(m.data, joint) for m in b.messages([state])]
    ts = np.array([s.stamp_ns for s in st])
    z = np.array([s.z for s in st])
    k = np.clip(np.searchsorted(tr, ts, side='right') - 1, 0, tr.size - 1)
    z_ref = zr[k] + vr[k] * (ts - tr[k]) * 1e-9      # the controller's first-order hold
    m = (ts > tr[0] + skip * 1e9) & (ts < ts[-1] - 0.2e9)
    for g in np.flatnonzero(np.diff(tr) > 0.1e9):
        m &= ~((ts > tr[g]) & (ts < tr[g + 1] + 1.0e9))
    for k in np.flatnonzero(np.array([s.i for s in st]) == 0.0):
        m &= ~((ts >= ts[k]) & (ts < ts[k] + 0.2e9))
    if not m.any():
        return math.nan, np.empty(0)
    return float(np.sqrt(np.mean((z_ref[m] - z[m]) ** 2))), (ts[m] - tr[0]) * 1e-9


def in_process(moments: np.ndarray, command_delay: int) -> float:
    """
    RMS of z_ref - z [m] of the paper's sine run in process, at ``moments`` of its time [s].

    The same controller and plant (simplified model) at :data:`RATE`, the sine's time zero
    its start (as the bag's is the reference's first sample); its error interpolated between
    periods. NaN when there are no moments.
    """
    if moments.size == 0:
        return math.nan
    r = run_closed_loop(Params(), Sine(0.04, 1.0), float(np.max(moments)) + 0.1,
                        model='simplified', dt=1.0 / RATE, supervised=True,
                        command_delay=command_delay)
    e = np.interp(moments, r.t, r.z_ref - r.z)
    return float(np.sqrt(np.mean(e ** 2)))


def apc(dom: int, tmp: str, seconds: float, rt: int) -> dict:
    """Measure the reference node's APC of a 4 mm, 10 Hz sine in real time, and without it."""
    a, f = 0.004, APC_HZ
    err = {}
    for corrected in (False, True):
        bag = Path(tmp) / f'apc_{corrected}'
        loop = {'rt_priority': rt} if rt else {}
        with NodeProcesses(dom, Path(tmp) / f'logs_apc_{corrected}', bound=BOUND) as procs:
            procs.start_loop('realtime', bag=bag, plant=loop, controller={**loop, **TIMING},
                             reference={'amplitude': a, 'frequency': f,
                                        'amplitude_phase_control': corrected})
            wait_for_counts(bag, {'/state': int(seconds * 1000)}, BAG_WAIT)
            procs.stop(['recorder', 'reference', 'controller', 'plant'])
        amp, phase = fundamental(bag, f, cycles=min(20, int(seconds * f / 2)))
        ratio = amp / a * complex(math.cos(math.radians(phase)), math.sin(math.radians(phase)))
        err[corrected] = abs(ratio - 1.0)
    return {'err_apc': round(err[True], 4), 'err_pid': round(err[False], 4),
            'ratio': round(err[True] / err[False], 3)}


def rig(dom: int, tmp: str, seconds: float, rt: int = 0) -> dict:
    """
    Measure the controller on a ros2_control driver and on our plant against in process.

    ``rt``: SCHED_FIFO priority of the controller and of the driver or our plant (0: none).
    """
    rig_bag, our_bag = Path(tmp) / 'rig', Path(tmp) / 'ours'
    loop = {'rt_priority': rt} if rt else {}
    with NodeProcesses(dom, Path(tmp) / 'logs_rig', bound=BOUND) as procs:
        procs.start('recorder', {'out': str(rig_bag), 'topics': [
            '/joint_states', '/servo_valve_controller/commands', '/reference', '/events']})
        procs.wait_status(contract.RECORDER_STATUS, lambda st: True, 120)
        procs.start('controller', {
            'rate_hz': RATE, 'state_topic': '/joint_states', 'joint': JOINT,
            'command_interface': 'forward_command',
            'command_topic': '/servo_valve_controller/commands', **loop, **TIMING})
        procs.start('driver', cmd=[sys.executable, '-m', 'ros_ehs.benchmarks.ros2_control_driver',
                                   '--rate', str(RATE), '--joint', JOINT,
                                   '--rt-priority', str(rt)])
        procs.wait_status(contract.RECORDER_STATUS, recording('/joint_states'), 120)
        procs.start('reference', {'wait_subscribers': 2})
        procs.wait_status(contract.REFERENCE_STATUS, reference_started, 120)
        wait_for_counts(rig_bag, {'/joint_states': int((seconds + 1) * RATE)}, BAG_WAIT)
        procs.stop(['recorder', 'reference', 'controller', 'driver'])
        figures = json.loads(procs['driver'].output().strip().splitlines()[-1])
    with NodeProcesses(dom, Path(tmp) / 'logs_ours', bound=BOUND) as procs:
        procs.start_loop('realtime', bag=our_bag, plant={'rate_hz': RATE, **loop},
                         controller={'rate_hz': RATE, **loop, **TIMING})
        wait_for_counts(our_bag, {'/state': int((seconds + 1) * RATE)}, BAG_WAIT)
        procs.stop(['recorder', 'reference', 'plant', 'controller'])
    skip = min(SKIP, seconds / 2)
    rms_rig, at_rig = tracking(rig_bag, '/joint_states', JOINT, skip)
    rms_ours, at_ours = tracking(our_bag, '/state', contract.JOINT_PISTON, skip)
    # the yardsticks at the moments each run counted: a command a period late (the driver's)
    # and on arrival (our plant's)
    pred = {1: in_process(at_rig, 1), 0: in_process(at_ours, 0)}
    return {'rms_rig_mm': round(rms_rig * 1e3, 4), 'rms_rig_in_process_mm': round(
        pred[1] * 1e3, 4), 'ratio_rig': round(rms_rig / pred[1], 3),
        'rms_ours_mm': round(rms_ours * 1e3, 4), 'rms_ours_in_process_mm': round(
            pred[0] * 1e3, 4), 'ratio_ours': round(rms_ours / pred[0], 3),
        'counted_rig': int(at_rig.size), 'counted_ours': int(at_ours.size),
        'driver_stale_cycles': figures['stale_cycles'], 'driver_cycles': figures['cycles'],
        'loop_timing_rig': _indicated(rig_bag), 'loop_timing_ours': _indicated(our_bag),
        # our plant's piston, every state after the ramp-on (load.figures), none left out
        'piston_ours': piston(our_bag)}


def _indicated(bag: Path) -> int:
    """Return how many times a bag's controller indicated ``loop_timing`` (its events)."""
    return sum(1 for e in safety_events(open_bag(bag))
               if e.kind == 'trip' and e.detector == 'loop_timing')


def main(argv=None) -> int:
    """Run the benchmark; print figures, the last line JSON."""
    ap = argparse.ArgumentParser(prog='python -m ros_ehs.benchmarks realtime',
                                 description=__doc__.strip().splitlines()[0])
    ap.add_argument('--seconds', type=positive, default=10.0,
                    help=f'each run [s], at least {SHORTEST:g}; the tracking RMS skips the '
                    f'first {SKIP:g} s of a run (of a run shorter than {2 * SKIP:g} s, its '
                    'first half)')
    ap.add_argument('--rt-priority', type=int, default=50,
                    help='SCHED_FIFO priority of the plant (or the driver) and the controller in '
                    'every run (0: the default scheduler)')
    a = ap.parse_args(argv)
    if a.seconds < SHORTEST:
        ap.error(f'argument --seconds: must be at least {SHORTEST:g} s (the tracking RMS '
                 'leaves out the ramp-on)')
    tmp = tempfile.mkdtemp(prefix='ehs_realtime_')
    with domain_id() as dom:
        try:
            fig = {'seconds': a.seconds,
                   'apc': apc(dom, tmp, a.seconds, a.rt_priority),
                   'rig': rig(dom, tmp, a.seconds, a.rt_priority)}
        except BaseException:
            # the bags and the nodes' logs stay for whoever reads the error
            print(f'python -m ros_ehs.benchmarks realtime: its bags and logs are kept in {tmp}',
                  file=sys.stderr)
            raise
    shutil.rmtree(tmp, ignore_errors=True)
    return report(fig)


if __name__ == '__main__':
    sys.exit(main())
