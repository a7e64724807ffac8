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
The layers' imports run one way: core, data, web, nodes, tools (ros_ehs.LAYERS).

Every module of the two packages is found by walking them (pkgutil), not from a list, and
imported in a fresh interpreter; each one's own imports (read from its source, module level
and inside functions alike) may name only its own layer or one below.
"""

import ast
import importlib
import importlib.util
from pathlib import Path
import pkgutil
import subprocess
import sys

import ros_ehs
import ros_ehs_msgs_py


def _modules():
    out = []
    for pkg in (ros_ehs, ros_ehs_msgs_py):
        out.append(pkg.__name__)
        out += [m.name for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.')]
    return out


def _is_module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def _imports(module: str) -> set:
    """Return the ros_ehs modules that ``module``'s source imports (absolute names)."""
    spec = importlib.util.find_spec(module)
    tree = ast.parse(Path(spec.origin).read_text())
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            for a in node.names:     # ``from pkg import module`` imports that module
                sub = f'{node.module}.{a.name}'
                found.add(sub if _is_module(sub) else node.module)
    return {m for m in found if m.split('.')[0] in ('ros_ehs', 'ros_ehs_msgs_py')}


def test_every_module_belongs_to_one_layer_and_imports_only_its_own_or_lower():
    mods = _modules()
    assert len(mods) > 60          # the walk found the packages
    bad = []
    for m in mods:
        mine = ros_ehs.layer_of(m)
        for dep in _imports(m):
            theirs = ros_ehs.layer_of(dep)
            if ros_ehs.LAYERS.index(theirs) > ros_ehs.LAYERS.index(mine):
                bad.append(f'{m} ({mine}) imports {dep} ({theirs})')
    assert not bad, '\n'.join(bad)


def test_a_module_outside_every_layer_is_named():
    import pytest
    with pytest.raises(ValueError, match='ros_ehs.stray'):
        ros_ehs.layer_of('ros_ehs.stray')


def test_every_module_imports_in_a_fresh_interpreter_and_the_core_and_data_without_rclpy():
    code = ('import importlib, sys\n'
            'import ros_ehs\n'
            'mods = sys.argv[1:]\n'
            'low = [m for m in mods\n'
            '       if ros_ehs.layer_of(m) in ("contract", "core", "data", "web")]\n'
            'for m in low:\n'
            '    importlib.import_module(m)\n'
            'ros = sorted(m for m in sys.modules\n'
            "             if m.split('.')[0] in ('rclpy', 'rcl_interfaces'))\n"
            "print('ROS:' + ','.join(ros))\n"
            'for m in mods:\n'
            '    importlib.import_module(m)\n'
            "print('ALL:' + str(len(mods)))\n")
    mods = _modules()
    res = subprocess.run([sys.executable, '-c', code, *mods], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    lines = res.stdout.strip().splitlines()
    assert lines[-2] == 'ROS:', lines[-2]
    assert lines[-1] == f'ALL:{len(mods)}'


def test_no_module_of_the_core_imports_another_that_imports_it_back():
    # a cycle inside a layer is a layering problem too (model.coefficients <-> kernels was one)
    graph = {m: _imports(m) for m in _modules()}
    cycles = sorted(f'{a} <-> {b}' for a, deps in graph.items() for b in deps
                    if a < b and a in graph.get(b, ()))
    assert not cycles, cycles


def test_the_nodes_that_do_not_simulate_start_without_numba():
    # numba's import costs a node 0.3-0.4 CPU-s at every start, and the suite starts these
    # nodes hundreds of times; only the plant and the fitting nodes step the model's kernels
    nodes = ['controller', 'reference', 'recorder', 'station', 'procedure', 'campaign']
    code = ('import importlib, sys\n'
            'for n in sys.argv[1:]:\n'
            "    importlib.import_module('ros_ehs.nodes.' + n)\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'llvmlite')))\n")
    res = subprocess.run([sys.executable, '-c', code, *nodes], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.strip() == '[]', res.stdout[:500]


def test_a_core_packages_names_import_on_first_use_and_a_wrong_one_is_named():
    code = ('import sys\n'
            'import ros_ehs.core.model as m\n'
            "before = 'ros_ehs.core.model.plant' in sys.modules\n"
            'names = dir(m)\n'
            'cls = m.Plant\n'
            "print(before, 'ros_ehs.core.model.plant' in sys.modules, 'Plant' in vars(m),\n"
            "      'Plant' in names and 'flow_gain_kq' in names, cls.__module__)\n"
            'try:\n'
            '    m.Plnat\n'
            'except AttributeError as err:\n'
            '    print(err)\n')
    res = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.splitlines() == [
        'False True True True ros_ehs.core.model.plant',
        "module 'ros_ehs.core.model' has no attribute 'Plnat'"], res.stdout
