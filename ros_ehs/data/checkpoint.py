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
A test's checkpoint on disk: written atomically, read back with a clear error.

:func:`write_checkpoint` writes the JSON to a temporary file beside the checkpoint, flushes
and ``fsync``\\ s it, renames it over the checkpoint (atomic on POSIX) and ``fsync``\\ s the
directory: after a power cut the file is the old checkpoint or the new one, whole, never a
mix. A full disk or a read-only directory raises :class:`OSError` and leaves the previous
checkpoint as it was. :func:`read_checkpoint` returns None when there is none.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping

from ros_ehs.core.errors import InputError

__all__ = ['read_checkpoint', 'resume_point', 'write_checkpoint']


def write_checkpoint(path: str | os.PathLike, state: Mapping[str, Any]) -> int:
    """Write ``state`` (JSON values) to ``path`` atomically; return the bytes written."""
    p = Path(path)
    data = json.dumps(state, allow_nan=True, sort_keys=True).encode()
    tmp = p.with_name(p.name + '.tmp')
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
        os.fsync(fd)
    except OSError:
        os.close(fd)
        tmp.unlink(missing_ok=True)
        raise
    os.close(fd)
    os.replace(tmp, p)
    dfd = os.open(p.parent, os.O_RDONLY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)
    return len(data)


def resume_point(path: str | os.PathLike, now: str | None = None) -> tuple[dict | None, str]:
    """
    Return the checkpoint a restarted node resumes from, and what became of it.

    None when there is none, or when its test had finished: that test is over and this is the
    next one; its checkpoint is renamed ``<stem>.finished_<now>.json`` (``now``: a UTC time
    stamp, default the clock's), so that nothing recorded is lost.
    """
    p = Path(path)
    cp = read_checkpoint(p)
    if cp is None or cp.get('state') != 'finished':
        return cp, ''
    import time
    now = now or time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())
    done = p.with_name(f'{p.stem}.finished_{now}.json')
    p.rename(done)
    return None, (f"the last test had finished ({cp.get('result')}, {cp.get('total')} cycles; "
                  f'its checkpoint is now {str(done)!r}): a new test')


def read_checkpoint(path: str | os.PathLike) -> dict | None:
    """Return the checkpoint at ``path``, None when there is none; InputError naming a bad one."""
    p = Path(path)
    try:
        text = p.read_text()
    except FileNotFoundError:
        return None
    except OSError as err:
        raise InputError(f'cannot read the checkpoint {str(p)!r}: {err}') from None
    try:
        state = json.loads(text)
    except ValueError as err:
        raise InputError(f'the checkpoint {str(p)!r} is not JSON ({err}): move it away to '
                         'start the test afresh') from None
    if not isinstance(state, dict):
        raise InputError(f'the checkpoint {str(p)!r} is not a mapping')
    return state
