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
The recorder node: topics into a rosbag2-style MCAP bag (:class:`ros_ehs.data.bag.BagWriter`).

Subscriptions are raw (the CDR bytes go to the file without a decode). ``topics`` defaults
to every contract topic of this namespace; other topics named there are subscribed when
they appear on the graph (their type is discovered). As in rosbag2, a topic is subscribed
when its first publisher is discovered, with QoS adapted to the publishers: reliable if every
one offers reliable (the loop topics in lock-step), else best effort; depth ``depth``. The
``offered_qos_profiles`` stored are the publishers'.

Its status in ``diagnostics`` (``ros_ehs/recorder``, every ``diagnostics_period`` and at each
change) lists the topics it records (``recording``) and those whose subscription has matched a
publisher (``matched``), from which on that publisher's messages reach the bag: matching can
take seconds after discovery, and ``NodeProcesses.start_loop`` waits for it before the loop
starts. It also counts the messages and files, and turns ERROR with the reason when the
recorder stops recording. The log says the same for a person.

Long runs (a fatigue rig records for days): the bag is split into files of at most
``max_bag_size`` bytes or ``max_bag_duration`` seconds (default 600 s), each chunk compressed
with ``compression`` (default zstd: 4-5x smaller at well under 1 % of a core), so memory,
file sizes and the loss a damaged file can cause stay bounded (docs/recording.md).

Disk space and write errors: the recorder refuses to start with less than ``min_free_space``
free; while running it warns (once a minute) below ``warn_free_space`` with the time left at
the current rate, and below ``min_free_space`` it stops recording cleanly. A write error
(disk full, I/O error) is logged once, naming the file and the free space; nothing more is
written, ``metadata.yaml`` is written for everything flushed before (all of it readable), and
the node exits with code 1.

Crash safety is the writer's: the open chunk is closed and flushed every ``flush_period``
(default 50 ms, also on a timer when traffic stops), so SIGKILL loses at most that much, in
every file of a split bag. SIGINT/SIGTERM close the bag properly (summary, metadata.yaml).
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
import time

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.task import Future
from ros_ehs.core.errors import BagError
from ros_ehs.core.options import RECORDER
from ros_ehs.data.bag.writer import BagWriter, free_bytes
from ros_ehs.nodes.fastdds_profile import heartbeat_period
from ros_ehs.nodes.parameters import declare_settings
from ros_ehs.nodes.ros_common import (diagnostics, ERROR, msg_class, OK, qos_profile, qos_spec,
                                      run, steady_clock)
import ros_ehs_msgs_py as contract

__all__ = ['OPTIONS', 'RecorderNode', 'main', 'default_bag_path']

#: the node's options (declared in :mod:`ros_ehs.core.options`)
OPTIONS = RECORDER


def default_bag_path() -> Path:
    """Return ``bags/ehs_<UTC time>`` (rosbag2's ``rosbag2_<time>`` convention)."""
    return Path('bags') / datetime.now(timezone.utc).strftime('ehs_%Y_%m_%d-%H_%M_%S')


class RecorderNode(Node):
    """Record topics to a bag (see the module docstring)."""

    #: after SIGINT, keep taking in the messages DDS has already queued for this long [s]
    drain_period = 0.3
    #: the same under use_sim_time (lock-step, reliable loop topics): what a stall of this
    #: process made it miss is resent at each writer's next heartbeat, up to a heartbeat
    #: period later (the Fast DDS profile's: 0.1 s in the package's, 3 s in Fast DDS's own),
    #: and this much more; the writers are still running when NodeProcesses.stop stops us first
    LOCKSTEP_MARGIN = 0.5

    def __init__(self, **kwargs) -> None:
        super().__init__('recorder', **kwargs)
        self.opt = declare_settings(self, OPTIONS)
        self._sim_time = bool(self.get_parameter('use_sim_time').value)
        self._clock = self.get_clock()
        if self._sim_time:
            self.drain_period = heartbeat_period() + self.LOCKSTEP_MARGIN
        out = Path(self.opt['out'] or default_bag_path())
        free = free_bytes(out)
        if 0 <= free < int(self.opt['min_free_space']):
            raise BagError(self._low_space('not recording to', out, free))
        self.writer = BagWriter(out, flush_period=float(self.opt['flush_period']),
                                fsync=bool(self.opt['fsync']),
                                compression=str(self.opt['compression']),
                                max_bag_size=int(self.opt['max_bag_size']),
                                max_bag_duration=float(self.opt['max_bag_duration']))
        self.path = out
        self.done = Future()
        self.failure = ''
        self._subs = {}
        self._matched: set[str] = set()      # topics whose subscription has matched a publisher
        self._dirty = False
        self._files = 1
        self._space_warned = -1e9
        wanted = list(self.opt['topics']) or [t.name for t in contract.TOPICS]
        self._wanted = {self.resolve_topic_name(n): n for n in wanted}
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              qos_profile(contract.DIAGNOSTICS.qos))
        self._discover()
        self.create_timer(float(self.opt['discovery_period']), self._discover,
                          clock=steady_clock())
        self.create_timer(float(self.opt['flush_period']), self._flush, clock=steady_clock())
        self.create_timer(1.0, self._check_space, clock=steady_clock())
        self.create_timer(float(self.opt['diagnostics_period']), self._diagnose,
                          clock=steady_clock())
        self.get_logger().info(
            f'recording {sorted(self._wanted)} to {out} ({self.opt["compression"]}, split at '
            f'{self.opt["max_bag_duration"]:g} s / {self.opt["max_bag_size"]} bytes; '
            f'{free / 1e9:.1f} GB free)')

    def _now(self) -> int:
        """Return the receive time [ns]: the node's clock (``/clock`` under use_sim_time)."""
        if self._sim_time:
            return self._clock.now().nanoseconds
        return time.time_ns()      # the same system time, without a Time object

    def _take_waiting(self, full: str, sub) -> None:
        """
        Write whatever else waits in ``sub``'s reader (raw) to ``full``.

        rmw_fastrtps reports fewer new-message events than messages after a pause (SIGSTOP,
        a busy machine) and the EventsExecutor takes one message per event, so the rest would
        wait for later events, or for none at the end (3600 messages waited so in one paused
        lock-step run).
        """
        for got in iter(lambda: sub.handle.take_message(sub.msg_type, True), None):
            self.writer.write(full, got[0], self._now())

    def _subscribe(self, full: str, msg_type: str, offered: list, reliability: str,
                   durability: str = 'volatile') -> None:
        """Subscribe raw to ``full`` and add it to the bag (a type not installed: warn)."""
        try:
            cls = msg_class(msg_type)
        except KeyError as err:
            self.get_logger().warning(f'not recording {full}: {err}')
            self._subs[full] = None
            return
        self.writer.add_topic(full, msg_type, offered)
        qos = qos_profile(contract.QosSpec(reliability, int(self.opt['depth']), durability))
        write, now = self.writer.write, self._now

        def on_msg(data: bytes, topic=full) -> None:
            if self.failure:
                return
            try:
                write(topic, data, now())
                self._take_waiting(topic, sub)
            except BagError as err:
                if not self.writer.closed:     # closed: a late callback of a stuck executor
                    self._fail(err)
                return
            self._dirty = True
            if len(self.writer.files) != self._files:
                self._files = len(self.writer.files)
                self.get_logger().info(f'split: now writing {self.writer.file_name}')

        sub = self.create_subscription(cls, full, on_msg, qos, raw=True)
        self._subs[full] = sub
        self.get_logger().info(f'recording {full} ({msg_type}, {reliability})')

    def _report_matches(self) -> bool:
        """Note (and log) once per topic when its subscription has matched a publisher."""
        new = False
        for full, sub in self._subs.items():
            if sub is not None and full not in self._matched:
                n = sub.get_publisher_count()
                if n:
                    self._matched.add(full)
                    new = True
                    self.get_logger().info(f'matched {full} ({n} publisher(s))')
        return new

    def _diagnose(self) -> None:
        """Publish the recorder's status (see the module docstring)."""
        w = self.writer
        values = {'bag': str(self.path),
                  'recording': ','.join(sorted(t for t, s in self._subs.items() if s is not None)),
                  'matched': ','.join(sorted(self._matched)),
                  'messages': w.count, 'files': len(w.files)}
        level, msg = (ERROR, self.failure) if self.failure else (OK, 'recording')
        self.pub_diag.publish(diagnostics(self, contract.RECORDER_STATUS, level, msg, values))

    def _discover(self) -> None:
        if self.failure:
            return
        known = len(self._subs)
        matched = self._report_matches()
        missing = [t for t in self._wanted if t not in self._subs]
        if missing:
            self._subscribe_new(missing)
        if matched or len(self._subs) != known:     # say what changed now, once
            self._diagnose()

    def _subscribe_new(self, missing: list[str]) -> None:
        """Subscribe to each of ``missing`` that now has a publisher."""
        types = None
        for full in missing:
            pubs = self.get_publishers_info_by_topic(full)
            if not pubs:
                continue
            if types is None:
                types = dict(self.get_topic_names_and_types())
            try:
                msg_type = contract.by_name(self._wanted[full]).msg_type
            except KeyError:
                if full not in types:
                    continue
                msg_type = types[full][0]
            specs = [qos_spec(p.qos_profile) for p in pubs]
            rel = ('reliable' if all(q.reliability == 'reliable' for q in specs)
                   else 'best_effort')
            # as rosbag2 adapts: transient local when every publisher offers it, so what a
            # publisher sent before this recorder (or before a restarted publisher was
            # matched, as discovery goes) is delivered late rather than lost
            dur = ('transient_local' if all(q.durability == 'transient_local' for q in specs)
                   else 'volatile')
            try:
                self._subscribe(full, msg_type, [q.as_rosbag2() for q in specs], rel, dur)
            except BagError as err:
                self._fail(err)
                return

    def _flush(self) -> None:
        if self._dirty:
            self._dirty = False
            try:
                self.writer.flush()
            except BagError as err:
                self._fail(err)

    def _check_space(self) -> None:
        """Warn as space runs low; stop cleanly below ``min_free_space``."""
        if self.failure:
            return
        free = free_bytes(self.path)
        if free < 0:
            return
        t = time.monotonic()
        if free < int(self.opt['min_free_space']):
            self._fail(BagError(self._low_space('stopped recording to', self.path, free)))
        elif free < int(self.opt['warn_free_space']) and t - self._space_warned >= 60.0:
            self._space_warned = t
            f = self.writer.files[-1]      # the open file's bytes per second of log time
            span = (f['end_ns'] - f['start_ns']) * 1e-9 if f['count'] else 0.0
            size = (self.path / f['path']).stat().st_size
            left = free * span / size if span > 1.0 and size else 0.0
            self.get_logger().warning(
                f'disk space low: {free / 1e6:.1f} MB free for {self.path}'
                + (f', about {left / 3600:.1f} h at the current rate' if left else '')
                + f'; recording stops at {int(self.opt["min_free_space"]) / 1e6:.1f} MB')

    def _low_space(self, what: str, path: Path, free: int) -> str:
        return (f'{what} {str(path)!r}: {free / 1e6:.1f} MB free on its filesystem, below '
                f'min_free_space = {int(self.opt["min_free_space"]) / 1e6:.1f} MB')

    def _fail(self, err: BagError) -> None:
        """Stop recording after ``err`` (logged once); the node then closes and exits 1."""
        if self.failure:
            return
        self.failure = str(err)
        self.get_logger().error(str(err))
        self._diagnose()
        if not self.done.done():
            self.done.set_result(1)

    def close(self) -> None:
        """Take what is still queued, close the bag (summary, metadata.yaml), log its content."""
        if self.writer.closed:
            return
        try:
            for full, sub in self._subs.items():
                if sub is not None and not self.failure:
                    self._take_waiting(full, sub)
            self.writer.close()
        except BagError as err:
            self.failure = self.failure or str(err)
        w = self.writer
        counts = ', '.join(f'{k} {n}' for k, n in w.counts.items())
        files = f'{len(w.files)} file' + ('s' if len(w.files) > 1 else '')
        if not self.failure:
            print(f'[recorder] closed {self.path}: {w.count} messages in {files} ({counts})',
                  flush=True)
            return
        kept = w.metadata(flushed=True)['message_count']
        meta = w.metadata_error or 'metadata.yaml written for them'
        print(f'[recorder] error: {self.failure}; {kept} messages readable in {self.path} '
              f'({files}); {meta}', flush=True)


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs recorder``."""
    return run(RecorderNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
