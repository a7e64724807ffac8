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
"""Benchmarks a user can run on their own machine: ``python -m ros_ehs.benchmarks <name>``."""

import argparse
import json
import math
import os
import time
from typing import Any, Callable

from ros_ehs.core.errors import ParameterError
from ros_ehs.core.settings import parse_value, Setting

#: how long a benchmark waits for one start step of its nodes or its page [s]: generous, since
#: a benchmark on a loaded machine is slow, not broken (the figures say how slow)
BOUND = 180.0


#: Debian's Chromium, as the station and load benchmarks drive it (Playwright)
CHROMIUM = '/usr/bin/chromium'
#: Chromium on a machine without a network (the flags keep it from calling home)
CHROMIUM_ARGS = ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
                 '--disable-background-networking', '--disable-component-update',
                 '--disable-sync']


#: what the bare ping (``ros_ehs.benchmarks.pingpong``) prints when its first echo is back
FIRST_ECHO = 'pingpong: first echo'


def wait_first_echo(ping, timeout: float = BOUND) -> None:
    """
    Wait until the bare ping (a :class:`ros_ehs.nodes.processes.NodeProcess`) has an echo.

    Discovery takes seconds on a busy machine: a ping-pong measured before its pong answers
    measures nothing (a pong with no CPU time once made a ratio divide by zero). Raises
    RuntimeError, with the ping's output, when the ping exits or ``timeout`` [s] passes.
    """
    end = time.monotonic() + timeout
    while FIRST_ECHO not in ping.output():
        if not ping.alive():
            raise RuntimeError(f'the bare ping exited before its first echo:\n'
                               f'{ping.output()[-2000:]}')
        if time.monotonic() >= end:
            raise RuntimeError(f'the bare ping had no echo within {timeout:g} s:\n'
                               f'{ping.output()[-2000:]}')
        time.sleep(0.05)


def positive(text: str) -> float:
    """Parse a finite number > 0 (an argparse ``type``): NaN, inf, 0 and below are refused."""
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f'must be a finite number > 0, not {text!r}')
    return v


def count(text: str) -> int:
    """Parse a whole number >= 1 (an argparse ``type``)."""
    try:
        v = int(text)
    except ValueError:
        v = 0
    if v < 1:
        raise argparse.ArgumentTypeError(f'must be a whole number >= 1, not {text!r}')
    return v


def setting(spec: Setting) -> Callable[[str], Any]:
    """Return an argparse ``type`` that takes a value of ``spec`` (its range and kind)."""
    def parse(text: str) -> Any:
        try:
            return spec.check(parse_value(text))
        except (ParameterError, ValueError) as err:
            raise argparse.ArgumentTypeError(str(err)) from None
    parse.__name__ = spec.name
    return parse


def cpu(text: str) -> int:
    """Parse the index of one of this machine's CPUs (an argparse ``type``)."""
    n = os.cpu_count() or 1
    try:
        v = int(text)
    except ValueError:
        v = -1
    if not 0 <= v < n:
        raise argparse.ArgumentTypeError(f'must be a CPU of this machine (0 to {n - 1}), '
                                         f'not {text!r}')
    return v


def positives(text: str) -> list:
    """Parse a comma-separated list of finite numbers > 0 (an argparse ``type``)."""
    return [positive(x) for x in text.split(',')]


def report(figures: dict) -> int:
    """Print ``figures`` one per line, then all of them as one JSON object on the last line."""
    width = max(map(len, figures)) + 2
    for k, v in figures.items():
        print(f'{k:>{width}}: {v}')
    print(json.dumps(figures))
    return 0
