"""
The campaign node's rules (``ros_ehs.data.campaign_rig``), in process.

The procedure node's part is played by a virtual test of each specimen's procedure on the
model: its cycle records and its end go in as the node would publish them.
"""

import json

import pytest
from ros_ehs.benchmarks.campaign import BENCH_CAMPAIGN, BENCH_RIG
from ros_ehs.core.campaign.spec import parse_campaign
from ros_ehs.core.errors import InputError
from ros_ehs.core.params import ALL_SPECS, preset
from ros_ehs.core.procedure.spec import load_procedure
from ros_ehs.core.settings import parse_assignment
from ros_ehs.core.sim.virtual_test import run_procedure
from ros_ehs.data.campaign_rig import RECORDS_WAIT_S, RigCampaign
from ros_ehs.data.store import ResultStore
import yaml


def _rig():
    return preset('fatigue_actuator').replace(**dict(parse_assignment(v, ALL_SPECS)
                                                     for v in BENCH_RIG))


def _setup(tmp_path):
    f = tmp_path / 'campaign.yaml'
    f.write_text(yaml.safe_dump(BENCH_CAMPAIGN))
    c = parse_campaign(BENCH_CAMPAIGN)
    store = ResultStore(tmp_path / 'campaign.db')
    return c, f, store


def _run(job, params, cut=None):
    """Run the loaded procedure as a procedure node would: its records (ns), its status."""
    r = run_procedure(load_procedure(job['file']), params, max_seconds=120.0)
    rows = [list(x) for x in r.cycles]
    for x in rows:
        x[2] = x[2] * 1e9                                  # the contract's end stamp [ns]
    status = {'file': job['file'], 'state': 'finished', 'result': r.result,
              'reason': r.reason, 'total_cycles': str(r.total_cycles)}
    return rows if cut is None else rows[:cut], status, r


def test_the_operators_next_specimen_is_loaded_run_and_recorded_once(tmp_path):
    c, f, store = _setup(tmp_path)
    rc = RigCampaign(c, f, store, tmp_path / 'out', params={'k_L': 1.0e7})
    ok, why, job = rc.next_specimen('C-0117')                       # the id on the coupon
    assert ok and why.startswith('C-0117 at 9000') and job['level'] == 9000.0
    assert json.loads((tmp_path / 'out' / 'current.json').read_text())['specimen'] == 'C-0117'
    again = rc.next_specimen()
    assert not again[0] and 'C-0117 is under way' in again[1]
    rows, status, r = _run(job, _rig())
    for k in range(0, len(rows), 10):                      # in batches, as published
        rc.take_cycles(rows[k:k + 10])
    assert rc.status({**status, 'state': 'running'}) is None
    assert rc.status({**status, 'file': 'other.yaml'}) is None
    rec = rc.status(status)
    assert rec.specimen == 'C-0117' and rec.result == 'failed' and rec.cycles == r.total_cycles
    assert abs(rec.peak - 9000.0) < 0.02 * 8100.0 and rec.note.endswith(
        f'from {r.total_cycles} of {r.total_cycles} cycle records')
    assert [x.specimen for x in store.results(rc.cid)] == ['C-0117']
    assert rc.current is None and not (tmp_path / 'out' / 'current.json').exists()
    assert rc.status(status) is None                        # recorded once
    ok, why, job2 = rc.next_specimen()                               # the plan's id, its level
    assert ok and job2['specimen'] == 'S02' and job2['level'] == 9000.0


def test_a_restarted_campaign_node_waits_for_the_test_under_way_and_records_it(tmp_path):
    """Killed mid-test: the new one finds the specimen under way; records missed are said."""
    c, f, store = _setup(tmp_path)
    rc = RigCampaign(c, f, store, tmp_path / 'out')
    ok, _, job = rc.next_specimen()
    rows, status, r = _run(job, _rig())
    rc.take_cycles(rows[:30])
    store.close()
    store = ResultStore(tmp_path / 'campaign.db')           # the node restarted
    rc = RigCampaign(c, f, store, tmp_path / 'out')
    assert rc.current['specimen'] == 'S01'
    assert not rc.next_specimen()[0]
    rc.take_cycles(rows[40:])                               # 30..39 published while down
    # the test's end came before the records published while down: they are waited for,
    # and come (the topic keeps them for a subscriber that comes late)
    assert rc.status(status, now=100.0) is None
    assert rc.status(status, now=100.0 + RECORDS_WAIT_S - 0.01) is None
    rc.take_cycles(rows[20:40])                             # replayed: each count kept once
    rec = rc.status(status, now=101.0)
    assert rec.cycles == r.total_cycles and rec.note.endswith(
        f'from {r.total_cycles} of {r.total_cycles} cycle records')
    assert [x.specimen for x in store.results(rc.cid)] == ['S01']


def test_specimen_protect_is_switched_on_only_before_the_coupons_test_starts(tmp_path):
    c, f, store = _setup(tmp_path)
    rc = RigCampaign(c, f, store, tmp_path / 'out')
    assert not rc.may_protect('S01', None)                  # nothing under way
    ok, _, job = rc.next_specimen()
    mine = job['file']
    assert rc.may_protect('S01', None)                      # the procedure node not heard
    assert rc.may_protect('S01', ('old.yaml', 'finished'))  # not loaded yet
    assert rc.may_protect('S01', (mine, 'idle'))            # loaded, not started
    assert not rc.may_protect('S01', (mine, 'running'))     # would take the test over
    assert not rc.may_protect('S01', (mine, 'switching'))
    assert not rc.may_protect('S02', (mine, 'idle'))        # not the coupon under way


def test_a_restarted_campaign_leaves_a_procedure_node_that_runs_its_specimen_as_it_is(tmp_path):
    """Loaded again, a test that ended while the campaign node was down would be put aside."""
    c, f, store = _setup(tmp_path)
    rc = RigCampaign(c, f, store, tmp_path / 'out')
    assert rc.must_load(('old.yaml', 'finished')) is False  # nothing under way
    rc.next_specimen()
    again = RigCampaign(c, f, store, tmp_path / 'out')      # the campaign node restarted
    mine = again.current['file']
    assert again.must_load(None) is None                    # not heard yet: ask again
    for state in ('finished', 'running', 'held', 'interrupted', 'idle'):
        assert again.must_load((mine, state)) is False, state
    assert again.must_load(('launch.yaml', 'idle')) is True  # the procedure node restarted
    # the test that ended while it was down is recorded from the node's status, once
    rows, status, r = _run(again.current, _rig())
    again.take_cycles(rows)
    rec = again.status(status, now=0.0)
    assert rec is not None and rec.specimen == 'S01' and rec.cycles == r.total_cycles
    assert again.status(status, now=1.0) is None


def test_records_that_never_come_leave_the_achieved_levels_to_those_that_did(tmp_path):
    c, f, store = _setup(tmp_path)
    rc = RigCampaign(c, f, store, tmp_path / 'out')
    ok, _, job = rc.next_specimen()
    rows, status, r = _run(job, _rig())
    rc.take_cycles(rows[:30] + rows[40:])                   # 30..39 lost for good
    assert rc.status(status, now=7.0) is None
    rec = rc.status(status, now=7.0 + RECORDS_WAIT_S)
    assert rec.note.endswith(f'from {r.total_cycles - 10} of {r.total_cycles} cycle records')
    # without a clock (a caller that cannot wait): at once, with what has come
    ok, _, job = rc.next_specimen()
    rows, status, r = _run(job, _rig())
    rc.take_cycles(rows[:5])
    assert rc.status(status).note.endswith(f'from 5 of {r.total_cycles} cycle records')


def test_an_id_that_is_not_one_or_tested_already_is_refused_and_an_ended_campaign_says_why(
        tmp_path):
    c, f, store = _setup(tmp_path)
    rc = RigCampaign(c, f, store, tmp_path / 'out')
    assert 'letters, digits' in rc.next_specimen('../etc')[1]
    ok, _, job = rc.next_specimen('A1')
    rows, status, _ = _run(job, _rig())
    rc.take_cycles(rows)
    rc.status(status)
    assert 'A1 is in the store already' in rc.next_specimen('A1')[1]
    rc.abandon('the procedure node refused it')
    assert rc.next_specimen('A2')[0]
    rc.abandon('the procedure node refused it')
    assert (tmp_path / 'out' / 'A2' / 'abandoned').read_text().startswith('the procedure')
    short = {**BENCH_CAMPAIGN, 'name': 'short', 'plan': {
        'method': 'levels', 'levels': [9000.0, 7000.0], 'specimens': 1}}
    f2 = tmp_path / 'short.yaml'
    f2.write_text(yaml.safe_dump(short))
    rc = RigCampaign(parse_campaign(short), f2, store, tmp_path / 'out2')
    for _ in range(2):
        ok, _, job = rc.next_specimen()
        rows, status, _ = _run(job, _rig())
        rc.take_cycles(rows)
        rc.status(status)
    ok, why, _ = rc.next_specimen()
    assert not ok and why.startswith('the campaign has ended: ')


def test_a_record_of_the_specimen_under_way_that_is_not_one_is_named(tmp_path):
    c, f, store = _setup(tmp_path)
    (tmp_path / 'out').mkdir()
    (tmp_path / 'out' / 'current.json').write_text('{not json')
    with pytest.raises(InputError, match='current.json: not the campaign node record'):
        RigCampaign(c, f, store, tmp_path / 'out')
