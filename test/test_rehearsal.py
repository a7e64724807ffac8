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
A campaign rehearsed: the same seeds give the same results wherever it runs.

In process, on a local cluster and on a real Dask cluster (its own CLIs) that loses a worker;
a scheduler that does not answer is named.
"""

import json
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import pytest
from ros_ehs.core.campaign.spec import parse_campaign
from ros_ehs.core.errors import DataError
from ros_ehs.core.params import preset
from ros_ehs.data.campaign import virtual_specimen
from ros_ehs.data.rehearsal import (alternative_plans, law_specimen, rehearse,
                                    rehearse_replicate, truth)
from test_campaign import COUPON

#: 8 coupons at 4 levels of a 1e7 N/m specimen whose life is 5000 cycles at 9 kN, scattered
CAMPAIGN = {'name': 'rehearsed', 'template': COUPON, 'level': {'kind': 'max_load', 'R': 0.1},
            'run_out': 20000, 'plan': {'method': 'levels',
                                       'levels': [10000, 8500, 7000, 5500], 'specimens': 2},
            'target': {'kind': 'load_at_life', 'life': 5000, 'confidence': 0.9,
                       'width': 0.05}}
RIG = {'k_L': 1.0e7, 'specimen_life': 5000.0, 'specimen_life_range': 9000.0,
       'specimen_scatter': 0.15}
#: what a wait for a cluster may take at most [s] (a loaded machine: seconds)
BOUND = 120.0


def _setup():
    return parse_campaign(CAMPAIGN), preset('fatigue_actuator', **RIG)


def test_the_law_gives_the_coupon_the_virtual_test_gives():
    c, p = _setup()
    from ros_ehs.core.campaign.runner import Next
    nxt = Next('S01', 8500.0, 1)
    law = law_specimen(c, nxt, p, seed=3)
    virt = virtual_specimen(c, nxt, p, seed=3)
    assert law.result == virt.result == 'failed'
    # the stiffness-drop detector's trip by the model's closed form against the jumped
    # virtual test of the same coupon (its taper and settling included)
    assert abs(law.cycles - virt.cycles) <= 0.01 * virt.cycles, (law.cycles, virt.cycles)


def test_the_truth_is_the_specimen_laws():
    c, p = _setup()
    t = truth(c, p)
    assert t['k'] == 3.0 and t['scatter'] == 0.15
    from ros_ehs.data.rehearsal import _law_cycles, _level_step
    life = _law_cycles(c, t['target'], p.replace(specimen_scatter=0.0),
                       _level_step(c, t['target']))
    assert life == pytest.approx(5000.0, abs=1.0)       # whole cycles: a step at 5000


def test_a_replicate_is_a_function_of_its_seed_and_number():
    c, p = _setup()
    t = truth(c, p)
    a = rehearse_replicate(c, p, 7, 3, 'law', t)
    assert a == rehearse_replicate(c, p, 7, 3, 'law', t)
    assert a['cycles'] != rehearse_replicate(c, p, 7, 4, 'law', t)['cycles']
    assert a['specimens'] == 8 and a['k'] is not None and a['covers']['slope'] is not None


def test_the_other_plans_have_the_same_specimen_count_over_the_same_levels():
    c, _ = _setup()
    plans = alternative_plans(c)
    assert list(plans) == ['levels (given)', 'pearl_string', 'staircase', 'adaptive']
    assert plans['pearl_string'].plan == {'method': 'pearl_string', 'start': 10000.0,
                                          'step': 4500.0 / 7, 'specimens': 8}
    assert plans['adaptive'].plan['low'] == 5500.0 and plans['adaptive'].plan['high'] == 1e4


def test_the_same_seed_gives_the_same_rehearsal_in_process_and_on_a_local_cluster():
    c, p = _setup()
    one = rehearse(c, p, 3, seed=2, lives='law', plans='all', workers=0)
    two = rehearse(c, p, 3, seed=2, lives='law', plans='all', workers=2)
    assert one.workers == 0 and two.workers == 2
    assert one.replicates == two.replicates and one.plans == two.plans
    s = one.plans['levels (given)']
    assert s['replicates'] == 3 and s['rig_h']['median'] > 0 and s['coverage']['slope']
    assert rehearse(c, p, 3, seed=3, lives='law', workers=0).replicates != \
        {k: v for k, v in one.replicates.items() if k == 'levels (given)'}


def test_a_scheduler_that_does_not_answer_is_named():
    c, p = _setup()
    with pytest.raises(DataError, match=r"no Dask scheduler answered at 'tcp://127.0.0.1:9'"):
        rehearse(c, p, 2, lives='law', scheduler='tcp://127.0.0.1:9')


def _wait_file(path: Path, proc) -> None:
    end = time.monotonic() + BOUND
    while not path.exists():
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < end, f'no {path} from the scheduler'
        time.sleep(0.05)


def test_a_real_cluster_that_loses_a_worker_gives_the_same_result(tmp_path):
    c, p = _setup()
    exe = Path(sys.executable).parent / 'dask'
    sched_file = tmp_path / 'scheduler.json'
    env = dict(os.environ, DASK_DISTRIBUTED__WORKER__DAEMON='False')
    # the cluster at the lowest priority: the suite's other tests (real-time ones among them)
    # keep the CPU they would have had
    nice = ['nice', '-n', '19']
    procs = [subprocess.Popen([*nice, str(exe), 'scheduler', '--host', '127.0.0.1', '--port', '0',
                               '--no-dashboard', '--scheduler-file', str(sched_file)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              env=env)]
    try:
        _wait_file(sched_file, procs[0])
        address = json.loads(sched_file.read_text())['address']
        for _ in range(2):        # no nanny: a SIGKILL ends the worker, nothing restarts it
            procs.append(subprocess.Popen(
                [*nice, str(exe), 'worker', address, '--nthreads', '1', '--no-nanny',
                 '--no-dashboard'], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                env=env))
        from distributed import Client
        with Client(address, timeout=BOUND) as cl:
            cl.wait_for_workers(2, timeout=BOUND)
        killed = []

        def progress(done, total):
            if done >= 4 and not killed:             # mid-rehearsal: a worker dies
                procs[1].send_signal(signal.SIGKILL)
                procs[1].wait(BOUND)
                killed.append(done)
        got = rehearse(c, p, 12, seed=5, lives='law', scheduler=address, progress=progress)
        assert killed and killed[0] < 12
        assert got.workers == 2
        alone = rehearse(c, p, 12, seed=5, lives='law', workers=0)
        assert got.replicates == alone.replicates and got.plans == alone.plans
    finally:
        for pr in procs:
            if pr.poll() is None:
                pr.send_signal(signal.SIGTERM)
        for pr in procs:
            try:
                pr.wait(BOUND)
            except subprocess.TimeoutExpired:
                pr.kill()


def test_the_cli_rehearses_and_writes_its_table(tmp_path):
    import yaml
    (tmp_path / 'c.yaml').write_text(yaml.safe_dump(CAMPAIGN))
    sets = [a for k, v in RIG.items() for a in ('--set', f'{k}={v}')]
    out = tmp_path / 'r.json'
    run = subprocess.run([sys.executable, '-m', 'ros_ehs.tools.cli', 'campaign-rehearse',
                          str(tmp_path / 'c.yaml'), '--replicates', '4', '--lives', 'law',
                          '--in-process', '--preset', 'fatigue_actuator', '--out', str(out),
                          *sets], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert 'truth (the specimen law): slope 3, scatter 0.15 decades' in run.stdout
    for plan in ('levels (given)', 'pearl_string', 'staircase', 'adaptive'):
        assert plan in run.stdout
    assert '4/4' in run.stderr.replace('\r', '\n').splitlines()[-1] or '16/16' in run.stderr
    d = json.loads(out.read_text())
    assert set(d['plans']) == {'levels (given)', 'pearl_string', 'staircase', 'adaptive'}
    assert all(len(v) == 4 for v in d['replicates'].values())
    assert not math.isnan(d['plans']['adaptive']['rig_h']['median'])


@pytest.mark.parametrize('kw, says', [
    ({'replicates': 0}, '`replicates` = 0 must be a whole number >= 1'),
    ({'replicates': 2, 'plans': 'best'}, "`plans` = 'best' must be 'given' or 'all'"),
    ({'replicates': 2, 'lives': 'guess'}, "`lives` = 'guess' must be one of"),
])
def test_a_bad_rehearsal_request_is_named(kw, says):
    from ros_ehs.core.errors import InputError
    c, p = _setup()
    replicates = kw.pop('replicates')
    with pytest.raises(InputError, match=says):
        rehearse(c, p, replicates, workers=0, **kw)
