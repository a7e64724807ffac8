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
r"""
Message definitions as rosbag2 stores them: the ``ros2msg`` text and the RIHS01 type hash.

The text is built exactly as rosbag2's ``LocalMessageDefinitionSource`` does
(``rosbag2_cpp/src/rosbag2_cpp/local_message_definition_source.cpp``): the type's ``.msg``
file verbatim, then each dependency, visited depth first in sorted order, once each, as
``"\n" + "=" * 80 + "\nMSG: pkg/Type\n" + text``. Files come from
the ROS prefix on ``AMENT_PREFIX_PATH`` (``share/<pkg>/msg``); no rclpy needed.

A service's events (``<pkg>/srv/<Name>_Event``, what rosbag2 records of a service since Jazzy)
are stored with the *service's* definition, request and response apart by ``---`` (rosbag2
issue 2365), not the event message's: :func:`service_event_definition` builds the message
the events are (``service_msgs/ServiceEventInfo info``, at most one request, at most one
response) from it, so they decode as any message does.
"""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path
import re

from ros_ehs.core.errors import BagError

__all__ = ['SERVICE_EVENT_INFO', 'full_definition', 'msg_file', 'service_event_definition',
           'type_hash']

_TYPE_RE = re.compile(r'^([a-zA-Z0-9_]+)/(?:msg/|srv/)?([a-zA-Z0-9_]+)$')
_DEP_RE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVES = {'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
               'int32', 'uint32', 'int64', 'uint64', 'string'}
_SEP = '=' * 80
_EVENT_RE = re.compile(r'^([a-zA-Z0-9_]+)/srv/([a-zA-Z0-9_]+)_Event$')
#: ``service_msgs/msg/ServiceEventInfo`` (Jazzy), what leads every service event
SERVICE_EVENT_INFO = """uint8 REQUEST_SENT = 0
uint8 REQUEST_RECEIVED = 1
uint8 RESPONSE_SENT = 2
uint8 RESPONSE_RECEIVED = 3
uint8 event_type
builtin_interfaces/Time stamp
char[16] client_gid
int64 sequence_number
"""


def _split(msg_type: str) -> tuple[str, str]:
    m = _TYPE_RE.match(msg_type)
    if not m:
        raise BagError(f'{msg_type!r} is not a ROS message type name (pkg/msg/Type)')
    return m.group(1), m.group(2)


def _share_dirs():
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            yield Path(prefix) / 'share'


def msg_file(msg_type: str, suffix: str = '.msg') -> Path:
    """Return the installed ``share/<pkg>/msg/<Type><suffix>`` file of ``msg_type``."""
    pkg, name = _split(msg_type)
    for share in _share_dirs():
        f = share / pkg / 'msg' / (name + suffix)
        if f.is_file():
            return f
    raise BagError(f'no {suffix} file for {msg_type!r} under AMENT_PREFIX_PATH='
                   f'{os.environ.get("AMENT_PREFIX_PATH", "")!r} (source scripts/env.sh)')


@functools.lru_cache(maxsize=None)
def _text(pkg_type: str) -> str:
    return msg_file(pkg_type).read_text()


def _deps(text: str, pkg: str) -> list[str]:
    out = set()
    for m in _DEP_RE.finditer(text):
        name = m.group(1)
        if name in _PRIMITIVES:
            continue
        out.add(name if '/' in name else f'{pkg}/{name}')
    return sorted(out)


@functools.lru_cache(maxsize=None)
def full_definition(msg_type: str) -> str:
    """Return the rosbag2 ``ros2msg`` schema text of ``msg_type`` with all dependencies."""
    pkg, name = _split(msg_type)
    seen: set[str] = set()

    def expand(p: str, n: str) -> str:
        text = _text(f'{p}/{n}')
        parts = [text]
        for dep in _deps(text, p):
            if dep in seen:
                continue
            seen.add(dep)
            dp, dn = _split(dep)
            parts.append(f'\n{_SEP}\nMSG: {dep}\n' + expand(dp, dn))
        return ''.join(parts)

    return expand(pkg, name)


@functools.lru_cache(maxsize=None)
def type_hash(msg_type: str) -> str:
    """Return the ``RIHS01_...`` type hash of ``msg_type`` from its generated JSON."""
    pkg, name = _split(msg_type)
    full = f'{pkg}/msg/{name}'
    data = json.loads(msg_file(full, '.json').read_text())
    for entry in data.get('type_hashes', []):
        if entry.get('type_name') == full:
            return entry['hash_string']
    raise BagError(f'no type hash for {full!r} in its JSON description')


def service_event_definition(msg_type: str, text: str) -> tuple[str, str] | None:
    """
    Return ``(name, definition)`` of a service event type stored with its service's text.

    ``msg_type`` ``<pkg>/srv/<Name>_Event`` and ``text`` the service's definition (request
    ``---`` response, then the definitions they use, each after a separator and ``MSG:``
    line; a ``SRV:`` header line first is allowed): the event message's ``ros2msg`` text,
    under a name the definition parser takes (``<pkg>/srv/<Name>Event``). None when
    ``msg_type`` is no service event or ``text`` holds no ``---``.
    """
    m = _EVENT_RE.match(msg_type)
    if m is None:
        return None
    body = re.sub(r'^={3,}\s*\nSRV:[^\n]*\n', '', text.lstrip('\n'), count=1)
    own, sep_, rest = body.partition(f'\n{_SEP}\n')
    req, dashes, resp = own.partition('\n---\n')
    if not dashes and not own.startswith('---'):
        return None
    if own.startswith('---'):
        req, resp = '', own[3:].lstrip('\n')
    pkg, name = m.group(1), m.group(2).replace('_', '')
    parts = [f'service_msgs/ServiceEventInfo info\n{pkg}/{name}Request[<=1] request\n'
             f'{pkg}/{name}Response[<=1] response\n',
             f'{_SEP}\nMSG: service_msgs/msg/ServiceEventInfo\n{SERVICE_EVENT_INFO}',
             f'{_SEP}\nMSG: builtin_interfaces/msg/Time\nint32 sec\nuint32 nanosec\n',
             f'{_SEP}\nMSG: {pkg}/srv/{name}Request\n{req}\n',
             f'{_SEP}\nMSG: {pkg}/srv/{name}Response\n{resp}\n']
    if sep_:
        parts.append(f'{_SEP}\n{rest}')
    return f'{pkg}/srv/{name}Event', ''.join(parts)
