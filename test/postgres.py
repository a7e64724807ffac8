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
A real PostgreSQL server of a test's own: Debian's, in a fresh data directory.

``scripts/postgres.sh`` (run by the README's test command) installs the Debian package.
The server listens on a free TCP port on the loopback (and a Unix socket in its own
directory, for psql), trusts local connections, and is stopped at the end; as root it runs
as the ``postgres`` user (the server refuses root). Its clients here are Debian's ``psql``
(not our code) and the store through SQLAlchemy and psycopg.
"""

import glob
import os
from pathlib import Path
import pwd
import shutil
import socket
import subprocess
import tempfile

#: what a server's start, stop or command may take at most [s] (a loaded machine: seconds)
BOUND = 120.0


def _bin() -> Path:
    found = sorted(glob.glob('/usr/lib/postgresql/*/bin/postgres'))
    if not found:
        raise RuntimeError('no PostgreSQL server under /usr/lib/postgresql: run '
                           'scripts/postgres.sh as root (the README test command does)')
    return Path(found[-1]).parent


class Postgres:
    """A PostgreSQL server in a temporary directory, with one database, ``ehs``."""

    def __init__(self) -> None:
        self.bin = _bin()
        self.root = Path(tempfile.mkdtemp(prefix='ehs-pg-'))
        self.data, self.sock = self.root / 'data', self.root / 'sock'
        self.sock.mkdir()
        self.user = None
        if os.geteuid() == 0:
            self.user = 'postgres'
            pw = pwd.getpwnam(self.user)
            for p in (self.root, self.sock):
                os.chown(p, pw.pw_uid, pw.pw_gid)
        self._run('initdb', '-D', str(self.data), '-A', 'trust', '-U', 'postgres',
                  '--no-sync', '-E', 'UTF8')
        self.start()
        self.psql('create database ehs', db='postgres')

    def _run(self, exe: str, *args: str) -> str:
        cmd = [str(self.bin / exe), *args]
        if self.user:
            cmd = ['runuser', '-u', self.user, '--', *cmd]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=BOUND)
        if r.returncode:
            raise RuntimeError(f'{exe} failed ({r.returncode}): {r.stderr.strip()[-2000:]}')
        return r.stdout

    def start(self) -> None:
        """Start the server on a free loopback port (waits until it accepts connections)."""
        for attempt in range(3):          # a port taken between its choice and the start
            with socket.socket() as s:
                s.bind(('127.0.0.1', 0))
                self.port = s.getsockname()[1]
            try:
                self._run('pg_ctl', '-D', str(self.data), '-w', '-t', str(int(BOUND)), '-l',
                          str(self.root / 'log'), '-o',
                          f'-k {self.sock} -p {self.port} -c listen_addresses=127.0.0.1',
                          'start')
                return
            except RuntimeError:
                if attempt == 2:
                    raise

    def crash(self) -> None:
        """Stop the server as a power cut would: at once, no checkpoint (recovery at start)."""
        self._run('pg_ctl', '-D', str(self.data), '-m', 'immediate', '-w', 'stop')

    @property
    def url(self) -> str:
        """Return the ``ehs`` database's SQLAlchemy URL (psycopg over TCP)."""
        return f'postgresql+psycopg://postgres@127.0.0.1:{self.port}/ehs'

    def psql(self, sql: str, db: str = 'ehs') -> str:
        """Run ``sql`` through Debian's psql; return its unaligned rows."""
        r = subprocess.run([str(self.bin / 'psql'), '-X', '-q', '-At', '-v', 'ON_ERROR_STOP=1',
                            '-h', str(self.sock), '-p', str(self.port), '-U', 'postgres',
                            '-d', db, '-c', sql],
                           capture_output=True, text=True, timeout=BOUND)
        if r.returncode:
            raise RuntimeError(f'psql failed: {r.stderr.strip()}')
        return r.stdout.strip()

    def dump(self) -> str:
        """Return the ``ehs`` database as ``pg_dump`` writes it (to compare before and after)."""
        r = subprocess.run([str(self.bin / 'pg_dump'), '-h', str(self.sock), '-p',
                            str(self.port), '-U', 'postgres',
                            '--no-owner', 'ehs'], capture_output=True, text=True,
                           timeout=BOUND)
        if r.returncode:
            raise RuntimeError(f'pg_dump failed: {r.stderr.strip()}')
        # without the random key pg_dump guards its psql meta-commands with, per dump
        return '\n'.join(ln for ln in r.stdout.splitlines()
                         if not ln.startswith(('\\restrict', '\\unrestrict')))

    def close(self) -> None:
        """Stop the server and remove its directory."""
        try:
            self._run('pg_ctl', '-D', str(self.data), '-m', 'fast', '-w', 'stop')
        except RuntimeError:
            pass                                   # not running (a test crashed it)
        shutil.rmtree(self.root, ignore_errors=True)
