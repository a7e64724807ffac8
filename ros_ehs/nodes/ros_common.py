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
The rclpy plumbing every ros_ehs node shares.

* :func:`qos_profile` turns a contract :class:`~ros_ehs_msgs_py.QosSpec` into a QoSProfile,
  :func:`qos_spec` back;
* :func:`declare_specs` declares parameters from the one table (:mod:`ros_ehs.params`) with
  their unit, meaning and range, and :class:`Option` declares a node's own settings;
* :func:`validate_changes` turns a rejected live change into ``SetParametersResult`` with the
  reason;
* :func:`run` is every node's ``main``: ``--params-file`` handling, the EventsExecutor, and a
  clean shutdown on SIGINT/SIGTERM (the node's ``close()`` runs, so a bag is closed properly);
* :func:`diagnostics` builds the ``diagnostics`` message.
"""

from __future__ import annotations

import gc
import importlib
import math
import os
import signal
import sys
from typing import Any, Callable, Iterable, NamedTuple, Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from ros_ehs.errors import EhsError, ParameterError
from ros_ehs.params import Params, ParamSpec
import ros_ehs_msgs_py as contract

__all__ = ['CPU_AFFINITY', 'EPOCH_PERIODS', 'OK', 'WARN', 'ERROR', 'Option', 'RT_PRIORITY',
           'PLANT_STATUS', 'SIDE_THREADS',
           'check_names', 'declare_options', 'declare_specs', 'diagnostics', 'msg_class',
           'qos_profile', 'qos_spec', 'read_msg', 'rejected_names', 'ros_args', 'run',
           'set_cpu_affinity', 'set_realtime', 'steady_clock', 'update_options',
           'validate_changes']

OK, WARN, ERROR = 0, 1, 2
#: The name of the plant's status in ``diagnostics``: level OK once its loop is closed
#: (watchdog armed, not tripped); a reference with ``wait_loop`` waits for it.
PLANT_STATUS = 'ros_ehs/plant'

#: A stamp (or ``/clock``) further back than this many periods than the last one starts a
#: new run: a restarted plant, a replayed bag (the controller's and reference's policies).
EPOCH_PERIODS = 5


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


def steady_clock() -> Clock:
    """Return a steady (monotonic) clock for wall-time loops and watchdogs."""
    return Clock(clock_type=ClockType.STEADY_TIME)


# -- parameters --------------------------------------------------------------------------------
class Option(NamedTuple):
    """A node's own setting (not a model or controller parameter): declared once here."""

    name: str
    default: Any
    description: str
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = True


def _descriptor(description: str, read_only: bool, lo=None, hi=None, integer=False,
                choices=()) -> ParameterDescriptor:
    d = ParameterDescriptor(description=description, read_only=read_only)
    if choices:
        d.additional_constraints = f'one of {list(choices)}'
    if lo is not None and hi is not None and math.isfinite(lo) and math.isfinite(hi):
        if integer:
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                         to_value=float(hi), step=0.0)]
    return d


def _coerce_int_overrides(node: Node, names: Iterable[str]) -> None:
    """Let ``kp: 1`` in a params file mean 1.0 (rclpy rejects integers for doubles)."""
    ov = getattr(node, '_parameter_overrides', None)
    if not isinstance(ov, dict):
        return
    for n in names:
        p = ov.get(n)
        if p is not None and p.type_ == Parameter.Type.INTEGER:
            ov[n] = Parameter(n, Parameter.Type.DOUBLE, float(p.value))


def declare_specs(node: Node, specs: Sequence[ParamSpec], values: Params,
                  read_only: bool = False) -> None:
    """Declare each spec as a ROS parameter: value from ``values``, unit/meaning, range."""
    _coerce_int_overrides(node, [s.name for s in specs if not s.is_choice])
    for s in specs:
        d = _descriptor(f'{s.meaning} [{s.unit}]' if s.unit else s.meaning, read_only,
                        s.lo, s.hi, choices=s.choices)
        v = values[s.name]
        node.declare_parameter(s.name, v if s.is_choice else float(v), d)


def _not_a_choice(o: Option, value: Any) -> str | None:
    """Return why ``value`` is not one of option ``o``'s choices, or None if it is."""
    if o.choices and value not in o.choices:
        return f'parameter `{o.name}` = {value!r} is not one of {list(o.choices)}'
    return None


def declare_options(node: Node, options: Sequence[Option]) -> dict[str, Any]:
    """Declare a node's options; return their values by name (checked against choices)."""
    _coerce_int_overrides(node, [o.name for o in options if isinstance(o.default, float)])
    out = {}
    for o in options:
        integer = isinstance(o.default, int) and not isinstance(o.default, bool)
        d = _descriptor(o.description, o.read_only, o.lo, o.hi, integer, o.choices)
        if isinstance(o.default, list) and not o.default:
            ptype = Parameter.Type.STRING_ARRAY
            v = node.declare_parameter(o.name, ptype, d).value or []
        else:
            v = node.declare_parameter(o.name, o.default, d).value
        why = _not_a_choice(o, v)
        if why:
            raise ParameterError(why)
        out[o.name] = v
    return out


def update_options(values: dict[str, Any], changes: Sequence[Parameter],
                   options: Sequence[Option]) -> None:
    """Apply accepted live changes of ``options`` to a node's option ``values``."""
    live = {o.name for o in options if not o.read_only}
    for p in changes:
        if p.name in live:
            values[p.name] = p.value


def node_params(node: Node, base: Params, specs: Sequence[ParamSpec]) -> Params:
    """Return ``base`` with the values of ``specs`` as the node now holds them (validated)."""
    return base.replace(**{s.name: node.get_parameter(s.name).value for s in specs})


def rejected_names(changes: Sequence[Parameter], declared: Callable[[str], bool]
                   ) -> str | None:
    """
    Return why a live change names no parameter the node can change, or None.

    An empty name, an undeclared one, and ``use_sim_time`` (read when the node starts: its
    clocks and staleness checks follow it) are rejected.
    """
    for p in changes:
        if not p.name or not p.name.strip():
            return 'a parameter with an empty name'
        if not declared(p.name):
            return f'parameter `{p.name}` is not declared by this node'
        if p.name == 'use_sim_time':
            return ('`use_sim_time` is read when the node starts (its clocks and staleness '
                    'checks follow it): restart the node with the new value')
    return None


def check_names(node: Node) -> None:
    """
    Make ``node`` reject live changes whose names :func:`rejected_names` rejects.

    Call it once every parameter is declared (rclpy runs these callbacks on declarations
    too): :func:`run` does, for every node.
    """
    def check(changes):
        why = rejected_names(changes, node.has_parameter)
        if why:
            node.get_logger().warning(f'parameter change rejected: {why}',
                                      throttle_duration_sec=1.0)
        return SetParametersResult(successful=why is None, reason=why or '')

    node.add_on_set_parameters_callback(check)


def validate_changes(current: Params, changes: Sequence[Parameter],
                     specs: Sequence[ParamSpec], options: Sequence[Option] = ()
                     ) -> tuple[SetParametersResult, Params | None]:
    """
    Check a live parameter change: return the result for rclpy and the new Params.

    The new set is validated as a whole (ranges and cross-relations such as F_cc <= F_sc),
    so the reason names the offending parameter. (Names are checked before, for every node:
    :func:`run` registers :func:`check_names`.)
    """
    names = {s.name for s in specs}
    opts = {o.name: o for o in options}
    upd = {}
    for p in changes:
        if p.name in names:
            upd[p.name] = p.value
        elif p.name in opts and (why := _not_a_choice(opts[p.name], p.value)):
            return SetParametersResult(successful=False, reason=why), None
    if not upd:
        return SetParametersResult(successful=True), None
    try:
        new = current.replace(**upd)
    except ParameterError as err:
        return SetParametersResult(successful=False, reason=str(err)), None
    return SetParametersResult(successful=True), new


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


def _thread_ids() -> list[int]:
    """Return the ids of this process's threads (the executor's and the middleware's)."""
    return [int(t) for t in os.listdir('/proc/self/task')]


#: Fast DDS threads (by name) that carry no message of the loop, which goes over shared
#: memory: UDP receptions (discovery; a peer on another host), timed events (announcements,
#: heartbeats), the asynchronous writer, the shared-memory watchdog. ``set_cpu_affinity``
#: keeps them off the loop's CPU: measured (12 alternating pairs of 10 s
#: main-job benches), 8 of 12 windows without a watchdog trip against 3 of 12 with them on it.
SIDE_THREADS = ('dds.udp.', 'dds.ev.', 'dds.asyn.', 'dds.shm.wdog')


def _thread_name(tid: int) -> str:
    try:
        with open(f'/proc/self/task/{tid}/comm') as f:
            return f.read().strip()
    except OSError:
        return ''


def set_realtime(priority: int) -> str:
    """
    Put every thread of this process (the executor's and the middleware's) on SCHED_FIFO.

    ``priority`` 1-99; 0 leaves the default scheduler. Threads started later inherit it.
    Returns what was done, or why not (no CAP_SYS_NICE and no ``ulimit -r``): never raises,
    a node without the privilege runs on as before.
    """
    if priority <= 0:
        return ''
    try:
        param = os.sched_param(priority)
        for tid in _thread_ids():
            os.sched_setscheduler(tid, os.SCHED_FIFO, param)
    except (OSError, AttributeError) as err:
        return (f'rt_priority {priority} not applied ({getattr(err, "strerror", err)}): it '
                'needs CAP_SYS_NICE or an rtprio limit (ulimit -r, /etc/security/limits.conf)')
    return f'threads on SCHED_FIFO priority {priority}'


def set_cpu_affinity(cpu: int) -> str:
    """
    Keep the threads of this process that carry the loop on CPU ``cpu`` (-1: anywhere).

    The loop's threads are the executor's, the Python ones and the middleware's
    shared-memory listeners; the middleware's other threads (:data:`SIDE_THREADS`:
    discovery, timed events) go to the other CPUs this process may use, so that a node
    joining the network or a participant's announcement does not hold the loop's CPU (on one
    CPU: all on it). Returns what was done, or why not (no such CPU); never raises.
    """
    if cpu < 0:
        return ''
    try:
        others = (set(os.sched_getaffinity(0)) - {cpu}) or {cpu}
        for tid in _thread_ids():
            side = _thread_name(tid).startswith(SIDE_THREADS)
            os.sched_setaffinity(tid, others if side else {cpu})
    except (OSError, AttributeError) as err:
        return (f'cpu_affinity {cpu} not applied ({getattr(err, "strerror", err)}): this '
                f'machine has CPUs {sorted(os.sched_getaffinity(0))}')
    return f'threads on CPU {cpu} (discovery and timed events on CPUs {sorted(others)})'


#: The ``cpu_affinity`` option of the loop nodes; ``Launch.start_loop`` sets it by default
#: (``ros_ehs.launch.loop_placement``). Measured on the 2-core VM, plant and controller on one
#: CPU and the reference on the other: 12400-14450 lock-step steps/s against 6280-8060
#: unpinned (a ping-pong between two processes on one core skips the cross-core wake-up; the
#: bare rclpy ping-pong gains 1.2-1.5x), and in real time no watchdog trip in 30 of 30 10 s
#: windows the machine did not stall (docs/nodes.md, "CPU placement").
CPU_AFFINITY = Option('cpu_affinity', -1, 'keep the threads of the node that carry the loop '
                      "on this CPU, the middleware's discovery and timed events on the "
                      'others (-1: anywhere); a bench: plant and controller on one, the '
                      'reference on another', -1, 1023)


#: The ``rt_priority`` option of the loop nodes (plant and controller), as ros2_control's
#: controller manager has ``thread_priority``.
RT_PRIORITY = Option('rt_priority', 0, 'real time: SCHED_FIFO priority of all the threads of '
                     'the node (1-99), so that other work on the machine cannot delay a '
                     'period; 0: the default scheduler. Needs CAP_SYS_NICE or ulimit -r',
                     0, 99)


def run(factory: Callable[[], Node], args: Sequence[str] | None = None,
        executor: str = 'events') -> int:
    """
    Create the node from ``factory`` and spin it until SIGINT/SIGTERM or until it is done.

    A node may define ``done`` (an rclpy Future: spin until it completes), ``drain_period``
    (seconds to keep spinning after a signal, to take in what is queued) and ``close()``
    (called once, after spinning, even after a signal). A configuration error (bad parameter,
    missing bag) is printed as one line and gives exit code 2, never a traceback.
    """
    argv = ros_args(sys.argv if args is None else args)
    # Our own SIGINT/SIGTERM handling: leave the spin loop first, then close the node (a bag
    # gets its summary), then shut rclpy down. With rclpy's handler the context dies while
    # callbacks still publish.
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    stop = []
    previous = {sig: signal.signal(sig, lambda signum, frame: stop.append(signum))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    node = None
    rc = 0
    try:
        node = factory()
        check_names(node)
        for said in (set_realtime(int(getattr(node, 'rt_priority', 0))),
                     set_cpu_affinity(int(getattr(node, 'cpu_affinity', -1)))):
            if said:
                (node.get_logger().info if said.startswith('threads') else
                 node.get_logger().warning)(said)
        # Real time: a full garbage collection walks every object of rclpy, numpy, numba and
        # scipy (about 85000, 46 ms on the project's VM: a dozen missed periods at 1 kHz).
        # What exists after start-up lives as long as the node: move it out of the
        # collector's sight (no collection first: that alone delayed the first tick by
        # ~100 ms); what the loop allocates later is still collected.
        gc.freeze()
        if executor == 'events':
            from rclpy.experimental import EventsExecutor
            exe = EventsExecutor()
        else:
            exe = SingleThreadedExecutor()
        exe.add_node(node)
        done = getattr(node, 'done', None) or Future()
        # Spin in slices of 0.1 s so our signal flag is seen; the wheel's
        # EventsExecutor.spin() busy-loops after a shutdown, and spin_once per event costs
        # more CPU at 1 kHz.
        while not stop and rclpy.ok() and not done.done():
            exe.spin_until_future_complete(done, timeout_sec=0.1)
        drain = float(getattr(node, 'drain_period', 0.0))
        if stop and drain > 0 and rclpy.ok():      # take in what is already queued
            exe.spin_until_future_complete(Future(), timeout_sec=drain)
        if done.done():
            rc = int(done.result() or 0)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (EhsError, KeyError, ValueError, OSError) as err:
        name = getattr(factory, '__name__', 'node')
        print(f'[{name}] error: {err}', file=sys.stderr)
        rc = 2
    except ParameterException as err:
        print(f'[{getattr(factory, "__name__", "node")}] parameter error: {err}',
              file=sys.stderr)
        rc = 2
    finally:
        if node is not None:
            close = getattr(node, 'close', None)
            if close is not None:
                close()
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return rc
