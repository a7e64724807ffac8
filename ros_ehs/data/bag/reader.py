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
Read rosbag2 bags (ours, real rosbag2 ones, split, sqlite3, truncated) without ROS.

:func:`open_bag` accepts a bag directory (``metadata.yaml`` plus one or more ``.mcap`` or
``.db3`` files) or a bare ``.mcap``/``.db3`` file. A split bag reads as one bag: its files in
the order ``metadata.yaml`` lists them (files it does not list, left by a recorder killed
after a split, follow in the order of their number), its messages merged in log-time order.

* MCAP files are read in one linear pass over their records, so a file cut short by a killed
  recorder is read up to its last complete record: :attr:`Bag.truncated` says so and
  :attr:`Bag.problem` says why (and which file). Compressed chunks (zstd, lz4) are undone.
* sqlite3 files (``.db3``, rosbag2's default before Iron) are read with Python's ``sqlite3``;
  their message definitions come from the file when it has them (Iron and later) and
  otherwise from the installed interfaces.

``start``/``end`` [s, from the bag's first message] keep only the messages of that window of
log time; files that ``metadata.yaml`` places wholly outside it are not read at all, so a
window of a day-long split bag costs what the window holds. Anything that is not a rosbag2
bag raises :class:`~ros_ehs.core.errors.BagError` naming the file and the problem.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import io
import os
from pathlib import Path
import re
import sqlite3
import struct
import time
from typing import Any, Iterator

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import get_chunk_data_stream, StreamReader
from ros_ehs.core.errors import BagError
import yaml

__all__ = ['Bag', 'BagMessage', 'TopicInfo', 'bag_counts', 'open_bag', 'wait_for_counts']

_MAGIC = b'\x89MCAP0\r\n'
_SQLITE_MAGIC = b'SQLite format 3\x00'
_STORAGE = {'mcap': '.mcap', 'sqlite3': '.db3'}
_MAX_NS = 9223372036854775807
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE = 0x03, 0x04, 0x05
_RECORD = struct.Struct('<BQ')          # opcode, content length
_MESSAGE = struct.Struct('<HIQQ')       # channel id, sequence, log time, publish time


class _ChunkReader(StreamReader):
    """mcap's stream reader that skips the message indexes: the chunks carry every message."""

    def _read_record(self, opcode: int, length: int):
        if opcode == Opcode.MESSAGE_INDEX:
            return None         # left unread: the stream skips its ``length`` bytes
        return super()._read_record(opcode, length)


def _chunk_records(chunk: Chunk):
    """
    Yield the records of a chunk: messages as (channel id, log time, publish time, data).

    The mcap package's own chunk reader builds a record object through several reads per
    field; this loop unpacks a message's fixed fields at once (3x faster on a 1 kHz bag).
    Schemas and channels (a few per file) go through the mcap package's parsers.
    """
    stream, size = get_chunk_data_stream(chunk)
    data = stream.read(size)
    off, end = 0, len(data)
    rec, msg = _RECORD.unpack_from, _MESSAGE.unpack_from
    while off < end:
        if off + 9 > end:
            raise EOFError(f'chunk record header cut at {off} of {end} bytes')
        op, length = rec(data, off)
        body = off + 9
        off = body + length
        if off > end:
            raise EOFError(f'chunk record cut: {length} bytes at {body} of {end}')
        if op == _OP_MESSAGE:
            ch, _, log, pub = msg(data, body)
            yield ch, log, pub, data[body + 22:off]
        elif op in (_OP_SCHEMA, _OP_CHANNEL):
            sub = ReadDataStream(io.BytesIO(data[body:off]))
            yield (Schema if op == _OP_SCHEMA else Channel).read(sub)


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


@dataclass(frozen=True)
class _File:
    """One file of a bag and what ``metadata.yaml`` says of its time span [ns] (or None)."""

    path: Path
    start_ns: int | None = None
    end_ns: int | None = None


#: libyaml's loader where PyYAML was built with it (its wheels are): the same documents, parsed
#: eight times faster (a bench bag's metadata.yaml); a bag's metadata and QoS, at each open
_YAML_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def _yaml(text: str) -> Any:
    return yaml.load(text, Loader=_YAML_LOADER)     # noqa: S506 (a safe loader)


def _parse_qos(text: Any) -> list[dict[str, Any]]:
    if isinstance(text, list):
        return text
    if not text:
        return []
    try:
        q = _yaml(text)
    except yaml.YAMLError:
        return []
    return q if isinstance(q, list) else []


def _number(p: Path) -> tuple[int, str]:
    m = re.search(r'_(\d+)\.[a-z0-9]+$', p.name)
    return (int(m.group(1)) if m else -1, p.name)


def _read_metadata(meta: Path) -> dict[str, Any]:
    try:
        info = _yaml(meta.read_text())['rosbag2_bagfile_information']
        if not isinstance(info, dict):
            raise TypeError('not a mapping')
    except (yaml.YAMLError, KeyError, TypeError) as e:
        raise BagError(f'{str(meta)!r} is not a rosbag2 metadata file: {e}') from None
    return info


def _bag_files(path: Path) -> tuple[list[_File], dict[str, Any] | None, list[str]]:
    """Return the bag's files in order, its metadata (or None) and the files it lacks."""
    if not path.exists():
        raise BagError(f'no bag at {str(path)!r}')
    if path.is_file():
        return [_File(path)], None, []
    meta = path / 'metadata.yaml'
    info = _read_metadata(meta) if meta.is_file() else None
    storage = (info or {}).get('storage_identifier') or None
    if storage is not None and storage not in _STORAGE:
        raise BagError(f'bag {str(path)!r} uses storage {storage!r}; this reader reads '
                       f'{sorted(_STORAGE)}')
    if (info or {}).get('compression_format'):
        raise BagError(f'bag {str(path)!r} is compressed as whole files or messages '
                       f'({info["compression_format"]!r}, mode {info.get("compression_mode")!r}'
                       '); decompress it first (ros2 bag convert), or record with MCAP chunk '
                       'compression, which this reader reads')
    suffixes = [_STORAGE[storage]] if storage else list(_STORAGE.values())
    found = sorted((p for s in suffixes for p in path.glob('*' + s)), key=_number)
    spans = {}
    for f in (info or {}).get('files') or []:
        try:
            start = int(f['starting_time']['nanoseconds_since_epoch'])
            spans[f['path']] = (start, start + int(f['duration']['nanoseconds']))
        except (KeyError, TypeError, ValueError):
            continue
    listed = [str(n) for n in (info or {}).get('relative_file_paths') or []]
    missing = [n for n in listed if not (path / n).is_file()]
    names = [n for n in listed if n not in missing]
    names += [p.name for p in found if p.name not in names]   # left by a killed recorder
    if not names:
        raise BagError(f'bag directory {str(path)!r} holds no bag file (.mcap or .db3)'
                       + (f'; metadata.yaml lists {missing}, which are missing'
                          if missing else ''))
    files = [_File(path / n, *spans.get(n, (None, None))) for n in names]
    return files, info, missing


class Bag:
    """
    A bag read into memory: :attr:`topics`, :meth:`messages`, :meth:`decoded`.

    ``start``/``end``: a window of log time [s] from the bag's first message (see the module
    docstring); :attr:`files` are the files read, in order.
    """

    def __init__(self, path: str | os.PathLike, *, start: float | None = None,
                 end: float | None = None) -> None:
        self.path = Path(path)
        for k, v in (('start', start), ('end', end)):
            if v is not None and not (isinstance(v, (int, float)) and v == v and v >= 0
                                      and v != float('inf')):
                raise BagError(f'`{k}` = {v!r} s must be a finite time >= 0 from the start '
                               'of the bag')
        if start is not None and end is not None and end <= start:
            raise BagError(f'`end` = {end!r} s must come after `start` = {start!r} s')
        all_files, info, missing = _bag_files(self.path)
        self.file = all_files[0].path
        self.files: list[Path] = []
        self.topics: dict[str, TopicInfo] = {}
        self.metadata: dict[str, dict[str, str]] = {}
        self.profile = ''
        self._msgs: list[BagMessage] = []
        self._decoders: dict[str, Any] = {}
        self._schemas_by_type: dict[str, tuple[str, str]] = {}
        self._problems = [f'{str(self.path / n)!r} is missing (metadata.yaml lists it)'
                          for n in missing]
        t0 = None
        if info and int(info.get('message_count') or 0) > 0:
            try:
                t0 = int(info['starting_time']['nanoseconds_since_epoch'])
            except (KeyError, TypeError, ValueError):
                t0 = None
        self._window: tuple[int | None, int | None] = (None, None)
        windowed = start is not None or end is not None

        def window(base: int) -> tuple[int, int]:      # [start, end] as log times [ns]
            return (base + int((start or 0) * 1e9),
                    _MAX_NS if end is None else base + int(end * 1e9))

        for f in all_files:
            if windowed and t0 is None and self._msgs:      # no metadata: file 0 fixes t0
                t0 = min(m.log_time_ns for m in self._msgs)
            if windowed and t0 is not None:
                lo, hi = self._window = window(t0)
                if f.start_ns is not None and (f.start_ns > hi or f.end_ns < lo):
                    continue            # wholly outside the window: not read
            self._read_file(f.path)
            self.files.append(f.path)
        self._msgs.sort(key=lambda m: m.log_time_ns)   # once: every query is in time order
        if windowed and self._msgs:
            lo, hi = window(t0 if t0 is not None else self._msgs[0].log_time_ns)
            self._msgs = [m for m in self._msgs if lo <= m.log_time_ns <= hi]
            for t in self.topics.values():
                t.count = 0
            for m in self._msgs:
                self.topics[m.topic].count += 1
        self.truncated = bool(self._problems)
        self.problem = '; '.join(self._problems)

    # -- reading -----------------------------------------------------------------------------
    def _read_file(self, file: Path) -> None:
        with open(file, 'rb') as fh:
            head = fh.read(16)
        if head.startswith(_MAGIC):
            self._read_mcap(file)
        elif head.startswith(_SQLITE_MAGIC):
            self._read_db3(file)
        else:
            raise BagError(f'{str(file)!r} is not an MCAP file (bad magic bytes) nor a '
                           'sqlite3 (.db3) bag file')

    def _topic(self, name: str, msg_type: str, qos: Any, type_hash: str, encoding: str,
               schema_encoding: str) -> None:
        if name not in self.topics:
            self.topics[name] = TopicInfo(name, msg_type, 0, _parse_qos(qos), type_hash,
                                          encoding, schema_encoding)

    def _read_mcap(self, file: Path) -> None:
        data = file.read_bytes()
        schemas: dict[int, Schema] = {}
        channels: dict[int, tuple[str, str]] = {}
        n_before = len(self._msgs)
        reader = _ChunkReader(io.BytesIO(data), emit_chunks=True)

        def records():
            for r in reader.records:
                if isinstance(r, Chunk):
                    yield from _chunk_records(r)
                else:
                    yield r
        msgs, topics = self._msgs, self.topics
        lo, hi = self._window
        lo = -_MAX_NS if lo is None else lo     # no window: every int64 log time
        hi = _MAX_NS if hi is None else hi
        try:
            for rec in records():
                if type(rec) is tuple:      # a message of a chunk (the fast path)
                    ch = channels.get(rec[0])
                    if ch is None or not lo <= rec[1] <= hi:
                        continue
                    msgs.append(BagMessage(ch[0], rec[1], rec[2], rec[3], ch[1]))
                    topics[ch[0]].count += 1
                elif isinstance(rec, Message):
                    ch = channels.get(rec.channel_id)
                    if ch is None or not lo <= rec.log_time <= hi:
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
                        self._schemas_by_type.setdefault(
                            msg_type, (s.encoding, s.data.decode(errors='replace')))
                    self._topic(rec.topic, msg_type, rec.metadata.get('offered_qos_profiles'),
                                rec.metadata.get('topic_type_hash', ''), rec.message_encoding,
                                s.encoding if s else '')
                elif isinstance(rec, Metadata):
                    self.metadata[rec.name] = dict(rec.metadata)
                elif isinstance(rec, Header):
                    self.profile = rec.profile
        except (McapError, EOFError, ValueError, KeyError, IndexError, struct.error) as e:
            self._problems.append(f'{str(file)!r}: {type(e).__name__}: {e}'.strip())
            if not channels and len(self._msgs) == n_before and not self.topics:
                raise BagError(f'{str(file)!r} is truncated before any topic was written '
                               f'({self._problems[-1]})') from None

    def _read_db3(self, file: Path) -> None:
        try:
            con = sqlite3.connect(file.absolute().as_uri() + '?mode=ro', uri=True)
        except sqlite3.Error as e:
            raise BagError(f'{str(file)!r} cannot be opened as sqlite3: {e}') from None
        try:
            tables = {r[0] for r in con.execute('SELECT name FROM sqlite_master WHERE type = ?',
                                                ('table',))}
            if not {'topics', 'messages'} <= tables:
                raise BagError(f'{str(file)!r} is a sqlite3 file but not a rosbag2 bag '
                               f'(tables {sorted(tables)})')
            cols = {r[1] for r in con.execute('PRAGMA table_info(topics)')}
            qos = 'offered_qos_profiles' if 'offered_qos_profiles' in cols else "''"
            rihs = 'type_description_hash' if 'type_description_hash' in cols else "''"
            topics = {}
            for tid, name, typ, fmt, q, h in con.execute(
                    f'SELECT id, name, type, serialization_format, {qos}, {rihs} FROM topics'):
                topics[tid] = (name, typ)
                self._topic(name, typ, q, h, fmt, 'ros2msg')
            if 'message_definitions' in tables:
                for typ, enc, text in con.execute(
                        'SELECT topic_type, encoding, encoded_message_definition '
                        'FROM message_definitions'):
                    if enc == 'ros2msg' and text:
                        self._schemas_by_type.setdefault(typ, (enc, text))
            lo, hi = self._window
            rows = con.execute('SELECT topic_id, timestamp, data FROM messages WHERE '
                               'timestamp >= ? AND timestamp <= ? ORDER BY timestamp',
                               (lo if lo is not None else -_MAX_NS,
                                hi if hi is not None else _MAX_NS))
            for tid, t, data in rows:
                name, typ = topics.get(tid, (None, None))
                if name is None:
                    continue
                self._msgs.append(BagMessage(name, int(t), int(t), bytes(data), typ))
                self.topics[name].count += 1
        except sqlite3.DatabaseError as e:
            self._problems.append(f'{str(file)!r}: sqlite3: {e}')
            if not self.topics:
                raise BagError(f'{str(file)!r} is not a readable sqlite3 bag: {e}') from None
        finally:
            con.close()

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
            enc, text = self._schemas_by_type.get(msg_type, ('', ''))
            if not enc and msg_type:          # sqlite3 bags before Iron: installed .msg
                from ros_ehs.data.bag.definitions import full_definition
                enc, text = 'ros2msg', full_definition(msg_type)
            if enc != 'ros2msg':
                raise BagError(f'type {msg_type!r} in {str(self.file)!r} has schema encoding '
                               f'{enc or "none"!r}; only ros2msg can be decoded')
            from mcap_ros2._dynamic import generate_dynamic
            from ros_ehs.data.bag.definitions import service_event_definition
            name, text = service_event_definition(msg_type, text) or (msg_type, text)
            try:
                dec = generate_dynamic(name, text)[name]
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


def open_bag(path: str | os.PathLike, *, start: float | None = None,
             end: float | None = None) -> Bag:
    """Open and read the bag at ``path`` (directory, ``.mcap`` or ``.db3`` file)."""
    return Bag(path, start=start, end=end)


def bag_counts(path: str | os.PathLike) -> dict[str, int]:
    """
    Return ``{topic: count}`` of what the bag at ``path`` holds on disk now.

    For a bag being recorded (a recorder flushes every ``flush_period``, so the live file shows
    its progress). Raises :class:`BagError` as :func:`open_bag` does, also while the recorder
    has not yet written its first topic.
    """
    return {k: v.count for k, v in open_bag(path).topics.items()}


def wait_for_counts(path: str | os.PathLike, least: dict[str, int], timeout: float,
                    poll: float = 0.05) -> dict[str, int]:
    """
    Wait until the bag at ``path`` (being recorded) holds ``least`` = {topic: count} messages.

    Returns the counts then. Until then the bag may not be there or be unreadable (not yet
    created, no topic written yet); after ``timeout`` [s] raises :class:`BagError` saying what
    it held, or why it could not be read. Polls every ``poll`` s, or twice as long as a read
    took: a bag is read whole, and a long wait on a large bag would otherwise keep a CPU busy
    reading it (waiting costs at most a third of one).
    """
    end = time.monotonic() + timeout
    while True:
        start = time.monotonic()
        try:
            counts = bag_counts(path)
            held = str(counts or 'no topic')
        except BagError as err:
            counts, held = {}, f'nothing readable ({err})'
        if all(counts.get(k, 0) >= n for k, n in least.items()):
            return counts
        if time.monotonic() >= end:
            raise BagError(f'{str(path)!r}: after {timeout:g} s the bag holds {held}, '
                           f'not {least}')
        time.sleep(max(poll, 2.0 * (time.monotonic() - start)))
