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
"""The nodes' common plumbing: QoS profiles to and from the contract's records."""

import ros_ehs_msgs_py as c


def test_contract_node_topics_are_contract_topics():
    for node, t in c.NODE_TOPICS.items():
        for topic in t.publishes + t.subscribes:
            assert topic in c.TOPICS, (node, topic)
            assert not topic.name.startswith('/') or topic is c.CLOCK   # relative names
    assert c.COMMAND in c.NODE_TOPICS['plant'].subscribes
    assert c.COMMAND in c.NODE_TOPICS['controller'].publishes


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


class _Client:
    """A service client whose first ``lost`` requests are never answered."""

    def __init__(self, lost):
        from rclpy.task import Future
        self.Future, self.lost, self.sent, self.dropped = Future, lost, [], []

    def call_async(self, request):
        fut = self.Future()
        self.sent.append(request)
        if len(self.sent) > self.lost:
            fut.set_result(('answer to', request))
        return fut

    def remove_pending_request(self, fut):
        self.dropped.append(fut)


def test_an_unanswered_request_goes_out_again_and_the_answer_is_returned():
    from ros_ehs.nodes.ros_common import call_until_answered
    cli, waited = _Client(lost=1), []

    def spin(until, seconds):
        waited.append(seconds)
        return until()

    assert call_until_answered(cli, 'req', spin, timeout=60.0, resend=5.0) == ('answer to', 'req')
    assert cli.sent == ['req', 'req'] and len(cli.dropped) == 1    # the lost one given up
    assert waited == [5.0, 5.0]                                      # each waited resend s


def test_a_request_never_answered_within_the_bound_gives_none():
    from ros_ehs.nodes.ros_common import call_until_answered
    cli = _Client(lost=10**9)
    assert call_until_answered(cli, 'req', lambda until, s: until(), timeout=0.05) is None
    assert len(cli.sent) == len(cli.dropped) >= 1
