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
Start ros_ehs nodes as processes and stop them cleanly (not ROS 2 ``launch``).

:class:`NodeProcesses` is what ``launch_scripts/``, the benchmarks and the integration tests use:
each node runs as ``python -m ros_ehs.nodes.<node> --ros-args ...`` (the same code
``ros2 run ros_ehs <node>`` runs), with its own log file, on one ``ROS_DOMAIN_ID``. Stopping
sends SIGINT in the given order, waits, and only then escalates to SIGTERM and SIGKILL, so a
recorder closes its bag.

:meth:`NodeProcesses.start_loop` learns what each node is ready for from its status in
``diagnostics`` (:meth:`NodeProcesses.status`, :meth:`NodeProcesses.wait_status`: a
:class:`ros_ehs.nodes.status_watch.StatusWatch` that joins the domain just before the first
node starts), never from its log; the logs are for people.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import json
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time
from typing import Any, Callable, Iterable

from ros_ehs.core.errors import EhsError
from ros_ehs.nodes.fastdds_profile import use_profile
from ros_ehs.nodes.fastdds_shm import clean_zombies, SHM_DIR
from ros_ehs.nodes.scheduling import (cpu_hogs, describe_threads, LOOP_CPUS_ENV,
                                      loop_placement, thread_states)
import ros_ehs_msgs_py as contract

__all__ = ['DUMP_SIGNAL', 'KILL_WAIT', 'LOOP_CPUS_ENV', 'NodeProcesses', 'StartupError',
           'launch_script', 'loop_closed', 'loop_placement', 'NodeProcess', 'node_command',
           'NODES', 'reap_killed', 'recording', 'reference_started']


def launch_script(name: str) -> Path:
    """
    Return the path of ``launch_scripts/<name>``: in this source tree, or installed.

    A colcon install puts them in the package's share directory
    (``share/ros_ehs/launch_scripts``, found through the ament index), not beside the code.
    """
    here = Path(__file__).resolve().parents[2] / 'launch_scripts' / name
    if here.exists():
        return here
    try:
        from ament_index_python.packages import get_package_share_directory
        installed = Path(get_package_share_directory('ros_ehs')) / 'launch_scripts' / name
    except (ImportError, LookupError, ValueError):
        installed = None
    if installed is None or not installed.exists():
        raise FileNotFoundError(f'launch_scripts/{name} is neither beside the code ({here}) '
                                'nor installed in the ros_ehs share directory')
    return installed


#: The signal that makes a node (every one runs :func:`ros_ehs.nodes.ros_common.run`) write
#: every thread's stack to its log at once (faulthandler, from its C handler: no GIL needed),
#: whatever it is doing: :meth:`NodeProcesses.stop` sends it to a node that did not exit in
#: time, before it signals it again
DUMP_SIGNAL = signal.SIGUSR1
#: How long the stacks have to reach the log before the next signal [s]
DUMP_WAIT = 1.0

#: How long a SIGKILLed process has to be gone [s]: one whose thread never gets a CPU (a
#: SCHED_FIFO thread holding it) is not, and nothing waits on it for good
KILL_WAIT = 10.0


def reap_killed(name: str, p: subprocess.Popen) -> None:
    """Wait :data:`KILL_WAIT` s for SIGKILLed ``p``; if it is still there, say why on stderr."""
    try:
        p.wait(KILL_WAIT)
        return
    except subprocess.TimeoutExpired:
        pass
    threads = thread_states(p.pid)
    print(f'{name} (pid {p.pid}) is still there {KILL_WAIT:g} s after SIGKILL: a thread of '
          'it gets no CPU to die on. Its threads:\n' + describe_threads(threads)
          + '\nthreads that held a CPU over the next 0.5 s:\n'
          + (describe_threads(cpu_hogs()) or '  none'), file=sys.stderr, flush=True)


#: The node executables of the package (``ros2 run ros_ehs <name>``).
NODES = ('plant', 'controller', 'reference', 'recorder', 'player', 'identify', 'procedure',
         'station', 'campaign')


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, float):
        return repr(v)      # always a double to rclpy: '1.0', '1e-05'
    if isinstance(v, (list, tuple)):
        return '[' + ','.join(_value(x) for x in v) + ']'
    if isinstance(v, str):      # quoted: '-p' values are YAML, where off or 1e3 is no string
        return "'" + v.replace("'", "''") + "'"
    return str(v)


def node_command(node: str, params: dict[str, Any] | None = None,
                 params_file: str | os.PathLike | None = None,
                 extra: Iterable[str] = ()) -> list[str]:
    """Return the command line that runs ``node`` with ``params`` (``-p name:=value``)."""
    if node not in NODES:
        raise ValueError(f'unknown node {node!r}; nodes: {list(NODES)}')
    cmd = [sys.executable, '-m', f'ros_ehs.nodes.{node}', '--ros-args']
    if params_file:
        cmd += ['--params-file', str(params_file)]
    for k, v in (params or {}).items():
        cmd += ['-p', f'{k}:={_value(v)}']
    return cmd + list(extra)


@dataclass
class NodeProcess:
    """One running node: its name, Popen, log file and (a plant) its figures file."""

    name: str
    popen: subprocess.Popen
    log: Path
    cmd: list[str] = field(default_factory=list)
    figures_file: Path | None = None
    node: str = ''          #: the node it runs (one of NODES), '' for another command

    @property
    def pid(self) -> int:
        """Process id."""
        return self.popen.pid

    def alive(self) -> bool:
        """Return True while the process runs."""
        return self.popen.poll() is None

    def output(self) -> str:
        """Return what the node has logged so far."""
        try:
            return self.log.read_text(errors='replace')
        except OSError:
            return ''

    def figures(self) -> dict:
        """Return the figures a plant wrote to its ``figures_file`` at exit."""
        try:
            return json.loads(self.figures_file.read_text())
        except (AttributeError, OSError, ValueError) as e:
            raise RuntimeError(f'no figures from {self.name} ({e}); its log:\n' +
                               self.output()[-3000:]) from None


#: each node's status name in ``diagnostics`` (the contract's)
STATUS_OF = {'plant': contract.PLANT_STATUS, 'controller': contract.CONTROLLER_STATUS,
             'reference': contract.REFERENCE_STATUS, 'recorder': contract.RECORDER_STATUS,
             'identify': contract.IDENTIFY_STATUS, 'procedure': contract.PROCEDURE_STATUS,
             'station': contract.STATION_STATUS, 'campaign': contract.CAMPAIGN_STATUS}


def loop_closed(st: contract.NodeStatus) -> bool:
    """Whether the plant's status says its loop is closed (level OK)."""
    return st.level == 0


def reference_started(st: contract.NodeStatus) -> bool:
    """Whether the reference's status says its trajectory has started (time zero)."""
    return st.values.get('started') == 'True'


def recording(*topics: contract.Topic | str) -> Callable[[contract.NodeStatus], bool]:
    """Return whether the recorder's status lists every one of ``topics`` as recorded."""
    names = {'/' + getattr(t, 'name', t).lstrip('/') for t in topics}
    return lambda st: names <= st.listed('recording')


class StartupError(EhsError, RuntimeError):
    """A node did not start or did not reach the state start_loop waits for (its log attached)."""


class NodeProcesses:
    """
    A set of node processes on one ROS domain; a context manager that stops them all.

    ``domain_id`` defaults to the environment's ``ROS_DOMAIN_ID``; ``log_dir`` to a new
    temporary directory. Discovery stays on this host (``ROS_AUTOMATIC_DISCOVERY_RANGE``
    LOCALHOST unless set), on the package's Fast DDS profile unless the environment names one
    (:mod:`ros_ehs.nodes.fastdds_profile`). ``clean_shm``: first remove the shared-memory
    ports and segments that processes which did not exit cleanly left in ``/dev/shm``
    (:func:`ros_ehs.nodes.fastdds_shm.clean_zombies`; what was done is in ``self.shm_cleanup``).
    ``bound`` [s]: how long each step of :meth:`start_loop` and each :meth:`wait_status` waits
    unless told (a test suite on a loaded machine passes its own, longer one).
    """

    def __init__(self, domain_id: int | None = None, log_dir: str | os.PathLike | None = None,
                 env: dict[str, str] | None = None, clean_shm: bool = True,
                 bound: float = 60.0) -> None:
        if not (math.isfinite(bound) and bound > 0):
            raise ValueError(f'`bound` = {bound!r} s must be finite and > 0')
        self.bound = float(bound)
        self.env = dict(os.environ)
        self.env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        self.env['PYTHONUNBUFFERED'] = '1'
        self.env['RCUTILS_LOGGING_BUFFERED_STREAM'] = '0'
        if domain_id is not None:
            self.env['ROS_DOMAIN_ID'] = str(int(domain_id))
        self.env.update(env or {})
        use_profile(self.env)          # the package's Fast DDS profile, unless one is named
        self.log_dir = Path(log_dir) if log_dir else Path(tempfile.mkdtemp(prefix='ehs_logs_'))
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.procs: dict[str, NodeProcess] = {}
        self.watch = None     # a StatusWatch, from the first node started
        self.shm_cleanup = clean_zombies() if clean_shm and SHM_DIR.is_dir() else None
        self.placement: tuple[int, int] | None = None     # set by start_loop

    def start(self, node: str, params: dict[str, Any] | None = None, *,
              name: str | None = None, params_file: str | os.PathLike | None = None,
              extra: Iterable[str] = (), cmd: list[str] | None = None) -> NodeProcess:
        """
        Start ``node`` (or an explicit ``cmd``) as process ``name`` (default the node).

        A plant writes its figures at exit to ``<log_dir>/<name>.figures.json`` (its
        ``figures_file``, unless given): :meth:`NodeProcess.figures` reads them.
        """
        name = name or node
        if name in self.procs and self.procs[name].alive():
            raise ValueError(f'process {name!r} is already running')
        figures = None
        if node == 'plant' and cmd is None:
            figures = Path((params or {}).get('figures_file') or
                           self.log_dir / f'{name}.figures.json')
            figures.unlink(missing_ok=True)
            params = {**(params or {}), 'figures_file': str(figures)}
        if self.watch is None and node in NODES:
            # on the domain before the first node: it joins no running loop, misses no status
            from ros_ehs.nodes.status_watch import StatusWatch
            dom = self.env.get('ROS_DOMAIN_ID')
            self.watch = StatusWatch(int(dom) if dom else None, self.env)
        if self.watch is not None and node in STATUS_OF:   # a restarted node's old word is void
            self.watch.forget(STATUS_OF[node])
        if cmd is None and params_file is None and \
                node in ('plant', 'controller', 'reference', 'procedure') and \
                'rt_priority' not in (params or {}):
            # a harness (bench.py, a benchmark, a test) says the priority it wants: its nodes
            # run as before unless asked (bench.py asks in real time, as `ros2 run`'s automatic
            # default does; here without the real-time Fast DDS profile, which that needs)
            params = {**(params or {}), 'rt_priority': 0}
        cmd = cmd or node_command(node, params, params_file, extra)
        log = self.log_dir / f'{name}.log'
        fh = open(log, 'wb')
        p = subprocess.Popen(cmd, env=self.env, stdout=fh, stderr=subprocess.STDOUT,
                             stdin=subprocess.DEVNULL)
        fh.close()
        ours = node if node in NODES else ''      # its own command too: an installed script
        self.procs[name] = NodeProcess(name, p, log, cmd, figures, ours)
        return self.procs[name]

    def __getitem__(self, name: str) -> NodeProcess:
        """Return process ``name``."""
        return self.procs[name]

    def kill(self, name: str) -> None:
        """SIGKILL process ``name`` (a crash, for the robustness tests)."""
        p = self.procs[name].popen
        if p.poll() is None:
            p.send_signal(signal.SIGKILL)
            reap_killed(name, p)

    def stop(self, names: Iterable[str] | None = None, timeout: float = 10.0) -> dict[str, int]:
        """
        Stop processes in the order given (default: reverse start order) with SIGINT.

        Each gets ``timeout`` seconds to exit, then SIGTERM, then SIGKILL. Returns the exit
        codes (negative: killed by that signal; None: still there :data:`KILL_WAIT` s after
        SIGKILL, said on stderr with its threads and what held the CPUs). A node still
        running after ``timeout`` is first sent :data:`DUMP_SIGNAL`: its threads' stacks go
        to its log (and a line saying so to stderr), where the hang shows.
        """
        order = list(names) if names is not None else list(reversed(list(self.procs)))
        codes = {}
        for n in order:
            proc = self.procs[n]
            p = proc.popen
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
                try:
                    p.wait(timeout)
                except subprocess.TimeoutExpired:
                    if proc.node:
                        p.send_signal(DUMP_SIGNAL)
                        print(f"{n} did not exit within {timeout:g} s of SIGINT: its threads' "
                              f'stacks are in {proc.log}', file=sys.stderr, flush=True)
                        try:
                            p.wait(DUMP_WAIT)
                        except subprocess.TimeoutExpired:
                            pass
                    p.terminate()
                    try:
                        p.wait(3.0)
                    except subprocess.TimeoutExpired:
                        p.kill()
                        reap_killed(n, p)
            codes[n] = p.returncode
        return codes

    def start_loop(self, mode: str = 'realtime', *, bag: str | os.PathLike | None = None,
                   plant: dict[str, Any] | None = None,
                   controller: dict[str, Any] | None = None,
                   reference: dict[str, Any] | bool = True,
                   recorder: dict[str, Any] | None = None,
                   procedure: dict[str, Any] | None = None,
                   params_file: str | os.PathLike | None = None,
                   pin: bool | None = None,
                   timeout: float | None = None) -> None:
        """
        Start the bench loop (recorder if ``bag``, controller, reference, plant) in order.

        The order makes sure a recorder loses nothing to discovery, which takes seconds
        between processes started together, and that the trajectory starts on a closed loop:

        * lock-step: the recorder, then the controller and the reference (under sim time it
          waits for ``/clock``); once the recorder records their topics, the plant, which
          starts stepping only when the controller (and the recorder) listen to ``state``;
        * real time: the recorder, the controller and the reference; once the recorder
          records the reference, the plant. Every participant is then discovered before
          the loop closes: one joining a running loop held its CPU at times (a watchdog trip
          in the loop's first 4-5 s in 3 of 10 runs; started first, 0 of 12).
          The reference's time zero waits for its subscribers (the controller and the
          recorder) and for the plant's diagnostics to report the loop closed, with the
          recorder listening to ``state`` (``wait_loop``, the plant's ``wait_subscribers``):
          the controller holds the first measured position until then, and the bag holds
          the states from time zero on.

        Returns when everything runs. ``plant``, ``controller``, ``reference``, ``recorder``:
        extra parameters (``reference=False``: no reference node). ``procedure`` (its
        options, ``file`` among them): the procedure node in the reference's place. Raises
        :class:`StartupError` naming the step that did not happen, with that node's log.
        ``timeout`` [s]: each step's wait (default ``bound``).

        ``pin`` (default: when this process may use two CPUs or more) sets the nodes'
        ``cpu_affinity`` as :func:`loop_placement` says, unless given in ``plant``,
        ``controller`` or ``reference``: the loop is a ping-pong, and one between two
        processes on one CPU skips the cross-CPU wake-up of a halted vCPU: lock-step runs
        1.5-2.3x faster, and a real-time bench has no watchdog trip in a window the machine
        does not stall (docs/nodes.md, "CPU placement").
        """
        if mode not in ('realtime', 'lockstep'):
            raise ValueError(f"mode: expected 'realtime' or 'lockstep', got {mode!r}")
        timeout = self.bound if timeout is None else timeout
        lock = mode == 'lockstep'
        cpus = loop_placement(pin)
        if cpus is not None:
            loop_cpu, ref_cpu = cpus
            plant = {'cpu_affinity': loop_cpu, **(plant or {})}
            controller = {'cpu_affinity': loop_cpu, **(controller or {})}
            if reference is not False:
                reference = {'cpu_affinity': ref_cpu,
                             **({} if reference is True else reference)}
            if procedure is not None:
                procedure = {'cpu_affinity': ref_cpu, **procedure}
        self.placement = cpus
        pf = params_file
        rec = bag is not None
        if procedure is not None:
            reference = False

        def start_reference(**extra):
            ref = {'use_sim_time': lock, **extra, **({} if reference is True else reference)}
            self.start('reference', ref, params_file=pf)

        if rec:
            self.start('recorder', {'out': str(bag), 'use_sim_time': lock, **(recorder or {})},
                       params_file=pf)
            self._expect('recorder', contract.RECORDER_STATUS, lambda st: True,
                         timeout, 'the recorder did not start')
        self.start('controller', {'lockstep': lock, **(controller or {})}, params_file=pf)
        if procedure is not None:
            # the controller's ramp-on, which the test waits for and does not learn from
            ramp = {'ramp_time': controller['ramp_time']} if controller and \
                'ramp_time' in controller else {}
            self.start('procedure', {'use_sim_time': lock, **ramp, **procedure},
                       params_file=pf)
        if lock:
            first = [contract.COMMAND]
            if reference is not False:
                start_reference()
                first.append(contract.REFERENCE)
            if procedure is not None:
                first += [contract.REFERENCE, contract.CYCLES]
            if rec:
                self._expect('recorder', contract.RECORDER_STATUS, recording(*first), timeout,
                             'the recorder did not discover the controller and reference')
        if not lock and reference is not False:
            start_reference(wait_subscribers=2 if rec else 1, wait_loop=True)
            if rec:
                self._expect('recorder', contract.RECORDER_STATUS, recording(contract.REFERENCE),
                             timeout, 'the recorder did not discover the reference')
        if rec and not lock:
            # the controller's commands reach the bag from the loop's first period: matching
            # took 2 s after discovery at times (a bag began 1.2 s after the sine's start)
            command = '/' + contract.COMMAND.name.lstrip('/')
            self._expect('recorder', contract.RECORDER_STATUS,
                         lambda st: command in st.listed('matched'),
                         timeout, "the recorder did not match the controller's commands")
        # lock-step: the plant starts stepping when they listen; real time: it reports the
        # loop running only then, and the reference's time zero waits for that report
        # the controller, the recorder and a reference that corrects from the state
        corrects = isinstance(reference, dict) and any(
            reference.get(k) for k in ('amplitude_phase_control', 'peak_valley_control'))
        pl = {'mode': mode, 'wait_subscribers': 1 + rec + corrects + (procedure is not None),
              **(plant or {})}
        self.start('plant', pl, params_file=pf)
        self._expect('plant', contract.PLANT_STATUS, loop_closed, timeout,
                     'the loop did not close')
        if rec:
            loop = (contract.STATE, contract.LOAD_CELL, contract.PRESSURE_P, contract.PRESSURE_T)
            loop += (contract.CLOCK,) if lock else (contract.COMMAND,)
            self._expect('recorder', contract.RECORDER_STATUS, recording(*loop), timeout,
                         "the recorder did not discover the loop's topics")
        if not lock and reference is not False:
            self._expect('reference', contract.REFERENCE_STATUS, reference_started, timeout,
                         'the reference did not start: no controller (and recorder) to start '
                         'for, or no diagnostics from the plant saying its loop is closed')

    def status(self, status_name: str) -> contract.NodeStatus | None:
        """Return the latest status ``status_name`` on the domain (None: none seen yet)."""
        return None if self.watch is None else self.watch.status(status_name)

    def watch_report(self) -> str:
        """Say what the status watch has heard (:meth:`StatusWatch.report`), for a failure."""
        return 'no status watch' if self.watch is None else self.watch.report()

    def status_value(self, status_name: str, key: str, default: float = 0.0) -> float:
        """Return the number ``key`` of the latest status ``status_name`` (``default``: none)."""
        st = self.status(status_name)
        try:
            return float(st.values[key]) if st is not None else default
        except (KeyError, ValueError):
            return default

    def wait_status(self, status_name: str, ready: Callable[[contract.NodeStatus], bool],
                    timeout: float | None = None) -> contract.NodeStatus | None:
        """
        Wait until status ``status_name`` satisfies ``ready``; return that status.

        None after ``timeout`` s (default ``bound``). ``ready`` is judged on every message as
        it comes (a state shorter than the poll is not missed: a lock-step dwell passes in
        a few milliseconds) and on the newest status every 50 ms (a condition on something
        else, such as a process that ended, is seen without a new message).
        """
        end = time.monotonic() + (self.bound if timeout is None else timeout)
        w = self.watch.waiter(status_name, ready) if self.watch is not None else None
        try:
            while True:
                st = self.status(status_name)
                if st is not None and ready(st):
                    return st
                if w is not None and w.event.wait(0.05):
                    if w.error is not None:
                        raise w.error
                    return w.status
                if w is None:
                    time.sleep(0.05)
                if time.monotonic() >= end:
                    return None
        finally:
            if w is not None:
                self.watch.unwait(w)

    def _expect(self, name: str, status_name: str,
                ready: Callable[[contract.NodeStatus], bool], timeout: float,
                what: str) -> None:
        """Wait until ``ready(status)``; any child that exits meanwhile fails it at once."""
        end = time.monotonic() + timeout
        while True:
            st = self.status(status_name)
            if st is not None and ready(st):
                return
            dead = [n for n, p in self.procs.items() if not p.alive()]
            if dead:
                n = dead[0]
                code = self.procs[n].popen.returncode
                raise StartupError(f'{n} exited with code {code} while the bench was starting '
                                   f'(waiting: {what}); {n} log:\n' +
                                   self.procs[n].output()[-3000:])
            if time.monotonic() >= end:
                seen = ('no status from it' if st is None else
                        f'its status: {st.message!r} {st.values}')
                raise StartupError(f'{what} ({status_name} in diagnostics, {timeout:g} s; '
                                   f'{seen}; {self.watch_report()}); {name} log:\n' +
                                   self.procs[name].output()[-3000:])
            time.sleep(0.05)

    def close(self) -> None:
        """Stop everything still running; leave the domain."""
        self.stop()
        if self.watch is not None:
            self.watch.close()
            self.watch = None

    def __enter__(self) -> 'NodeProcesses':
        """Return self."""
        return self

    def __exit__(self, *exc) -> None:
        """Stop everything still running; leave the domain."""
        self.close()
