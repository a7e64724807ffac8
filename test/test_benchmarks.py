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
The benchmarks: each runs here with short arguments, so none can rot, and ends with its JSON.

Their figures are not judged here (they are measured against a yardstick of the same run,
docs/benchmarks.md); that each runs to its end and says what it measured is.
"""

import json
import os

import pytest
from ros_ehs.benchmarks.__main__ import BENCHMARKS, main
from waits import BOUND


@pytest.mark.parametrize('bench, args, says', [
    ('window', ['--windows', '0'], "argument --windows: must be a whole number >= 1, not '0'"),
    ('window', ['--seconds', '0'], "argument --seconds: must be a finite number > 0, not '0'"),
    ('window', ['--seconds', 'nan'], "argument --seconds: must be a finite number > 0, not 'nan'"),
    ('loop', ['--rounds', '0'], "argument --rounds: must be a whole number >= 1, not '0'"),
    ('loop', ['--seconds', 'nan'], "argument --seconds: must be a finite number > 0, not 'nan'"),
    ('lockstep', ['--seconds', '-1'], "argument --seconds: must be a finite number > 0, not '-1'"),
    ('lockstep', ['--rounds', 'two'], "argument --rounds: must be a whole number >= 1, not 'two'"),
    ('soak', ['--seconds', 'inf'], "argument --seconds: must be a finite number > 0, not 'inf'"),
    ('soak', ['--sample', '0'], "argument --sample: must be a finite number > 0, not '0'"),
    ('soak', ['--max-bag-duration', 'nan'], 'argument --max-bag-duration: must be a finite'),
    ('record', ['--rates', '20000,x'], "argument --rates: must be a finite number > 0, not 'x'"),
    ('record', ['--rates', '-5'], "argument --rates: must be a finite number > 0, not '-5'"),
    ('record', ['--seconds', 'inf'], "argument --seconds: must be a finite number > 0, not 'inf'"),
    ('record', ['--compressions', 'gzip'], '--compressions takes none, zstd or lz4'),
    ('verdict', ['--rigs', '0'], "argument --rigs: must be a whole number >= 1, not '0'"),
    ('verdict', ['--fits-out', '/nonexistent/fits.jsonl'],
     "argument --fits-out: cannot write '/nonexistent/fits.jsonl': No such file or directory"),
    ('drift', ['--duration', '8'], 'argument --duration: must be at least 15 s (one 10 s window'),
    ('drift', ['--duration', 'nan'], 'argument --duration: must be a finite number > 0'),
    ('tracking', ['--sweep-seconds', '2'], 'argument --sweep-seconds: must be at least 3 s'),
    ('paper', ['--duration', '0.01'],
     'paper: error: tracking_metrics: nothing left after skipping 1.0 s'),
    ('identify', ['--seconds', '0.05'], 'identify: error: bench: too little data: 50 samples'),
    ('fatigue', ['--speed-runs', '0'],
     "argument --speed-runs: must be a whole number >= 1, not '0'"),
    ('station', ['--seconds', 'nan'], 'argument --seconds: must be a finite number > 0'),
    ('realtime', ['--seconds', '1'], 'argument --seconds: must be at least 2 s'),
    ('station', ['--rt-priority', '120'], 'argument --rt-priority: parameter `rt_priority`'),
    ('station', ['--browser-cpu', '99'], 'argument --browser-cpu: must be a CPU of this'),
    ('freeze', ['--pauses', '0.5,-1'], "argument --pauses: must be a finite number > 0, not '-1'"),
    ('freeze', ['--seconds', '2', '--pauses', '1'],
     'argument --seconds: 2 s must be at least the longest pause plus 1.5 s')])
def test_the_benchmarks_refuse_bad_numbers_by_name(bench, args, says, capsys):
    # in process (the dispatcher's own main; the command line's is tested below): an
    # exception other than argparse's exit would fail the test with its traceback
    try:
        code = main([bench, *args])
    except SystemExit as done:
        code = done.code
    err = capsys.readouterr().err
    assert code == 2 and says in err, err


def test_the_benchmarks_are_named_when_asked_wrong():
    import subprocess
    import sys
    module = 'ros_ehs.benchmarks'
    r = subprocess.run([sys.executable, '-m', module, 'nope'], capture_output=True, text=True,
                       timeout=BOUND)
    assert r.returncode == 2 and 'usage: python -m ros_ehs.benchmarks {model,paper,' in r.stderr
    r = subprocess.run([sys.executable, '-m', module, 'loop', '--rounds', '0'],
                       capture_output=True, text=True, timeout=BOUND)
    assert r.returncode == 2 and 'argument --rounds: must be a whole number' in r.stderr
    # an EhsError from a run: one line naming the benchmark, no traceback
    r = subprocess.run([sys.executable, '-m', module, 'identify', '--seconds', '0.05'],
                       capture_output=True, text=True, timeout=BOUND)
    assert r.returncode == 2 and 'Traceback' not in r.stderr, r.stderr
    assert r.stderr.strip() == ('python -m ros_ehs.benchmarks identify: error: bench: too '
                                'little data: 50 samples (need at least 500, e.g. 0.5 s at '
                                '1 kHz)')


#: each benchmark's short run, and a figure its JSON must hold
SHORT = {
    'model': (['--seconds', '0.3', '--err-seconds', '0.05', '--fidelity-seconds', '0.3'],
              'rtf_full'),
    'paper': (['--duration', '2.0'], 'rms_err_ffpid_m'),
    'tracking': (['--frequencies', '10', '--cycles', '3', '--sweep-seconds', '3',
                  '--drive-seconds', '2', '--iterations', '1'], 'targets_met'),
    'identify': (['--seconds', '1.5'], 'fit_s'),
    'drift': (['--duration', '15'], 'rising'),
    'loop': (['--seconds', '1', '--rounds', '1'], 'rounds'),
    'live': (['--seconds', '2', '--rounds', '2'], 'per_round'),
    'lockstep': (['--seconds', '0.3', '--rounds', '1'], 'steps_per_s'),
    'window': (['--windows', '1', '--seconds', '1'], 'windows'),
    'record': (['--seconds', '0.3', '--rates', '1000', '--compressions', 'none',
                '--kills', '1'], 'sigkill_lost_ms'),
    'soak': (['--seconds', '4', '--max-bag-duration', '1', '--sample', '0.5'],
             'rss_slope_mb_per_h'),
    'realtime': (['--seconds', '2'], 'rig'),
    'force': (['--frequencies', '20', '--cycles', '3', '--specimens', 'stiff'], 'protect'),
    'fatigue': (['--life', '200', '--speed-cycles', '10', '--speed-runs', '1', '--long-cycles',
                 '200', '--kills', '1'], 'resume'),
    'verdict': (['--rigs', '1', '--seconds', '2', '--first', '12', '--fits-out',
                 '{tmp}/fits.jsonl'], 'misses'),
    'station': (['--seconds', '2', '--rounds', '2'], 'updates_per_s'),
    'freeze': (['--pauses', '0.2', '--runs', '1', '--seconds', '2'], 'per_pause'),
    'transitions': (['--only', 'starts', 'faults', '--hold', '0.2'], 'worst'),
    'load': (['--seconds', '2', '--cases', 'stall'], 'met'),   # busy, browser and live
    # would starve the suite's other workers: the short run is the quiet runs and the stall
    'integrity': (['--only', 'envelope', '--cycles', '5'], 'met'),
    'campaign': (['--sets', '1', '--no-bench'], 'fit'),
    'rehearsal': (['--cases', '1', '--runout', '2000', '--failure', '2000', '--replicates',
                   '2', '--scaling-replicates', '2', '--virtual-replicates', '1',
                   '--specimens', '1'], 'coverage'),
}


def test_every_benchmark_has_a_short_run():
    assert set(SHORT) == set(BENCHMARKS)


def test_every_benchmark_has_its_figure_and_command_in_the_docs():
    from pathlib import Path
    doc = Path(__file__).resolve().parents[1] / 'docs' / 'benchmarks.md'
    rows = [[c.strip() for c in ln.split('|')[1:-1]] for ln in doc.read_text().splitlines()
            if ln.startswith('| ') and not ln.startswith(('| bench |', '|---'))]
    named = {r[0]: r for r in rows if len(r) == 4}
    assert set(named) == set(BENCHMARKS), set(BENCHMARKS) ^ set(named)
    for name, (_, command, figure, yardstick) in named.items():
        assert command.startswith(f'`python -m ros_ehs.benchmarks {name}'), (name, command)
        assert figure and yardstick, name


def test_a_window_that_fails_stops_its_machine_probes(monkeypatch):
    """The window benchmark's probes (one per CPU) end with a window that raises."""
    import psutil
    from ros_ehs.benchmarks import window
    seen = []

    def fails(*args):
        me = psutil.Process()
        seen.extend(c for c in me.children() if 'ros_ehs.benchmarks.sleeper' in c.cmdline())
        raise RuntimeError('the bench failed')
    monkeypatch.setattr(window, '_ours', fails)
    with pytest.raises(RuntimeError, match='the bench failed'):
        window.main(['--windows', '1', '--seconds', '1', '--rt-priority', '0'])
    assert len(seen) == len(os.sched_getaffinity(0))
    assert not [p for p in seen if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]


def _left_in_session(sid: int) -> list[str]:
    """
    Kill what is still running in session ``sid``; return the command lines killed.

    A process still exiting when the benchmark's own has ended (a pool's worker whose memory
    is already released: an empty command line) is given 5 s to be gone first: it was once
    reported as left running.
    """
    import psutil
    found = {}
    for p in psutil.process_iter(['pid', 'cmdline', 'status']):
        try:
            if os.getsid(p.pid) == sid and p.info['status'] != psutil.STATUS_ZOMBIE:
                found[p] = ' '.join(p.info['cmdline'] or [])[:200]
        except (ProcessLookupError, psutil.Error):
            pass
    _, alive = psutil.wait_procs(list(found), timeout=5.0)
    left = []
    for p in alive:
        try:
            if p.status() != psutil.STATUS_ZOMBIE:
                left.append(found[p] or p.name())
                p.kill()
        except (ProcessLookupError, psutil.Error):
            pass
    return left


@pytest.mark.ros
@pytest.mark.parametrize('bench', sorted(SHORT))
def test_each_benchmark_runs_short_and_ends_with_its_json(bench, dom, tmp_path):
    import subprocess
    import sys
    args, key = SHORT[bench]
    args = [x.replace('{tmp}', str(tmp_path)) for x in args]
    # in a session of its own, its output to files: what it leaves running is found (and
    # cannot hold a pipe open, which kept this test waiting once on a failed run's probes)
    out, err = tmp_path / 'out.txt', tmp_path / 'err.txt'
    with open(out, 'w') as o, open(err, 'w') as e:
        p = subprocess.Popen([sys.executable, '-m', 'ros_ehs.benchmarks', bench, *args],
                             stdout=o, stderr=e, stdin=subprocess.DEVNULL, text=True,
                             start_new_session=True,
                             env={**os.environ, 'ROS_DOMAIN_ID': str(dom)})
        try:
            code = p.wait(timeout=900)
        finally:
            left = _left_in_session(p.pid)
    said = out.read_text()[-3000:] + err.read_text()[-3000:]
    assert code == 0, said
    assert not left, f'{bench} left processes running: {left}\n{said}'
    last = json.loads(out.read_text().strip().splitlines()[-1])
    assert isinstance(last, dict) and key in last, (key, list(last))
    if bench == 'verdict':      # each fit a JSON line, with what its verdict judged
        rows = [json.loads(x) for x in (tmp_path / 'fits.jsonl').read_text().splitlines()]
        assert [(r['rig'], r['model']) for r in rows] == [(12, 'reduced'), (12, 'simplified')]
        assert all({'errors', 'reasons', 'failed', 'held_out', 'noise_ratio', 'restart'}
                   <= set(r) for r in rows)
        assert all(len(r['failed']) == len(r['reasons']) for r in rows)
        assert 'false_alarms_by_rule' in last
        assert set(last['restarts']) == {'reduced', 'simplified'}


def test_the_verdict_benchmark_counts_what_the_second_start_did():
    """Kept second starts counted closer or farther by the worst error, and kinds moved."""
    from ros_ehs.benchmarks.verdict import restarts

    def fit(worst, kind, first=None, kept=True):
        restart = {} if first is None else {
            'kept': kept, 'first_errors': {'F_cc': first, 'c_c': 0.01}}
        return {'worst_error': worst, 'kind': kind, 'restart': restart}

    fits = [fit(0.02, 'good'),                          # not run
            fit(0.04, 'good', first=-0.12),             # bad -> good, closer
            fit(0.086, 'between', first=-0.056),        # farther, same kind
            fit(0.03, 'good', first=0.03, kept=False),  # ran, not kept
            fit(0.109, 'bad', first=0.093)]             # farther, between -> bad
    assert restarts(fits) == {'ran': 4, 'kept': 3, 'closer': 1, 'farther': 2,
                              'moves': {'bad->good': 1, 'between->bad': 1}}
    assert restarts([]) == {'ran': 0, 'kept': 0, 'closer': 0, 'farther': 0, 'moves': {}}
