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
"""Where a node's threads run: SCHED_FIFO priority and CPU placement."""

import pytest


_RT_CHECK = """
import os, sys
from ros_ehs.nodes.scheduling import set_realtime
if sys.argv[1] == 'drop':
    os.setgid(65534)
    os.setuid(65534)
print(set_realtime(0) == '')
print(set_realtime(10))
print(sorted({os.sched_getscheduler(int(t)) for t in os.listdir('/proc/self/task')}))
"""


@pytest.mark.ros
@pytest.mark.parametrize('who', ['self', 'drop'])
def test_rt_priority_is_applied_to_every_thread_or_refused_with_a_reason(who, python_lines):
    """The loop nodes' ``rt_priority``: SCHED_FIFO on all threads, or a reason why not."""
    import os
    if who == 'drop' and os.geteuid() != 0:
        who = 'self'          # already unprivileged: the refusal path runs as is
    zero, said, policies = python_lines(_RT_CHECK, who)
    assert zero == 'True'                       # 0: the default scheduler, nothing said
    if said.startswith('threads on SCHED_FIFO priority 10'):
        assert policies == f'[{os.SCHED_FIFO}]'
    else:
        assert 'rt_priority 10 not applied' in said and 'CAP_SYS_NICE' in said, said
        assert policies == f'[{os.SCHED_OTHER}]'


@pytest.mark.ros
def test_cpu_affinity_keeps_every_thread_on_one_cpu_or_says_why_not(python_lines):
    import os
    # its lines marked: Fast DDS logs to the same stdout (a shared-memory port another
    # participant held at that moment: "[RTPS_TRANSPORT_SHM Error] Failed init_port ...",
    # once in a full run, where a fifth line was taken for the probe's)
    code = ('import os\n'
            'from ros_ehs.nodes.scheduling import set_cpu_affinity\n'
            'import rclpy\n'
            'rclpy.init()\n'
            'node = rclpy.create_node("pinned")\n'       # the middleware's threads exist
            'say = lambda x: print("probe:", x)\n'
            'say(set_cpu_affinity(-1) == "")\n'
            'say(set_cpu_affinity(1000))\n'
            'say(set_cpu_affinity(0))\n'
            'names = {t: open(f"/proc/self/task/{t}/comm").read().strip()'
            ' for t in os.listdir("/proc/self/task")}\n'
            'say(sorted({(n, tuple(sorted(os.sched_getaffinity(int(t)))))'
            ' for t, n in names.items()}))\n')
    said = python_lines(code)
    lines = [ln[len('probe: '):] for ln in said if ln.startswith('probe: ')]
    assert len(lines) == 4, said
    none, bad, good, placed = lines
    assert none == 'True'
    assert 'cpu_affinity 1000 not applied' in bad and 'this machine has CPUs' in bad
    others = sorted(set(os.sched_getaffinity(0)) - {0}) or [0]
    assert good == f'threads on CPU 0 (discovery and timed events on CPUs {others})'
    # the kernel's own record, per thread: Fast DDS's discovery (UDP) and event threads on
    # the other CPUs, everything else (Python, the shared-memory listeners) on CPU 0
    import ast
    from ros_ehs.nodes.scheduling import SIDE_THREADS
    placed = ast.literal_eval(placed)        # [(thread name, its CPUs)], one per distinct pair
    names = [n for n, _ in placed]
    assert any(n.startswith(('dds.udp.', 'dds.ev.')) for n in names), names
    assert any(n.startswith('dds.shm.') and n != 'dds.shm.wdog' for n in names), names
    for name, cpus in placed:
        want = others if name.startswith(SIDE_THREADS) else [0]
        assert list(cpus) == want, (name, cpus)
    assert len(os.sched_getaffinity(0)) >= 1     # the test process itself is untouched


@pytest.mark.ros
def test_real_time_priority_raises_the_middlewares_side_threads_too(python_lines):
    """Discovery and timed events take the mutexes the loop's sends take: SCHED_FIFO too."""
    import os
    code = ('import os\n'
            'from ros_ehs.nodes.scheduling import set_realtime, thread_states\n'
            'import rclpy\n'
            'rclpy.init()\n'
            'node = rclpy.create_node("raised")\n'       # the middleware's threads exist
            'print("probe:", set_realtime(10))\n'
            'print("probe:", sorted({(t["name"], t["policy"], t["priority"])'
            ' for t in thread_states(os.getpid())}))\n')
    lines = [ln[len('probe: '):] for ln in python_lines(code) if ln.startswith('probe: ')]
    assert len(lines) == 2, lines
    said, placed = lines
    if 'not applied' in said:           # unprivileged: nothing raised, said why
        assert os.geteuid() != 0 and 'CAP_SYS_NICE' in said
        return
    assert said.startswith('threads on SCHED_FIFO priority 10; a thread busy 0.5 s without '
                           'sleeping dumps the stacks, 5 s ends the process'), said
    import ast
    from ros_ehs.nodes.scheduling import SIDE_THREADS
    placed = ast.literal_eval(placed)
    assert any(n.startswith(SIDE_THREADS) for n, _, _ in placed), placed
    assert any(n.startswith('dds.shm.') and n != 'dds.shm.wdog' for n, _, _ in placed), placed
    assert {(policy, priority) for _, policy, priority in placed} == {('SCHED_FIFO', 10)}, \
        placed


_RUNAWAY = """
import os, sys, time
from ros_ehs.nodes import scheduling
scheduling.RUNAWAY = (0.2, 1.0)
os.sched_setaffinity(0, {int(sys.argv[1])})
print(scheduling.set_realtime(1), flush=True)
def runaway():
    while True:
        pass
runaway()
"""


@pytest.mark.ros
def test_a_real_time_thread_that_never_sleeps_says_where_it_is_and_is_ended():
    """
    A runaway loop at SCHED_FIFO: its stacks after the first limit, ended at the second.

    The real kernel's RLIMIT_RTTIME, at 0.2 and 1 s here (:data:`RUNAWAY` is 0.5 and 5 s),
    and at priority 1: under every node's, so no loop of a parallel test is held.
    """
    import os
    import subprocess
    import sys
    from ros_ehs.nodes.scheduling import realtime_allowed
    if not realtime_allowed(1):
        pytest.fail('this test needs SCHED_FIFO (root or an rtprio limit)')
    cpu = sorted(os.sched_getaffinity(0))[-1]
    out = subprocess.run([sys.executable, '-c', _RUNAWAY, str(cpu)], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == -9, (out.returncode, out.stdout, out.stderr)
    assert out.stdout.startswith('threads on SCHED_FIFO priority 1;') and \
        'a thread busy 0.2 s without sleeping dumps the stacks, 1 s ends the process' \
        in out.stdout, out.stdout
    # the stacks, at least once, with the loop that ran away in them
    assert 'most recent call first' in out.stderr and 'in runaway' in out.stderr, out.stderr


_LIMITS = """
import resource
from ros_ehs.nodes.scheduling import RUNAWAY, set_realtime
if __import__('sys').argv[1] == 'lower':
    resource.setrlimit(resource.RLIMIT_RTTIME, (100000, 300000))
said = set_realtime(1)
print(said.startswith('threads on SCHED_FIFO'), resource.getrlimit(resource.RLIMIT_RTTIME))
"""


@pytest.mark.parametrize('before', ['none', 'lower'])
def test_the_runaway_limit_is_set_on_a_raised_process_and_never_raises_one_set_before(
        before, python_lines):
    """RLIMIT_RTTIME: :data:`RUNAWAY` in microseconds, or the lower limit already there."""
    from ros_ehs.nodes.scheduling import realtime_allowed, RUNAWAY
    if not realtime_allowed(1):
        pytest.fail('this test needs SCHED_FIFO (root or an rtprio limit)')
    raised, limits = python_lines(_LIMITS, before)[-1].split(' ', 1)
    assert raised == 'True'
    want = (100000, 300000) if before == 'lower' else tuple(int(x * 1e6) for x in RUNAWAY)
    assert limits == str(want)


_STARVED = """
import os, sys, time
os.sched_setaffinity(0, {int(sys.argv[1])})
os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(sys.argv[2])))
print('ready', flush=True)
if sys.argv[3] == 'hog':
    end = time.monotonic() + float(sys.argv[4])
    while time.monotonic() < end:
        pass
else:
    while True:
        time.sleep(0.01)
"""


@pytest.mark.ros
def test_a_killed_process_that_gets_no_cpu_is_said_with_what_holds_it_not_waited_for(
        monkeypatch, capsys):
    """
    A process whose CPU a SCHED_FIFO thread holds does not die on SIGKILL until it runs.

    The real kernel: a sleeper at SCHED_FIFO 1 and a busy loop at SCHED_FIFO 2 on the same
    CPU (both under every node's priority: no loop of a parallel test is held), the loop
    running until the test ends it (at most 20 s, if the test itself dies), not for a time
    the test must finish within. Killed meanwhile, the sleeper is still there after the
    wait; the stop says so, with its threads and the busy loop by pid, and returns.
    """
    import os
    import subprocess
    import sys
    from ros_ehs.nodes import processes
    from ros_ehs.nodes.scheduling import realtime_allowed
    if not realtime_allowed(2):
        pytest.fail('this test needs SCHED_FIFO (root or an rtprio limit)')
    cpu = sorted(os.sched_getaffinity(0))[-1]
    start = {'stdout': subprocess.PIPE, 'text': True}
    victim = subprocess.Popen([sys.executable, '-c', _STARVED, str(cpu), '1', 'sleep'], **start)
    hog = None
    try:
        assert victim.stdout.readline().strip() == 'ready'
        hog = subprocess.Popen([sys.executable, '-c', _STARVED, str(cpu), '2', 'hog', '20'],
                               **start)
        assert hog.stdout.readline().strip() == 'ready'
        monkeypatch.setattr(processes, 'KILL_WAIT', 0.5)
        victim.kill()
        processes.reap_killed('victim', victim)
        said = capsys.readouterr().err
        assert victim.poll() is None, 'the victim died at once: its CPU was not held'
        assert f'victim (pid {victim.pid}) is still there 0.5 s after SIGKILL' in said, said
        assert f'pid {victim.pid} tid {victim.pid} python' in said and 'SCHED_FIFO 1' in said
        held = said.split('threads that held a CPU')[1]
        assert f'pid {hog.pid} tid {hog.pid}' in held and 'SCHED_FIFO 2' in held, said
    finally:
        for p in (hog, victim):
            if p is not None:
                p.kill()
                p.wait(30)
    assert victim.returncode == -9


def test_without_the_privilege_the_bench_says_what_a_normal_priority_loop_risks(monkeypatch):
    import os
    from ros_ehs.nodes import scheduling

    def refuse(*_):
        raise PermissionError(1, 'Operation not permitted')
    monkeypatch.setattr(os, 'sched_setscheduler', refuse)
    assert scheduling.realtime_allowed(50) is False
    said = scheduling.set_realtime(50)
    assert 'not applied (Operation not permitted)' in said and scheduling.RISK in said
    assert 'loop_timing' in scheduling.RISK


def test_realtime_allowed_leaves_the_scheduler_as_it_was():
    import os
    from ros_ehs.nodes.scheduling import realtime_allowed
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    realtime_allowed(50)
    assert (os.sched_getscheduler(0), os.sched_getparam(0)) == before


def test_the_automatic_priority_is_the_benchs_in_real_time_none_in_lock_step():
    from ros_ehs.nodes.scheduling import AUTO_PRIORITY, BENCH_PRIORITY, node_priority, RISK
    asked = []

    def allowed(priority):
        asked.append(priority)
        return True
    assert node_priority(AUTO_PRIORITY, True, allowed) == (BENCH_PRIORITY, '')
    assert asked == [BENCH_PRIORITY]
    assert node_priority(AUTO_PRIORITY, False, allowed) == (0, '')      # lock-step, sim time
    assert asked == [BENCH_PRIORITY]
    # refused: the default scheduler, and one sentence of what that risks
    priority, said = node_priority(AUTO_PRIORITY, True, lambda p: False)
    assert priority == 0 and said.startswith('rt_priority -1 (automatic): SCHED_FIFO 50 is '
                                             'not allowed') and 'ulimit -r' in said
    assert RISK in said
    # what a user sets is applied as set (set_realtime says itself when it cannot)
    for option in (0, 1, 80):
        assert node_priority(option, True, lambda p: False) == (option, '')


def test_the_setpoints_source_runs_under_the_loop():
    from ros_ehs.nodes.scheduling import (AUTO_PRIORITY, node_priority, REFERENCE_PRIORITY,
                                          setpoint_priority)
    asked = []

    def allowed(priority):
        asked.append(priority)
        return True
    # the reference and procedure nodes' automatic priority: 40, under the loop's 50
    assert node_priority(AUTO_PRIORITY, True, allowed, auto=REFERENCE_PRIORITY) == (40, '')
    assert asked == [40]
    assert node_priority(AUTO_PRIORITY, False, allowed, auto=REFERENCE_PRIORITY) == (0, '')
    priority, said = node_priority(AUTO_PRIORITY, True, lambda p: False, auto=40)
    assert priority == 0 and 'SCHED_FIFO 40 is not allowed' in said
    # what bench.py gives it under a loop's priority: 10 under, at most 40, never 0 under one
    assert [setpoint_priority(p) for p in (0, 1, 11, 30, 50, 90)] == [0, 1, 1, 20, 40, 40]


def test_the_automatic_cpu_keeps_the_loop_on_its_own_and_the_rest_off_it():
    from ros_ehs.nodes.scheduling import AUTO_CPU, node_cpu
    assert node_cpu(AUTO_CPU, True, lambda: (1, 0)) == 1
    assert node_cpu(AUTO_CPU, False, lambda: (1, 0)) == 0
    assert node_cpu(AUTO_CPU, False, lambda: None) == -1         # one CPU: anywhere
    assert node_cpu(AUTO_CPU, True, lambda: None) == -1

    def bad():
        raise ValueError('ROS_EHS_LOOP_CPUS = ...')
    assert node_cpu(AUTO_CPU, True, bad) == -1
    for option in (-1, 0, 3):
        assert node_cpu(option, True, lambda: (1, 0)) == option


def test_every_node_defaults_to_the_automatic_placement():
    from ros_ehs.core.options import NODE_OPTIONS
    from ros_ehs.nodes.scheduling import AUTO_CPU, AUTO_PRIORITY
    for node, settings in NODE_OPTIONS.items():
        by = {s.name: s for s in settings}
        if 'cpu_affinity' in by:
            assert by['cpu_affinity'].default == AUTO_CPU, node
        if 'rt_priority' in by:
            assert by['rt_priority'].default == AUTO_PRIORITY, node
            # the loop, and the setpoint's source under it
            assert node in ('plant', 'controller', 'reference', 'procedure'), node
