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
The barest rclpy ping-pong: the yardstick of ``bench loop`` and ``bench lockstep``.

``python -m ros_ehs.benchmarks.pingpong ping|pong|volley``. Nothing of ros_ehs is imported here:
plain ``rclpy.init``, one node, the EventsExecutor, best effort depth 1, JointState.

* ``ping``: a 1 kHz steady timer publishes a JointState (the size of our ``state``) stamped
  with its sequence number; a cycle is fresh when the echo of the previous ping came back
  before this tick; the round trip is timed from publish to echo; ``late_commands`` counts
  what the plant counts so (no echo for the 3 periods ending at the next tick: its
  ``LATE_PERIODS``), and lists the newest 100 as ``late_log`` (``[time.monotonic(), ms
  without an echo]``, as the plant's ``late_log`` starts).
* ``pong``: echoes each ping from its subscription callback, with the same stamp.
* ``volley``: the next ping goes out as soon as the echo of the last is back (a bare
  lock-step): round trips per second.
* ``relay`` and ``--relay``: the barest lock-step *with a reference process*, the lock-step
  bench's earlier topology (a clock and a reference every period). The volley also
  publishes a ``rosgraph_msgs/Clock`` with each ping (as the plant then did); the relay
  answers each clock k with a JointState stamped k + 1 (and k itself first); the pong echoes
  ping k only once it holds the relay's message k (as the controller waits for the
  reference of the state's stamp).

``--raw`` sends serialized messages (``publish`` of bytes, ``raw=True`` subscriptions), the
path the loop nodes take (ping, pong, volley). ``--reliable`` uses the
lock-step loop's QoS (reliable, depth 10000) instead;
``--rt-priority N`` puts every thread on SCHED_FIFO priority N, as the loop nodes' option
``rt_priority`` does; ``--cpu N`` keeps them on CPU N, as ``cpu_affinity`` does. On SIGINT
the ping or volley prints its figures as one JSON line; ``--seconds S`` ends a volley by
itself S seconds after its first echo (its caller waits for it to exit, not on a clock).
"""

from collections import deque
import json
import os
import signal
import struct
import sys
import threading
import time

import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.experimental import EventsExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from ros_ehs.benchmarks import FIRST_ECHO
from ros_ehs.nodes.ros_common import STOP_GRACE
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState

_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
#: ``--reliable``: the lock-step loop's QoS (the contract's LOCKSTEP_QOS), for comparison
_RELIABLE = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)
_N = 100000      # samples kept (100 s at 1 kHz)


def _pct(values, q):
    if not values:
        return float('nan')
    v = sorted(values)
    return v[min(len(v) - 1, int(round(q / 100.0 * (len(v) - 1))))]


def main(argv=None) -> int:
    """Run ``ping``, ``pong``, ``volley`` or ``relay`` until SIGINT."""
    args = sys.argv[1:] if argv is None else argv
    role = args[0]
    qos = _RELIABLE if '--reliable' in args else _QOS
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(role)
    exe = EventsExecutor()
    exe.add_node(node)
    if '--rt-priority' in args:
        prio = os.sched_param(int(args[args.index('--rt-priority') + 1]))
        for tid in os.listdir('/proc/self/task'):
            os.sched_setscheduler(int(tid), os.SCHED_FIFO, prio)
    if '--cpu' in args:
        cpu = int(args[args.index('--cpu') + 1])
        for tid in os.listdir('/proc/self/task'):
            os.sched_setaffinity(int(tid), {cpu})
    msg = JointState(name=['piston', 'spool', 'servo_valve'], position=[0.01, 4e-5, 0.0],
                     velocity=[0.02, 0.0, 0.0], effort=[3.0, 0.0, 0.001])
    st = {'k': 0, 'fresh': 0, 'cycles': 0, 'back': 0, 'sent': 0.0, 't0': None, 'n': 0,
          'rx': None, 'trips': 0, 'tripped': False, 'last_tick': None, 'period_max': 0.0}
    rtt = []
    trip_log = deque(maxlen=100)

    relay = '--relay' in args
    seconds = float(args[args.index('--seconds') + 1]) if '--seconds' in args else 0.0
    raw = '--raw' in args
    wire = bytearray(serialize_message(msg))       # --raw: stamp.sec at bytes 4-7
    if role == 'pong' and relay:
        pub = node.create_publisher(JointState, 'pong', qos)
        held, waiting = set(), {}

        def on_ping(m):
            k = m.header.stamp.sec
            if k in held:
                held.discard(k)
                pub.publish(m)
            else:
                waiting[k] = m

        def on_ref(r):
            k = r.header.stamp.sec
            if k in waiting:
                pub.publish(waiting.pop(k))
            else:
                held.add(k)
        node.create_subscription(JointState, 'ping', on_ping, qos)
        node.create_subscription(JointState, 'ref', on_ref, qos)
    elif role == 'pong':
        pub = node.create_publisher(JointState, 'pong', qos)
        node.create_subscription(JointState, 'ping', pub.publish, qos, raw=raw)
    elif role == 'relay':
        pub = node.create_publisher(JointState, 'ref', qos)

        def on_clock(c):
            k = c.clock.sec
            if not st['k']:
                msg.header.stamp.sec = k
                pub.publish(msg)
            st['k'] = k
            msg.header.stamp.sec = k + 1
            pub.publish(msg)
        node.create_subscription(ClockMsg, 'clock', on_clock, qos)
    else:
        pub = node.create_publisher(JointState, 'ping', qos)
        pub_clock = node.create_publisher(ClockMsg, 'clock', qos) if relay else None
        clock_msg = ClockMsg()

        def send():
            st['k'] += 1
            msg.header.stamp.sec = st['k']
            st['sent'] = time.monotonic()
            if pub_clock is not None:
                clock_msg.clock.sec = st['k']
                pub_clock.publish(clock_msg)
            if raw:
                struct.pack_into('<i', wire, 4, st['k'])
                pub.publish(bytes(wire))
            else:
                pub.publish(msg)

        def on_pong(m):
            if (struct.unpack_from('<i', m, 4)[0] if raw else m.header.stamp.sec) == st['k']:
                if st['rx'] is None:        # the pair talks: what a bench waits for
                    print(FIRST_ECHO, flush=True)
                st['n'] += 1
                st['rx'] = time.monotonic()
                if len(rtt) < _N:
                    rtt.append(st['rx'] - st['sent'])
                st['back'] = st['k']
                if role == 'volley':
                    if st['t0'] is None:
                        st['t0'] = time.monotonic()
                    if seconds and st['rx'] - st['t0'] >= seconds:
                        stop.append(1)
                        return
                    send()

        node.create_subscription(JointState, 'pong', on_pong, qos, raw=raw)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        if role == 'ping':
            def tick():
                t = time.monotonic()
                if st['last_tick'] is not None:
                    st['period_max'] = max(st['period_max'], t - st['last_tick'])
                st['last_tick'] = t
                if st['rx'] is not None:     # from the first echo, as the plant counts
                    st['cycles'] += 1
                    st['fresh'] += st['back'] == st['k']
                    # the plant's late-command rule (3 periods), counted the same way
                    late = st['rx'] is not None and time.monotonic() + 1e-3 - st['rx'] > 3e-3
                    if late and not st['tripped']:
                        st['trips'] += 1
                        trip_log.append([round(t, 6), round((t - st['rx']) * 1e3, 3)])
                    st['tripped'] = late
                send()
            node.create_timer(1e-3, tick, clock=steady)
        else:
            def kick():        # start, or restart after a lost message
                if pub.get_subscription_count() and (
                        st['k'] == 0 or time.monotonic() - st['sent'] > 0.05):
                    send()
            node.create_timer(0.05, kick, clock=steady)

    # spun as the loop nodes spin theirs (ros_common.run): on a thread, in 0.1 s slices, and
    # waited for at most STOP_GRACE after the stop, so the figures come out whatever the
    # middleware does
    spinning = threading.Event()
    spinning.set()

    def spin():
        while spinning.is_set() and rclpy.ok():
            exe.spin_until_future_complete(Future(), timeout_sec=0.1)

    thread = threading.Thread(target=spin, name='pingpong-executor', daemon=True)
    thread.start()
    while not stop and thread.is_alive():
        time.sleep(0.05)
    spinning.clear()
    thread.join(STOP_GRACE)
    if role == 'ping':
        ms = 1e3
        print(json.dumps({'cycles': st['cycles'], 'fresh_cycles': st['fresh'],
                          'late_commands': st['trips'],
                          'fresh_cycle_fraction': st['fresh'] / max(1, st['cycles']),
                          'rtt_p50_ms': _pct(rtt, 50) * ms, 'rtt_p99_ms': _pct(rtt, 99) * ms,
                          'rtt_max_ms': max(rtt, default=float('nan')) * ms,
                          'period_max_ms': st['period_max'] * ms,
                          'late_log': list(trip_log)}), flush=True)
    elif role == 'volley':
        dt = time.monotonic() - (st['t0'] or time.monotonic())
        n = st['n']
        print(json.dumps({'volleys': n, 'volleys_per_s': n / dt if dt > 0 else 0.0}),
              flush=True)
    if thread.is_alive():
        print(f'{role}: the executor did not return within {STOP_GRACE:g} s of the stop',
              file=sys.stderr, flush=True)
        os._exit(1)         # its shutdown would wait on the same executor
    exe.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
