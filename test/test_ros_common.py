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
"""The nodes' common layer: options, live parameter changes, QoS, scheduling, placement."""

import math

import pytest
from ros_ehs.control.controller import Controller
from ros_ehs.control.feedforward import MODEL_PARAMS
from ros_ehs.params import CONTROL_SPECS, Params
import ros_ehs_msgs_py as c


@pytest.mark.ros
def test_live_changes_are_validated_as_a_whole_with_a_reason():
    from rclpy.parameter import Parameter
    from ros_ehs.nodes.controller import SPECS
    from ros_ehs.nodes.ros_common import validate_changes
    cur = Params()
    res, new = validate_changes(cur, [Parameter('kp', value=1.5)], SPECS)
    assert res.successful and new['kp'] == 1.5
    res, new = validate_changes(cur, [Parameter('F_cc', value=cur['F_sc'] + 1.0)], SPECS)
    assert not res.successful and new is None and 'must not exceed' in res.reason
    res, _ = validate_changes(cur, [Parameter('u_max', value=5.0)], SPECS)
    assert not res.successful and 'u_max' in res.reason and 'outside' in res.reason
    res, new = validate_changes(cur, [Parameter('use_sim_time', value=True)], SPECS)
    assert res.successful and new is None          # not ours: nothing to rebuild
    from ros_ehs.nodes.ros_common import rejected_names
    declared = {'kp', 'use_sim_time'}.__contains__
    assert rejected_names([Parameter('kp', value=1.5)], declared) is None
    assert rejected_names([Parameter('', value=1.0)], declared) == \
        'a parameter with an empty name'
    assert rejected_names([Parameter('kp', value=1.5), Parameter('nope', value=1.0)],
                          declared) == 'parameter `nope` is not declared by this node'
    assert 'restart the node' in rejected_names([Parameter('use_sim_time', value=True)],
                                                declared)
    res, _ = validate_changes(cur, [Parameter('antiwindup', value='clamp')], SPECS)
    assert not res.successful and "`antiwindup` = 'clamp' is not one of" in res.reason
    from ros_ehs.nodes.plant import OPTIONS
    from ros_ehs.params import PLANT_SPECS
    res, _ = validate_changes(cur, [Parameter('timing', value='bogus')], PLANT_SPECS, OPTIONS)
    assert not res.successful and res.reason == (
        "parameter `timing` = 'bogus' is not one of ['timer', 'thread']")


def test_controller_declares_every_value_its_feedforward_reads():
    names = {s.name for s in CONTROL_SPECS} | set(MODEL_PARAMS)
    p = Params()

    class Only(dict):
        def __getitem__(self, k):
            if k not in names:
                raise KeyError(f'the controller does not declare {k}')
            return dict.__getitem__(self, k)

    ctrl = Controller(Only(p.items()), 1e-3)       # raises if MODEL_PARAMS misses one
    assert math.isfinite(ctrl.step(0.01, 0.0, 0.0))


def test_contract_node_topics_are_contract_topics():
    for node, t in c.NODE_TOPICS.items():
        for topic in t.publishes + t.subscribes:
            assert topic in c.TOPICS, (node, topic)
            assert not topic.name.startswith('/') or topic is c.CLOCK   # relative names
    assert c.COMMAND in c.NODE_TOPICS['plant'].subscribes
    assert c.COMMAND in c.NODE_TOPICS['controller'].publishes


def test_nodes_doc_is_generated_from_the_options():
    from ros_ehs.nodes.docs import DOC, render
    text = DOC.read_text()
    assert render(text) == text, 'docs/nodes.md is stale: run python -m ros_ehs.nodes.docs'


def test_qos_round_trips_through_rosbag2_entries_old_and_new():
    for q in (c.LOOP_QOS, c.RECORD_QOS, c.QosSpec('reliable', 5, 'transient_local')):
        assert c.QosSpec.from_rosbag2(q.as_rosbag2()) == q
    # rosbag2's older numeric enums; 0 (system default) and a missing entry give defaults
    assert c.QosSpec.from_rosbag2({'reliability': 2, 'durability': 1, 'depth': 3}) == \
        c.QosSpec('best_effort', 3, 'transient_local')
    assert c.QosSpec.from_rosbag2({'reliability': 0, 'depth': 0}) == c.QosSpec()
    assert c.QosSpec.from_rosbag2(None) == c.RECORD_QOS


def test_qos_spec_inverts_qos_profile():
    from ros_ehs.nodes.ros_common import qos_profile, qos_spec
    for q in (c.LOOP_QOS, c.RECORD_QOS, c.LOCKSTEP_QOS,
              c.QosSpec('reliable', 5, 'transient_local'),
              c.QosSpec('best_effort', 3, history='keep_all')):
        assert qos_spec(qos_profile(q)) == q


def test_lockstep_turns_the_best_effort_loop_topics_reliable_and_nothing_else():
    for t in c.TOPICS:
        assert t.qos_in(False) == t.qos
        lock = t.qos_in(True)
        if t.qos.reliability == 'best_effort':
            assert lock == c.LOCKSTEP_QOS and lock.reliability == 'reliable' and lock.depth >= 1000
        else:
            assert lock == t.qos
    assert c.STATE.qos_in(True) == c.CLOCK.qos_in(True) == c.LOCKSTEP_QOS


@pytest.mark.ros
def test_live_options_follow_accepted_changes_read_only_ones_do_not():
    from rclpy.parameter import Parameter
    from ros_ehs.nodes.plant import OPTIONS
    from ros_ehs.nodes.ros_common import update_options
    opt = {o.name: o.default for o in OPTIONS}
    update_options(opt, [Parameter('watchdog_periods', value=5),
                         Parameter('rate_hz', value=500.0)], OPTIONS)
    assert opt['watchdog_periods'] == 5 and opt['rate_hz'] == 1000.0


_RT_CHECK = """
import os, sys
from ros_ehs.nodes.ros_common import set_realtime
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
    code = ('import os\n'
            'from ros_ehs.nodes.ros_common import set_cpu_affinity\n'
            'import rclpy\n'
            'rclpy.init()\n'
            'node = rclpy.create_node("pinned")\n'       # the middleware's threads exist
            'print(set_cpu_affinity(-1) == "")\n'
            'print(set_cpu_affinity(1000))\n'
            'print(set_cpu_affinity(0))\n'
            'names = {t: open(f"/proc/self/task/{t}/comm").read().strip()'
            ' for t in os.listdir("/proc/self/task")}\n'
            'print(sorted({(n, tuple(sorted(os.sched_getaffinity(int(t)))))'
            ' for t, n in names.items()}))\n')
    none, bad, good, placed = python_lines(code)
    assert none == 'True'
    assert 'cpu_affinity 1000 not applied' in bad and 'this machine has CPUs' in bad
    others = sorted(set(os.sched_getaffinity(0)) - {0}) or [0]
    assert good == f'threads on CPU 0 (discovery and timed events on CPUs {others})'
    # the kernel's own record, per thread: Fast DDS's discovery (UDP) and event threads on
    # the other CPUs, everything else (Python, the shared-memory listeners) on CPU 0
    import ast
    from ros_ehs.nodes.ros_common import SIDE_THREADS
    placed = ast.literal_eval(placed)        # [(thread name, its CPUs)], one per distinct pair
    names = [n for n, _ in placed]
    assert any(n.startswith(('dds.udp.', 'dds.ev.')) for n in names), names
    assert any(n.startswith('dds.shm.') and n != 'dds.shm.wdog' for n in names), names
    for name, cpus in placed:
        want = others if name.startswith(SIDE_THREADS) else [0]
        assert list(cpus) == want, (name, cpus)
    assert len(os.sched_getaffinity(0)) >= 1     # the test process itself is untouched
