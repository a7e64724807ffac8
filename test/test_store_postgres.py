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
The results store on a real PostgreSQL server (Debian's), beside SQLite.

The same records through both hold the same contents; what PostgreSQL holds is read back by
its own client, psql; another program's database and a newer schema, made with psql, are
refused and left as pg_dump saw them; records committed by writers SIGKILLed and by a
server stopped as a power cut would stop it are there after its recovery, each once.
"""

import math

from postgres import Postgres
import pytest
from ros_ehs.core.errors import DataError, InputError
from ros_ehs.data.store import ResultStore, rows, SCHEMA_VERSION
from test_store import _rec, check_committed, check_migrated, kill_two_writers, V1


@pytest.fixture
def pg():
    server = Postgres()
    try:
        yield server
    finally:
        server.close()


def test_the_same_records_hold_the_same_contents_in_sqlite_and_postgresql(pg, tmp_path):
    lite, post = ResultStore(tmp_path / 'c.db'), ResultStore(pg.url)
    recs = [_rec(1), _rec(2, result='run_out', mean=math.nan, note='runout: no crack'),
            _rec(3, result='invalid', reason='stopped by the operator', cycles=0,
                 params={'k_L': 1.25e7, 'tau_v': 0.0063, 'note': 'ünïcode'})]
    ids = []
    for s in (lite, post):
        cid = s.campaign('6082-T6 R=0.1', 'ab' * 32)
        for r in recs:
            s.record(cid, r)
        with pytest.raises(InputError, match="'C-01' is already recorded"):
            s.record(cid, _rec(1))
        ids.append(cid)
    assert _nan_equal(rows(lite, ids[0]), rows(post, ids[1]))
    assert [r.specimen for r in post.results(ids[1])] == ['C-01', 'C-02', 'C-03']
    post.close()
    # what PostgreSQL's own client reads: the schema version, one row a specimen, a NULL
    # where the mean was not a number, the big counts as integers
    assert pg.psql("select value from ros_ehs_meta where key = 'schema_version'") == \
        str(SCHEMA_VERSION)
    got = pg.psql('select specimen, result, cycles, mean is null from specimens order by id')
    assert got.splitlines() == ['C-01|failed|20000|f', 'C-02|run_out|30000|t',
                                'C-03|invalid|0|f']
    big = ResultStore(pg.url)
    big.record(ids[1], _rec(4, cycles=10**10))            # beyond 32 bits: a run-out count
    assert pg.psql("select cycles from specimens where specimen = 'C-04'") == str(10**10)
    big.close()


def _nan_equal(a, b) -> bool:
    def norm(rs):
        return [{k: ('nan' if isinstance(v, float) and math.isnan(v) else v)
                 for k, v in r.items()} for r in rs]
    return norm(a) == norm(b)


def test_another_programs_database_or_a_newer_schema_is_refused_and_left_alone(pg):
    pg.psql('create table orders (id serial primary key, item text); '
            "insert into orders (item) values ('hydraulic oil')")
    before = pg.dump()
    with pytest.raises(DataError, match='tables of another program .*orders'):
        ResultStore(pg.url)
    assert pg.dump() == before
    pg.psql('drop table orders')
    ResultStore(pg.url).close()
    pg.psql(f"update ros_ehs_meta set value = '{SCHEMA_VERSION + 1}' "
            "where key = 'schema_version'")
    before = pg.dump()
    with pytest.raises(DataError, match=f'schema version {SCHEMA_VERSION + 1}, newer'):
        ResultStore(pg.url)
    assert pg.dump() == before


def test_an_unreachable_server_is_named(pg):
    pg.crash()
    with pytest.raises(DataError, match='cannot be opened'):
        ResultStore(pg.url)


def test_committed_records_survive_killed_writers_and_a_crashed_server(pg):
    ResultStore(pg.url).close()
    done = kill_two_writers(pg.url)
    pg.crash()                                   # no checkpoint: the WAL's recovery at start
    pg.start()
    s = ResultStore(pg.url)
    check_committed(s, done)
    s.close()


def test_a_version_1_store_is_migrated_on_postgresql(pg):
    pg.psql(V1.replace('{id}', 'SERIAL PRIMARY KEY'))
    check_migrated(ResultStore(pg.url))
    assert pg.psql("select value from ros_ehs_meta where key = 'schema_version'") == \
        str(SCHEMA_VERSION)
