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
"""Fixtures of the DDS tests: a ROS domain of the test's own, and an rclpy node on it."""

import fcntl
import os
import pickle
import signal
import subprocess
import sys
import time

from domain_coordinator import domain_id
import pytest
from ros_ehs.nodes.fastdds_profile import use_profile
from ros_ehs.nodes.processes import LOOP_CPUS_ENV
from waits import BOUND

#: this process's participants (the `ros` fixture's, the status watch's) on the nodes' profile
use_profile()


def _place_loops() -> None:
    """Give the xdist workers' benches the loop CPUs in turn (they all took the first)."""
    worker = os.environ.get('PYTEST_XDIST_WORKER', '')
    cpus = sorted(os.sched_getaffinity(0))
    if worker.startswith('gw') and len(cpus) >= 2 and not os.environ.get(LOOP_CPUS_ENV):
        k = int(worker[2:]) % len(cpus)
        os.environ[LOOP_CPUS_ENV] = f'{cpus[k]},{cpus[(k + 1) % len(cpus)]}'


_place_loops()

#: a ROS domain of this test process's own for the whole session, in ROS_DOMAIN_ID: a node, a
#: bench or a CLI a test starts without naming a domain cannot hear another worker's (two
#: benches on the default domain once did: one read the other's recorder error). A test that
#: starts nodes still takes a domain of its own (``dom``).
_SESSION_DOMAIN = domain_id()
os.environ['ROS_DOMAIN_ID'] = str(_SESSION_DOMAIN.__enter__())


@pytest.fixture(scope='session')
def once(tmp_path_factory, worker_id):
    """
    Return a getter of results built by one xdist worker for all: ``get(name, build)``.

    pytest-xdist's pattern for a fixture built once: the first worker to ask builds it in a
    folder of the directory every worker shares, under a file lock, and pickles the result;
    the others wait on the lock and read it. ``build(folder)`` may keep what its result names
    (bags) in ``folder``.
    """
    base = tmp_path_factory.getbasetemp()
    if worker_id != 'master':
        base = base.parent

    def get(name, build):
        root = base / name
        root.mkdir(exist_ok=True)
        with open(root / '.lock', 'w') as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            done = root / 'result.pickle'
            if done.exists():
                return pickle.loads(done.read_bytes())
            value = build(root)
            done.write_bytes(pickle.dumps(value))
            return value
    return get


@pytest.fixture
def dom():
    with domain_id() as d:
        yield d


@pytest.fixture
def ros(dom):
    """Give the test its own rclpy node on the test's domain, with a spin helper."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=dom)
    node = rclpy.create_node('ehs_test', context=ctx)
    exe = SingleThreadedExecutor(context=ctx)
    exe.add_node(node)

    def spin(seconds=0.0, until=None, timeout=BOUND):
        end = time.monotonic() + (timeout if until else seconds)
        while time.monotonic() < end:
            exe.spin_once(timeout_sec=0.02)
            if until is not None and until():
                return True
        return until is None

    node.spin = spin
    yield node
    exe.shutdown()
    node.destroy_node()
    rclpy.shutdown(context=ctx)


@pytest.fixture
def sigkilled():
    """
    Return ``run(script, bag, first)``: run a writer ``script`` on ``bag``, SIGKILL it.

    The script prints each stamp it wrote; the kill comes after ``first`` of them. Returns
    every stamp printed, so a test judges the bag on what the writer had written, not on
    wall-clock sleeps.
    """
    def run(script: str, bag, first: int) -> list[int]:
        p = subprocess.Popen([sys.executable, '-c', script, str(bag)],
                             stdout=subprocess.PIPE, text=True)
        written = [int(p.stdout.readline()) for _ in range(first)]
        p.send_signal(signal.SIGKILL)
        written += [int(line) for line in p.stdout.read().split()]
        p.wait()
        return written
    return run


@pytest.fixture
def python_lines():
    """
    Return ``run(code, *args)``: the output lines of ``code`` in a fresh interpreter.

    A fresh interpreter has its own threads, scheduler and imports.
    """
    def run(code: str, *args: str) -> list[str]:
        out = subprocess.run([sys.executable, '-c', code, *args], capture_output=True,
                             text=True, timeout=BOUND)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip().splitlines()
    return run
