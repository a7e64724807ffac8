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
The results store on SQLite: records once, refuses what is not its own, survives a kill.

Foreign databases are made with Python's own sqlite3 module, not with the store's code.
"""

import math
import signal
import sqlite3
import subprocess
import sys

import pytest
from ros_ehs.core.errors import DataError, InputError
from ros_ehs.data.store import ResultStore, SCHEMA_VERSION, SpecimenRecord


def _rec(n: int, **kw) -> SpecimenRecord:
    base = {'specimen': f'C-{n:02d}', 'level': 9000.0 - 500 * n, 'result': 'failed',
            'cycles': 10_000 * (n + 1), 'mean': 4950.0, 'amplitude': 4050.0, 'r_ratio': 0.1,
            'amplitude_spread': 3.0, 'started': '2026-12-05T01:00:00+00:00',
            'ended': '2026-12-05T02:00:00+00:00', 'bags': (f'bags/c{n}',),
            'procedure_hash': 'ab' * 32, 'params': {'k_L': 1e7}, 'note': ''}
    return SpecimenRecord(**{**base, **kw})


def test_records_come_back_as_written_each_once(tmp_path):
    db = tmp_path / 'c.db'
    s = ResultStore(db)
    cid = s.campaign('6082', 'ff' * 32)
    assert s.campaign('6082') == cid                         # found again, not made twice
    s.record(cid, _rec(1))
    s.record(cid, _rec(2, result='run_out', mean=math.nan))
    with pytest.raises(InputError, match="'C-01' is already recorded"):
        s.record(cid, _rec(1))
    s.close()
    again = ResultStore(db)
    got = again.results(cid)
    assert [r.specimen for r in got] == ['C-01', 'C-02']
    assert got[0] == _rec(1) and got[1].result == 'run_out' and math.isnan(got[1].mean)
    # what sqlite3 itself reads: the schema version and one row a specimen
    con = sqlite3.connect(db)
    assert con.execute("select value from ros_ehs_meta where key = 'schema_version'"
                       ).fetchone() == (str(SCHEMA_VERSION),)
    assert con.execute('select count(*) from specimens').fetchone() == (2,)


@pytest.mark.parametrize('rec, says', [
    (_rec(1, result='broken'), "`result` = 'broken'"),
    (_rec(1, result='invalid'), 'needs its `reason`'),
    (_rec(1, level=math.nan), '`level` = nan'),
    (_rec(1, cycles=-1), '`cycles` = -1'),
    (_rec(1, specimen=''), 'needs its `specimen`'),
])
def test_a_bad_record_is_named_and_nothing_is_written(tmp_path, rec, says):
    s = ResultStore(tmp_path / 'c.db')
    cid = s.campaign('x')
    with pytest.raises(InputError, match=says):
        s.record(cid, rec)
    assert s.results(cid) == []


def _sql(db, script: str) -> None:
    """Run ``script`` on ``db`` with Python's own sqlite3 (another program's writes)."""
    con = sqlite3.connect(db)
    con.executescript(script)
    con.close()


def test_a_database_of_another_program_or_a_newer_schema_is_refused_and_left_alone(tmp_path):
    other = tmp_path / 'other.db'
    _sql(other, 'create table orders (id integer primary key, item text)')
    before = other.read_bytes()
    with pytest.raises(DataError, match='tables of another program .*orders'):
        ResultStore(other)
    assert other.read_bytes() == before
    newer = tmp_path / 'newer.db'
    ResultStore(newer).close()
    _sql(newer, f"update ros_ehs_meta set value = '{SCHEMA_VERSION + 1}' "
         "where key = 'schema_version'")
    with pytest.raises(DataError, match=f'schema version {SCHEMA_VERSION + 1}, newer'):
        ResultStore(newer)
    notours = tmp_path / 'notours.db'
    ResultStore(notours).close()
    _sql(notours, "update ros_ehs_meta set value = 'labsoft' where key = 'program'")
    with pytest.raises(DataError, match="made by 'labsoft'"):
        ResultStore(notours)
    (tmp_path / 'junk.db').write_bytes(b'not a database at all' * 100)
    with pytest.raises(DataError, match='cannot be opened'):
        ResultStore(tmp_path / 'junk.db')


WRITER = """
import sys, time
from ros_ehs.data.store import ResultStore, SpecimenRecord
s = ResultStore(sys.argv[1])
cid = s.campaign('kill')
for n in range(100000):
    s.record(cid, SpecimenRecord(f'{sys.argv[2]}-{n}', 5000.0, 'failed', n))
    print(n, flush=True)
"""


def kill_two_writers(where: str) -> dict:
    """Start two writers on ``where``, SIGKILL both after 30 records; return their last."""
    who = ('rig', 'model')
    writers = [subprocess.Popen([sys.executable, '-c', WRITER, where, w],
                                stdout=subprocess.PIPE, text=True) for w in who]
    done = {}
    for w, name in zip(writers, who):
        for _ in range(30):                      # 30 committed records each, then SIGKILL
            last = w.stdout.readline()
        done[name] = int(last)
    for w in writers:
        w.send_signal(signal.SIGKILL)
        w.wait(60)
    return done


def check_committed(store: ResultStore, done: dict) -> None:
    """Check every record each writer was told was committed is there, once, in order."""
    got = [r.specimen for r in store.results(store.campaign('kill'))]
    for name, last in done.items():
        mine = [g for g in got if g.startswith(name + '-')]
        assert mine[:last + 1] == [f'{name}-{n}' for n in range(last + 1)]
        assert len(mine) == len(set(mine))


def test_committed_records_survive_a_writer_killed_and_two_writers_share_a_store(tmp_path):
    db = tmp_path / 'c.db'
    ResultStore(db).close()
    done = kill_two_writers(str(db))
    check_committed(ResultStore(db), done)
    con = sqlite3.connect(db)
    assert con.execute('pragma integrity_check').fetchone() == ('ok',)


#: version 1's tables, as that version made them (SQL, not the store's code); ``{id}`` is the
#: database's auto-numbered key
V1 = """
CREATE TABLE ros_ehs_meta (key VARCHAR(64) PRIMARY KEY, value VARCHAR(256) NOT NULL);
CREATE TABLE campaigns (id {id}, name VARCHAR(256) NOT NULL UNIQUE,
    file_hash VARCHAR(64) NOT NULL, created VARCHAR(40) NOT NULL);
CREATE TABLE specimens (id {id}, campaign_id INTEGER NOT NULL REFERENCES campaigns (id),
    specimen VARCHAR(128) NOT NULL, level FLOAT NOT NULL, result VARCHAR(16) NOT NULL,
    reason TEXT NOT NULL, cycles BIGINT NOT NULL, mean FLOAT, amplitude FLOAT, r_ratio FLOAT,
    amplitude_spread FLOAT, started VARCHAR(40) NOT NULL, ended VARCHAR(40) NOT NULL,
    bags TEXT NOT NULL, procedure_hash VARCHAR(64) NOT NULL, params TEXT NOT NULL,
    note TEXT NOT NULL, CONSTRAINT one_record_a_specimen UNIQUE (campaign_id, specimen));
INSERT INTO ros_ehs_meta VALUES ('program', 'ros_ehs'), ('schema_version', '1');
INSERT INTO campaigns (name, file_hash, created) VALUES ('old', '', '2026-12-01T00:00:00');
INSERT INTO specimens (campaign_id, specimen, level, result, reason, cycles, mean, amplitude,
    r_ratio, amplitude_spread, started, ended, bags, procedure_hash, params, note)
    VALUES (1, 'V1-01', 8000.0, 'failed', '', 123456, 4400.0, 3600.0, 0.1, 2.0, '', '',
            '["bags/v1"]', '', '{}', 'recorded by version 1');
"""


def check_migrated(store) -> None:
    """Check a version 1 store opened by this code: migrated, its record kept, writable."""
    cid = store.campaign('old')
    (old,) = store.results(cid)
    assert old.specimen == 'V1-01' and old.cycles == 123456 and old.bags == ('bags/v1',)
    assert math.isnan(old.peak) and math.isnan(old.duration_s)
    store.record(cid, _rec(2, peak=8010.0, valley=801.0, duration_s=3600.0))
    new = store.results(cid)[1]
    assert (new.peak, new.valley, new.duration_s) == (8010.0, 801.0, 3600.0)


def test_a_version_1_store_is_migrated_in_place(tmp_path):
    db = tmp_path / 'v1.db'
    _sql(db, V1.replace('{id}', 'INTEGER PRIMARY KEY'))
    store = ResultStore(db)
    check_migrated(store)
    store.close()
    con = sqlite3.connect(db)
    assert con.execute("select value from ros_ehs_meta where key = 'schema_version'"
                       ).fetchone() == (str(SCHEMA_VERSION),)
    cols = [r[1] for r in con.execute('pragma table_info(specimens)')]
    assert cols[-3:] == ['peak', 'valley', 'duration_s']
    con.close()
    _sql(db, "update ros_ehs_meta set value = '0' where key = 'schema_version'")
    # the store is in WAL mode: its bytes move when a closing connection checkpoints the log
    # into the file (a flaky byte comparison once), its content does not
    before = list(sqlite3.connect(db).iterdump())
    with pytest.raises(DataError, match='schema version 0, which no migration starts from'):
        ResultStore(db)
    assert list(sqlite3.connect(db).iterdump()) == before
