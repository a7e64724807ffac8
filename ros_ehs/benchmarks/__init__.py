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
