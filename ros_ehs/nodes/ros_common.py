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
The rclpy plumbing every ros_ehs node shares: QoS, messages, diagnostics, the run loop.

* :func:`qos_profile` turns a contract :class:`~ros_ehs_msgs_py.QosSpec` into a QoSProfile,
  :func:`qos_spec` back;
* :func:`read_msg` converts a message, or logs and skips a malformed one;
* :func:`run` is every node's ``main``: ``--params-file`` handling, scheduling
  (:mod:`ros_ehs.nodes.scheduling`), the EventsExecutor, and a clean shutdown on
  SIGINT/SIGTERM (the node's ``close()`` runs, so a bag is closed properly);
* :func:`diagnostics` builds the ``diagnostics`` message.

Parameters: :mod:`ros_ehs.nodes.parameters`.
"""

from __future__ import annotations

import faulthandler
import gc
import importlib
import os
import signal
import sys
import threading
import time
from typing import Any, Callable, Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from ros_ehs.core.errors import EhsError
from ros_ehs.nodes.fastdds_profile import ENV, use_profile
from ros_ehs.nodes.parameters import check_names
from ros_ehs.nodes.processes import DUMP_SIGNAL, launch_script
from ros_ehs.nodes.scheduling import (BENCH_PRIORITY, node_cpu, node_priority, realtime_allowed,
                                      set_cpu_affinity, set_realtime)
import ros_ehs_msgs_py as contract

__all__ = ['ERROR', 'OK', 'PLANT_STATUS', 'RESEND', 'WARN', 'call_service', 'call_until_answered',
           'diagnostics', 'msg_class', 'qos_profile', 'qos_spec', 'read_msg', 'ros_args', 'run',
           'set_parameters_request', 'steady_clock', 'STOP_DUMP', 'STOP_GRACE']

OK, WARN, ERROR = 0, 1, 2
#: The plant's status in ``diagnostics`` (level OK once its loop is closed; see the contract)
PLANT_STATUS = contract.PLANT_STATUS

#: After a stop, the executor has this long to return before the node closes without it [s].
STOP_GRACE = 2.0

#: A process not gone this long after its stop's drain and ``STOP_GRACE`` writes every
#: thread's Python stack to stderr (its log) [s]: faulthandler's own thread does it, which
#: needs no GIL, so a process hung anywhere (its close, a middleware call, a thread that
#: keeps the GIL) still says where, before its supervisor's SIGKILL
STOP_DUMP = 5.0


def qos_profile(spec: Any, depth: int | None = None) -> QoSProfile:
    """Return the rclpy QoSProfile of a contract QosSpec (``depth`` overrides its depth)."""
    rel = {'reliable': ReliabilityPolicy.RELIABLE,
           'best_effort': ReliabilityPolicy.BEST_EFFORT}[spec.reliability]
    dur = {'volatile': DurabilityPolicy.VOLATILE,
           'transient_local': DurabilityPolicy.TRANSIENT_LOCAL}[spec.durability]
    hist = {'keep_last': HistoryPolicy.KEEP_LAST, 'keep_all': HistoryPolicy.KEEP_ALL}[spec.history]
    return QoSProfile(history=hist, depth=int(depth or spec.depth), reliability=rel,
                      durability=dur)


def qos_spec(profile: Any) -> contract.QosSpec:
    """Return the contract QosSpec of an rclpy QoSProfile (the inverse of qos_profile)."""
    return contract.QosSpec(
        'reliable' if profile.reliability == ReliabilityPolicy.RELIABLE else 'best_effort',
        max(1, int(profile.depth)),
        'transient_local' if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
        else 'volatile',
        'keep_all' if profile.history == HistoryPolicy.KEEP_ALL else 'keep_last')


def msg_class(msg_type: str):
    """Return the Python class of ``pkg/msg/Name`` (KeyError naming the type if unknown)."""
    try:
        pkg, kind, name = msg_type.split('/')
        return getattr(importlib.import_module(f'{pkg}.{kind}'), name)
    except (ValueError, ImportError, AttributeError):
        raise KeyError(f'message type {msg_type!r} is not installed') from None


def set_parameters_request(**values: Any):
    """Return a ``SetParameters`` request setting ``values`` (rclpy's own conversion)."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter
    return SetParameters.Request(parameters=[Parameter(k, value=v).to_parameter_msg()
                                             for k, v in values.items()])


def steady_clock() -> Clock:
    """Return a steady (monotonic) clock for wall-time loops and watchdogs."""
    return Clock(clock_type=ClockType.STEADY_TIME)


# -- messages ---------------------------------------------------------------------------------
def read_msg(node: Node, convert: Callable[[Any], Any], msg: Any, what: str) -> Any:
    """
    Return ``convert(msg)`` (a contract ``*_from_msg``), or None for a malformed message.

    A malformed message (missing joint, short arrays) is logged, throttled to once a second;
    the caller counts it.
    """
    try:
        return convert(msg)
    except (ValueError, IndexError, AttributeError) as err:
        node.get_logger().warning(f'ignored a malformed {what}: {err}',
                                  throttle_duration_sec=1.0)
        return None


# -- diagnostics ------------------------------------------------------------------------------
def diagnostics(node: Node, name: str, level: int, message: str,
                values: dict[str, Any]) -> DiagnosticArray:
    """Return a DiagnosticArray with one status ``name`` (values as strings, floats %.6g)."""
    arr = DiagnosticArray()
    arr.header.stamp = node.get_clock().now().to_msg()
    st = DiagnosticStatus(level=bytes([level]), name=name, message=message,
                          hardware_id=node.get_namespace().strip('/') or 'axis')
    st.values = [KeyValue(key=k, value=(f'{v:.6g}' if isinstance(v, float) else str(v)))
                 for k, v in values.items()]
    arr.status = [st]
    return arr


# -- running ----------------------------------------------------------------------------------
def ros_args(argv: Sequence[str]) -> list[str]:
    """
    Return ``argv`` with a bare ``--params-file FILE`` moved inside ``--ros-args``.

    ``ros2 run ros_ehs plant --params-file f.yaml`` then works as
    ``... --ros-args --params-file f.yaml`` does.
    """
    argv = list(argv)
    out, extra, k = [], [], 0
    in_ros = False
    while k < len(argv):
        a = argv[k]
        if a == '--ros-args':
            in_ros = True
        elif a == '--':
            in_ros = False
        if not in_ros and a == '--params-file' and k + 1 < len(argv):
            extra += ['--params-file', argv[k + 1]]
            k += 2
            continue
        out.append(a)
        k += 1
    if extra:
        out += ['--ros-args'] + extra
    return out


#: a service request unanswered this long [s] goes out again (see call_until_answered)
RESEND = 5.0


def call_until_answered(client: Any, request: Any,
                        spin: Callable[[Callable[[], bool], float], bool], timeout: float,
                        resend: float = RESEND) -> Any:
    """
    Call a service through ``client``, sending the request again while it is unanswered.

    Returns the response, or None when nothing answered within ``timeout`` [s]. ``spin(until,
    seconds)`` spins the caller's node until ``until()`` or for ``seconds``, and says which.
    A request goes out again after ``resend`` s unanswered: one sent while discovery had
    matched only this side (a server restarted after a kill lingers in discovery until its
    lease ends; a client made just now) is never answered. Only for services that a repeat
    answers harmlessly.
    """
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        fut = client.call_async(request)
        if spin(fut.done, min(resend, max(end - time.monotonic(), 0.1))):
            return fut.result()
        client.remove_pending_request(fut)
    return None


def call_service(node: Node, executor: Any, srv_type: Any, name: str, request: Any,
                 timeout: float) -> Any:
    """
    Call service ``name`` from ``node`` (spun by ``executor``) until it answers; return that.

    A harness's call (a benchmark's, a bench's): the client waits for the server, the request
    goes out again while unanswered (:func:`call_until_answered`), and the client is
    destroyed after. Raises RuntimeError naming the service when nothing answered within
    ``timeout`` [s]. Only for services that a repeat answers harmlessly.
    """
    def spin(until: Callable[[], bool], seconds: float) -> bool:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.02)
            if until():
                return True
        return False

    cli = node.create_client(srv_type, name)
    try:
        res = call_until_answered(cli, request, spin, timeout) \
            if spin(cli.service_is_ready, timeout) else None
    finally:
        node.destroy_client(cli)
    if res is None:
        raise RuntimeError(f'no answer from {name} in {timeout:g} s')
    return res


def _wait_acked(node: Node, bound: float = 2.0) -> None:
    """
    Wait, up to ``bound`` s in all, until every reliable reader has what this node published.

    A reliable writer that is destroyed drops what its readers have not acknowledged: a
    node's last word (the controller's 0 A, the last state) would miss a recorder now and then.
    """
    end = time.monotonic() + bound
    for pub in list(node.publishers):
        if pub.qos_profile.reliability != ReliabilityPolicy.RELIABLE:
            continue
        left = end - time.monotonic()
        if left <= 0:
            return
        try:
            pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9)))
        except Exception:                          # noqa: BLE001 a closing middleware
            return


def run(factory: Callable[[], Node], args: Sequence[str] | None = None,
        executor: str = 'events') -> int:
    """
    Create the node from ``factory`` and spin it until SIGINT/SIGTERM or until it is done.

    A node may define ``done`` (an rclpy Future: spin until it completes), ``stop()`` (called
    first when a signal comes: the controller sends its safe command there), ``drain_period``
    (seconds to keep spinning after a signal, to take in what is queued), ``close()``
    (called once, after spinning, even after a signal) and ``busy`` (True when a worker
    thread of its own is still computing: the process then exits without the interpreter's
    teardown, once everything is closed). A configuration error (bad parameter,
    missing bag) is printed as one line and gives exit code 2, never a traceback.

    **A bounded stop**: the executor spins on a thread of its own, and this (the main) thread
    only waits for a signal or ``done``; then it calls ``stop()``, lets the executor drain,
    asks it to return and waits at most ``STOP_GRACE`` seconds for it. An executor that does
    not return does not keep the node alive: ``close()`` runs anyway and the process exits
    with its code (and a line saying so), so every node exits within a bounded time of its
    signal, whatever the middleware does. A process still there :data:`STOP_DUMP` seconds
    after that writes every thread's stack to stderr: where it hangs.
    """
    argv = ros_args(sys.argv if args is None else args)
    # first: a node asked for its stacks (a supervisor about to kill it) says where it is even
    # if its main thread never runs Python again (starved of the GIL, in a middleware call)
    faulthandler.register(DUMP_SIGNAL, all_threads=True, chain=False)
    # Our own SIGINT/SIGTERM handling: leave the spin loop first, then close the node (a bag
    # gets its summary), then shut rclpy down. With rclpy's handler the context dies while
    # callbacks still publish.
    if not os.environ.get(ENV) and realtime_allowed(BENCH_PRIORITY):
        # a process whose loop nodes take SCHED_FIFO by default (rt_priority -1) gets the
        # profile bench.py gives a real-time bench's nodes: its shared-memory ports' 30 ms
        # check (docs/nodes.md)
        try:
            os.environ[ENV] = str(launch_script('fastdds_rt.xml'))
        except FileNotFoundError:        # a pip install without the share directory
            pass
    use_profile()              # the package's Fast DDS profile, unless one is named
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    # The stop is a byte in a pipe, not a threading.Event: a Python signal handler runs in
    # the main thread between two of its bytecodes, and Event.set() there deadlocked a plant
    # whose main thread was inside Event.wait() holding the Event's lock (SIGTERM ignored,
    # then SIGINT: the kind of cpython#126434). os.write takes no lock.
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)

    def wake(*_: object) -> None:
        try:
            os.write(wake_w, b'.')
        except OSError:          # the pipe full of wake-ups (or closed at the end): enough
            pass

    previous = {sig: signal.signal(sig, wake) for sig in (signal.SIGINT, signal.SIGTERM)}
    # The kernel may deliver a signal to any thread (the executor's, the middleware's): the
    # Python handler then waits for the main thread's next bytecode, and the main thread is
    # blocked in os.read below. The wake-up fd is written by the C handler on whichever
    # thread it runs, so the read returns (a node once ignored its SIGINT for good).
    previous_fd = signal.set_wakeup_fd(wake_w, warn_on_full_buffer=False)
    node = None
    rc = 0
    stuck = False
    name = getattr(factory, '__name__', 'node')
    try:
        node = factory()
        check_names(node)
        # the defaults (automatic): a loop node in real time on SCHED_FIFO when it may, or
        # said once what it risks; the loop's nodes on its CPU, the others off it
        priority, refused = node_priority(int(getattr(node, 'rt_priority', 0)),
                                          bool(getattr(node, 'realtime', False)),
                                          auto=int(getattr(node, 'auto_priority',
                                                           BENCH_PRIORITY)))
        cpu = node_cpu(int(getattr(node, 'cpu_affinity', -1)),
                       bool(getattr(node, 'carries_loop', False)))
        # placed first, then raised: a thread moved while still on the default scheduler
        # gets its share of a CPU that a SCHED_FIFO thread holds; raised first, it waited
        # there behind it for good (docs/nodes.md)
        for said in (refused, set_cpu_affinity(cpu), set_realtime(priority)):
            if said:
                (node.get_logger().info if said.startswith('threads') else
                 node.get_logger().warning)(said)
        # Real time: a full garbage collection walks every object of rclpy, numpy, numba and
        # scipy (about 85000, 46 ms: a dozen missed periods at 1 kHz). What exists after
        # start-up lives as long as the node: move it out of the collector's sight (no
        # collection first: that alone delayed the first tick by ~100 ms); what the loop
        # allocates later is still collected.
        gc.freeze()
        if executor == 'events':
            from rclpy.experimental import EventsExecutor
            exe = EventsExecutor()
        else:
            exe = SingleThreadedExecutor()
        exe.add_node(node)
        done = getattr(node, 'done', None) or Future()
        spinning = threading.Event()       # cleared: the spin thread is to return
        spinning.set()

        def spin() -> None:
            # in slices of 0.1 s, so the flag is seen; the wheel's EventsExecutor.spin()
            # busy-loops after a shutdown, and spin_once per event costs more CPU at 1 kHz
            try:
                while spinning.is_set() and rclpy.ok() and not done.done():
                    exe.spin_until_future_complete(done, timeout_sec=0.1)
            except (KeyboardInterrupt, ExternalShutdownException):
                pass
            finally:
                wake()

        thread = threading.Thread(target=spin, name='ehs-executor', daemon=True)
        thread.start()
        os.read(wake_r, 1)       # a signal, or the spin thread's end (done, a shutdown)
        drain = float(getattr(node, 'drain_period', 0.0))
        # armed before the node's stop(): a hang there is dumped too
        faulthandler.dump_traceback_later(drain + STOP_GRACE + STOP_DUMP)
        if not done.done() and hasattr(node, 'stop'):
            node.stop()
        if not done.done() and drain > 0:      # take in what is already queued
            thread.join(drain)
        spinning.clear()
        thread.join(STOP_GRACE)
        if thread.is_alive():
            stuck = True
            print(f'[{name}] the executor did not return within {STOP_GRACE:g} s of the stop: '
                  'closing without it', file=sys.stderr, flush=True)
        elif done.done():
            rc = int(done.result() or 0)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (EhsError, KeyError, ValueError, OSError) as err:
        print(f'[{name}] error: {err}', file=sys.stderr)
        rc = 2
    except ParameterException as err:
        print(f'[{name}] parameter error: {err}', file=sys.stderr)
        rc = 2
    finally:
        if node is not None:
            close = getattr(node, 'close', None)
            if close is not None:
                close()
            if stuck:        # the executor's thread holds the middleware: leave it there
                _leave(rc)
            _wait_acked(node)
            node.destroy_node()
        rclpy.try_shutdown()
        faulthandler.cancel_dump_traceback_later()
        faulthandler.unregister(DUMP_SIGNAL)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        signal.set_wakeup_fd(previous_fd)
        os.close(wake_r)
        os.close(wake_w)
        if node is not None and getattr(node, 'busy', False):
            # a worker thread still in compiled code (a refit): the interpreter's teardown
            # under it crashed once (SIGSEGV); everything is closed, so leave now
            _leave(rc)
    return rc


def _leave(rc: int) -> None:
    """Exit with ``rc`` now, without the interpreter's teardown (the output flushed)."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(rc)
