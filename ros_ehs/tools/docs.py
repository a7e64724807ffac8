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
``python -m ros_ehs.tools.docs``: write the generated parts of the docs from the settings.

The options tables of ``docs/nodes.md`` (between ``<!-- options:begin -->`` and
``<!-- options:end -->``, from :data:`ros_ehs.core.options.NODE_OPTIONS` and the reference's
waveform), ``docs/cli.md`` (from :data:`ros_ehs.core.options.CLI_OPTIONS`),
``docs/parameters.md`` (from :mod:`ros_ehs.core.params`) and the key tables of
``docs/procedures.md`` (from :mod:`ros_ehs.core.procedure.spec`), the campaign file's keys of
``docs/campaigns.md`` (from :mod:`ros_ehs.core.campaign.spec`). ``test/test_options.py``
checks that the files are up to date.
"""

from __future__ import annotations

from pathlib import Path
import sys
from typing import Sequence

from ros_ehs.core.control.waveforms import WAVEFORM
from ros_ehs.core.options import CLI_OPTIONS, CLI_POSITIONAL, NODE_OPTIONS
from ros_ehs.core.params import markdown_table
from ros_ehs.core.settings import Setting

__all__ = ['DOCS', 'cli_markdown', 'options_markdown', 'procedure_markdown', 'render',
           'settings_table', 'write']

BEGIN, END = '<!-- options:begin -->', '<!-- options:end -->'
DOCS = Path(__file__).resolve().parents[2] / 'docs'


def _default(s: Setting) -> str:
    d = s.default
    if s.kind == 'float':
        return f'`{d:g}`'
    if s.kind in ('list',):
        return '`[' + ', '.join(d) + ']`' if d else '`[]`'
    return f'`{d!r}`' if s.kind in ('str', 'choice') else f'`{d}`'.lower() if \
        s.kind == 'bool' else f'`{d}`'


def settings_table(settings: Sequence[Setting], head: str = 'option',
                   flag: bool = False, positional: Sequence[str] = ()) -> list[str]:
    """Return the markdown rows of ``settings``: name, unit, default, meaning."""
    out = [f'| {head} | unit | default | meaning |', '|---|---|---|---|']
    for s in settings:
        name = s.name
        if flag and name not in positional:
            name = '--' + name.replace('_', '-')
            if s.kind == 'bool':
                name += f' / --no-{s.name.replace("_", "-")}'
            name += ''.join(f' / {f}' for f in s.flags)
        out.append(f'| `{name}` | {s.unit} | {_default(s)} | {s.describe()} |')
    return out


def options_markdown() -> str:
    """Return the options tables of every node."""
    out = []
    for n, table in NODE_OPTIONS.items():
        out += [f'### `{n}`', ''] + settings_table(table) + ['']
        if n == 'reference':
            out += ['The waveform (live: a change restarts it):', ''] + \
                settings_table(WAVEFORM) + ['']
    return '\n'.join(out)


def cli_markdown() -> str:
    """Return docs/cli.md: every ``ehs_sim`` command's options."""
    out = ['# ehs_sim', '',
           'Generated from `ros_ehs/core/options.py` by `python -m ros_ehs.tools.docs`; do not '
           'edit by hand.', '',
           '`ehs_sim <command> --help` says the same. A list option takes several values '
           '(`--holdout a b`) or one comma-separated one (`--free d_c,F_cc`); a flag takes '
           '`--name` or `--no-name`.', '']
    for cmd, table in CLI_OPTIONS.items():
        pos = CLI_POSITIONAL.get(cmd, ())
        usage = ' '.join(p.upper() for p in pos)
        out += [f'## `ehs_sim {cmd}{" " + usage if usage else ""}`', '']
        out += settings_table(table, 'option', flag=True, positional=pos) + ['']
    return '\n'.join(out)


def procedure_markdown() -> str:
    """Return the tables of a procedure file's keys (docs/procedures.md)."""
    from ros_ehs.core.procedure.spec import COMMON_KEYS, END_KEYS, STEP_KEYS, TEST_KEYS
    out = ['### The test', ''] + settings_table(TEST_KEYS, 'key') + ['']
    out += ['### Every step', ''] + settings_table(COMMON_KEYS, 'key') + ['']
    for kind, keys in STEP_KEYS.items():
        out += [f'### `{kind}`', ''] + settings_table(keys, 'key') + ['']
    for kind, keys in END_KEYS.items():
        out += [f'### end condition `{kind}`', ''] + settings_table(keys, 'key') + ['']
    return '\n'.join(out)


def campaign_markdown() -> str:
    """Return the tables of a campaign file's keys (docs/campaigns.md)."""
    from ros_ehs.core.campaign.spec import CAMPAIGN_KEYS, PLAN_KEYS
    out = ['### The campaign', ''] + settings_table(CAMPAIGN_KEYS, 'key') + ['']
    for kind, keys in PLAN_KEYS.items():
        out += [f'### plan `{kind}`', ''] + settings_table(keys, 'key') + ['']
    return '\n'.join(out)


def render(text: str, body=None) -> str:
    """Return ``text`` with the part between the markers regenerated (docs/nodes.md's)."""
    a, b = text.index(BEGIN) + len(BEGIN), text.index(END)
    return text[:a] + '\n' + (body or options_markdown)() + '\n' + text[b:]


def write(docs: Path = DOCS) -> list[Path]:
    """Write every generated doc under ``docs``; return the files written."""
    nodes = docs / 'nodes.md'
    nodes.write_text(render(nodes.read_text()))
    (docs / 'cli.md').write_text(cli_markdown() + '\n')
    (docs / 'parameters.md').write_text(markdown_table() + '\n')
    proc = docs / 'procedures.md'
    proc.write_text(render(proc.read_text(), procedure_markdown))
    camp = docs / 'campaigns.md'
    camp.write_text(render(camp.read_text(), campaign_markdown))
    return [nodes, docs / 'cli.md', docs / 'parameters.md', proc, camp]


def main() -> int:
    """Rewrite the generated docs in place."""
    for p in write():
        print(f'wrote {p}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
