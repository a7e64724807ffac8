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
A campaign's results store: every specimen's record, in a real database.

An embedded SQLite file by default (``ResultStore('campaign.db')``), or any database
SQLAlchemy reaches by URL (``postgresql+psycopg://...``), through the same code: SQLAlchemy
Core, a well-kept toolkit that speaks each database's dialect, so the store's SQL is
written once (docs/campaigns.md says why not an ORM: the records are rows, not objects).

**Tables.** ``ros_ehs_meta`` (the program that made the store and its schema version),
``campaigns`` (name, the campaign file's hash, when made) and ``specimens`` (one row a
specimen: its id, the level specified and achieved with their spread, cycles, result and
reason, times, bags, the procedure's hash, the rig's parameters, the operator's note). A
specimen is recorded once: a second record of the same id in a campaign is refused.

**Schema versions.** A store of an older schema version is migrated when opened, in one
transaction (:data:`MIGRATIONS`: version 2 added each specimen's achieved ``peak`` and
``valley`` and its test's ``duration_s``; the records of version 1 read NaN there).

**What it refuses.** A database that has tables but no ``ros_ehs_meta`` (another program's)
and one whose schema version is newer than this code's are refused with a clear error and
left untouched. Every record is one transaction: committed, it survives a writer killed
at any moment (SQLite in WAL mode, ``synchronous=FULL``); two writers (the rig's campaign
and a rehearsal) serialise on the database's own locks.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
import datetime as _dt
import json
import math
import os
from pathlib import Path
from typing import Any, Sequence

from ros_ehs.core.errors import DataError, InputError

__all__ = ['MIGRATIONS', 'RESULTS', 'SCHEMA_VERSION', 'ResultStore', 'SpecimenRecord']

#: the store's schema version (a store of a newer one is refused, an older one migrated)
SCHEMA_VERSION = 2
#: the statements that take a store from version v to v + 1, by v
MIGRATIONS = {1: ('ALTER TABLE specimens ADD COLUMN peak FLOAT',
                  'ALTER TABLE specimens ADD COLUMN valley FLOAT',
                  'ALTER TABLE specimens ADD COLUMN duration_s FLOAT')}
#: the record's columns that may be NaN (NULL in the database)
_FLOATS = ('mean', 'amplitude', 'r_ratio', 'amplitude_spread', 'peak', 'valley', 'duration_s')
#: the program that writes the store (a store that says otherwise is refused)
PROGRAM = 'ros_ehs'
#: a specimen's results: failed, run out, or invalid (with its reason)
RESULTS = ('failed', 'run_out', 'invalid')


@dataclass(frozen=True)
class SpecimenRecord:
    """One specimen's result (SI units; times as ISO 8601 strings)."""

    specimen: str
    level: float
    result: str
    cycles: int
    reason: str = ''
    mean: float = math.nan            #: achieved: the cycles' mean level
    amplitude: float = math.nan       #: achieved: their amplitude
    r_ratio: float = math.nan         #: achieved: valley over peak
    amplitude_spread: float = math.nan   #: the amplitude's standard deviation over cycles
    peak: float = math.nan            #: achieved: the cycles' median peak
    valley: float = math.nan          #: achieved: their median valley
    duration_s: float = math.nan      #: the test's time on the rig (simulated: the model's) [s]
    started: str = ''
    ended: str = ''
    bags: Sequence[str] = field(default_factory=tuple)
    procedure_hash: str = ''
    params: dict = field(default_factory=dict)
    note: str = ''

    def check(self) -> None:
        """Raise InputError naming what is wrong with the record."""
        if not self.specimen:
            raise InputError('a specimen record needs its `specimen` id')
        if self.result not in RESULTS:
            raise InputError(f'specimen {self.specimen!r}: `result` = {self.result!r} must '
                             f'be one of {list(RESULTS)}')
        if self.result == 'invalid' and not self.reason:
            raise InputError(f'specimen {self.specimen!r}: an invalid result needs its '
                             '`reason`')
        if not (math.isfinite(self.level) and self.level > 0):
            raise InputError(f'specimen {self.specimen!r}: `level` = {self.level!r} must be '
                             'finite and > 0')
        if not (isinstance(self.cycles, int) and self.cycles >= 0):
            raise InputError(f'specimen {self.specimen!r}: `cycles` = {self.cycles!r} must '
                             'be a whole number >= 0')


def _url(where: str | os.PathLike) -> str:
    s = str(where)
    return s if '://' in s else f'sqlite:///{Path(s).resolve()}'


class ResultStore:
    """A campaign results store at ``where`` (a file path: SQLite; or a database URL)."""

    def __init__(self, where: str | os.PathLike) -> None:
        import sqlalchemy as sa
        self.url = _url(where)
        self.engine = sa.create_engine(self.url)
        md = sa.MetaData()
        self.meta = sa.Table('ros_ehs_meta', md, sa.Column('key', sa.String(64),
                                                           primary_key=True),
                             sa.Column('value', sa.String(256), nullable=False))
        self.campaigns = sa.Table(
            'campaigns', md, sa.Column('id', sa.Integer, primary_key=True),
            sa.Column('name', sa.String(256), nullable=False, unique=True),
            sa.Column('file_hash', sa.String(64), nullable=False),
            sa.Column('created', sa.String(40), nullable=False))
        self.specimens = sa.Table(
            'specimens', md, sa.Column('id', sa.Integer, primary_key=True),
            sa.Column('campaign_id', sa.Integer, sa.ForeignKey('campaigns.id'), nullable=False),
            sa.Column('specimen', sa.String(128), nullable=False),
            sa.Column('level', sa.Float, nullable=False),
            sa.Column('result', sa.String(16), nullable=False),
            sa.Column('reason', sa.Text, nullable=False),
            sa.Column('cycles', sa.BigInteger, nullable=False),
            sa.Column('mean', sa.Float), sa.Column('amplitude', sa.Float),
            sa.Column('r_ratio', sa.Float), sa.Column('amplitude_spread', sa.Float),
            sa.Column('peak', sa.Float), sa.Column('valley', sa.Float),
            sa.Column('duration_s', sa.Float),
            sa.Column('started', sa.String(40), nullable=False),
            sa.Column('ended', sa.String(40), nullable=False),
            sa.Column('bags', sa.Text, nullable=False),
            sa.Column('procedure_hash', sa.String(64), nullable=False),
            sa.Column('params', sa.Text, nullable=False),
            sa.Column('note', sa.Text, nullable=False),
            sa.UniqueConstraint('campaign_id', 'specimen', name='one_record_a_specimen'))
        self._md = md
        self._open()

    def _durable(self) -> None:
        """SQLite: committed means on disk, also in a crash; writers wait for each other."""
        import sqlalchemy as sa
        if self.engine.dialect.name != 'sqlite':
            return

        @sa.event.listens_for(self.engine, 'connect')
        def _pragmas(conn, _record):
            cur = conn.cursor()
            cur.execute('PRAGMA journal_mode=WAL')
            cur.execute('PRAGMA synchronous=FULL')
            cur.execute('PRAGMA busy_timeout=30000')
            cur.close()
        self.engine.dispose()               # the connection that looked had none of it

    def _open(self) -> None:
        import sqlalchemy as sa
        try:
            names = set(sa.inspect(self.engine).get_table_names())
        except sa.exc.SQLAlchemyError as err:
            raise DataError(f'the store {self._where()} cannot be opened: '
                            f'{str(err).splitlines()[0]}') from None
        if names and 'ros_ehs_meta' not in names:
            raise DataError(f'the store {self._where()} holds tables of another program '
                            f'({", ".join(sorted(names)[:5])}): refused, left untouched')
        if names:
            with self.engine.connect() as c:
                meta = dict(c.execute(sa.select(self.meta.c.key, self.meta.c.value)).all())
            if meta.get('program') != PROGRAM:
                raise DataError(f'the store {self._where()} was made by '
                                f'{meta.get("program")!r}, not {PROGRAM}: refused')
            try:
                version = int(meta.get('schema_version', ''))
            except ValueError:
                raise DataError(f'the store {self._where()} has no readable schema version '
                                f'({meta.get("schema_version")!r}): refused, left '
                                'untouched') from None
            if version > SCHEMA_VERSION:
                raise DataError(f'the store {self._where()} has schema version {version}, '
                                f"newer than this program's {SCHEMA_VERSION}: refused, left "
                                'untouched (update ros_ehs)')
            self._durable()
            if version < SCHEMA_VERSION:
                self._migrate(version)
            return
        self._durable()
        with self.engine.begin() as c:
            self._md.create_all(c)
            c.execute(self.meta.insert(), [{'key': 'program', 'value': PROGRAM},
                                           {'key': 'schema_version',
                                            'value': str(SCHEMA_VERSION)}])

    def _migrate(self, version: int) -> None:
        """Take the store from ``version`` to this code's, in one transaction."""
        import sqlalchemy as sa
        if version not in MIGRATIONS:
            raise DataError(f'the store {self._where()} has schema version {version}, which '
                            'no migration starts from: refused, left untouched')
        with self.engine.begin() as c:
            for v in range(version, SCHEMA_VERSION):
                for stmt in MIGRATIONS[v]:
                    c.execute(sa.text(stmt))
            c.execute(self.meta.update().where(self.meta.c.key == 'schema_version')
                      .values(value=str(SCHEMA_VERSION)))

    def _where(self) -> str:
        return repr(self.engine.url.render_as_string(hide_password=True))

    def campaign(self, name: str, file_hash: str = '') -> int:
        """Return the id of campaign ``name``, made if new."""
        import sqlalchemy as sa
        find = sa.select(self.campaigns.c.id).where(self.campaigns.c.name == name)
        with self.engine.begin() as c:
            row = c.execute(find).first()
            if row is not None:
                return int(row[0])
        now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec='seconds')
        try:
            with self.engine.begin() as c:
                res = c.execute(self.campaigns.insert().values(name=name, file_hash=file_hash,
                                                               created=now))
                return int(res.inserted_primary_key[0])
        except sa.exc.IntegrityError:           # another writer made it meanwhile
            with self.engine.connect() as c:
                return int(c.execute(find).scalar_one())

    def names(self) -> dict[str, int]:
        """Return the store's campaigns: each name and its id."""
        import sqlalchemy as sa
        with self.engine.connect() as c:
            return {str(n): int(i) for i, n in c.execute(
                sa.select(self.campaigns.c.id, self.campaigns.c.name)
                .order_by(self.campaigns.c.id)).all()}

    def record(self, campaign_id: int, rec: SpecimenRecord) -> None:
        """Record a specimen's result, once (a second record of its id is refused)."""
        import sqlalchemy as sa
        rec.check()
        row = asdict(rec)
        row['bags'] = json.dumps(list(rec.bags))
        row['params'] = json.dumps(rec.params, sort_keys=True)
        for k in _FLOATS:
            if not math.isfinite(row[k]):
                row[k] = None
        try:
            with self.engine.begin() as c:
                c.execute(self.specimens.insert().values(campaign_id=campaign_id, **row))
        except sa.exc.IntegrityError:
            raise InputError(f'specimen {rec.specimen!r} is already recorded in campaign '
                             f'{campaign_id}: a specimen is recorded once') from None

    def results(self, campaign_id: int) -> list[SpecimenRecord]:
        """Return the campaign's records, in the order they were recorded."""
        import sqlalchemy as sa
        t = self.specimens
        with self.engine.connect() as c:
            rows = c.execute(sa.select(t).where(t.c.campaign_id == campaign_id)
                             .order_by(t.c.id)).mappings().all()
        out = []
        for r in rows:
            d = {k: r[k] for k in SpecimenRecord.__dataclass_fields__}
            d['bags'] = tuple(json.loads(d['bags']))
            d['params'] = json.loads(d['params'])
            for k in _FLOATS:
                d[k] = math.nan if d[k] is None else float(d[k])
            d['cycles'] = int(d['cycles'])
            out.append(SpecimenRecord(**d))
        return out

    def close(self) -> None:
        """Release the database's connections."""
        self.engine.dispose()


def rows(store: ResultStore, campaign_id: int) -> list[dict[str, Any]]:
    """Return the campaign's records as plain mappings, to compare two databases by."""
    return [asdict(r) for r in store.results(campaign_id)]
