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
Messages written by a writer that is not ours, for our decoders to read.

rosbags (:func:`diagnostic_array`), or rclpy's message classes filled field by field as
another node fills them (:func:`estimate`), never our encoders.
"""


def diagnostic_array(statuses, sec: int = 0, nanosec: int = 0):
    """
    Return a DiagnosticArray that rosbags built, serialized and read back.

    ``statuses``: (name, level, message, [(key, value), ...]) each; the header's stamp is
    ``sec``, ``nanosec``.
    """
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    msg = T['diagnostic_msgs/msg/DiagnosticArray'](
        header=T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](
            sec=sec, nanosec=nanosec), frame_id=''),
        status=[T['diagnostic_msgs/msg/DiagnosticStatus'](
            level=level, name=name, message=message, hardware_id='axis',
            values=[T['diagnostic_msgs/msg/KeyValue'](key=k, value=v) for k, v in values])
            for name, level, message, values in statuses])
    kind = msg.__msgtype__
    return ts.deserialize_cdr(ts.serialize_cdr(msg, kind), kind)


def estimate(values: dict, adequate: bool, message: str = 'a test refit', sec: int = 1):
    """
    Return a ``parameter_estimates`` DiagnosticArray (rclpy) built field by field.

    As an identify node sends it, not by our encoder: one status ``ros_ehs/identify/estimate``,
    level OK or WARN by ``adequate``, ``values`` its key-value pairs in order.
    """
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    st = DiagnosticStatus(level=DiagnosticStatus.OK if adequate else DiagnosticStatus.WARN,
                          name='ros_ehs/identify/estimate', message=message,
                          hardware_id='axis')
    st.values = [KeyValue(key=k, value=v) for k, v in values.items()]
    msg = DiagnosticArray(status=[st])
    msg.header.stamp.sec = sec
    return msg
