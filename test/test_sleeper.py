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
"""The machine yardstick and probes (``ros_ehs.benchmarks.sleeper``), without ROS."""

import json
import os

import pytest


def test_the_machine_yardstick_of_bench_loop_ticks_at_1khz_without_ros(python_lines):
    code = ('import json, sys, contextlib, io\n'
            'from ros_ehs.benchmarks import sleeper\n'
            'out = io.StringIO()\n'
            'with contextlib.redirect_stdout(out):\n'
            '    sleeper.main(["--seconds", "0.3"])\n'
            'f = json.loads(out.getvalue())\n'
            'f["rclpy_imported"] = "rclpy" in sys.modules\n'
            'print(json.dumps(f))\n')
    f = json.loads(python_lines(code)[-1])
    assert f['ticks'] == 300 and not f['rclpy_imported']
    assert f['max_gap_ms'] >= 0.9 and 0 <= f['stalls_2ms'] <= 300


def test_coincident_needs_the_spans_to_overlap_by_a_quarter_of_the_shorter():
    from ros_ehs.benchmarks.sleeper import coincident
    gaps = [(10.0, 4.0)]                              # a probe held over [9.996, 10.0]
    spans = [(10.001, 2.0),                           # [9.999, 10.001]: 1 ms of 2 overlap
             (10.0035, 4.0),                          # [9.9995, 10.0035]: 0.5 ms of 4
             (9.995, 1.0),                            # [9.994, 9.995]: before it
             (9.9985, 0.5)]                           # inside it
    assert coincident(spans, gaps) == [True, False, False, True]
    assert coincident(spans, []) == [False] * 4 and coincident([], gaps) == []


def _progress(p, ticks=0, gaps=0):
    """Read the probe's progress lines until it has ``ticks`` ticks and ``gaps`` gaps."""
    for line in p.stdout:
        if line.startswith('progress '):
            t, g = map(int, line.split()[1:])
            if t >= ticks and g >= gaps:
                return t, g
    raise AssertionError(f'the probe ended before {ticks} ticks and {gaps} gaps')


def test_the_machine_probe_runs_until_sigint_and_lists_its_long_gaps():
    import signal
    import subprocess
    import sys
    import time
    p = subprocess.Popen([sys.executable, '-m', 'ros_ehs.benchmarks.sleeper', '--seconds', '0',
                          '--gaps-over', '0.001', '--cpu', '4095', '--progress', '100'],
                         stdout=subprocess.PIPE, text=True)
    t, _ = _progress(p, 1000)
    p.send_signal(signal.SIGSTOP)        # held 50 ms, as a stalled machine would hold it
    time.sleep(0.05)
    p.send_signal(signal.SIGCONT)
    _progress(p, t + 300)             # on: the stall is among the newest gaps listed
    p.send_signal(signal.SIGINT)
    out, _ = p.communicate(timeout=60)
    f = json.loads(out.strip().splitlines()[-1])
    assert p.returncode == 0 and f['ticks'] > 500
    # every gap is over 1 us, so the list is full: the newest MAX_GAPS, bounded (over 0.5 ms,
    # as this test asked once, was not every gap: a tick late by a stall is followed by one
    # that catches up with the grid, a gap of less, on a loaded machine 178 of 1000)
    from ros_ehs.benchmarks.sleeper import hiccups, MAX_GAPS
    assert all(g > 0.001 for _, g, _ in f['gaps'])
    assert len(f['gaps']) == min(MAX_GAPS, f['ticks'])
    assert max(g for _, g, _ in f['gaps']) >= 45.0 and f['stalls_2ms'] >= 1
    # stopped, it was not queued for the CPU: the whole 50 ms gap is the "machine's"
    assert max(g for _, g in hiccups(f['gaps'])) >= 45.0
    assert f['not_applied'] == ['cpu not applied: Invalid argument']   # no CPU 4095: said


def test_a_probe_held_by_busy_threads_on_its_cpu_is_no_machine_hiccup():
    """A probe queued behind another process on its CPU says so: those gaps are not the machine."""
    import signal
    import subprocess
    import sys
    from ros_ehs.benchmarks.sleeper import hiccups
    cpu = max(os.sched_getaffinity(0))
    hog = subprocess.Popen([sys.executable, '-c', f'import os\nos.sched_setaffinity(0, {{{cpu}}})'
                            '\nwhile True: pass'])
    try:        # the probe at nice 19 beside a busy loop at nice 0: it waits for the CPU
        p = subprocess.Popen(['nice', '-n', '19', sys.executable, '-m',
                              'ros_ehs.benchmarks.sleeper', '--seconds', '0', '--gaps-over', '1.3',
                              '--cpu', str(cpu), '--progress', '10'],
                             stdout=subprocess.PIPE, text=True)
        _progress(p, gaps=101)           # held, again and again
        p.send_signal(signal.SIGINT)
        out, _ = p.communicate(timeout=60)
    finally:
        hog.kill()
    gaps = json.loads(out.strip().splitlines()[-1])['gaps']
    assert len(gaps) > 100, gaps          # held, again and again
    assert sum(w for _, _, w in gaps) > 0.3 * sum(g - 1.0 for _, g, _ in gaps), gaps[:10]
    assert len(hiccups(gaps)) < 0.1 * len(gaps), gaps[:10]


@pytest.mark.parametrize('args', [['--seconds', '-1'], ['--gaps-over', '-0.5']])
def test_the_machine_probe_refuses_negative_times_by_name(args):
    import subprocess
    import sys
    r = subprocess.run([sys.executable, '-m', 'ros_ehs.benchmarks.sleeper', *args],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and '--seconds, --gaps-over and --progress must be >= 0' in r.stderr
