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
The latest status of each node on a ROS domain, from ``diagnostics``.

What :class:`ros_ehs.nodes.processes.NodeProcesses` waits on while it starts a loop (the recorder
records and has matched a topic, the plant's loop is closed, the reference has started), so
that processes tell each other their readiness in messages, never in log text. The statuses
and their readiness values are the contract's (:mod:`ros_ehs_msgs_py.topics`).

The watch is an rclpy node in a context of its own, spun on a daemon thread, so it shares
nothing with an rclpy context the caller has; it installs no signal handler.
"""

from __future__ import annotations

import os
import threading
import time
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from ros_ehs.nodes.fastdds_profile import ENV
from ros_ehs.nodes.ros_common import qos_profile
import ros_ehs_msgs_py as contract

__all__ = ['DDS_ENVIRONMENT', 'StatusWatch', 'Waiter']

#: What a participant's DDS set-up is read from: the watch joins the domain as the nodes it
#: watches do (the same discovery range and Fast DDS profile: a participant on other
#: shared-memory timeouts can hold a writer that opens its port, docs/nodes.md)
DDS_ENVIRONMENT = ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_STATIC_PEERS', 'RMW_IMPLEMENTATION',
                   ENV, 'FASTDDS_DEFAULT_PROFILES_FILE')


class Waiter:
    """
    A condition on one status, judged on every message of it as it comes.

    ``status``: the first status that met ``ready`` (``event`` set); ``error``: what
    ``ready`` raised instead (``event`` set too).
    """

    def __init__(self, name: str, ready: Callable[[contract.NodeStatus], bool]) -> None:
        self.name, self.ready = name, ready
        self.event = threading.Event()
        self.status: contract.NodeStatus | None = None
        self.error: BaseException | None = None

    def judge(self, st: contract.NodeStatus) -> None:
        """Set ``event`` if ``st`` meets the condition (or the condition raises)."""
        if self.event.is_set() or st.name != self.name:
            return
        try:
            met = self.ready(st)
        except Exception as exc:
            self.error = exc
            self.event.set()
            return
        if met:
            self.status = st
            self.event.set()


class StatusWatch:
    """
    Listen to ``/diagnostics`` on ``domain_id`` and keep each status name's latest message.

    ``env``: the nodes' environment, whose :data:`DDS_ENVIRONMENT` variables this process takes
    before it joins. :meth:`status` returns a :class:`ros_ehs_msgs_py.NodeStatus` or None;
    :meth:`close` leaves the domain (also as a context manager). A message the contract
    cannot read is counted in ``rejected`` (its error in ``error``) and the watch goes on; an
    error that ends its thread is kept in ``error`` too. :meth:`report` says what it has
    heard, for a wait that timed out. :meth:`waiter` judges a condition on every message as
    it comes, so that a state shorter than a poll's period is not missed.
    """

    def __init__(self, domain_id: int | None = None, env: dict[str, str] | None = None) -> None:
        self._lock = threading.Lock()
        self._latest: dict[str, contract.NodeStatus] = {}
        self._heard: dict[str, float] = {}     # when each status last came [monotonic s]
        self.received = 0
        self.rejected = 0
        self.error: str | None = None
        self._waiters: list[Waiter] = []
        self._ctx = rclpy.Context()
        # the nodes' DDS environment while the participant is made, and only then: left in
        # os.environ it would reach every later child of this process (a test's temporary
        # Fast DDS profile, deleted since, made a fresh interpreter print an XML error)
        saved = {k: os.environ.get(k) for k in DDS_ENVIRONMENT}
        os.environ.update({k: env[k] for k in DDS_ENVIRONMENT if env and k in env})
        try:
            rclpy.init(context=self._ctx, domain_id=domain_id,
                       signal_handler_options=SignalHandlerOptions.NO)
            self._node = rclpy.create_node('ehs_status_watch', context=self._ctx,
                                           start_parameter_services=False,
                                           enable_rosout=False)
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        self._node.create_subscription(DiagnosticArray, '/' + contract.DIAGNOSTICS.name,
                                       self._on_diagnostics,
                                       qos_profile(contract.DIAGNOSTICS.qos))
        self._exe = SingleThreadedExecutor(context=self._ctx)
        self._exe.add_node(self._node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name='status_watch', daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            while not self._stop.is_set() and self._ctx.ok():
                self._exe.spin_once(timeout_sec=0.05)
        except Exception as exc:      # kept for report(): a silent death blinds every wait
            if not self._stop.is_set():
                self.error = f'the watch stopped: {type(exc).__name__}: {exc}'

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        try:
            statuses = contract.statuses_from_msg(msg)
        except Exception as exc:      # one peer's bad message must not end the watch
            with self._lock:
                self.rejected += 1
                self.error = f'a message rejected: {type(exc).__name__}: {exc}'
            return
        now = time.monotonic()
        with self._lock:
            self.received += 1
            for st in statuses:
                self._latest[st.name] = st
                self._heard[st.name] = now
            waiters = list(self._waiters)
        for w in waiters:
            for st in statuses:
                w.judge(st)

    def waiter(self, name: str, ready: Callable[[contract.NodeStatus], bool]) -> Waiter:
        """Judge ``ready`` on every status ``name`` from now on, until :meth:`unwait`."""
        w = Waiter(name, ready)
        with self._lock:
            self._waiters.append(w)
        return w

    def unwait(self, w: Waiter) -> None:
        """Stop judging ``w``."""
        with self._lock:
            if w in self._waiters:
                self._waiters.remove(w)

    def report(self) -> str:
        """Say what the watch has heard: messages, each status's age, its thread's state."""
        now = time.monotonic()
        with self._lock:
            ages = ', '.join(f'{n} {now - t:.1f} s ago' for n, t in sorted(self._heard.items()))
            msgs, bad, err = self.received, self.rejected, self.error
        alive = self._thread.is_alive()
        return (f'status watch: {msgs} diagnostics messages read, {bad} rejected; statuses '
                f'last heard: {ages or "none"}; its thread '
                f'{"spinning" if alive else "stopped"}' + (f'; {err}' if err else ''))

    def status(self, name: str) -> contract.NodeStatus | None:
        """Return the latest status called ``name`` (``ros_ehs/plant`` ...), or None."""
        with self._lock:
            return self._latest.get(name)

    def forget(self, name: str) -> None:
        """Drop the latest status called ``name`` (its node restarts: wait for a new one)."""
        with self._lock:
            self._latest.pop(name, None)
            self._heard.pop(name, None)

    def close(self) -> None:
        """Stop listening and leave the domain (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._exe.shutdown()
        self._node.destroy_node()
        if self._ctx.ok():
            rclpy.shutdown(context=self._ctx)

    def __enter__(self) -> 'StatusWatch':
        """Return self."""
        return self

    def __exit__(self, *exc) -> None:
        """Close."""
        self.close()
