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
"""Dispatch ``python -m ros_ehs.benchmarks <name>`` ."""

import importlib
import sys

from ros_ehs.core.errors import EhsError

#: the benchmarks, each a module of this package with a ``main(argv)``
BENCHMARKS = ('model', 'paper', 'identify', 'loop', 'lockstep', 'record', 'soak', 'window',
              'tracking', 'drift', 'live', 'realtime', 'force', 'fatigue', 'verdict',
              'station', 'freeze', 'transitions', 'load', 'integrity', 'campaign', 'rehearsal')


def main(argv=None) -> int:
    """Run the benchmark named by the first argument."""
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in BENCHMARKS:
        print(f'usage: python -m ros_ehs.benchmarks {{{",".join(BENCHMARKS)}}}',
              file=sys.stderr)
        return 2
    mod = importlib.import_module(f'ros_ehs.benchmarks.{argv[0]}')
    try:
        return mod.main(argv[1:])
    except EhsError as err:          # e.g. a run too short for the data it needs: one line
        print(f'python -m ros_ehs.benchmarks {argv[0]}: error: {err}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
