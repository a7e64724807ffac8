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
``python -m ros_ehs.nodes.docs``: write the node options tables into ``docs/nodes.md``.

The tables are derived from each node's ``OPTIONS`` (the one declaration), between the
markers ``<!-- options:begin -->`` and ``<!-- options:end -->``; ``test_options`` checks
that the file is up to date.
"""

from __future__ import annotations

import importlib
from pathlib import Path
import sys

from ros_ehs.nodes.processes import NODES

BEGIN, END = '<!-- options:begin -->', '<!-- options:end -->'
DOC = Path(__file__).resolve().parents[2] / 'docs' / 'nodes.md'


def options_markdown() -> str:
    """Return the options tables of every node."""
    out = []
    for n in NODES:
        mod = importlib.import_module(f'ros_ehs.nodes.{n}')
        out += [f'### `{n}`', '', '| option | default | meaning |', '|---|---|---|']
        for o in mod.OPTIONS:
            rng = f' [{o.lo:g}, {o.hi:g}]' if o.lo is not None else ''
            ch = f' (one of: {", ".join(o.choices)})' if o.choices else ''
            live = ' *live*' if not o.read_only else ''
            out.append(f'| `{o.name}` | `{o.default!r}` | {o.description}{ch}{rng}{live} |')
        out.append('')
    return '\n'.join(out)


def render(text: str) -> str:
    """Return ``text`` with the part between the markers regenerated."""
    a, b = text.index(BEGIN) + len(BEGIN), text.index(END)
    return text[:a] + '\n' + options_markdown() + '\n' + text[b:]


def main() -> int:
    """Rewrite docs/nodes.md in place."""
    DOC.write_text(render(DOC.read_text()))
    print(f'wrote {DOC}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
