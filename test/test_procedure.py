"""
The procedure's rules without DDS: the file checked whole, the steps timed, the cycles counted.

Each rule of :mod:`ros_ehs.core.procedure` (spec, runner, detectors) and of the virtual test,
on the stamps passed in: a perfect axis (the state is the reference) where the rule is the
runner's, the model where it is the test's.
"""

import math
from pathlib import Path

import numpy as np
import pytest
from ros_ehs.core.errors import DataError, InputError
from ros_ehs.core.model.specimen import Specimen
from ros_ehs.core.params import preset
from ros_ehs.core.procedure.detectors import Cycle, FailureDetector, TAPERED
from ros_ehs.core.procedure.runner import capture_counts, ProcedureRunner
from ros_ehs.core.procedure.spec import load_procedure, parse_procedure
from ros_ehs.core.sim.virtual_test import model_trip_cycle, run_procedure
from ros_ehs.data.fatigue import write_fatigue_report

MS = 1_000_000
T0 = 10**9                     # the first stamp [ns]
K = 1.0e6                      # the perfect axis's specimen [N/m]


def proc(*steps, **top):
    """Return a checked procedure of ``steps`` (mappings) and ``top`` keys."""
    return parse_procedure({'name': top.pop('name', 't'), 'steps': list(steps), **top})


CYCLIC = {'name': 'cycles', 'type': 'cyclic', 'waveform': 'sine', 'mean': 0.002,
          'amplitude': 0.001, 'frequency': 10.0, 'count': 20, 'compensation': 'none'}


class PerfectAxis:
    """A state that is the reference: z in displacement, the load ``K z`` (and back in force)."""

    def __init__(self, runner, stamp=T0, z=0.0):
        self.r = runner
        self.stamp = stamp
        self.refs = []
        self.r.measure(stamp, z, K * z)

    def run(self, seconds=None, until=None, bound=10**6):
        for _ in range(bound if seconds is None else int(round(seconds * 1000))):
            self.stamp += MS
            ref = self.r.sample(self.stamp)
            self.refs.append(ref)
            z, f = self.carry(ref)
            self.r.measure(self.stamp, z, f)
            if until is not None and until(self.r):
                return
        if until is not None:
            raise AssertionError(f'not reached in {bound} periods: {self.r.status()}')

    def carry(self, ref):
        """Return the (z, load) the axis measures for reference ``ref``."""
        if math.isfinite(ref.z_ref):
            return ref.z_ref, K * ref.z_ref
        return ref.f_ref / K, ref.f_ref


def started(p, **kw):
    r = ProcedureRunner(p, latency=0.0, **kw)
    ax = PerfectAxis(r)
    ok, why = r.start(ax.stamp)
    assert ok, why
    return r, ax


def finished(r):
    return r.state == 'finished'


# -- the file ---------------------------------------------------------------------------------
@pytest.mark.parametrize('doc, words', [
    ({'steps': []}, ['steps', 'non-empty']),
    ({'steps': [{'name': 'a', 'to': 1.0}]}, ['step 1', 'type']),
    ({'steps': [{'name': 'up', 'type': 'ramp', 'to': 0.01}]}, ['step 1 (up)', 'rate']),
    ({'steps': [{'name': 'up', 'type': 'ramp', 'to': 0.01, 'rate': -1.0}]},
     ['step 1 (up)', 'rate']),
    ({'steps': [{'name': 'up', 'type': 'ramp', 'to': float('nan'), 'rate': 1.0}]},
     ['step 1 (up)', 'to']),
    ({'steps': [{'name': 'up', 'type': 'ramp', 'to': 5000.0, 'rate': 1.0}]},
     ['step 1 (up)', 'to', 'force']),
    ({'steps': [CYCLIC, {**CYCLIC, 'name': 'cyc2', 'frequncy': 5.0}]},
     ['step 2 (cyc2)', 'frequncy']),
    ({'steps': [{**CYCLIC, 'peak': 0.003}]}, ['step 1 (cycles)', 'one way']),
    ({'steps': [{**CYCLIC, 'end': [{'stiffness_drop': {'drop': 2.0}}]}]},
     ['step 1 (cycles) end 1', 'stiffness_drop', 'drop']),
    ({'steps': [{**CYCLIC, 'end': [{'crack': {}}]}]}, ['step 1 (cycles) end 1', 'crack']),
    ({'steps': [{'name': 'd', 'type': 'dwell', 'time': 1.0,
                 'end': [{'underpeak': {}}]}]}, ['step 1 (d)', 'cyclic']),
    ({'steps': [{**CYCLIC, 'count': 0}]}, ['never ends', 'run_out']),
    ({'steps': [CYCLIC, CYCLIC]}, ['names', 'cycles']),
    ({'run_out': -3, 'steps': [CYCLIC]}, ['run_out']),
    ({'steps': [{**CYCLIC, 'compensation_gain': 1.5}]},
     ['step 1 (cycles)', 'compensation_gain']),
    ({'steps': [{**CYCLIC, 'mean': None, 'amplitude': None,
                 'blocks': [[0.002, 0.003, 5]]}]}, ['step 1 (cycles)', 'block 1']),
])
def test_a_bad_procedure_is_refused_naming_the_step_and_the_key(doc, words):
    doc = dict(doc)
    doc['steps'] = [{k: v for k, v in s.items() if v is not None} for s in doc['steps']]
    with pytest.raises(InputError) as err:
        parse_procedure(doc)
    for w in words:
        assert w in str(err.value), (w, str(err.value))


def test_a_procedure_file_that_is_not_yaml_names_the_file(tmp_path):
    f = tmp_path / 'bad.yaml'
    f.write_text('steps: [ {name: a, type: ramp\n')
    with pytest.raises(InputError, match='bad.yaml.*not YAML'):
        load_procedure(f)
    with pytest.raises(InputError, match='cannot read'):
        load_procedure(tmp_path / 'missing.yaml')


def test_a_report_of_a_bag_without_a_procedure_says_so(tmp_path):
    bag = Path(__file__).parent / 'fixtures' / 'rosbag2' / 'talker.mcap'
    with pytest.raises(DataError, match='no cycle on /procedure/cycles'):
        write_fatigue_report(bag, tmp_path / 'report')


def test_capture_counts_are_log_spaced():
    kept = [n for n in range(1, 1001) if capture_counts(n)]
    assert kept == [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000]


# -- the runner ---------------------------------------------------------------------------------
def test_a_cyclic_step_counts_its_cycles_exactly_and_ends_at_its_count():
    p = proc({'name': 'up', 'type': 'ramp', 'to': 0.002, 'rate': 0.02}, CYCLIC)
    r, ax = started(p)
    ax.run(until=finished)
    assert r.result == 'completed' and r.counts == [0, 20] and r.total == 20
    cycles = r.cycles
    assert [c.count for c in cycles] == list(range(1, 21))
    # the ramp takes 0.1 s, the cycles 2 s: the last cycle ends exactly 2.1 s after the start
    assert cycles[-1].end_ns == T0 + 2100 * MS
    # the first 3 tapered in (flagged), within the levels, growing
    assert [c.flags for c in cycles] == [TAPERED] * 3 + [0] * 17
    assert all(0.001 <= c.z_lo < c.z_hi <= 0.003 for c in cycles[:3])
    assert cycles[0].z_hi < cycles[1].z_hi < cycles[2].z_hi
    for c in cycles[3:]:    # a perfect axis: the extremes are the sine's (sampled at 1 kHz)
        assert c.z_hi == pytest.approx(0.003, abs=1e-9) and c.z_lo == pytest.approx(
            0.001, abs=1e-9)
        assert c.stiffness == pytest.approx(K, rel=1e-9)
    # full cycles at 1, 2, 5, 10, 20, each of one period
    assert [cap['count'] for cap in r.captures] == [1, 2, 5, 10, 20]
    assert all(len(cap['t']) == 100 for cap in r.captures)
    # then to the stop level (0) at the ramp's rate, and held
    assert ax.refs[-1].z_ref == 0.0


def test_a_state_lost_at_a_cycles_start_does_not_uncount_the_cycle():
    """
    A real-time loop loses a state now and then (a late period, a dropped message).

    A lost state at a cycle boundary once left 4 of 400 applied cycles uncounted on a bench
    (the cycle's first state came 2 ms after its start, and the cycle counted as begun
    mid-way): a cycle is whole when the step ran from its start, whatever states came.
    """
    p = proc({'name': 'up', 'type': 'ramp', 'to': 0.002, 'rate': 0.02}, CYCLIC)
    r, ax = started(p)
    lost = {T0 + (100 + 100 * k) * MS + d * MS for k in range(1, 20, 3) for d in (0, 1, 2)}
    while r.state != 'finished':
        ax.stamp += MS
        ref = r.sample(ax.stamp)
        if ax.stamp not in lost:                # every third cycle starts without its states
            r.measure(ax.stamp, ref.z_ref, K * ref.z_ref)
        assert ax.stamp < T0 + 10**10
    assert r.result == 'completed' and r.counts == [0, 20] and r.total == 20
    assert [c.count for c in r.cycles] == list(range(1, 21))


def test_a_non_finite_reading_makes_that_cycles_extremes_nan_not_a_number():
    # a NaN position or an infinite load within a cycle: its record says unknown, not a peak
    p = proc({'name': 'up', 'type': 'ramp', 'to': 0.002, 'rate': 0.02}, CYCLIC)
    r, ax = started(p)
    bad_z, bad_f = T0 + 350 * MS, T0 + 560 * MS          # in cycles 3 and 5
    while r.state != 'finished':
        ax.stamp += MS
        ref = r.sample(ax.stamp)
        z = math.nan if ax.stamp == bad_z else ref.z_ref
        f = -math.inf if ax.stamp == bad_f else K * ref.z_ref
        r.measure(ax.stamp, z, f)
        assert ax.stamp < T0 + 10**10
    assert r.total == 20
    by = {c.count: c for c in r.cycles}
    assert math.isnan(by[3].z_hi) and math.isnan(by[3].z_lo) and math.isfinite(by[3].f_hi)
    assert math.isnan(by[5].f_hi) and math.isnan(by[5].f_lo) and math.isfinite(by[5].z_lo)
    assert by[4].z_hi == pytest.approx(0.003, abs=1e-9) and by[4].f_lo == pytest.approx(
        K * 0.001, rel=1e-6)
    assert all(math.isfinite(c.cmd_hi) and math.isfinite(c.cmd_lo) for c in r.cycles)


def test_block_loading_counts_each_blocks_cycles_at_its_levels():
    blocks = [[0.003, 0.001, 3], [0.004, 0.0, 2]]
    p = proc({'name': 'blocks', 'type': 'cyclic', 'waveform': 'triangle', 'blocks': blocks,
              'frequency': 5.0, 'count': 10, 'compensation': 'none'})
    r, ax = started(p)
    ax.run(until=finished)
    assert r.total == 10
    # the mean from 0 (the measured position), 3 cycles tapered in inside the first block's
    # levels; then 3 + 2 a pass, each at its block's peak; a block's first cycle starts
    # where the last one ended (its valley)
    order = ([blocks[0]] * 3 + [blocks[1]] * 2) * 2
    assert all(0.001 - 1e-9 <= c.z_lo and c.z_hi <= 0.003 + 1e-9 for c in r.cycles[:3])
    prev = blocks[0][1]
    for c, b in zip(r.cycles[3:], order[3:]):
        assert c.z_hi == pytest.approx(b[0], abs=1e-9), (c, b)
        assert min(b[1], prev) - 1e-9 <= c.z_lo <= b[1] + 1e-4, (c, b)
        prev = b[1]


def test_a_sweep_counts_its_turns_of_phase_and_ends_at_its_duration():
    p = proc({'name': 'sweep', 'type': 'sweep', 'mean': 0.0, 'amplitude': 0.001, 'f0': 2.0,
              'f1': 10.0, 'duration': 2.0, 'compensation': 'none'})
    r, ax = started(p)
    ax.run(until=finished)
    # phase 2 pi (f0 t + (f1 - f0) t^2 / (2 T)): 2 * 2 + 8 * 2 / 2 = 12 turns in 2 s
    assert r.total == 12 and r.result == 'completed'
    assert r.cycles[-1].end_ns == T0 + 2000 * MS


def test_a_drive_step_plays_its_file_as_many_times_as_asked(tmp_path):
    from ros_ehs.data.drive_files import save_drive
    t = np.arange(0, 501) * 1e-3                     # 0.5 s a pass
    save_drive(tmp_path / 'road.csv', t, 0.002 * np.sin(2 * np.pi * 4.0 * t) ** 2)
    p = proc({'name': 'road', 'type': 'drive', 'file': str(tmp_path / 'road.csv'),
              'repeats': 3})
    r, ax = started(p)
    ax.run(until=finished)
    assert r.total == 3 and r.result == 'completed'
    assert max(c.z_hi for c in r.cycles) == pytest.approx(0.002, rel=1e-3)


def test_the_reference_is_continuous_through_every_step():
    p = proc({'name': 'up', 'type': 'ramp', 'to': 0.002, 'rate': 0.01},
             {'name': 'wait', 'type': 'dwell', 'time': 0.3}, CYCLIC)
    r, ax = started(p)
    ax.run(until=finished)
    z = np.array([ref.z_ref for ref in ax.refs])
    # 10 mm/s ramps and a 1 mm, 10 Hz sine: at most 63 um a period
    assert np.max(np.abs(np.diff(z))) < 2 * math.pi * 10 * 0.001 * 1e-3 * 1.01
    assert [e[0] for e in r.events if e[0] in ('step', 'step_end')] == \
        ['step', 'step_end', 'step', 'step_end', 'step', 'step_end']


def test_hold_freezes_the_command_and_resume_goes_on_at_the_same_count():
    p = proc({**CYCLIC, 'count': 30})
    r, ax = started(p)
    ax.run(until=lambda r: r.total == 12)
    ax.run(0.035)                      # a third of cycle 13
    ok, why = r.hold(ax.stamp)
    assert ok and r.state == 'held', why
    n = len(ax.refs)
    ax.run(0.5)
    held = {ref.z_ref for ref in ax.refs[n:]}
    assert len(held) == 1 and r.total == 12          # frozen; the cut cycle is not counted
    assert not r.hold(ax.stamp)[0]                   # nothing runs to hold
    ok, why = r.resume(ax.stamp)
    assert ok and 'cycle 12' in why, why
    m = len(ax.refs)
    ax.run(until=finished)
    z = np.array([ref.z_ref for ref in ax.refs[m - 1:]])
    assert np.max(np.abs(np.diff(z))) < 1e-4        # the lead-in: no jump
    assert r.result == 'completed' and r.total == 30 and r.counts == [30]
    assert [c.count for c in r.cycles] == list(range(1, 31))


def test_an_acting_interlock_interrupts_and_a_warning_does_not():
    p = proc(CYCLIC)
    r, ax = started(p)
    ax.run(0.25)
    r.event('trip', 'limit_position_max', 'warn', ax.stamp)
    assert r.state == 'running'
    r.event('trip', 'limit_position_max', 'hold', ax.stamp)
    assert r.state == 'interrupted' and 'limit_position_max' in r.reason + r.events[-1][3]
    assert r.resume(ax.stamp)[0]
    ax.run(until=finished)
    assert r.total == 20 and r.result == 'completed'


def test_a_specimen_break_fails_the_test_and_ramps_to_the_stop_level():
    p = proc({**CYCLIC, 'count': 0}, run_out=100, stop_level=0.0005)
    r, ax = started(p)
    ax.run(until=lambda r: r.total == 7)
    r.event('trip', 'specimen_break', 'hold', ax.stamp)
    assert r.result == 'failed' and r.failed_at == 7 and r.state == 'stopping'
    ax.run(until=finished)
    assert r.total == 7 and ax.refs[-1].z_ref == 0.0005
    assert r.status()['failed_at'] == 7


def test_the_controllers_own_switch_to_displacement_holds_the_axis_there():
    p = proc({**CYCLIC, 'count': 0, 'mean': 5000.0, 'amplitude': 4000.0,
              'control_mode': 'force'}, run_out=100, control_mode='force')
    r, ax = started(p)
    ax.run(until=lambda r: r.total == 3)
    r.event('trip', 'specimen_break', 'hold', ax.stamp)     # the stop ramp in N begins
    r.event('mode', 'displacement', 'hold', ax.stamp)      # and the controller left force
    ax.run(until=finished)
    ax.run(0.2)
    assert r.mode == 'displacement' and r.result == 'failed'
    z = ax.refs[-1].z_ref
    assert math.isfinite(z) and all(ref.z_ref == z for ref in ax.refs[-50:])


def test_the_run_out_ends_the_test_at_its_count():
    p = proc({**CYCLIC, 'count': 0, 'end': [{'stiffness_drop': {'drop': 0.1}}]}, run_out=25)
    r, ax = started(p)
    ax.run(until=finished)
    assert r.result == 'run_out' and r.total == 25 and 'tripped' not in r.reason


def test_a_time_end_condition_ends_the_step_and_a_level_crossing_too():
    p = proc({**CYCLIC, 'count': 0, 'end': [{'time': 0.55}], 'mean_rate': 0.1},
             {'name': 'away', 'type': 'ramp', 'to': 0.01, 'rate': 0.01,
              'end': [{'level': {'signal': 'position', 'above': 0.004}}]})
    r, ax = started(p)
    ax.run(until=finished)
    assert r.counts[0] == 5 and r.result == 'completed'
    ends = [e for e in r.events if e[0] == 'step_end']
    assert 'time 0.55' in ends[0][3] and 'crossed' in ends[1][3]
    assert max(ref.z_ref for ref in ax.refs) < 0.0041


def test_a_checkpoint_restores_the_counts_and_the_bag_adds_what_came_after_it():
    p = proc({**CYCLIC, 'count': 50, 'end': [{'stiffness_drop': {'settling': 2,
                                                                 'reference': 3}}]})
    r, ax = started(p)
    ax.run(until=lambda r: r.total == 17)
    cp = r.checkpoint()
    assert cp['counts'] == [17] and cp['detectors']['0'][0]['reference'] is not None
    ax.run(until=lambda r: r.total == 19)            # two cycles after it, in the bag only
    again = ProcedureRunner(p, latency=0.0)
    msg = again.restore(cp, recovered_total=19)
    assert again.state == 'interrupted' and again.total == 19 and '2 of them' in msg
    ax2 = PerfectAxis(again, ax.stamp + 5000 * MS, z=0.0025)
    assert again.resume(ax2.stamp)[0]
    ax2.run(until=finished)
    assert again.total == 50 and [c.count for c in again.cycles] == list(range(20, 51))
    assert again._detectors[0][0].reference == cp['detectors']['0'][0]['reference']
    with pytest.raises(InputError, match='not this procedure'):
        ProcedureRunner(proc(CYCLIC, name='other'), latency=0.0).restore(cp)


def test_a_restored_force_test_holds_the_load_it_first_measured_not_where_it_creeps():
    p = proc({**CYCLIC, 'count': 50, 'mean': 5000.0, 'amplitude': 4000.0,
              'control_mode': 'force'}, control_mode='force')
    r, ax = started(p)
    ax.run(until=lambda r: r.total == 3)
    again = ProcedureRunner(p, latency=0.0)
    again.restore(r.checkpoint())
    t = ax.stamp + MS
    again.measure(t, 5e-4, 7000.0)
    assert again.sample(t).f_ref == 7000.0
    again.measure(t + MS, 5.1e-4, 7300.0)       # the load creeps: the hold does not follow it
    assert again.sample(t + MS).f_ref == 7000.0 and again.sample(t + 9 * MS).f_ref == 7000.0


def test_an_interlock_during_the_final_stop_ends_the_test_interrupted_never_completed():
    r, ax = started(proc({**CYCLIC, 'count': 3}))
    ax.run(until=lambda r: r.state == 'stopping')
    assert r.result == 'completed' and r.total == 3
    r.event('trip', 'feedback', 'power_off', ax.stamp)
    assert r.state == 'finished' and r.result == 'interrupted' and r.total == 3
    assert 'feedback (power_off) during the stop' in r.reason
    assert any(e[0] == 'interlock' and e[1] == 'feedback' for e in r.events)
    # a failed test stays failed: the interlock joins its reason
    r, ax = started(proc({**CYCLIC, 'count': 50}))
    ax.run(until=lambda r: r.total == 2)
    r.event('trip', 'specimen_break', 'hold', ax.stamp)
    assert r.state == 'stopping' and r.result == 'failed'
    r.event('trip', 'hold_error', 'power_off', ax.stamp + MS)
    assert r.state == 'finished' and r.result == 'failed' and 'hold_error' in r.reason
    # an indicate-only trip changes nothing
    r, ax = started(proc({**CYCLIC, 'count': 3}))
    ax.run(until=lambda r: r.state == 'stopping')
    r.event('trip', 'limit_velocity', 'indicate', ax.stamp)
    ax.run(until=finished)
    assert r.result == 'completed'


class ShortAxis(PerfectAxis):
    """A perfect axis whose swing about the step's mean is ``gain`` of the command's."""

    def __init__(self, runner, gain, mean=0.002):
        super().__init__(runner)
        self.gain, self.mean = gain, mean

    def run(self, seconds=None, until=None, bound=10**6):
        for _ in range(bound if seconds is None else int(round(seconds * 1000))):
            self.stamp += MS
            ref = self.r.sample(self.stamp)
            self.refs.append(ref)
            z = self.mean + self.gain(self.stamp) * (ref.z_ref - self.mean)
            self.r.measure(self.stamp, z, K * z)
            if until is not None and until(self.r):
                return
        if until is not None:
            raise AssertionError(f'not reached in {bound} periods: {self.r.status()}')


def test_null_pacing_counts_only_cycles_carried_within_count_tolerance():
    p = proc({**CYCLIC, 'count_tolerance': 0.02, 'taper': 3})
    r = ProcedureRunner(p, latency=0.0)
    ax = ShortAxis(r, lambda t: 1.0)
    assert r.start(ax.stamp)[0]
    ax.run(until=finished)
    # the taper's cycles are carried, not counted: the step runs 20 whole cycles on
    assert r.result == 'completed' and r.total == 20 and r.counts == [20]
    pacing = [e for e in r.events if e[0] == 'pacing']
    assert 'count waiting' in pacing[0][3] and 'again after' in pacing[1][3]
    end = next(e for e in r.events if e[0] == 'step_end')
    assert end[2] == 20.0 and 'more carried outside count_tolerance, not counted' in end[3]
    nulls = int(end[3].split('; ')[1].split()[0])
    assert 1 <= nulls <= 3
    # without pacing the taper's cycles count: the step is over that much sooner
    r0, _ = started(proc({**CYCLIC, 'taper': 3}))
    _.run(until=finished)
    assert r0.total == 20 and _.stamp < ax.stamp


def test_a_level_never_reached_within_count_tolerance_interrupts_the_test():
    p = proc({**CYCLIC, 'count_tolerance': 0.02, 'null_cycles': 10, 'taper': 1})
    r = ProcedureRunner(p, latency=0.0)
    ax = ShortAxis(r, lambda t: 0.9)                 # 10 % short of its swing, always
    assert r.start(ax.stamp)[0]
    ax.run(until=lambda r: r.state == 'interrupted')
    assert r.total == 0
    ev = [e for e in r.events if e[0] == 'levels']
    assert ev and '10 cycles in a row outside count_tolerance' in ev[0][3]


def test_the_levels_detector_is_on_by_default_and_interrupts_a_step_its_rig_cannot_carry():
    r = ProcedureRunner(proc({**CYCLIC, 'count': 500, 'level_cycles': 10, 'taper': 1}),
                        latency=0.0)
    ax = ShortAxis(r, lambda t: 0.8)                 # a swing 20 % short: 10 % of the range
    assert r.start(ax.stamp)[0]
    ax.run(until=lambda r: r.state == 'interrupted', bound=10**5)
    assert r.total == 10          # the tapered one (not judged) and 9 off; the tenth not counted
    ev = [e for e in r.events if e[0] == 'levels']
    assert ev and '10 cycles in a row off by more than level_error (0.05' in ev[0][3]
    # within level_error it counts on; off for fewer than level_cycles in a row, too
    r = ProcedureRunner(proc({**CYCLIC, 'count': 30, 'level_cycles': 10}), latency=0.0)
    ax = ShortAxis(r, lambda t: 0.8 if (t - T0) % (500 * MS) < 300 * MS else 0.95)
    assert r.start(ax.stamp)[0]
    ax.run(until=finished)
    assert r.result == 'completed' and r.total == 30
    # off (level_error 0): never judged
    r = ProcedureRunner(proc({**CYCLIC, 'count': 30, 'level_cycles': 2, 'level_error': 0.0}),
                        latency=0.0)
    ax = ShortAxis(r, lambda t: 0.8)
    assert r.start(ax.stamp)[0]
    ax.run(until=finished)
    assert r.result == 'completed' and r.total == 30


def test_count_tolerance_is_refused_on_a_block_program():
    with pytest.raises(InputError, match='count_tolerance.*block'):
        proc({'name': 'b', 'type': 'cyclic', 'blocks': [[0.003, 0.001, 2], [0.002, 0.0, 1]],
              'frequency': 10.0, 'count': 6, 'count_tolerance': 0.02})


def test_a_step_in_the_other_mode_waits_for_the_controller_and_a_refusal_holds():
    p = proc({**CYCLIC, 'count': 3},
             {'name': 'load', 'type': 'ramp', 'to': 2000.0, 'rate': 1.0e4,
              'control_mode': 'force'})
    r, ax = started(p)
    ax.run(until=lambda r: r.request_mode is not None)
    assert r.state == 'switching' and r.request_mode == 'force'
    r.mode_switched(True, '', ax.stamp)
    ax.run(0.001)
    # the force ramp starts from the measured load (K z), not from the last command in m
    assert ax.refs[-1].f_ref == pytest.approx(K * r.state_measured()[0], rel=1e-3)
    ax.run(until=finished)
    assert r.result == 'completed' and r.mode == 'force'
    r2, ax2 = started(p)
    ax2.run(until=lambda r: r.request_mode is not None)
    r2.mode_switched(False, 'no load cell', ax2.stamp)
    assert r2.state == 'held' and 'no load cell' in r2.events[-1][3]


def test_a_start_waits_for_the_controllers_mode_and_switches_it_to_the_first_steps():
    """A node reads the controller's mode first: a force test never drives a position loop."""
    p = proc({'name': 'load', 'type': 'ramp', 'to': 2000.0, 'rate': 1.0e4,
              'control_mode': 'force'})
    r = ProcedureRunner(p, latency=0.0)
    r.mode_known = False                       # as the procedure node starts it
    ax = PerfectAxis(r)
    ok, why = r.start(ax.stamp)
    assert not ok and why == "the controller's control mode is not known yet (asking it)"
    assert r.state == 'idle' and not r.events
    assert r.status()['controller_mode'] == ''  # what a client waits on before ~/start
    r.controller_mode('displacement')          # the controller's answer
    assert r.status()['controller_mode'] == 'displacement'
    _starts_switching_to_force(r, ax)
    # the same controller already in force: no switch at all
    again = ProcedureRunner(p, latency=0.0)
    again.mode_known = False
    again.controller_mode('force')
    ok, _ = again.start(PerfectAxis(again).stamp)
    assert ok and again.state == 'running' and again.request_mode is None


def test_in_lock_step_a_window_once_sent_holds_and_a_switch_waits_at_its_stamp():
    """
    Lock-step: what a window sent says does not change, and a switch lands at one state.

    The loop runs as fast as the windows come, so which of two values sent for one stamp it
    used would depend on when each arrived: the hold before the start is a level at the first
    state (in real time it follows the measurement), and a step that switches the controller
    ends the window at its stamp, so the loop waits at the state after it, where the switch
    is sent and answered whenever the answer comes.
    """
    p = proc({'name': 'load', 'type': 'ramp', 'to': 2000.0, 'rate': 1.0e4,
              'control_mode': 'force'})
    ms = 10**6
    free = ProcedureRunner(p, latency=0.02)
    r = ProcedureRunner(p, latency=0.02, lockstep=True)
    for x in (r, free):
        x.controller_mode('displacement')
        x.measure(0, 1.0e-3, 10.0)
        assert {ref.z_ref for ref in x.window(0, 20 * ms)} == {1.0e-3}
        x.measure(ms, 1.2e-3, 12.0)
    assert {ref.z_ref for ref in r.window(ms, 20 * ms)} == {1.0e-3}
    assert {ref.z_ref for ref in free.window(ms, 20 * ms)} == {1.2e-3}   # real time: follows
    ok, why = r.start(ms)
    assert ok and r.state == 'switching' and r.request_mode == 'force', why
    assert r.park_ns == 21 * ms
    assert [ref.stamp_ns for ref in r.window(10 * ms, 20 * ms)][-1] == 21 * ms
    assert r.window(22 * ms, 20 * ms) == []
    for k in range(2, 22):
        r.measure(k * ms, 1.0e-3, 10.0)
        assert not r.parked
    r.measure(22 * ms, 1.0e-3, 10.0)     # the loop waits here for the reference at 22 ms
    assert r.parked
    r.mode_switched(True, '', r.last_stamp)
    assert r.state == 'running' and r.park_ns is None and not r.parked
    w = r.window(22 * ms, 40 * ms)
    assert w[0].stamp_ns == 22 * ms and len(w) == 41
    assert w[-1].f_ref == pytest.approx(10.0 + 1.0e4 * 0.02)   # the ramp from 42 ms, 1e4 N/s


def test_a_window_sent_again_from_its_start_says_what_it_said_across_a_steps_start():
    """
    A window asks again from its start: the segment in force there stays.

    A cyclic step that begins while the controller still ramps on lays three segments at once
    (the level, the mean's move, the wave); the ramp before them must stay for the stamps up
    to its end, or the next window would send them again as a hold of the measured load.
    """
    p = proc({'name': 'up', 'type': 'ramp', 'to': 4000.0, 'rate': 1.6e4},
             {'name': 'fatigue', 'type': 'cyclic', 'peak': 9000.0, 'valley': 1000.0,
              'frequency': 20.0, 'count': 5}, control_mode='force')
    ms = 10**6
    r = ProcedureRunner(p, latency=0.02, lockstep=True, ramp_time=1.0)
    r.measure(0, 0.0, 0.0)
    sent = {ref.stamp_ns: [ref.f_ref] for ref in r.window(0, 20 * ms)}   # idle: a level
    assert r.start(0)[0]
    for t in range(15, 400, 10):          # the ramp ends at 270 ms: inside two windows
        for k in range(t - 9, t + 1):
            r.measure(k * ms, 0.0, 584.0)              # a load that lags far behind
        for ref in r.window(t * ms, 20 * ms):
            sent.setdefault(ref.stamp_ns, []).append(ref.f_ref)
    changed = {t: v for t, v in sent.items() if len(set(v)) > 1}
    assert not changed, changed
    assert r.step_index == 1 and len(r._segs) <= 4


def _starts_switching_to_force(r, ax):
    """Start ``r``: it asks the controller for force first, then runs to its end."""
    ok, why = r.start(ax.stamp)
    assert ok, why
    assert r.state == 'switching' and r.request_mode == 'force'
    r.mode_switched(True, '', ax.stamp)
    ax.run(until=finished)
    assert r.result == 'completed' and r.mode == 'force'


def test_a_mode_another_node_set_is_known_and_the_start_switches_from_it():
    """
    The campaign node puts the controller in specimen protect for a coupon's installation.

    A runner that took the controller in force, then heard it switch to protect, switches it
    back at the start (it once did not, and drove a force step into a position loop whose
    output protect limits: the levels were not reached).
    """
    p = proc({'name': 'load', 'type': 'ramp', 'to': 2000.0, 'rate': 1.0e4,
              'control_mode': 'force'})
    r = ProcedureRunner(p, latency=0.0)
    r.controller_mode('force')
    ax = PerfectAxis(r)
    r.event('mode', 'displacement_force_limited', 'indicate', ax.stamp)
    assert r.mode == 'displacement_force_limited' and r.quantity == 'displacement'
    assert r.status()['controller_mode'] == 'displacement_force_limited'
    ref = r.sample(ax.stamp)                     # idle: the measured position, held
    assert math.isfinite(ref.z_ref) and math.isnan(ref.f_ref)
    _starts_switching_to_force(r, ax)


def test_a_resume_waits_for_the_controllers_mode_too():
    p = proc(CYCLIC)
    r, ax = started(p)
    ax.run(until=lambda r: r.total == 2)
    r.hold(ax.stamp)
    r.mode_known = False                       # a restarted node asking again
    ok, why = r.resume(ax.stamp)
    assert not ok and 'not known yet' in why and r.state == 'held'
    r.controller_mode('displacement')
    ok, why = r.resume(ax.stamp)
    assert ok, why


def test_a_start_or_resume_the_rigs_values_cannot_follow_is_refused_naming_the_step():
    """The controller's values in force (a node reads them): beyond them, no start, no resume."""
    from ros_ehs.core.params import Params
    fast = {**CYCLIC, 'frequency': 60.0, 'amplitude': 0.005}
    r = ProcedureRunner(proc(fast), latency=0.0)
    r.rig_params(Params())
    ax = PerfectAxis(r)
    ok, why = r.start(ax.stamp)
    assert not ok and r.state == 'idle' and not r.events
    assert why.startswith('the rig cannot follow this procedure:')
    assert 'step 1 (cycles): the piston must move at 1.885 m/s' in why
    r.rig_params(Params().replace(u_max=0.05, m_p=20.0))     # a bigger valve, lighter piston
    assert r.beyond_rig == [] and r.start(ax.stamp)[0]
    ax.run(until=lambda r: r.total == 2)
    r.hold(ax.stamp)
    r.rig_params(Params())                   # values identified meanwhile: the rig is smaller
    ok, why = r.resume(ax.stamp)
    assert not ok and r.state == 'held' and '60 Hz is above' in why


def test_a_step_whose_compensation_cannot_run_at_the_preview_is_refused_at_load():
    """Peak/valley control needs its correction in before the next cycle: named at load."""
    late = {**CYCLIC, 'name': 'fast', 'frequency': 40.0, 'waveform': 'triangle',
            'compensation': 'auto'}
    p = proc({'name': 'wait', 'type': 'dwell', 'time': 0.1}, late)
    with pytest.raises(InputError, match=r'step 2 \(fast\): its compensation cannot run with a '
                       r'preview of 0.02 s .*under half a period'):
        ProcedureRunner(p, latency=0.02)
    assert ProcedureRunner(p, latency=0.01).state == 'idle'      # under half of 25 ms
    # without compensation nothing is brought in ahead of time: any preview
    plain = proc({**late, 'compensation': 'none'})
    assert ProcedureRunner(plain, latency=0.02).state == 'idle'


def test_a_restarted_loop_interrupts_and_keeps_the_counts():
    p = proc(CYCLIC)
    r, ax = started(p)
    ax.run(until=lambda r: r.total == 4)
    r.new_run()
    assert r.state == 'interrupted' and r.total == 4
    ax2 = PerfectAxis(r, T0, z=0.002)                  # the stamps start again
    assert r.resume(ax2.stamp)[0]
    ax2.run(until=finished)
    assert r.total == 20


def test_start_needs_a_measured_state_and_an_idle_test():
    p = proc(CYCLIC)
    r = ProcedureRunner(p, latency=0.0)
    ok, why = r.start(T0)
    assert not ok and 'no measured state' in why
    r.measure(T0, 0.0, 0.0)
    assert r.start(T0)[0] and not r.start(T0)[0]


def test_time_to_go_counts_the_planned_steps():
    p = proc({'name': 'up', 'type': 'ramp', 'to': 0.002, 'rate': 0.01},
             {'name': 'wait', 'type': 'dwell', 'time': 0.3}, CYCLIC)
    r, ax = started(p)
    assert r.time_to_go() == pytest.approx(0.2 + 0.3 + 2.0)
    ax.run(0.3)                                  # the ramp done, 0.1 s of the dwell
    assert r.time_to_go() == pytest.approx(0.2 + 2.0, abs=2e-3)
    ax.run(until=lambda r: r.total == 5)
    assert r.time_to_go() == pytest.approx(1.5, abs=2e-3)
    until = proc({**CYCLIC, 'count': 0, 'end': [{'time': 1.0}]})
    assert math.isnan(ProcedureRunner(until, latency=0.0).time_to_go())


# -- the detectors ---------------------------------------------------------------------------
def cyc(n, k=K, z=(0.001, -0.001), f=None):
    f = f or (k * z[0], k * z[1])
    return Cycle(n, 0, n * 100 * MS, z[0], z[1], z[0], z[1], f[0], f[1])


def test_stiffness_drop_trips_after_settling_reference_and_persist():
    d = FailureDetector('stiffness_drop', {'drop': 0.1, 'settling': 3, 'reference': 2,
                                           'persist': 2}, 'displacement')
    assert not any(d.cycle(cyc(n, k=K * 0.5)) for n in (1, 2, 3))     # settling: not judged
    assert not d.cycle(cyc(4)) and not d.cycle(cyc(5, k=1.1 * K))       # the reference
    assert d.reference['stiffness'] == pytest.approx(1.05 * K)
    assert not d.cycle(cyc(6, k=0.94 * K))          # 10.5 % under: one cycle
    assert not d.cycle(cyc(7, k=K))                  # the run is broken
    assert not d.cycle(cyc(8, k=0.94 * K))
    assert not d.cycle(cyc(9, z=(math.nan, 0.0)))    # not judged, breaks the run
    assert not d.cycle(cyc(10, k=0.94 * K))
    why = d.cycle(cyc(11, k=0.90 * K))
    assert 'stiffness_drop' in why and d.tripped_at == 11
    again = FailureDetector('stiffness_drop', d.values, 'displacement')
    again.restore(d.state())
    assert again.reference == d.reference and again.judged == d.judged


def test_peak_valley_change_judges_the_uncontrolled_signal():
    d = FailureDetector('peak_valley_change', {'tolerance': 0.05, 'settling': 0,
                                               'reference': 1, 'persist': 1}, 'force')
    ref = Cycle(1, 0, 0, 1.0e4, 1.0e3, 0.0100, 0.0010, 1.0e4, 1.0e3)
    assert not d.cycle(ref)
    # the load (controlled) is held; the position's peak moved 4 % then 6 % of its range
    assert not d.cycle(Cycle(2, 0, 0, 1.0e4, 1.0e3, 0.01036, 0.0010, 1.0e4, 1.0e3))
    assert 'position' in d.cycle(Cycle(3, 0, 0, 1.0e4, 1.0e3, 0.01054, 0.0010, 1.0e4, 1.0e3))


def test_underpeak_judges_the_controlled_range_against_the_specified():
    d = FailureDetector('underpeak', {'fraction': 0.9, 'settling': 0, 'persist': 1}, 'force')
    assert not d.cycle(Cycle(1, 0, 0, 0, 0, 0, 0, 1.0e4, 1.0e3), (1.0e4, 1.0e3))
    assert 'underpeak' in d.cycle(Cycle(2, 0, 0, 0, 0, 0, 0, 9.0e3, 1.0e3), (1.0e4, 1.0e3))


def test_fitted_stiffness_drop_judges_adequate_fits_beyond_their_standard_errors():
    d = FailureDetector('fitted_stiffness_drop', {'drop': 0.1, 'sigmas': 2.0, 'settling': 3,
                                                  'reference': 2, 'persist': 2}, 'force')
    assert not any(d.cycle(cyc(n)) for n in range(1, 20))       # cycles only count
    d2 = FailureDetector('fitted_stiffness_drop', d.values, 'force')
    for n in (1, 2, 3):
        d2.cycle(cyc(n))
        assert not d2.estimate(0.5 * K, 1.0, True, n)             # settling: not judged
    assert d2.reference is None
    d2.cycle(cyc(4))
    assert not d2.estimate(0.5 * K, 1.0, False, 4)                # not adequate: not judged
    assert not d2.estimate(math.nan, 1.0, True, 4) and not d2.estimate(K, math.inf, True, 4)
    assert not d2.estimate(1.0 * K, 0.01 * K, True, 4)            # the reference: two fits
    assert not d2.estimate(1.1 * K, 0.01 * K, True, 5)
    assert d2.reference['stiffness'] == pytest.approx(1.05 * K) and d2.reference['at'] == 5
    limit = 0.9 * 1.05 * K
    # under the limit, but within two standard errors of it: a fit too uncertain to tell
    assert not d2.estimate(limit - 0.01 * K, 0.01 * K, True, 6)
    assert d2._beyond == 0
    assert not d2.estimate(limit - 0.03 * K, 0.01 * K, True, 7)   # beyond: one estimate
    assert not d2.estimate(limit - 0.03 * K, 0.01 * K, False, 8)  # not adequate: no break
    assert not d2.estimate(K, 0.01 * K, True, 9)                  # the run is broken
    assert not d2.estimate(limit - 0.03 * K, 0.01 * K, True, 10)
    why = d2.estimate(limit - 0.05 * K, 0.01 * K, True, 11)
    assert 'fitted_stiffness_drop' in why and 'k_L' in why and d2.tripped_at == 11
    assert not d2.estimate(0.1 * K, 0.0, True, 12)                # tripped once
    again = FailureDetector('fitted_stiffness_drop', d2.values, 'force')
    again.restore(d2.state())
    assert again.reference == d2.reference and again.judged == d2.judged
    # the cycle detectors take no estimate
    s = FailureDetector('stiffness_drop', {'drop': 0.1, 'settling': 0, 'reference': 1,
                                           'persist': 1}, 'force')
    assert not s.estimate(0.1 * K, 0.0, True, 1)


@pytest.mark.parametrize('observe', [False, True])
def test_a_fitted_stiffness_drop_fails_the_running_test_at_the_count_it_came(observe):
    step = {**CYCLIC, 'count': 0, 'taper': 1, 'end': [{'fitted_stiffness_drop': {
        'settling': 1, 'reference': 1, 'persist': 1}}]}     # the tapered cycle not judged
    p = proc({'name': 'up', 'type': 'ramp', 'to': 0.002, 'rate': 0.02}, step)
    assert p.ends_on('fitted_stiffness_drop') and not p.ends_on('stiffness_drop')
    r, ax = started(p, observe=observe)
    r.estimate(ax.stamp, K, 0.01 * K, True)                # the ramp: not a cyclic step
    ax.run(until=lambda r: r.total >= 3)
    r.estimate(ax.stamp, K, 0.01 * K, True)                # the reference
    ax.run(until=lambda r: r.total >= 5)
    n = len(ax.refs)
    r.estimate(T0, 0.7 * K, 0.01 * K, True)       # stamped at its window's end, long ago
    assert r.tripped == {'fitted_stiffness_drop': 5}
    if observe:
        assert r.state == 'running' and not r.result
        assert r.events[-1][:2] == ('detector', 'fitted_stiffness_drop'), r.events[-1]
        return
    assert r.result == 'failed' and r.failed_at == 5 and 'k_L' in r.reason
    ax.run(until=finished)
    assert r.total == 5 and ax.refs[-1].z_ref == 0.0       # to the stop level
    # from where the command was, without a jump (a 1 mm sine at 10 Hz moves 63 um a period)
    z = np.array([ref.z_ref for ref in ax.refs[n - 1:]])
    assert np.max(np.abs(np.diff(z))) < 7e-5


# -- the virtual test ------------------------------------------------------------------------
FATIGUE = {'name': 'coupon', 'control_mode': 'force', 'run_out': 5000, 'steps': [
    {'name': 'preload', 'type': 'ramp', 'to': 5500.0, 'rate': 2.0e4},
    {'name': 'settle', 'type': 'dwell', 'time': 0.2},
    {'name': 'fatigue', 'type': 'cyclic', 'waveform': 'sine', 'mean': 5500.0,
     'amplitude': 4500.0, 'frequency': 10.0, 'taper': 1,
     'end': [{'stiffness_drop': {'drop': 0.10}}, {'peak_valley_change': {'tolerance': 0.05}}]}]}


def test_a_virtual_test_trips_its_detectors_where_the_specimen_model_meets_them():
    """
    A force-controlled test of a degrading specimen, on the model, to its fracture.

    The detectors observe (they report and the test goes on); each trips within 1 % (here
    3 cycles) of the cycle at which the specimen model, under the load range the cycle
    table shows it carried, meets its criterion; the fracture ends the test within a cycle.
    """
    life = 300.0
    p = preset('fatigue_actuator', k_L=1.0e7, ramp_time=0.2, specimen_life=life,
               specimen_life_range=9000.0)
    r = run_procedure(parse_procedure(FATIGUE), p, keep_cycles=1000)
    assert r.result == 'failed' and 'specimen break' in r.reason
    assert r.fractured_at is not None and abs(r.total_cycles - r.fractured_at) <= 1.0
    table = r.cycles
    assert table.shape == (r.total_cycles, 10)
    peak, valley = np.median(table[:, 7]), np.median(table[:, 8])
    sp = Specimen(p)
    for e in parse_procedure(FATIGUE).steps[2].end:
        model = model_trip_cycle(sp, e.kind, e.values, peak, valley,
                                 taper=parse_procedure(FATIGUE).steps[2]['taper'])
        why = (e.kind, r.tripped, model)
        assert abs(r.tripped[e.kind] - model) <= max(1.0, 0.01 * model), why


def test_live_fits_of_the_degrading_specimen_trip_the_fitted_stiffness_drop():
    """
    The chain on the rig, in process: the loop's sensors, live refits of k_L, the detector.

    A LiveIdentifier refits the last half second of the running test (noisy position,
    velocity, pressures and load cell) every half second; its adequate estimates follow the
    specimen as it softens, and ``fitted_stiffness_drop`` trips after the cycle-based
    ``stiffness_drop`` (a window averages the last half second, two estimates must agree) and
    before the fracture. (Near the end of life the crack grows within a window, the halves
    disagree, and the verdict calls the fits not adequate: docs/procedures.md.)
    """
    from ros_ehs.core.identify.live import LiveIdentifier
    from ros_ehs.core.sim.virtual_test import LiveFits
    p = preset('fatigue_actuator', k_L=1.0e7, ramp_time=0.2, specimen_life=400.0,
               specimen_life_range=9000.0, load_cell_noise=20.0)
    doc = {**FATIGUE, 'steps': FATIGUE['steps'][:2] + [
        {**FATIGUE['steps'][2], 'end': [{'stiffness_drop': {'drop': 0.1}},
                                        {'fitted_stiffness_drop': {'drop': 0.1}}]}]}
    fits = LiveIdentifier(p, free=['k_L'], pushable=[], model='simplified', sigmas=3.0,
                          rel_change=0.02, push_period=0.0)
    r = run_procedure(parse_procedure(doc), p, keep_cycles=1000, noise=(5e-6, 1e-3, 2e4),
                      live=LiveFits(fits, window=0.5, period=0.5))
    assert r.result == 'failed' and r.fractured_at is not None
    tripped = r.tripped
    assert tripped['stiffness_drop'] < tripped['fitted_stiffness_drop'] < r.fractured_at, \
        (tripped, r.fractured_at)
    ok = [e for _, e, _ in r.estimates if e is not None and e.adequate]
    assert len(ok) >= 50 and len(r.estimates) >= 70, [why for *_, why in r.estimates]
    k = [e.values['k_L'] for e in ok]
    assert k[0] == pytest.approx(1.0e7, rel=0.02) and k[-1] < 0.9 * k[0]
    assert all(0 < e.stderr['k_L'] < 0.01 * e.values['k_L'] for e in ok)


def test_a_virtual_tests_memory_is_a_ring_of_cycles():
    p = preset('fatigue_actuator', k_L=1.0e7, ramp_time=0.2, specimen_life=1e12)
    doc = {**FATIGUE, 'run_out': 40}
    r = run_procedure(parse_procedure(doc), p, keep_cycles=16)
    assert r.result == 'run_out' and r.total_cycles == 40
    assert r.cycles.shape == (16, 10) and list(r.cycles[:, 0]) == list(range(25, 41))


# -- the checkpoint on disk ----------------------------------------------------------------
def test_a_checkpoint_is_written_whole_and_read_back(tmp_path):
    from ros_ehs.data.checkpoint import read_checkpoint, write_checkpoint
    p = tmp_path / 'test.checkpoint.json'
    assert read_checkpoint(p) is None
    write_checkpoint(p, {'total': 5, 'x': math.nan})
    write_checkpoint(p, {'total': 6, 'x': 1.0})
    assert read_checkpoint(p) == {'total': 6, 'x': 1.0}
    assert [f.name for f in tmp_path.iterdir()] == ['test.checkpoint.json']   # no temp left
    p.write_text('{"total": 6, "x"')                 # a file cut short (not ours: we rename)
    with pytest.raises(InputError, match='test.checkpoint.json.*not JSON.*afresh'):
        read_checkpoint(p)


def test_a_checkpoint_that_cannot_be_written_leaves_the_last_one(tmp_path):
    from ros_ehs.data.checkpoint import read_checkpoint, write_checkpoint
    p = tmp_path / 'test.checkpoint.json'
    write_checkpoint(p, {'total': 6})
    (tmp_path / 'test.checkpoint.json.tmp').mkdir()     # the temporary file cannot be made
    with pytest.raises(OSError):
        write_checkpoint(p, {'total': 7})
    assert read_checkpoint(p) == {'total': 6}


def test_a_finished_tests_checkpoint_is_kept_aside_and_a_new_test_begins(tmp_path):
    from ros_ehs.data.checkpoint import resume_point, write_checkpoint
    p = tmp_path / 'test.checkpoint.json'
    write_checkpoint(p, {'state': 'interrupted', 'total': 6})
    assert resume_point(p) == ({'state': 'interrupted', 'total': 6}, '')
    write_checkpoint(p, {'state': 'finished', 'result': 'failed', 'total': 9})
    cp, note = resume_point(p, now='20261126T080000Z')
    assert cp is None and 'failed, 9 cycles' in note and not p.exists()
    assert (tmp_path / 'test.checkpoint.finished_20261126T080000Z.json').exists()


def test_ehs_sim_procedure_prints_what_the_rig_would_do(tmp_path, capsys):
    import yaml
    from ros_ehs.tools.cli import main
    f = tmp_path / 'coupon.yaml'
    doc = {**FATIGUE, 'steps': FATIGUE['steps'][:2] + [
        {**FATIGUE['steps'][2], 'end': FATIGUE['steps'][2]['end'] + [
            {'fitted_stiffness_drop': {}}]}]}
    f.write_text(yaml.safe_dump(doc))
    out = tmp_path / 'cycles.csv'
    rc = main(['procedure', str(f), '--preset', 'fatigue_actuator', '--set', 'k_L=1e7',
               '--set', 'specimen_life=60', '--set', 'specimen_life_range=9000',
               '--set', 'ramp_time=0.2', '--out', str(out)])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert 'result: failed (the controller detected the specimen break' in text
    assert 'the specimen fractured at cycle' in text and 'x real time' in text
    assert 'fitted_stiffness_drop: not judged in a virtual test' in text
    rows = np.loadtxt(out, delimiter=',', skiprows=1)
    assert rows.shape[1] == 10 and rows[-1, 0] == rows.shape[0]
    f.write_text('steps: []\n')
    assert main(['procedure', str(f)]) == 2
    assert 'steps' in capsys.readouterr().err


def test_a_tapered_cycle_is_flagged_alike_in_the_core_and_on_the_wire():
    from ros_ehs_msgs_py import CYCLE_TAPERED, cycles_from_bytes, cycles_to_bytes
    assert TAPERED == CYCLE_TAPERED
    rows = [(1, 0, 5, 1.0, 0.0, 1.0, 0.0, 2.0, 1.0, TAPERED), (2, 0, 6, 1.0, 0.0, 1.0, 0.0, 2.0,
                                                               1.0)]
    back = cycles_from_bytes(cycles_to_bytes(rows))
    assert [r[-1] for r in back] == [TAPERED, 0] and [r[0] for r in back] == [1, 2]


def test_a_stiffness_reference_without_stiffness_judges_nothing():
    """A frozen load cell gave the reference cycles no load range: no division by zero."""
    d = FailureDetector('stiffness_drop', {'drop': 0.1, 'settling': 0, 'reference': 1,
                                           'persist': 1}, 'force')
    assert not d.cycle(Cycle(1, 0, 0, 1.0, 0.0, 0.002, 0.001, 5.0e3, 5.0e3))
    assert d.reference['stiffness'] == 0.0
    assert not d.cycle(Cycle(2, 0, 0, 1.0, 0.0, 0.002, 0.001, 9.0e3, 1.0e3))
    assert math.isnan(d.last_value)


def test_a_waveform_waits_for_the_controllers_ramp_on_and_does_not_learn_during_one():
    """A cycle the controller's ramp-on attenuates is neither carried nor learnt from."""
    step = {**CYCLIC, 'compensation': 'pvc', 'count': 0, 'mean_rate': 0.1}
    r = ProcedureRunner(proc(step, run_out=1000), latency=0.0, ramp_time=3.0)
    ax = PerfectAxis(r)
    assert r.start(ax.stamp)[0]
    ax.run(until=lambda r: r.total >= 1)
    assert r.cycles[0].end_ns >= T0 + 3 * 10**9 + 100 * MS     # after the ramp-on's 3 s
    ax.run(until=lambda r: r.total >= 30)
    corr = r._waves[0].wave.corr
    assert corr.judged >= 20                    # learnt from once the ramp-on was over
    r.event('reset', '', 'off', ax.stamp)      # a reset: the controller ramps on again
    n = corr.judged
    ax.run(until=lambda r: r.total >= 50)      # 2 s of its 3 s
    assert corr.judged == n
    ax.run(until=lambda r: r.total >= 70)
    assert corr.judged > n
    with pytest.raises(InputError, match='ramp_time'):
        ProcedureRunner(proc(step, run_out=1000), ramp_time=math.nan)


class ScaledAxis(PerfectAxis):
    """An axis that carries ``gain`` times the command's swing about its mean (2 mm)."""

    gain = 1.0

    def carry(self, ref):
        z = 0.002 + self.gain * (ref.z_ref - 0.002)
        return z, K * z


@pytest.mark.parametrize('gain', [0.9, 1.1])
def test_a_clipped_command_is_not_raised_by_the_compensation(gain):
    """
    Between the controller's ``clipped`` and ``unclipped`` events no larger command is learnt.

    A rig that falls short (0.9) while its command is clipped would wind the command into
    the limit: the amplitude stays; one that overshoots (1.1) still gets less. After the
    ``unclipped`` event it learns both ways.
    """
    r = ProcedureRunner(proc({**CYCLIC, 'compensation': 'pvc', 'count': 200}), latency=0.0)
    ax = ScaledAxis(r)
    ax.gain = gain
    assert r.start(ax.stamp)[0]
    ax.run(until=lambda r: r.total >= 2)            # in the taper: nothing learnt yet
    corr = r._waves[0].wave.corr
    assert corr.judged == 0
    r.event('clipped', 'saturation', 'off', ax.stamp)
    amp = corr.amp[0]
    ax.run(until=lambda r: corr.judged >= 5)
    assert corr.amp[0] == amp if gain < 1 else corr.amp[0] < amp * 0.97
    r.event('unclipped', '', 'off', ax.stamp)
    ax.run(0.3)
    assert (corr.amp[0] > amp * 1.03) if gain < 1 else corr.amp[0] < amp * 0.97


class AlternatingAxis(PerfectAxis):
    """An axis that overshoots the command's swing by 5 % a tenth of a second in three."""

    def carry(self, ref):
        g = 1.05 if int((self.stamp - T0) * 1e-8) % 3 == 0 else 1.0
        z = 0.002 + g * (ref.z_ref - 0.002)
        return z, K * z


@pytest.mark.parametrize('count', [10, 21])
def test_a_paced_step_ends_when_its_last_cycle_counted_never_one_short(count):
    """The last cycle outside count_tolerance: the step goes on until one more counts."""
    r = ProcedureRunner(proc({**CYCLIC, 'count': count, 'count_tolerance': 0.02}),
                        latency=0.0)
    ax = AlternatingAxis(r)
    assert r.start(ax.stamp)[0]
    ax.run(until=finished)
    nulls = r._null_cycles[0]
    assert r.result == 'completed' and r.total == count and nulls >= count // 2
    assert [c.count for c in r.cycles] == list(range(1, count + 1))
    # with a run-out inside the step: a run-out at exactly the run-out count
    r = ProcedureRunner(proc({**CYCLIC, 'count': 0, 'count_tolerance': 0.02},
                             run_out=count), latency=0.0)
    ax = AlternatingAxis(r)
    assert r.start(ax.stamp)[0]
    ax.run(until=finished)
    assert r.result == 'run_out' and r.total == count


def test_a_step_that_says_so_backs_its_frequency_off_until_its_cycles_count():
    """+-5 mm at 60 Hz on the default rig: backed off by fifths to where it is carried."""
    zs = []
    p = proc({'name': 'fast', 'type': 'cyclic', 'waveform': 'sine', 'mean': 0.0,
              'amplitude': 0.005, 'frequency': 60.0, 'count': 30, 'count_tolerance': 0.02,
              'frequency_min': 5.0, 'backoff_cycles': 5})
    r = run_procedure(p, preset('g761_baseline'), check=False,
                      probe=lambda ax, rn, reply, ref: zs.append(ax.x[ax._iz]))
    backed = [e[4] for e in r.events if e[0] == 'procedure' and 'backed off' in e[4]]
    assert r.result == 'completed' and r.total_cycles == 30, r.reason
    assert backed[0] == ('frequency backed off from 60 to 48 Hz after 5 cycles in a row '
                         'outside count_tolerance')
    f_end = 60.0 * 0.8 ** len(backed)
    assert 5.0 < f_end < 23.0               # under the valve's speed: 0.72 m/s / (2 pi 5 mm)
    # the cycles not counted overshoot while the frequency comes down: 5.24 mm at worst,
    # 2.4 % of the range, 90 mm from the end stops
    assert max(abs(z) for z in zs) < 0.0053
    # each counted cycle was carried within the tolerance
    c = r.cycles
    assert np.all(np.abs(c[:, 5] - 0.005) <= 0.02 * 0.01 + 1e-9)
    assert np.all(np.abs(c[:, 6] + 0.005) <= 0.02 * 0.01 + 1e-9)


def test_a_backed_off_frequency_survives_a_restart():
    """The checkpoint keeps the frequency reached: a restarted node resumes at it."""
    step = {**CYCLIC, 'compensation': 'none', 'count': 100, 'count_tolerance': 0.02,
            'frequency_min': 5.0, 'backoff_cycles': 3}
    r = ProcedureRunner(proc(step), latency=0.0)
    ax = ScaledAxis(r)
    ax.gain = 0.9                                 # never within 2 %: the frequency backs off
    assert r.start(ax.stamp)[0]
    ax.run(until=lambda r: r._freq.get(0, 10.0) < 7.0)
    assert r._freq[0] == pytest.approx(10.0 * 0.8 ** 2)
    cp = r.checkpoint()
    again = ProcedureRunner(proc(step), latency=0.0)
    again.restore(cp)
    ax2 = ScaledAxis(again, ax.stamp, z=0.002)
    assert again.resume(ax2.stamp)[0]
    ax2.run(until=lambda r: bool(r._waves))
    assert again._waves[0].wave.period == pytest.approx(1.0 / 6.4)


@pytest.mark.parametrize('extra, words', [
    ({'frequency_min': 5.0}, ['frequency_min', 'count_tolerance > 0']),
    ({'frequency_min': 20.0, 'count_tolerance': 0.02}, ['frequency_min', 'under `frequency`']),
])
def test_a_back_off_without_pacing_or_above_the_frequency_is_refused(extra, words):
    with pytest.raises(InputError) as err:
        proc({**CYCLIC, **extra})
    assert all(w in str(err.value) for w in words), err.value


def test_the_compensations_gain_is_the_steps():
    """A user reads and sets how much of a cycle's error is corrected (and its bound)."""
    for comp, kind in (('pvc', 'PeakValleyControl'), ('apc', 'AmplitudePhaseControl')):
        r, ax = started(proc({**CYCLIC, 'compensation': comp, 'compensation_gain': 0.3,
                              'compensation_limit': 0.5}))
        ax.run(until=lambda r: bool(r._waves))
        corr = r._waves[0].wave.corr
        assert type(corr).__name__ == kind and corr.gain == 0.3 and corr.limit == 0.5


def test_levels_the_rig_cannot_reach_interrupt_the_test_before_an_end_stop():
    """
    +-5 mm at 60 Hz on the default rig, its envelope not checked.

    The controller clips its command at every peak (its rate limit, the valve's current
    limit): the compensation learns nothing from those cycles
    (a correction learnt from them would wind the command into the limit); the levels
    detector interrupts the test, naming why, and the virtual test ends.
    """
    seen = []
    p = proc({'name': 'fast', 'type': 'cyclic', 'waveform': 'sine', 'mean': 0.0,
              'amplitude': 0.005, 'frequency': 60.0, 'count': 1000})
    r = run_procedure(p, preset('g761_baseline'), check=False,
                      probe=lambda ax, rn, reply, ref: seen.append(ax.x[ax._iz]))
    assert r.result == 'interrupted' and 'levels not reached' in r.reason, r.reason
    assert 'the controller clips its command: ' in r.reason and r.sim_s < 10.0
    assert max(abs(z) for z in seen) < 0.095 - 0.005     # never near an end stop


def test_every_counted_cycle_has_finite_levels_tapered_or_not():
    """The tapered cycles' levels too (peak/valley control takes no sample of them)."""
    p = proc({'name': 'up', 'type': 'ramp', 'to': 0.002, 'rate': 0.02},
             {**CYCLIC, 'compensation': 'pvc'})
    r, ax = started(p)
    ax.run(until=finished)
    assert [c.flags for c in r.cycles[:4]] == [TAPERED] * 3 + [0]
    assert all(math.isfinite(v) for c in r.cycles for v in (c.z_hi, c.z_lo, c.f_hi, c.f_lo))
    assert all(0.001 - 1e-6 <= c.z_lo <= c.z_hi <= 0.003 + 1e-6 for c in r.cycles)
