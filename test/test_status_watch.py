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
"""The status watch: the newest status of each node on a domain, from diagnostics."""

import pytest


@pytest.mark.ros
def test_the_watch_keeps_each_status_newest_and_forgets_a_restarted_nodes(dom):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from ros_ehs.nodes.status_watch import StatusWatch
    import ros_ehs_msgs_py as c

    def msg(level, started):
        return DiagnosticArray(status=[DiagnosticStatus(
            level=bytes([level]), name=c.REFERENCE_STATUS, message='sine',
            values=[KeyValue(key='started', value=started)])])
    with StatusWatch(dom) as watch:
        assert watch.status(c.REFERENCE_STATUS) is None
        watch._on_diagnostics(msg(1, 'False'))
        watch._on_diagnostics(msg(0, 'True'))
        st = watch.status(c.REFERENCE_STATUS)
        assert (st.level, st.values) == (0, {'started': 'True'}) and watch.received == 2
        watch.forget(c.REFERENCE_STATUS)
        assert watch.status(c.REFERENCE_STATUS) is None
    watch.close()                                  # idempotent


@pytest.mark.ros
def test_a_wait_sees_a_state_that_passed_between_two_polls(dom, tmp_path):
    """A lock-step dwell passes in milliseconds: the wait judges every message as it comes."""
    import threading
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from ros_ehs.nodes.processes import NodeProcesses
    from ros_ehs.nodes.status_watch import StatusWatch
    import ros_ehs_msgs_py as c

    def msg(step):
        return DiagnosticArray(status=[DiagnosticStatus(
            level=bytes([0]), name=c.PROCEDURE_STATUS, message=f'step {step}',
            values=[KeyValue(key='step_index', value=str(step))])])
    with NodeProcesses(dom, tmp_path / 'logs', bound=10.0) as procs:
        procs.watch = StatusWatch(dom)
        procs.watch._on_diagnostics(msg(1))

        def feed():     # once the wait listens: the dwell (step 2) and at once step 3
            for _ in range(10000):
                if procs.watch._waiters:
                    break
                threading.Event().wait(0.001)
            procs.watch._on_diagnostics(msg(2))
            procs.watch._on_diagnostics(msg(3))
        threading.Thread(target=feed).start()
        st = procs.wait_status(c.PROCEDURE_STATUS, lambda st: st.values['step_index'] == '2')
        assert st is not None and st.message == 'step 2'
        assert procs.status(c.PROCEDURE_STATUS).message == 'step 3'      # the newest
        assert procs.watch._waiters == []                                # the wait's gone
        # a condition that raises on a message fails the wait with it (false on step 3)
        threading.Thread(target=feed).start()
        with pytest.raises(KeyError):
            procs.wait_status(c.PROCEDURE_STATUS, lambda st: st.values['step_index'] == '2'
                              and st.values['nope'] == 'x')
        assert procs.wait_status(c.PROCEDURE_STATUS, lambda st: False, 0.2) is None


@pytest.mark.ros
def test_a_message_the_watch_cannot_read_is_counted_and_said_and_the_watch_goes_on(dom):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from ros_ehs.nodes.status_watch import StatusWatch
    import ros_ehs_msgs_py as c
    with StatusWatch(dom) as watch:
        assert 'read, 0 rejected; statuses last heard: none' in watch.report()
        watch._on_diagnostics(object())                       # not a DiagnosticArray
        watch._on_diagnostics(DiagnosticArray(status=[DiagnosticStatus(
            level=bytes([0]), name=c.REFERENCE_STATUS, message='sine')]))
        assert (watch.received, watch.rejected) == (1, 1)
        assert watch.status(c.REFERENCE_STATUS).message == 'sine'
        said = watch.report()
        assert '1 diagnostics messages read, 1 rejected' in said and 'AttributeError' in said \
            and f'{c.REFERENCE_STATUS} 0.' in said and 'thread spinning' in said, said


@pytest.mark.ros
def test_the_watch_takes_the_nodes_dds_environment_without_leaving_it_behind(dom, tmp_path):
    import os
    from ros_ehs.nodes.status_watch import StatusWatch
    profile = tmp_path / 'gone.xml'             # as a test's temporary profile, deleted later
    before = os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE')
    with StatusWatch(dom, {'FASTRTPS_DEFAULT_PROFILES_FILE': str(profile),
                           'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}):
        assert os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE') == before
    assert os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE') == before
