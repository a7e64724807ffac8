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
"""The package installs both ways: pip (console scripts) and colcon (the ros2 run layout)."""

import os
from pathlib import Path
import shutil
import subprocess
import sys
import urllib.request

import pytest

ROOT = Path(__file__).resolve().parents[1]


#: the rosdep key of each module from outside the package that it imports (the keys are
#: rosdistro's: rosdep/base.yaml, python.yaml, and the ROS packages of the same name); None:
#: no rosdep key exists, and only a benchmark needs it (installed from requirements.txt) or
#: pip installs it with the package (PIP_ONLY)
ROSDEP = {
    **{m: m for m in ('rclpy', 'ament_index_python', 'domain_coordinator', 'rcl_interfaces',
                      'diagnostic_msgs', 'geometry_msgs', 'rosgraph_msgs', 'sensor_msgs',
                      'std_msgs', 'std_srvs', 'trajectory_msgs')},
    'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'yaml': 'python3-yaml',
    'numba': 'python3-numba', 'matplotlib': 'python3-matplotlib', 'psutil': 'python3-psutil',
    'aiohttp': 'python3-aiohttp', 'mcap': 'mcap-ros2-support',
    'mcap_ros2': 'mcap-ros2-support', 'rosbags': 'python3-rosbags-pip',
    'sqlalchemy': 'python3-sqlalchemy',
    # the campaign benchmark's cross-checks only (requirements.txt pins them), as playwright
    'pylife': None, 'reliability': None, 'pandas': None,
    'playwright': None, 'threadpoolctl': None,
    # campaign rehearsals (rosdistro has no key for Dask's distributed)
    'distributed': None}

#: modules the package needs at run time that rosdistro has no key for (Debian packages
#: threadpoolctl as python3-threadpoolctl, rosdistro does not): pip installs them, from
#: setup.py's install_requires (and requirements.txt, pinned)
PIP_ONLY = {'threadpoolctl', 'distributed'}


def _imports() -> dict[str, set[str]]:
    """Return each top-level module from outside the package, and the files importing it."""
    import ast
    out: dict[str, set[str]] = {}
    for root in ('ros_ehs', 'ros_ehs_msgs_py', 'launch_scripts'):
        for path in (ROOT / root).rglob('*.py'):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split('.')[0]
                    if top not in sys.stdlib_module_names and top not in (
                            'ros_ehs', 'ros_ehs_msgs_py'):
                        out.setdefault(top, set()).add(str(path.relative_to(ROOT)))
    return out


def test_package_xml_names_every_module_the_package_imports():
    import xml.etree.ElementTree as ET
    imports = _imports()
    unknown = {m: sorted(f)[:2] for m, f in imports.items() if m not in ROSDEP}
    assert not unknown, f'modules without a rosdep key in ROSDEP: {unknown}'
    declared = {e.text.strip() for e in ET.parse(ROOT / 'package.xml').getroot()
                if e.tag in ('exec_depend', 'depend')}
    needed = {ROSDEP[m] for m in imports} - {None}
    assert needed <= declared, f'package.xml lacks {sorted(needed - declared)}'
    assert declared <= needed, f'package.xml names what nothing imports: {declared - needed}'


def test_modules_without_a_rosdep_key_are_installed_by_pip():
    import re
    imports = _imports()
    setup = (ROOT / 'setup.py').read_text()
    pinned = (ROOT / 'requirements.txt').read_text()
    for m in PIP_ONLY:
        assert m in imports and ROSDEP[m] is None, m
        assert f"'{m}'" in setup, f'setup.py install_requires lacks {m}'
        assert re.search(rf'^{m}==', pinned, re.M), f'requirements.txt does not pin {m}'


def _console_scripts():
    import ast
    tree = ast.parse((ROOT / 'setup.py').read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for k, v in zip(node.keys, node.values):
                if isinstance(k, ast.Constant) and k.value == 'console_scripts':
                    return [e.value.split('=')[0].strip() for e in v.elts]
    raise AssertionError('no console_scripts in setup.py')


def test_pip_install_puts_working_console_scripts_on_path(tmp_path):
    prefix = tmp_path / 'prefix'
    # --ignore-installed: never uninstall the developer's own (editable) copy
    res = subprocess.run([sys.executable, '-m', 'pip', 'install', '-q', '--no-deps',
                          '--ignore-installed', '--no-build-isolation', '--prefix', str(prefix),
                          str(ROOT)],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    site = next(prefix.glob('lib/python*/site-packages'))
    # the model's kernels run uncompiled: numba would compile them again for this copy (9
    # CPU-s; its cache is keyed by the file's path), and the colcon test below runs a
    # compiled plant from its install
    env = dict(os.environ, PYTHONPATH=str(site), PATH=f'{prefix / "bin"}:{os.environ["PATH"]}',
               NUMBA_DISABLE_JIT='1')
    for name in _console_scripts():
        assert (prefix / 'bin' / name).exists(), name
    out = subprocess.run(['ehs_sim', 'main', '--model', 'simplified', '--duration', '1.0'],
                         capture_output=True, text=True, env=env, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert 'rms error' in out.stdout
    bad = subprocess.run(['ehs_sim', 'main', '--preset', 'nonsense'], capture_output=True,
                         text=True, env=env, cwd=tmp_path)
    assert bad.returncode == 2 and 'unknown preset `nonsense`' in bad.stderr
    assert 'Traceback' not in bad.stderr


@pytest.mark.ros
@pytest.mark.skipif(shutil.which('colcon') is None, reason='colcon not installed')
def test_colcon_build_gives_the_ros2_run_layout(tmp_path):
    src = tmp_path / 'src' / 'ros_ehs'
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        '.venv', '.git', 'build', 'install', 'log', '.cache', '__pycache__', '*.egg-info'))
    listed = subprocess.run(['colcon', 'list'], cwd=tmp_path, capture_output=True, text=True)
    assert '(ros.ament_python)' in listed.stdout, listed.stdout + listed.stderr
    res = subprocess.run(['colcon', 'build', '--event-handlers', 'console_direct-'],
                         cwd=tmp_path, capture_output=True, text=True)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    install = tmp_path / 'install' / 'ros_ehs'
    lib = install / 'lib' / 'ros_ehs'
    for name in _console_scripts():
        assert os.access(lib / name, os.X_OK), f'{name} missing from {lib}'
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'ros_ehs').exists()
    # the launchers, and the Fast DDS profile bench.py hands its nodes under --rt-priority
    share = install / 'share' / 'ros_ehs' / 'launch_scripts'
    assert {'bench.py', 'replay.py', 'fastdds_rt.xml'} <= {p.name for p in share.iterdir()}
    # the environment the README's `source install/setup.bash` gives (colcon-bash)
    shown = subprocess.run(['bash', '-c', 'source install/setup.bash && env -0'], cwd=tmp_path,
                           capture_output=True, text=True)
    assert shown.returncode == 0, shown.stderr
    sourced = dict(v.split('=', 1) for v in shown.stdout.split('\0') if '=' in v)
    site = next(install.glob('lib/python*/site-packages'))
    assert str(site) in sourced['PYTHONPATH'].split(':'), sourced['PYTHONPATH']
    prefix_path = sourced['AMENT_PREFIX_PATH']
    assert prefix_path.split(':')[0] == str(install), prefix_path
    env = dict(os.environ, AMENT_PREFIX_PATH=prefix_path)
    # what `ros2 run ros_ehs <exe>` does: ament_index lookup, then lib/<pkg>/<exe>
    code = ('from ament_index_python.packages import get_package_prefix\n'
            "print(get_package_prefix('ros_ehs'))")
    found = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True)
    assert found.stdout.strip() == str(install), found.stderr

    # the colcon-built executables start and talk (what `ros2 run ros_ehs plant` starts)
    from domain_coordinator import domain_id
    from ros_ehs.nodes.processes import loop_closed, NodeProcesses
    from waits import BOUND
    from ros_ehs_msgs_py import PLANT_STATUS, REFERENCE_STATUS, STATION_STATUS
    with domain_id() as dom:
        built = {'PYTHONPATH': sourced['PYTHONPATH'], 'AMENT_PREFIX_PATH': prefix_path}
        with NodeProcesses(dom, tmp_path / 'logs', env=built, bound=BOUND) as procs:
            procs.start('plant', cmd=[str(lib / 'plant')])
            procs.start('controller', cmd=[str(lib / 'controller')])
            ok = procs.wait_status(PLANT_STATUS, loop_closed)
            # the station's page and its charting library came with the install
            procs.start('station', cmd=[str(lib / 'station'), '--ros-args', '-p', 'port:=0'])
            served = procs.wait_status(STATION_STATUS, lambda st: 'url' in st.values)
            procs.start('reference', cmd=[str(lib / 'reference')])
            referenced = procs.wait_status(REFERENCE_STATUS, lambda st: True)
            placed = {n: _placement(procs[n].pid)
                      for n in ('plant', 'controller', 'station', 'reference')}
            url = procs.status(STATION_STATUS).values['url'] if served else ''
            page = urllib.request.urlopen(url, timeout=30).read() if served else b''
            lib_js = urllib.request.urlopen(url + 'static/vendor/uPlot.iife.min.js',
                                            timeout=30).read() if served else b''
            codes = procs.stop(['station', 'reference', 'controller', 'plant'])
    assert ok, procs['plant'].output()[-2000:] + procs['controller'].output()[-2000:]
    assert served, procs['station'].output()[-2000:]
    assert b'ros_ehs station' in page and lib_js.startswith(b'/*! https://github.com/leeoniya')
    assert referenced, procs['reference'].output()[-2000:]
    assert codes == {'station': 0, 'reference': 0, 'controller': 0, 'plant': 0}
    # started as `ros2 run` starts them, without options: the loop's nodes on SCHED_FIFO 50
    # when this user may (else a warning of what that risks), on the loop's CPU; the reference
    # on SCHED_FIFO 40 under them, off it; the station off it at normal priority
    from ros_ehs.nodes.scheduling import (BENCH_PRIORITY, loop_placement, realtime_allowed,
                                          REFERENCE_PRIORITY, RISK)
    may = realtime_allowed(BENCH_PRIORITY)
    cpus = loop_placement()
    for name in ('plant', 'controller'):
        policy, priority, cpu = placed[name]
        if may:
            assert (policy, priority) == (os.SCHED_FIFO, BENCH_PRIORITY), (name, placed)
        else:
            assert policy == os.SCHED_OTHER and RISK in procs[name].output(), name
        assert cpu == (None if cpus is None else {cpus[0]}), (name, placed)
    assert placed['reference'][:2] == ((os.SCHED_FIFO, REFERENCE_PRIORITY) if may else
                                       (os.SCHED_OTHER, 0)), placed
    assert placed['reference'][2] == (None if cpus is None else {cpus[1]}), placed
    assert placed['station'][:2] == (os.SCHED_OTHER, 0), placed
    assert placed['station'][2] == (None if cpus is None else {cpus[1]}), placed
    where = subprocess.run([str(lib / 'identify'), '--ros-args', '-p', 'bags:=[nope]'],
                           env=dict(env, PYTHONPATH=sourced['PYTHONPATH']), capture_output=True,
                           text=True)
    assert where.returncode == 2 and 'no bag at' in where.stderr, where.stderr


def _placement(pid: int) -> tuple[int, int, set | None]:
    """Return a process's main thread's scheduling policy, priority and CPUs (None: all)."""
    cpus = os.sched_getaffinity(pid)
    return (os.sched_getscheduler(pid), os.sched_getparam(pid).sched_priority,
            None if cpus == os.sched_getaffinity(0) else cpus)


def test_launch_scripts_are_found_from_the_source_tree_or_the_install(tmp_path, monkeypatch):
    """Benches find launch_scripts/ beside the code, else in the ament share directory."""
    import ros_ehs.nodes.processes as processes
    assert processes.launch_script('bench.py') == ROOT / 'launch_scripts' / 'bench.py'
    share = tmp_path / 'share' / 'ros_ehs' / 'launch_scripts'
    share.mkdir(parents=True)
    (share / 'bench.py').write_text('')
    fake = tmp_path / 'site' / 'ros_ehs' / 'processes.py'       # an installed copy of the code
    fake.parent.mkdir(parents=True)
    monkeypatch.setattr(processes, '__file__', str(fake))
    monkeypatch.setattr('ament_index_python.packages.get_package_share_directory',
                        lambda name: str(tmp_path / 'share' / name))
    assert processes.launch_script('bench.py') == share / 'bench.py'
    with pytest.raises(FileNotFoundError, match='launch_scripts/nothing.py'):
        processes.launch_script('nothing.py')
