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
Write rosbag2-compatible MCAP bags: ``<dir>/<dir>_0.mcap`` plus ``<dir>/metadata.yaml``.

What rosbag2 (Jazzy) writes and reads (research notes section 1): profile ``ros2``; one schema
per type, encoding ``ros2msg`` with the full definition text; channels with encoding ``cdr``
and metadata ``offered_qos_profiles`` (v9 YAML) and ``topic_type_hash`` (RIHS01); a
``rosbag2`` metadata record and ``metadata.yaml`` with the same v9 ``BagMetadata``.

Crash safety: the Python MCAP writer keeps the open chunk in memory, so a SIGKILL would lose
it. :meth:`BagWriter.flush` closes the chunk and flushes the file, and :meth:`BagWriter.write`
does so whenever ``flush_period`` (default 50 ms) of wall time has passed, so a killed
recorder loses at most that much; :func:`ros_ehs.bag.reader.open_bag` recovers the
truncated file. ``fsync=True`` also survives power loss, at some cost.
"""

from __future__ import annotations

import copy
import os
from pathlib import Path
import time
from typing import Any, Iterable

from mcap.writer import CompressionType, Writer
from ros_ehs.bag.definitions import full_definition, type_hash
from ros_ehs.errors import BagError
import yaml

__all__ = ['BagWriter', 'bag_metadata']

_MAX_NS = 9223372036854775807


def _qos_yaml(qos: Iterable[Any]) -> list[dict[str, Any]]:
    return [copy.deepcopy(q.as_rosbag2() if hasattr(q, 'as_rosbag2') else dict(q))
            for q in qos]


def bag_metadata(file_name: str, topics: list[dict[str, Any]], start_ns: int, end_ns: int,
                 count: int, ros_distro: str) -> dict[str, Any]:
    """Return a complete rosbag2 v9 ``BagMetadata`` mapping (rosbag2's decode is strict)."""
    start = start_ns if count else _MAX_NS
    dur = max(0, end_ns - start_ns) if count else 0
    return {
        'version': 9,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': dur},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': count,
        'topics_with_message_count': copy.deepcopy(topics),
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [file_name],
        'files': [{'path': file_name, 'starting_time': {'nanoseconds_since_epoch': start},
                   'duration': {'nanoseconds': dur}, 'message_count': count}],
        'custom_data': {},
        'ros_distro': ros_distro,
    }


class BagWriter:
    """
    A rosbag2-style bag being written. Use as a context manager, or call :meth:`close`.

    Parameters
    ----------
    path : str or Path
        The bag directory to create (must not exist, or be empty).
    flush_period : float
        Wall time [s] after which :meth:`write` closes the open chunk and flushes the file.
    fsync : bool
        Also ``os.fsync`` on every flush (survives power loss, not only a killed process).
    chunk_size : int
        MCAP chunk size [bytes] (rosbag2's default 768 KiB); chunks also close on flush.

    """

    def __init__(self, path: str | os.PathLike, *, flush_period: float = 0.05,
                 fsync: bool = False, chunk_size: int = 768 * 1024,
                 ros_distro: str | None = None) -> None:
        self.path = Path(path)
        if not (isinstance(flush_period, (int, float)) and flush_period > 0):
            raise BagError(f'`flush_period` = {flush_period!r} s must be > 0')
        if self.path.exists() and (not self.path.is_dir() or any(self.path.iterdir())):
            raise BagError(f'bag directory {str(self.path)!r} already exists and is not empty')
        self.path.mkdir(parents=True, exist_ok=True)
        self.file_name = f'{self.path.name}_0.mcap'
        self._f = open(self.path / self.file_name, 'wb')
        self._w = Writer(self._f, chunk_size=chunk_size, compression=CompressionType.NONE)
        self._w.start(profile='ros2', library='ros_ehs')
        self._finalize_chunk = getattr(self._w, '_Writer__finalize_chunk', None)
        self.flush_period = float(flush_period)
        self.fsync = bool(fsync)
        self.ros_distro = ros_distro or os.environ.get('ROS_DISTRO', 'jazzy')
        self._schemas: dict[str, int] = {}
        self._topics: dict[str, dict[str, Any]] = {}
        self._encoders: dict[str, Any] = {}
        self._last_flush = time.monotonic()
        self.count = 0
        self.start_ns = _MAX_NS
        self.end_ns = 0
        self.closed = False

    # -- topics ------------------------------------------------------------------------------
    def add_topic(self, name: str, msg_type: str, qos: Any = ()) -> None:
        """Register topic ``name`` of type ``msg_type`` offered with QoS profile(s) ``qos``."""
        self._check_open()
        if name in self._topics:
            if self._topics[name]['type'] != msg_type:
                raise BagError(f'topic {name!r} already registered as '
                               f'{self._topics[name]["type"]}, not {msg_type}')
            return
        if msg_type not in self._schemas:
            text = full_definition(msg_type)
            self._schemas[msg_type] = self._w.register_schema(msg_type, 'ros2msg',
                                                              text.encode())
        qos_list = _qos_yaml([qos] if hasattr(qos, 'as_rosbag2') else qos)
        rihs = type_hash(msg_type)
        meta = {'offered_qos_profiles': yaml.safe_dump(qos_list, sort_keys=False),
                'topic_type_hash': rihs}
        cid = self._w.register_channel(name, 'cdr', self._schemas[msg_type], meta)
        self._topics[name] = {'id': cid, 'type': msg_type, 'qos': qos_list, 'hash': rihs,
                              'count': 0}

    @property
    def topics(self) -> dict[str, str]:
        """Return the registered topics: name -> type."""
        return {k: v['type'] for k, v in self._topics.items()}

    @property
    def counts(self) -> dict[str, int]:
        """Return the messages written so far per topic."""
        return {k: v['count'] for k, v in self._topics.items()}

    # -- messages ----------------------------------------------------------------------------
    def write(self, topic: str, data: bytes, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Write serialized CDR ``data`` on ``topic`` (``log_time`` = receive time [ns])."""
        t = self._topics.get(topic)
        if t is None:
            self._check_open()
            raise BagError(f'topic {topic!r} is not registered (add_topic first)')
        log_time_ns = int(log_time_ns)
        if log_time_ns < 0:
            raise BagError(f'negative log time {log_time_ns} ns on {topic!r}')
        pub = log_time_ns if publish_time_ns is None else int(publish_time_ns)
        self._w.add_message(t['id'], log_time=log_time_ns, data=data, publish_time=pub)
        t['count'] += 1
        self.count += 1
        self.start_ns = min(self.start_ns, log_time_ns)
        self.end_ns = max(self.end_ns, log_time_ns)
        if time.monotonic() - self._last_flush >= self.flush_period:
            self.flush()

    def write_msg(self, topic: str, msg: Any, log_time_ns: int,
                  publish_time_ns: int | None = None) -> None:
        """Serialize ``msg`` (nested dicts or a message object) to CDR and write it."""
        t = self._topics.get(topic)
        if t is None:
            raise BagError(f'topic {topic!r} is not registered (add_topic first)')
        enc = self._encoders.get(t['type'])
        if enc is None:
            from mcap_ros2._dynamic import serialize_dynamic
            enc = serialize_dynamic(t['type'], full_definition(t['type']))[t['type']]
            self._encoders[t['type']] = enc
        self.write(topic, enc(msg), log_time_ns, publish_time_ns)

    def flush(self) -> None:
        """Close the open chunk and flush it to the OS (and to disk with ``fsync``)."""
        if self.closed:
            return
        if self._finalize_chunk is not None:
            self._finalize_chunk()
        self._f.flush()
        if self.fsync:
            os.fsync(self._f.fileno())
        self._last_flush = time.monotonic()

    # -- close -------------------------------------------------------------------------------
    def metadata(self) -> dict[str, Any]:
        """Return the v9 ``BagMetadata`` of what has been written so far."""
        topics = [{'topic_metadata': {'name': k, 'type': v['type'],
                                      'serialization_format': 'cdr',
                                      'offered_qos_profiles': v['qos'],
                                      'type_description_hash': v['hash']},
                   'message_count': v['count']} for k, v in self._topics.items()]
        return bag_metadata(self.file_name, topics, self.start_ns, self.end_ns, self.count,
                            self.ros_distro)

    def close(self) -> None:
        """Write the metadata record, the MCAP summary and ``metadata.yaml``."""
        if self.closed:
            return
        meta = self.metadata()
        text = yaml.safe_dump(meta, sort_keys=False)
        self._w.add_metadata('rosbag2', {'serialized_metadata': text})
        self._w.finish()
        self._f.close()
        self.closed = True
        with open(self.path / 'metadata.yaml', 'w') as f:
            yaml.safe_dump({'rosbag2_bagfile_information': meta}, f, sort_keys=False)

    def _check_open(self) -> None:
        if self.closed:
            raise BagError(f'bag {str(self.path)!r} is closed')

    def __enter__(self) -> 'BagWriter':
        return self

    def __exit__(self, *exc) -> None:
        self.close()
