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
"""A command a test runs that times out is killed with every process it started."""

import os
import select
import subprocess
import sys

import pytest
from scripts import run_script
from waits import BOUND


def test_a_command_that_times_out_is_killed_with_what_it_started():
    # the command starts a child that would outlive it, prints the child's pid, then hangs
    code = ('import subprocess, sys, time\n'
            'c = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])\n'
            'print(c.pid, flush=True)\n'
            'time.sleep(600)\n')
    with pytest.raises(subprocess.TimeoutExpired) as err:
        run_script([sys.executable, '-c', code], timeout=10.0)
    child = int(err.value.stdout.split()[0])
    assert f'--- stdout, its last 3000 characters ---\n{child}' in str(err.value)
    try:
        fd = os.pidfd_open(child)       # readable once the process has exited
    except ProcessLookupError:
        return                          # gone, and reaped already
    try:
        exited, _, _ = select.select([fd], [], [], BOUND)
    finally:
        os.close(fd)
    assert exited, f'the child {child} outlived the command'


def test_a_command_that_ends_gives_its_code_and_output():
    r = run_script([sys.executable, '-c', 'import sys; print("out"); sys.exit(3)'], timeout=60)
    assert r.returncode == 3 and r.stdout == 'out\n' and r.stderr == ''
