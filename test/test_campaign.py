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
A campaign run into its store: in order, resumed from the store, its virtual coupons, its report.

The same virtual campaign goes into SQLite and into a real PostgreSQL server and the two hold
the same records; the report's page is opened in headless Chromium; the CLI is run as a user
runs it.
"""

from dataclasses import asdict, replace
import json
import math
from pathlib import Path
import subprocess
import sys

from postgres import Postgres
import pytest
from ros_ehs.core.campaign.spec import parse_campaign
from ros_ehs.core.params import preset
from ros_ehs.data.campaign import run_campaign, specimen_seed, virtual_specimen
from ros_ehs.data.campaign_report import write_campaign_report
from ros_ehs.data.store import ResultStore, SpecimenRecord
from test_campaign_runner import _draw
from test_station_browser import browser  # noqa: F401 the fixture
import yaml

COUPON = {'name': 'coupon', 'control_mode': 'force', 'steps': [
    {'name': 'preload', 'type': 'ramp', 'to': 5000.0, 'rate': 2.0e4},
    {'name': 'fatigue', 'type': 'cyclic', 'waveform': 'sine', 'peak': 1.0e4, 'valley': 1.0e3,
     'frequency': 20.0, 'end': [{'stiffness_drop': {'drop': 0.1}}]}]}
#: 6 virtual coupons at 3 levels, the lowest running out: about 10 s in process
CAMPAIGN = {'name': 'virtual 6082', 'template': COUPON, 'level': {'kind': 'max_load', 'R': 0.1},
            'run_out': 2000, 'plan': {'method': 'levels', 'levels': [9000, 6500, 4000],
                                      'specimens': 2}}
#: the fatigue actuator with a 1e7 N/m coupon whose life is 200 cycles at 9 kN, scattered
RIG = {'k_L': 1.0e7, 'specimen_life': 200.0, 'specimen_life_range': 9000.0,
       'specimen_scatter': 0.1}


def _fake(campaign):
    """Return a test that draws each specimen's life from a known law (no model)."""
    def test(nxt):
        r = _draw([nxt.level], seed=nxt.index, run_out=campaign.run_out)[0]
        return SpecimenRecord(nxt.specimen, nxt.level, r.result, r.cycles)
    return test


def test_a_campaign_runs_its_plan_and_goes_on_from_its_store(tmp_path):
    c = parse_campaign({**CAMPAIGN, 'run_out': 1e7,
                        'plan': {'method': 'levels', 'levels': [9000, 7000, 5000],
                                 'specimens': 2}})
    store = ResultStore(tmp_path / 'c.db')
    first = run_campaign(c, store, _fake(c), max_specimens=4)
    assert first.tested == 4 and not first.verdict.done
    nxt = first.verdict.next_specimen
    assert nxt.specimen == 'S05' and nxt.level == 5000.0
    calls = []

    def crashing(nxt):
        calls.append(nxt.specimen)
        raise RuntimeError('the process died')     # during S05: nothing recorded of it
    with pytest.raises(RuntimeError):
        run_campaign(c, store, crashing)
    store.close()
    again = ResultStore(tmp_path / 'c.db')           # as a restarted process opens it
    end = run_campaign(c, again, _fake(c))
    assert calls == ['S05'] and end.tested == 2 and end.verdict.done
    assert [r.specimen for r in end.records] == [f'S0{j}' for j in range(1, 7)]
    assert [r.level for r in end.records] == [9000.0] * 2 + [7000.0] * 2 + [5000.0] * 2
    assert run_campaign(c, again, _fake(c)).tested == 0        # ended: nothing more


def test_a_test_that_returns_another_specimen_is_refused(tmp_path):
    c = parse_campaign(CAMPAIGN)
    store = ResultStore(tmp_path / 'c.db')
    with pytest.raises(Exception, match="returned specimen 'X' at 9000 for 'S01'"):
        run_campaign(c, store, lambda n: SpecimenRecord('X', n.level, 'failed', 10))
    assert store.results(store.campaign(c.name)) == []


def _virtual(campaign, store):
    p = preset('fatigue_actuator', **RIG)
    return run_campaign(campaign, store, lambda n: virtual_specimen(campaign, n, p, seed=5),
                        file_hash='ab' * 32)


def _content(recs):
    out = []
    for r in recs:
        d = asdict(r)
        for k in ('started', 'ended'):
            d.pop(k)
        out.append({k: ('nan' if isinstance(v, float) and math.isnan(v) else v)
                    for k, v in d.items()})
    return out


def test_virtual_coupons_give_the_same_store_in_sqlite_and_postgresql(tmp_path):
    c = parse_campaign(CAMPAIGN)
    lite = _virtual(c, ResultStore(tmp_path / 'c.db'))
    pg = Postgres()
    try:
        store = ResultStore(pg.url)
        post = _virtual(c, store)
        assert _content(lite.records) == _content(post.records)
        assert pg.psql('select count(*), count(distinct specimen) from specimens') == '6|6'
        store.close()
    finally:
        pg.close()
    recs = lite.records
    assert lite.verdict.done and lite.verdict.reason == 'plan done: 6 valid specimens'
    assert [r.result for r in recs] == ['failed'] * 4 + ['run_out'] * 2
    for r in recs:
        # each coupon at its level: its achieved peak and valley within 2 % of the range
        assert abs(r.peak - r.level) < 0.02 * 0.9 * r.level
        assert abs(r.valley - 0.1 * r.level) < 0.02 * 0.9 * r.level
        assert r.duration_s > r.cycles / 20.0 and r.params['k_L'] == 1.0e7
        assert r.procedure_hash and 'specimen_seed' in r.note
    seeds = {r.params['specimen_seed'] for r in recs}
    assert seeds == {float(specimen_seed(5, j)) for j in range(1, 7)}
    # the coupons scatter: the two at each level differ
    assert recs[0].cycles != recs[1].cycles and recs[2].cycles != recs[3].cycles
    assert recs[4].cycles == recs[5].cycles == 2000


def test_an_off_level_coupon_is_invalid_and_tested_again(tmp_path):
    c = parse_campaign(CAMPAIGN)
    store = ResultStore(tmp_path / 'c.db')
    good = _fake(c)

    def sloppy(nxt):
        rec = good(nxt)
        return replace(rec, result='invalid', reason='achieved 3 % off') if \
            nxt.index == 2 else rec
    out = run_campaign(c, store, sloppy)
    assert [r.specimen for r in out.records][:3] == ['S01', 'S02', 'S03']
    assert [r.result for r in out.records].count('invalid') == 1
    assert out.records[2].level == 9000.0            # S02's level again, as S03
    assert len(out.records) == 7 and out.verdict.reason == 'plan done: 6 valid specimens'


def test_the_cli_runs_a_campaign_and_its_report_opens_in_chromium(tmp_path, browser):  # noqa: F811
    (tmp_path / 'coupon.yaml').write_text(yaml.safe_dump(COUPON))
    doc = {**CAMPAIGN, 'procedure': 'coupon.yaml'}
    doc.pop('template')
    (tmp_path / 'campaign.yaml').write_text(yaml.safe_dump(doc))
    sets = [a for k, v in RIG.items() for a in ('--set', f'{k}={v}')]
    run = subprocess.run([sys.executable, '-m', 'ros_ehs.tools.cli', 'campaign',
                          str(tmp_path / 'campaign.yaml'), '--store', str(tmp_path / 'c.db'),
                          '--preset', 'fatigue_actuator', '--max-specimens', '3', *sets],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert 'not ended (--max-specimens); next S04 at 6500' in run.stdout
    run = subprocess.run([sys.executable, '-m', 'ros_ehs.tools.cli', 'campaign',
                          str(tmp_path / 'campaign.yaml'), '--store', str(tmp_path / 'c.db'),
                          '--preset', 'fatigue_actuator', *sets],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert '6 specimens in the store (3 tested now): plan done' in run.stdout
    out = tmp_path / 'report'
    run = subprocess.run([sys.executable, '-m', 'ros_ehs.tools.cli', 'campaign-report',
                          str(tmp_path / 'c.db'), '--out', str(out)],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert 'virtual 6082: 6 specimens (4 failed, 2 run out, 0 invalid)' in run.stdout
    assert (out / 'specimens_pylife.csv').read_text().splitlines()[0] == \
        'load,cycles,fracture'
    fit = json.loads((out / 'fit.json').read_text())['basquin']
    assert fit['failures'] == 4 and fit['run_outs'] == 2
    assert fit['k_interval'][0] < fit['k'] < fit['k_interval'][1]
    page = browser.new_page()
    page.goto((out / 'report.html').as_uri())
    assert page.locator('#specimens tbody tr').count() == 6
    assert page.eval_on_selector('#sn', 'img => img.complete && img.naturalWidth') > 400
    assert page.locator('text=run_out').count() == 2
    page.close()


def test_a_report_names_a_missing_campaign(tmp_path):
    store = ResultStore(tmp_path / 'c.db')
    store.campaign('a')
    store.campaign('b')
    with pytest.raises(Exception, match=r"holds 2 campaigns \(\['a', 'b'\]\): name one"):
        write_campaign_report(store, tmp_path / 'r')
    with pytest.raises(Exception, match="no campaign 'c' in the store"):
        write_campaign_report(store, tmp_path / 'r', 'c')
    rep = write_campaign_report(store, tmp_path / 'r', 'a')
    assert rep.specimens == 0 and rep.fit['basquin'] is None
    assert Path(tmp_path / 'r' / 'report.html').is_file()


def test_a_campaign_on_the_lock_step_bench_survives_a_power_cut_during_specimen_4(tmp_path):
    """
    ``bench.py --campaign``: six coupons through the nodes, every process killed during S04.

    The campaign benchmark's bench part, as it runs: after the kill the same command goes on
    from the store and S04's checkpoint; six specimens, each once, each linked to its bags
    (S04 to two, its cycle records in them 1..its count, each once), the report written, and
    S04's count as far from its coupon model's as the
    uninterrupted failures' are (its crack carried over the restart).
    """
    from ros_ehs.benchmarks.campaign import bench_campaign
    b = bench_campaign(tmp_path)
    assert b['exit_codes'][1] == 0 and b['specimens'] == 6, b
    assert b['recorded_once'] and b['linked_to_bags'] and b['killed_and_resumed'], b
    assert b['s04_records_each_once'], b
    assert b['report']
    assert [r['bags'] for r in b['results']] == [1, 1, 1, 2, 1, 1]
    off = b['offset_cycles']
    others = [v for k, v in off.items() if k != 'S04']
    assert 'S04' in off and others
    assert min(others) - 2.0 <= off['S04'] <= max(others) + 2.0, off
    for r in b['results']:           # every coupon carried its level (tolerance 2 %)
        assert abs(r['peak'] - r['level']) < 0.02 * 0.9 * r['level'], r


def test_the_bench_campaign_gives_the_same_store_in_postgresql_and_sqlite(tmp_path):
    """
    ``bench.py --campaign`` through the nodes twice: into SQLite, and into a real PostgreSQL.

    The two stores hold the same six specimens, row for row, exactly: ids, results, counts,
    reasons, the achieved levels, bags (named relative to each run's folder), the procedure's
    hash, the rig's values and the notes (their times aside). The bench over DDS repeats
    itself bit for bit: a window of references once sent never changes, and the procedure's
    switch of the controller to force lands at the state after the switch's stamp, where the
    loop waits for it (docs/campaigns.md).
    """
    from ros_ehs.benchmarks.campaign import BENCH_CAMPAIGN, BENCH_RIG
    from ros_ehs.nodes.processes import launch_script
    spec = tmp_path / 'campaign.yaml'
    spec.write_text(yaml.safe_dump(BENCH_CAMPAIGN))
    pg = Postgres()
    try:
        runs = {}
        for kind, store in (('sqlite', None), ('postgresql', pg.url)):
            out = tmp_path / kind
            cmd = [sys.executable, str(launch_script('bench.py')), '--campaign', str(spec),
                   '--out', str(out), '--preset', 'fatigue_actuator']
            for v in BENCH_RIG:
                cmd += ['--set', v]
            cmd += ['--store', store] if store else []
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
            assert r.returncode == 0, (kind, r.stdout[-3000:], r.stderr[-3000:])
            st = ResultStore(store or out / 'campaign.db')
            recs = st.results(st.campaign(BENCH_CAMPAIGN['name']))
            st.close()
            rows = _content(recs)
            for row in rows:
                row['bags'] = [str(Path(b).relative_to(out)) for b in row['bags']]
            runs[kind] = rows
        assert pg.psql('select count(*), count(distinct specimen) from specimens') == '6|6'
    finally:
        pg.close()
    assert len(runs['sqlite']) == 6 and len(runs['postgresql']) == 6
    diff = [(a['specimen'], k, a[k], b.get(k)) for a, b in zip(runs['sqlite'], runs['postgresql'])
            for k in a if a[k] != b.get(k)]
    assert not diff, diff


@pytest.mark.parametrize('what, args, says', [
    ('a campaign with a NaN run-out', {'run_out': float('nan')}, 'run_out'),
    ('a key it does not know', {'runout': 10}, 'runout'),
    ('a rig value out of range', None, 'specimen_life'),
])
def test_the_bench_campaign_refuses_bad_input_by_name_before_anything_moves(
        tmp_path, what, args, says):
    """``bench.py --campaign``: a bad campaign file or rig value is one named line, exit 2."""
    import subprocess
    import sys
    from pathlib import Path
    f = tmp_path / 'c.yaml'
    f.write_text(yaml.safe_dump({**CAMPAIGN, **(args or {})}))
    cmd = [sys.executable, str(Path(__file__).resolve().parents[1] / 'launch_scripts' /
                               'bench.py'), '--campaign', str(f), '--out', str(tmp_path / 'o'),
           '--preset', 'fatigue_actuator']
    if args is None:
        cmd += ['--set', 'specimen_life=-5']
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (what, r.stdout, r.stderr)
    assert r.stderr.startswith('bench: ') and says in r.stderr, (what, r.stderr)
    assert 'Traceback' not in r.stderr and not (tmp_path / 'o').exists()
