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
Cycle jumping: the specimen's jump equals its cycles one by one; counts stay exact.

A jumped virtual test is compared with the same test simulated period by period (the exact
run, the yardstick): its count, its detectors' trips and its fracture.
"""

import math

import numpy as np
import pytest
from ros_ehs.core.errors import InputError
from ros_ehs.core.model.specimen import Specimen
from ros_ehs.core.params import preset
from ros_ehs.core.procedure.detectors import EXTRAPOLATED
from ros_ehs.core.procedure.runner import JUMP_MARGIN, ProcedureRunner
from ros_ehs.core.procedure.spec import parse_procedure
from ros_ehs.core.sim.jumps import CycleJumps
from ros_ehs.core.sim.virtual_test import run_procedure

SP = {'k_L': 1.0e7, 'specimen_life': 5000.0, 'specimen_life_range': 9000.0}


def _half_cycles(sp: Specimen, n: int, lo: float, hi: float) -> None:
    """Carry n whole cycles of lo..hi through the specimen's reversal counting."""
    for _ in range(n):
        for f in np.linspace(lo, hi, 8)[1:]:
            sp.update(float(f))
        for f in np.linspace(hi, lo, 8)[1:]:
            sp.update(float(f))


@pytest.mark.parametrize('m', [3.0, 2.0, 4.0])
def test_a_jump_grows_the_crack_as_the_cycles_one_by_one(m):
    p = preset('fatigue_actuator', **SP, specimen_paris_m=m)
    one, jump = Specimen(p), Specimen(p)
    for sp in (one, jump):
        _half_cycles(sp, 3, 1000.0, 10000.0)       # under way: reversals found, crack grown
    _half_cycles(one, 400, 1000.0, 10000.0)
    jump.advance(400, 9000.0)
    assert jump.a == pytest.approx(one.a, rel=1e-9) and jump.cycles == one.cycles
    assert jump.cycles_left(9000.0) == pytest.approx(one.cycles_left(9000.0), rel=1e-9)


def test_cycles_left_is_where_the_crack_reaches_one_and_a_jump_never_fractures():
    sp = Specimen(preset('fatigue_actuator', **SP))
    left = sp.cycles_left(9000.0)
    assert left == pytest.approx(sp.cycles_to(1.0, 9000.0))      # from the initial crack
    assert sp.grown(left * 0.999, 9000.0) < 1.0 and sp.grown(left * 1.001, 9000.0) == 1.0
    with pytest.raises(InputError, match='would fracture the specimen'):
        sp.advance(int(left) + 1, 9000.0)
    assert sp.a == sp.a0 and not sp.broken
    below = Specimen(preset('fatigue_actuator', **SP, specimen_fatigue_limit=5000.0))
    assert below.grown(10 ** 9, 4000.0) == below.a0 and math.isinf(below.cycles_left(4000.0))


def _count_test(count: int) -> dict:
    return {'name': 'count', 'steps': [
        {'name': 'to mean', 'type': 'ramp', 'to': 0.002, 'rate': 0.01},
        {'name': 'cycles', 'type': 'cyclic', 'waveform': 'sine', 'mean': 0.002,
         'amplitude': 0.001, 'frequency': 10.0, 'count': count}]}


def test_the_runner_credits_a_jump_and_ends_its_step_that_much_sooner():
    r = ProcedureRunner(parse_procedure(_count_test(100)), latency=0.0)
    assert r.jump_room() == 0                              # not running
    with pytest.raises(InputError, match='0 may be jumped now'):
        r.jump(10)


def test_a_jumped_count_limited_step_counts_exactly_its_cycles():
    p = preset('table1_estimated')
    exact = run_procedure(parse_procedure(_count_test(400)), p)
    r = run_procedure(parse_procedure(_count_test(400)), p, jumps=CycleJumps())
    assert (r.result, r.total_cycles) == (exact.result, exact.total_cycles) == \
        ('completed', 400)
    assert r.jumped > 300 and r.sim_s < 0.3 * exact.sim_s
    t = r.cycles
    assert list(t[:, 0]) == list(range(1, 401))             # each count once, in order
    jumped = (t[:, 9].astype(int) & EXTRAPOLATED) != 0
    assert jumped.sum() == r.jumped and not jumped[-JUMP_MARGIN:].any()
    assert np.all(np.diff(t[:, 2]) > 0)                       # the rig's time runs on
    assert r.rig_s == pytest.approx(exact.sim_s, abs=0.2)


FATIGUE = {'name': 'coupon', 'control_mode': 'force', 'run_out': 10 ** 7, 'steps': [
    {'name': 'preload', 'type': 'ramp', 'to': 5500.0, 'rate': 2.0e4},
    {'name': 'settle', 'type': 'dwell', 'time': 0.2},
    {'name': 'fatigue', 'type': 'cyclic', 'waveform': 'sine', 'peak': 1.0e4, 'valley': 1.0e3,
     'frequency': 20.0,
     'end': [{'stiffness_drop': {'drop': 0.10}}, {'peak_valley_change': {'tolerance': 0.05}}]}]}


def test_a_jumped_fatigue_test_trips_and_fractures_where_the_exact_one_does():
    p = preset('fatigue_actuator', **SP)
    proc = parse_procedure(FATIGUE)
    exact = run_procedure(proc, p, keep_cycles=20000)
    r = run_procedure(proc, p, keep_cycles=20000, jumps=CycleJumps())
    assert r.result == exact.result == 'failed'
    assert r.jumped > 0.5 * r.total_cycles
    for kind, n in exact.tripped.items():
        assert abs(r.tripped[kind] - n) <= max(2, 0.005 * n), (kind, r.tripped, exact.tripped)
    assert abs(r.fractured_at - exact.fractured_at) <= max(2, 0.005 * exact.fractured_at)
    assert abs(r.total_cycles - exact.total_cycles) <= max(2, 0.005 * exact.total_cycles)


def test_a_run_out_is_reached_exactly_by_jumps():
    p = preset('fatigue_actuator', **SP, specimen_fatigue_limit=9500.0)   # never grows
    proc = parse_procedure({**FATIGUE, 'run_out': 20000})
    r = run_procedure(proc, p, jumps=CycleJumps())
    assert (r.result, r.total_cycles) == ('run_out', 20000)
    assert r.jumped > 19000 and r.rig_s > 20000 / 20.0


def test_bad_jump_settings_are_named():
    with pytest.raises(InputError, match='`stiffness` = 0'):
        CycleJumps(stiffness=0.0)
    with pytest.raises(InputError, match='`between` = 0'):
        CycleJumps(between=0)


def test_a_jumped_drive_step_fractures_where_the_exact_one_does(tmp_path):
    from ros_ehs.data.drive_files import save_drive
    t = np.arange(0, 501) * 1e-3                     # a 0.5 s pass: 5 cycles of varying range
    f = 5500.0 + 4500.0 * np.sin(2 * np.pi * 10.0 * t) * (0.8 + 0.2 * np.sin(2 * np.pi * 2 * t))
    save_drive(tmp_path / 'road.csv', t, f)
    doc = {'name': 'road', 'control_mode': 'force', 'steps': [
        {'name': 'preload', 'type': 'ramp', 'to': 5500.0, 'rate': 2.0e4},
        {'name': 'road', 'type': 'drive', 'file': str(tmp_path / 'road.csv'),
         'repeats': 10 ** 6}]}              # no detectors on a drive: the break ends it
    p = preset('fatigue_actuator', **{**SP, 'specimen_life': 1500.0})
    proc = parse_procedure(doc)
    exact = run_procedure(proc, p, keep_cycles=5000)
    r = run_procedure(proc, p, keep_cycles=5000, jumps=CycleJumps())
    assert r.result == exact.result == 'failed' and r.jumped > 0.2 * r.total_cycles
    # the fracture in the specimen's cycles, and the passes counted
    assert abs(r.fractured_at - exact.fractured_at) <= max(1, 0.005 * exact.fractured_at)
    assert abs(r.total_cycles - exact.total_cycles) <= max(1, 0.005 * exact.total_cycles)
