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
The identify node's live mode over DDS, on lock-step loops.

Pushes reach a running controller, and a rig that is not the fitted model is never pushed.
The tests wait for the estimates the node publishes, never for a time.
"""

import pytest
from ros_ehs.core.params import preset
from ros_ehs.nodes.processes import NodeProcesses
import ros_ehs_msgs_py as c
from waits import BOUND, rosbags_read

pytestmark = pytest.mark.ros

NOISE = {'noise_z': 5e-6, 'noise_v': 1e-3, 'noise_p': 2e4, 'seed': 3}
#: the controller starts with friction and damping 30 % off the plant's (Table 1 estimated)
WRONG = {'F_cc': 730.0, 'F_sc': 1540.0, 'c_c': 12000.0}
#: the refits at normal priority: these tests judge what is pushed, not the scheduling (at
#: the rig's idle priority a machine whose cores another process keeps busy starves them, as
#: it should; test_stop checks that the default refits at SCHED_IDLE)
LIVE = {'live': True, 'push': True, 'window': 4.0, 'period': 2.0, 'push_period': 0.0,
        'cpu_affinity': -1, 'refit_priority': 'normal', 'use_sim_time': True}
#: the loop at twice the rig's speed, from when the identify node listens (the plant waits for
#: it, the controller and the recorder): a loop as fast as it runs would step on through
#: every refit, tens of seconds of sim time the tests do not need
LOOP = {**NOISE, 'duration': 600.0, 'real_time_factor': 2.0, 'wait_subscribers': 3}


def _estimates(bag):
    """Return the bag's parameter estimates, decoded by rosbags (not our reader)."""
    return rosbags_read(bag, '/parameter_estimates', c.estimate_from_msg)


def _controller_values(ros, names):
    from rclpy.parameter_client import AsyncParameterClient
    cli = AsyncParameterClient(ros, 'controller')
    assert ros.spin(until=cli.services_are_ready, timeout=BOUND)
    fut = cli.get_parameters(names)
    assert ros.spin(until=fut.done, timeout=BOUND)
    return dict(zip(names, (v.double_value for v in fut.result().values)))


def _listen(ros):
    """Return the list the estimates the identify node publishes go into, as they come."""
    from diagnostic_msgs.msg import DiagnosticArray
    from ros_ehs.nodes.ros_common import qos_profile
    got = []
    ros.create_subscription(DiagnosticArray, c.ESTIMATES.name,
                            lambda m: got.append(c.estimate_from_msg(m)),
                            qos_profile(c.ESTIMATES.qos))
    return got


def _run(procs, bag, plant, ros, done):
    """
    Run a lock-step loop with the live identify node until ``done(estimates)`` says so.

    Returns the controller's values then, and the identify node's log.
    """
    got = _listen(ros)
    procs.start('identify', LIVE)
    procs.start_loop('lockstep', bag=bag, plant={**LOOP, **plant},
                     controller=WRONG, reference={'cpu_affinity': -1})
    assert ros.spin(until=lambda: done(got), timeout=BOUND), (got, procs['identify'].output())
    values = _controller_values(ros, list(WRONG))
    procs.stop(['recorder', 'identify', 'reference', 'controller', 'plant'])
    return values, procs['identify'].output()


def test_live_fits_are_pushed_to_the_running_controller(dom, tmp_path, ros):
    bag = tmp_path / 'bag'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        # a push, and a refit after it (of a loop that has the pushed values: no change)
        values, out = _run(procs, bag, {}, ros, lambda est: any(e.pushed for e in est[:-1]))
    true = preset('table1_estimated')
    assert 'live push to `controller`' in out, out[-3000:]
    for n in WRONG:       # the controller now has the plant's values, not its wrong ones
        assert values[n] == pytest.approx(true[n], rel=0.03), (n, values, out[-3000:])
    est = _estimates(bag)
    assert est and any(e.pushed for e in est)
    pushed = [e for e in est if e.pushed]
    assert all(e.adequate for e in pushed)
    for e in pushed:       # each pushed estimate carries its standard errors
        assert set(e.values) == set(e.stderr) and all(s > 0 for s in e.stderr.values())
    assert 'Traceback' not in out


def test_a_rig_that_is_not_the_fitted_model_is_never_pushed(dom, tmp_path, ros):
    """The full 10-state plant, fitted with the simplified model: inadequate, never pushed."""
    bag = tmp_path / 'bag'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        values, out = _run(procs, bag, {'model': 'full'}, ros,
                           lambda est: sum(bool(e.values) for e in est) >= 2)
    assert values == pytest.approx(WRONG)       # untouched
    est = [e for e in _estimates(bag) if e.values]
    assert est, out[-3000:]
    assert not any(e.pushed for e in est)
    assert all(not e.adequate and 'not adequate' in e.verdict for e in est), est
    assert all(e.failed for e in est), est          # over DDS, in the bag: its rules
    assert 'live push to' not in out


def test_a_push_target_that_does_not_take_the_values_is_named_and_never_pushed(
        dom, tmp_path, ros):
    """The live node pointed at a node that does not declare the feedforward's values."""
    got = _listen(ros)
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start('identify', {**LIVE, 'controller': 'recorder'})
        procs.start_loop('lockstep', bag=tmp_path / 'bag', plant=LOOP,
                         reference={'cpu_affinity': -1})
        # named once, and it refits on: two estimates, never pushed
        assert ros.spin(until=lambda: len(got) >= 2, timeout=BOUND), \
            procs['identify'].output()[-3000:]
        procs.stop(['recorder', 'identify', 'reference', 'controller', 'plant'])
    assert not any(e.pushed for e in got)
    out = procs['identify'].output()
    assert "`recorder` does not declare ['d_c', 'F_cc', 'F_sc', 'l_iac', 'c_c']" in out, out
    assert out.count('does not declare') == 1 and 'live push to' not in out
    assert 'live refit at' in out and 'Traceback' not in out
