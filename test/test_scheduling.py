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
