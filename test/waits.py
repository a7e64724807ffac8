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
What the DDS tests wait for: a message, a status, a count on disk; never the clock.

Each wait has a bound (generous: a test waits for what it needs, so a loaded machine only
makes it slower), and says on timeout what it saw.
"""

from ros_ehs.data.bag import wait_for_counts
from ros_ehs.nodes.ros_common import call_until_answered
import ros_ehs_msgs_py as c

#: the bound of a wait for a lock-step run or a bag [s]: a run of seconds takes a few on a
#: quiet machine, and several times that with both cores busy
BOUND = 180.0


def lockstep_complete(procs, name: str = 'plant', timeout: float = BOUND) -> None:
    """Wait until the lock-step plant says its run is complete (its status, not its log)."""
    assert procs.wait_status(c.PLANT_STATUS, lambda st: st.message == 'lock-step run complete',
                             timeout), procs[name].output()[-3000:]


def rosbags_read(bag, topic: str, convert) -> list:
    """Return ``convert(msg)`` of each message on ``topic``, decoded by rosbags (not ours)."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as r:
        conns = [x for x in r.connections if x.topic == topic]
        return [convert(ts.deserialize_cdr(raw, conn.msgtype))
                for conn, _, raw in r.messages(conns)]


def wait_for_bag(bag, least: dict, timeout: float = BOUND) -> dict:
    """Wait until the bag being recorded holds ``least`` = {topic: count} on disk (bounded)."""
    return wait_for_counts(bag, least, timeout)


def status_value(procs, status: str, key: str, default: float = 0.0) -> float:
    """Return a number from a node's newest status (``default`` before any)."""
    return procs.status_value(status, key, default)


def wait_value(procs, status: str, key: str, least: float, timeout: float = BOUND) -> None:
    """Wait until a node's status says ``key`` >= ``least``."""
    assert procs.wait_status(status, lambda st: float(st.values.get(key, 'nan')) >= least,
                             timeout), (status, key, least, procs.status(status))


def call_service(ros, srv_type, name: str, request, timeout: float = BOUND):
    """
    Call service ``name`` from the test's node and return the response, with a bound.

    One client per service, kept on the node: a second client made for the same service sent
    a request the server had not discovered yet, and it was never answered (discovery matches
    the two sides one at a time). An unanswered request goes out again
    (:func:`ros_ehs.nodes.ros_common.call_until_answered`); the services called so are ones a
    repeat answers harmlessly.
    """
    cli = service_client(ros, srv_type, name, timeout)
    res = call_until_answered(cli, request, lambda until, t: ros.spin(until=until, timeout=t),
                              timeout)
    assert res is not None, f'{name} did not answer in {timeout:g} s'
    return res


def service_client(ros, srv_type, name: str, timeout: float = BOUND):
    """Return the test node's client of service ``name`` (made once), once the service is up."""
    clients = ros.__dict__.setdefault('_ehs_clients', {})
    cli = clients.get((srv_type, name))
    if cli is None:
        cli = clients[(srv_type, name)] = ros.create_client(srv_type, name)
    assert ros.spin(until=cli.service_is_ready, timeout=timeout), f'no service {name}'
    return cli


def set_parameter(ros, node: str, name: str, value):
    """Set parameter ``name`` of ``node`` through its parameter service; return the result."""
    from rclpy.parameter import Parameter
    from rcl_interfaces.srv import SetParameters
    req = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    return call_service(ros, SetParameters, f'{node}/set_parameters', req).results[0]


class Paused:
    """
    The lock-step loop held still (the plant's ``paused``) while a test calls a service.

    The answer to the state already sent steps the loop once more; the state after it waits
    until the pause ends. No process is stopped: Fast DDS takes a process frozen for more
    than about a second for a crashed one and can drop its paths for good
    (docs/recording.md, "A recorder that stalls"), which a freeze of the plant did to a loop
    once (it went on only by the plant's resends, 20 periods a second).
    """

    def __init__(self, ros):
        self.ros = ros

    def _set(self, on: bool) -> None:
        res = set_parameter(self.ros, '/plant', 'paused', on)
        assert res.successful, res.reason

    def __enter__(self):
        self._set(True)

    def __exit__(self, *exc):
        self._set(False)
