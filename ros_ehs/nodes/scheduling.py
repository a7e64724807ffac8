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
Where and how a node's threads run: SCHED_FIFO priority and CPU placement, through /proc.

:func:`set_realtime` and :func:`set_cpu_affinity` apply a node's ``rt_priority`` and
``cpu_affinity`` options (:data:`RT_PRIORITY`, :data:`CPU_AFFINITY`) to every thread of the
process; each returns what it did, or why not, and never raises.
"""

from __future__ import annotations

import os

__all__ = ['AUTO_CPU', 'AUTO_PRIORITY', 'BENCH_PRIORITY', 'LOOP_CPUS_ENV', 'POLICIES',
           'REFERENCE_PRIORITY', 'RISK', 'RUNAWAY', 'SIDE_THREADS', 'cpu_hogs', 'describe_threads',
           'loop_placement', 'node_cpu', 'node_priority', 'realtime_allowed', 'rtprio_limit',
           'set_cpu_affinity', 'set_realtime', 'setpoint_priority', 'thread_states']


def _thread_ids() -> list[int]:
    """Return the ids of this process's threads (the executor's and the middleware's)."""
    return [int(t) for t in os.listdir('/proc/self/task')]


#: Fast DDS threads (by name) that carry no message of the loop, which goes over shared
#: memory: UDP receptions (discovery; a peer on another host), timed events (announcements,
#: heartbeats), the asynchronous writer, the shared-memory watchdog. ``set_cpu_affinity``
#: keeps them off the loop's CPU: measured (12 alternating pairs of 10 s
#: bench runs), 8 of 12 windows without a watchdog trip against 3 of 12 with them on it.
SIDE_THREADS = ('dds.udp.', 'dds.ev.', 'dds.asyn.', 'dds.shm.wdog')


def _thread_name(tid: int) -> str:
    try:
        with open(f'/proc/self/task/{tid}/comm') as f:
            return f.read().strip()
    except OSError:
        return ''


#: The SCHED_FIFO priority a real-time bench gives its plant and controller unless told
#: otherwise (``launch_scripts/bench.py``; the ``load`` benchmark runs the bench so)
BENCH_PRIORITY = 50
#: The SCHED_FIFO priority the setpoint's source (reference, procedure node) takes by default
#: in real time: under the loop's, above everything else (a browser on its CPU once held the
#: reference 91 ms: the controller carried it on a straight line and the piston, 4.5 mm off
#: the sine when the next came, was pulled back with 15 kN)
REFERENCE_PRIORITY = 40


def setpoint_priority(loop: int) -> int:
    """Return the setpoint source's priority under a loop at ``loop`` (0: none)."""
    return min(REFERENCE_PRIORITY, max(1, loop - 10)) if loop > 0 else 0


#: What a loop without real-time priority risks, said wherever it cannot have it.
RISK = ('the loop runs at normal priority: any other busy process on this machine (a browser, '
        'a build, a live refit) can delay its periods, the valve holding its last command '
        'meanwhile (python -m ros_ehs.benchmarks load measures what that does to the piston); '
        'loop_timing holds the axis when a state is answered 20 ms late')


def realtime_allowed(priority: int = 1) -> bool:
    """Say whether this process may use SCHED_FIFO ``priority`` (tried, then undone)."""
    try:
        old, param = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        os.sched_setscheduler(0, old, param)
        return True
    except (OSError, AttributeError):
        return False


def set_realtime(priority: int) -> str:
    """
    Put every thread of this process (the executor's and the middleware's) on SCHED_FIFO.

    ``priority`` 1-99; 0 leaves the default scheduler. Threads started later inherit it.
    The middleware's side threads (:data:`SIDE_THREADS`) too: they take the mutexes the
    loop's sends take, and one of them on the default scheduler, held by a busy browser
    while it had one, held the loop's send (a load benchmark's browser case missed its
    target 3 times in 12 runs so, 0 in 7 with them raised). A thread that spins at this
    priority is ended by :data:`RUNAWAY`. Returns what was done, or why not (no
    CAP_SYS_NICE and no ``ulimit -r``): never raises, a node without the privilege runs on
    as before.
    """
    if priority <= 0:
        return ''
    try:
        param = os.sched_param(priority)
        for tid in _thread_ids():
            os.sched_setscheduler(tid, os.SCHED_FIFO, param)
    except (OSError, AttributeError) as err:
        return (f'rt_priority {priority} not applied ({getattr(err, "strerror", err)}): it '
                'needs CAP_SYS_NICE or an rtprio limit (ulimit -r, /etc/security/limits.conf); '
                f'{RISK}')
    return f'threads on SCHED_FIFO priority {priority}' + _limit_runaway()


#: A thread of a real-time process busy this long without sleeping [s] writes every thread's
#: stack to stderr (then once a second), and this long ends the process (RLIMIT_RTTIME, as
#: rtkit asks of the processes it raises): a loop period is a millisecond's work, and a
#: SCHED_FIFO thread that never sleeps holds its CPU from every thread under it for good
RUNAWAY = (0.5, 5.0)


def _limit_runaway() -> str:
    """Set :data:`RUNAWAY` on this process; return what to add to the news (or why not)."""
    import faulthandler
    import resource
    import signal

    def under(limit: int, old: int) -> int:         # never above a limit already set
        return limit if old == resource.RLIM_INFINITY else min(limit, old)
    try:
        old = resource.getrlimit(resource.RLIMIT_RTTIME)
        resource.setrlimit(resource.RLIMIT_RTTIME,
                           tuple(under(int(x * 1e6), o) for x, o in zip(RUNAWAY, old)))
        faulthandler.register(signal.SIGXCPU, all_threads=True, chain=False)
    except (OSError, ValueError, AttributeError, RuntimeError) as err:
        return f'; no limit on a runaway thread ({err})'
    return (f'; a thread busy {RUNAWAY[0]:g} s without sleeping dumps the stacks, '
            f'{RUNAWAY[1]:g} s ends the process')


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


#: the kernel's clock ticks per second, the unit of /proc's CPU times
_TICKS_PER_S = os.sysconf('SC_CLK_TCK')
#: scheduling policies by number, as /proc gives them
POLICIES = {0: 'SCHED_OTHER', 1: 'SCHED_FIFO', 2: 'SCHED_RR', 3: 'SCHED_BATCH', 5: 'SCHED_IDLE',
            6: 'SCHED_DEADLINE'}


def _task_stat(pid: int, tid: int) -> dict | None:
    """Return one thread's name, state, CPU, policy, priority and CPU time [s] from /proc."""
    try:
        with open(f'/proc/{pid}/task/{tid}/stat') as f:
            raw = f.read()
    except OSError:
        return None
    try:
        rest = raw[raw.rindex(')') + 2:].split()     # from field 3 (state) on
        return {'pid': pid, 'tid': tid, 'name': raw[raw.index('(') + 1:raw.rindex(')')],
                'state': rest[0], 'cpu': int(rest[36]), 'priority': int(rest[37]),
                'policy': POLICIES.get(int(rest[38]), rest[38]),
                'cpu_s': (int(rest[11]) + int(rest[12])) / _TICKS_PER_S}
    except (ValueError, IndexError):
        return None


def thread_states(pid: int) -> list[dict]:
    """
    Return the threads of process ``pid`` as the kernel has them (empty: no such process).

    Each: ``tid``, ``name``, ``state`` (R running or waiting for a CPU, S sleeping, D in the
    kernel), ``cpu`` (last ran on), ``policy``, ``priority`` and ``cpu_s`` (CPU time used).
    """
    try:
        tids = sorted(int(t) for t in os.listdir(f'/proc/{pid}/task'))
    except OSError:
        return []
    return [t for t in (_task_stat(pid, tid) for tid in tids) if t is not None]


def cpu_hogs(interval: float = 0.5, share: float = 0.5) -> list[dict]:
    """
    Return the threads of this machine that used more than ``share`` of a CPU over ``interval`` s.

    What held a CPU while a process could not run there; each as :func:`thread_states` gives
    it, with ``share`` (of one CPU) and the process's command line, the busiest first.
    """
    import time

    def every() -> dict:
        out = {}
        for d in os.listdir('/proc'):
            if d.isdigit():
                for t in thread_states(int(d)):
                    out[(t['pid'], t['tid'])] = t
        return out
    before, t0 = every(), time.monotonic()
    time.sleep(interval)
    after, dt = every(), max(time.monotonic() - t0, 1e-3)
    hogs = []
    for key, t in after.items():
        if key in before:
            used = (t['cpu_s'] - before[key]['cpu_s']) / dt
            if used > share:
                try:
                    with open(f'/proc/{t["pid"]}/cmdline', 'rb') as f:
                        cmd = f.read().replace(b'\0', b' ').decode(errors='replace').strip()
                except OSError:
                    cmd = '?'
                hogs.append({**t, 'share': round(used, 2), 'command': cmd[:200]})
    return sorted(hogs, key=lambda h: -h['share'])


def describe_threads(threads: list[dict]) -> str:
    """Return threads (:func:`thread_states`, :func:`cpu_hogs`) as lines for a log."""
    return '\n'.join(
        f"  pid {t['pid']} tid {t['tid']} {t['name']}: state {t['state']} on CPU {t['cpu']}, "
        f"{t['policy']} {t['priority']}"
        + (f", {t['share']:.0%} of a CPU: {t['command']}" if 'share' in t else '')
        for t in threads)


#: the environment variable that places the loop: ``LOOP_CPU,REFERENCE_CPU`` (e.g. ``1,0``)
LOOP_CPUS_ENV = 'ROS_EHS_LOOP_CPUS'


def loop_placement(pin: bool | None = None) -> tuple[int, int] | None:
    """
    Return the CPUs of a pinned loop, (plant and controller, reference), or None: unpinned.

    The first two CPUs this process may use, or the two that ``ROS_EHS_LOOP_CPUS`` names
    (two benches side by side, as the test suite's workers run them, each on its own CPU:
    both on the first one slowed both). ``pin`` None: only if this process may use two CPUs
    or more (on one CPU there is nothing to place); True: always (one CPU: all on it);
    False: never.
    """
    allowed = sorted(os.sched_getaffinity(0))
    if pin is False or (pin is None and len(allowed) < 2):
        return None
    named = os.environ.get(LOOP_CPUS_ENV, '').strip()
    if named:
        try:
            cpus = tuple(int(c) for c in named.split(','))
        except ValueError:
            cpus = ()
        if len(cpus) != 2 or not set(cpus) <= set(allowed):
            raise ValueError(f'{LOOP_CPUS_ENV} = {named!r}: expected two CPUs of this '
                             f'process, LOOP,REFERENCE, of {allowed}')
        return cpus
    return allowed[0], allowed[1 % len(allowed)]


#: ``rt_priority`` -1, the loop nodes' default: :data:`BENCH_PRIORITY` in real time when the
#: process may, the default scheduler in lock-step (no deadline to take priority for)
AUTO_PRIORITY = -1
#: ``cpu_affinity`` -2, every node's default: the loop's nodes (plant, controller) on the
#: loop's CPU of :func:`loop_placement`, the others (reference, procedure, identify, station)
#: on the other one, so that a refit or a browser's page is never served on the loop's CPU;
#: anywhere on a machine (or a process) with one CPU
AUTO_CPU = -2


def rtprio_limit() -> str:
    """Return this process's ``ulimit -r`` (its RLIMIT_RTPRIO) as the shell says it."""
    try:
        import resource
        soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
        return 'unlimited' if soft == resource.RLIM_INFINITY else str(soft)
    except (ImportError, OSError, AttributeError):
        return '?'


def node_priority(option: int, realtime: bool, allowed=realtime_allowed,
                  auto: int = BENCH_PRIORITY) -> tuple[int, str]:
    """
    Resolve a node's ``rt_priority`` option: return the priority to apply and what to say.

    ``option`` as set (:data:`AUTO_PRIORITY`: the default); ``realtime``: the node runs
    against the wall clock (not lock-step, not on sim time); ``allowed(priority)``: whether
    this process may take it; ``auto``: the automatic priority (the loop's
    :data:`BENCH_PRIORITY`, the setpoint source's :data:`REFERENCE_PRIORITY`). The returned
    sentence is empty, or once-only news for the node's log: the automatic priority refused,
    and what running without it risks.
    """
    if option != AUTO_PRIORITY:
        return option, ''
    if not realtime:
        return 0, ''
    if allowed(auto):
        return auto, ''
    return 0, (f'rt_priority {AUTO_PRIORITY} (automatic): SCHED_FIFO {auto} is not '
               f'allowed to this process (no CAP_SYS_NICE, ulimit -r {rtprio_limit()}); '
               f'{RISK}')


def node_cpu(option: int, loop: bool, placement=loop_placement) -> int:
    """
    Resolve a node's ``cpu_affinity`` option: return the CPU to keep it on (-1: anywhere).

    ``option`` as set (:data:`AUTO_CPU`: the default); ``loop``: the node carries the loop
    (plant, controller); ``placement()``: :func:`loop_placement`'s CPUs or None (one CPU).
    """
    if option != AUTO_CPU:
        return option
    try:
        cpus = placement()
    except ValueError:       # a bad ROS_EHS_LOOP_CPUS: the launcher says so; anywhere here
        return -1
    if cpus is None:
        return -1
    return cpus[0] if loop else cpus[1]
