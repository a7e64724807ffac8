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
"""The benchmarks' command lines."""

import pytest


@pytest.mark.parametrize('bench, args, says', [
    ('window', ['--windows', '0'], "argument --windows: must be a whole number >= 1, not '0'"),
    ('window', ['--seconds', '0'], "argument --seconds: must be a finite number > 0, not '0'"),
    ('window', ['--seconds', 'nan'], "argument --seconds: must be a finite number > 0, not 'nan'"),
    ('loop', ['--rounds', '0'], "argument --rounds: must be a whole number >= 1, not '0'"),
    ('loop', ['--seconds', 'nan'], "argument --seconds: must be a finite number > 0, not 'nan'"),
    ('lockstep', ['--seconds', '-1'], "argument --seconds: must be a finite number > 0, not '-1'"),
    ('lockstep', ['--rounds', 'two'], "argument --rounds: must be a whole number >= 1, not 'two'"),
    ('soak', ['--seconds', 'inf'], "argument --seconds: must be a finite number > 0, not 'inf'"),
    ('soak', ['--sample', '0'], "argument --sample: must be a finite number > 0, not '0'"),
    ('soak', ['--max-bag-duration', 'nan'], 'argument --max-bag-duration: must be a finite'),
    ('record', ['--rates', '20000,x'], "argument --rates: must be a finite number > 0, not 'x'"),
    ('record', ['--rates', '-5'], "argument --rates: must be a finite number > 0, not '-5'"),
    ('record', ['--seconds', 'inf'], "argument --seconds: must be a finite number > 0, not 'inf'"),
    ('record', ['--compressions', 'gzip'], '--compressions takes none, zstd or lz4')])
def test_the_benchmarks_refuse_bad_numbers_by_name(bench, args, says):
    import subprocess
    import sys
    r = subprocess.run([sys.executable, '-m', 'ros_ehs.benchmarks', bench, *args],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and says in r.stderr, r.stderr


def test_the_benchmarks_are_named_when_asked_wrong():
    import subprocess
    import sys
    module = 'ros_ehs.benchmarks'
    r = subprocess.run([sys.executable, '-m', module, 'nope'], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and 'usage: python -m ros_ehs.benchmarks {model,paper,' in r.stderr
    r = subprocess.run([sys.executable, '-m', module, 'loop', '--rounds', '0'],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and 'argument --rounds: must be a whole number' in r.stderr
