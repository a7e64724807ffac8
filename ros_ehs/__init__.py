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
ros_ehs: electro-hydraulic servo axis (MOOG G761-class valve, symmetric cylinder).

Five layers, whose imports run one way (``LAYERS``, lowest first; ``test/test_layers.py``
walks every module and checks it):

* ``ros_ehs.core``: the numerical core, every rule (numpy, scipy, numba; no ROS, no files);
* ``ros_ehs.data``: bag and data I/O (rosbag2 bags, a rig's topic map, reports, drive files);
* ``ros_ehs.web``: the operator's station's web server and page (aiohttp; no ROS);
* ``ros_ehs.nodes``: the rclpy nodes and the processes that run them;
* ``ros_ehs.tools`` and ``ros_ehs.benchmarks``: the ``ehs_sim`` command line, the benchmarks.

Below them all, the topic contract ``ros_ehs_msgs_py`` (plain values, no ROS import).

Importing the package sets ``OPENBLAS_NUM_THREADS=1`` unless it is set already (so before
numpy loads OpenBLAS, when ``ros_ehs`` is imported first, as every entry point does): the
fit's matrices are small (40000 x 7), and OpenBLAS's spinning threads made a refit of the
10 s sample bag take 1.85x its wall time in CPU and 25-40 % longer (0.85 s against 0.60 s
cold, 0.29 s against 0.23 s warm), on the CPU a loop node needs.
"""

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

__version__ = '0.1.0'

#: The layers, lowest first: a module may import its own layer and those below it.
LAYERS = ('contract', 'core', 'data', 'web', 'nodes', 'tools')
_PACKAGES = {'ros_ehs_msgs_py': 'contract', 'ros_ehs.core': 'core', 'ros_ehs.data': 'data',
             'ros_ehs.web': 'web', 'ros_ehs.nodes': 'nodes', 'ros_ehs.tools': 'tools',
             'ros_ehs.benchmarks': 'tools'}


def layer_of(module: str) -> str:
    """Return the layer of ``module`` (a dotted name); ValueError naming it if it has none."""
    if module == 'ros_ehs':
        return LAYERS[0]
    for pkg, layer in _PACKAGES.items():
        if module == pkg or module.startswith(pkg + '.'):
            return layer
    raise ValueError(f'module {module!r} is in no layer of ros_ehs ({sorted(_PACKAGES)})')
