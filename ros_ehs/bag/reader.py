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
Read rosbag2 MCAP bags (ours, real rosbag2 ones, and truncated ones) without ROS.

:func:`open_bag` accepts a bag directory (``metadata.yaml`` + ``*.mcap``) or a bare ``.mcap``
file. The file is read in one linear pass over its records, so a file cut short by a killed
recorder is read up to its last complete record: :attr:`Bag.truncated` says so and
:attr:`Bag.problem` says why. Anything that is not a ros2/cdr MCAP file raises
:class:`~ros_ehs.errors.BagError` naming the file and the problem.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import io
import os
from pathlib import Path
import struct
from typing import Any, Iterator

from mcap.exceptions import McapError
from mcap.records import Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from ros_ehs.errors import BagError
import yaml

__all__ = ['Bag', 'BagMessage', 'TopicInfo', 'open_bag']

_MAGIC = b'\x89MCAP0\r\n'


@dataclass
class TopicInfo:
    """One topic of a bag: name, ROS type, message count, offered QoS, type hash."""

    name: str
    msg_type: str
    count: int = 0
    qos: list[dict[str, Any]] = field(default_factory=list)
    type_hash: str = ''
    encoding: str = 'cdr'
    schema_encoding: str = 'ros2msg'


@dataclass(frozen=True)
class BagMessage:
    """One message: topic, receive (log) time and publish time [ns], CDR bytes."""

    topic: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes
    msg_type: str


def _parse_qos(text: str) -> list[dict[str, Any]]:
    if not text:
        return []
    try:
        q = yaml.safe_load(text)
    except yaml.YAMLError:
        return []
    return q if isinstance(q, list) else []


def _mcap_file(path: Path) -> Path:
    if not path.exists():
        raise BagError(f'no bag at {str(path)!r}')
    if path.is_file():
        return path
    meta = path / 'metadata.yaml'
    if meta.is_file():
        try:
            info = yaml.safe_load(meta.read_text())['rosbag2_bagfile_information']
            files = info.get('relative_file_paths') or []
        except (yaml.YAMLError, KeyError, TypeError) as e:
            raise BagError(f'{str(meta)!r} is not a rosbag2 metadata file: {e}') from None
        if info.get('storage_identifier', 'mcap') != 'mcap':
            raise BagError(f'bag {str(path)!r} uses storage '
                           f'{info.get("storage_identifier")!r}; only mcap is supported')
        if len(files) > 1:
            raise BagError(f'bag {str(path)!r} is split into {len(files)} files; '
                           'only single-file bags are supported')
        if files and (path / files[0]).is_file():
            return path / files[0]
    found = sorted(path.glob('*.mcap'))
    if len(found) != 1:
        raise BagError(f'bag directory {str(path)!r} holds {len(found)} .mcap files '
                       '(expected exactly one)')
    return found[0]


class Bag:
    """A bag read into memory: :attr:`topics`, :meth:`messages`, :meth:`decoded`."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.file = _mcap_file(self.path)
        self.topics: dict[str, TopicInfo] = {}
        self.metadata: dict[str, dict[str, str]] = {}
        self.truncated = False
        self.problem = ''
        self.profile = ''
        self._msgs: list[BagMessage] = []
        self._decoders: dict[str, Any] = {}
        self._read()
        self._msgs.sort(key=lambda m: m.log_time_ns)   # once: every query is in time order

    def _read(self) -> None:
        data = self.file.read_bytes()
        if not data.startswith(_MAGIC):
            raise BagError(f'{str(self.file)!r} is not an MCAP file (bad magic bytes)')
        schemas: dict[int, Schema] = {}
        channels: dict[int, tuple[str, str]] = {}
        self._schemas_by_type: dict[str, Schema] = {}
        reader = StreamReader(io.BytesIO(data))
        try:
            for rec in reader.records:
                if isinstance(rec, Message):
                    ch = channels.get(rec.channel_id)
                    if ch is None:
                        continue
                    self._msgs.append(BagMessage(ch[0], rec.log_time, rec.publish_time,
                                                 rec.data, ch[1]))
                    self.topics[ch[0]].count += 1
                elif isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    if rec.id in channels:
                        continue
                    s = schemas.get(rec.schema_id)
                    msg_type = s.name if s else ''
                    channels[rec.id] = (rec.topic, msg_type)
                    if s is not None:
                        self._schemas_by_type[msg_type] = s
                    if rec.topic not in self.topics:
                        self.topics[rec.topic] = TopicInfo(
                            rec.topic, msg_type, 0,
                            _parse_qos(rec.metadata.get('offered_qos_profiles', '')),
                            rec.metadata.get('topic_type_hash', ''), rec.message_encoding,
                            s.encoding if s else '')
                elif isinstance(rec, Metadata):
                    self.metadata[rec.name] = dict(rec.metadata)
                elif isinstance(rec, Header):
                    self.profile = rec.profile
        except (McapError, EOFError, ValueError, KeyError, IndexError, struct.error) as e:
            self.truncated = True
            self.problem = f'{type(e).__name__}: {e}'.strip()
        if not self.topics and self.truncated and not self._msgs:
            raise BagError(f'{str(self.file)!r} is truncated before any topic was written '
                           f'({self.problem})')

    # -- queries -----------------------------------------------------------------------------
    @property
    def message_count(self) -> int:
        """Messages read (all topics)."""
        return len(self._msgs)

    @property
    def start_ns(self) -> int:
        """Earliest log time [ns] (0 for an empty bag)."""
        return self._msgs[0].log_time_ns if self._msgs else 0

    @property
    def end_ns(self) -> int:
        """Latest log time [ns] (0 for an empty bag)."""
        return self._msgs[-1].log_time_ns if self._msgs else 0

    def describe(self) -> str:
        """One line per topic: ``name (type, count)``."""
        return ', '.join(f'{t.name} ({t.msg_type}, {t.count})' for t in self.topics.values())

    def messages(self, topics: list[str] | None = None) -> Iterator[BagMessage]:
        """Messages of ``topics`` (all if None), in log-time order."""
        if topics is not None:
            missing = [t for t in topics if t not in self.topics]
            if missing:
                raise BagError(f'bag {str(self.path)!r} has no topic {missing}; it has: '
                               f'{self.describe() or "no topics"}')
        want = None if topics is None else set(topics)
        return (m for m in self._msgs if want is None or m.topic in want)

    def decoder(self, msg_type: str):
        """Return a function CDR bytes -> decoded message (attribute access) for a type."""
        dec = self._decoders.get(msg_type)
        if dec is None:
            s = self._schemas_by_type.get(msg_type)
            if s is None or s.encoding != 'ros2msg':
                enc = s.encoding if s else 'none'
                raise BagError(f'type {msg_type!r} in {str(self.file)!r} has schema encoding '
                               f'{enc!r}; only ros2msg can be decoded')
            from mcap_ros2._dynamic import generate_dynamic
            try:
                dec = generate_dynamic(msg_type, s.data.decode())[msg_type]
            except Exception as e:  # noqa: B902 - parser errors are not typed
                raise BagError(f'cannot parse the definition of {msg_type!r}: {e}') from None
            self._decoders[msg_type] = dec
        return dec

    def decoded(self, topics: list[str] | None = None) -> Iterator[tuple[BagMessage, Any]]:
        """``(message, decoded)`` pairs of ``topics``, in log-time order."""
        for m in self.messages(topics):
            info = self.topics[m.topic]
            if info.encoding != 'cdr':
                raise BagError(f'topic {m.topic!r} has message encoding {info.encoding!r}; '
                               'only cdr is supported')
            try:
                yield m, self.decoder(m.msg_type)(m.data)
            except BagError:
                raise
            except Exception as e:  # noqa: B902 - CDR decoder errors are not typed
                raise BagError(f'message on {m.topic!r} at {m.log_time_ns} ns does not decode '
                               f'as {m.msg_type}: {e}') from None


def open_bag(path: str | os.PathLike) -> Bag:
    """Open and read the bag at ``path`` (directory or ``.mcap`` file)."""
    return Bag(path)
