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
The Fast DDS profile the nodes run with, and what the recorder reads from it (no ROS import).

Every node started by :func:`ros_ehs.nodes.ros_common.run` (``ros2 run``, ``NodeProcesses``,
``launch_scripts/bench.py``) calls :func:`use_profile` before it creates its participant:
unless ``FASTRTPS_DEFAULT_PROFILES_FILE`` already names a profile (the user's, or
``launch_scripts/fastdds_rt.xml`` for a real-time bench), it names :data:`PROFILE`. Its
settings and why are in the file: faster discovery announcements and a 0.1 s heartbeat of the
reliable writers (docs/nodes.md, "Fast DDS profile").

:func:`heartbeat_period` reads the reliable writers' heartbeat period from the profile in
effect (Fast DDS's 3 s when it sets none): the recorder's lock-step drain follows it.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
import xml.etree.ElementTree as ET

__all__ = ['ENV', 'FASTDDS_HEARTBEAT', 'PROFILE', 'heartbeat_period', 'use_profile']

#: the environment variable Fast DDS reads its XML profiles from
ENV = 'FASTRTPS_DEFAULT_PROFILES_FILE'
#: the package's profile
PROFILE = Path(__file__).resolve().with_name('fastdds.xml')
#: Fast DDS's own heartbeat period of a reliable writer [s]
FASTDDS_HEARTBEAT = 3.0


def use_profile(env: dict | None = None) -> str:
    """Name the package's profile in ``env`` (default ``os.environ``) unless one is named."""
    env = os.environ if env is None else env
    if not env.get(ENV):
        env[ENV] = str(PROFILE)
    return env[ENV]


def heartbeat_period(env: dict | None = None) -> float:
    """
    Return the heartbeat period [s] of the default data writer of the profile in effect.

    Fast DDS's default (:data:`FASTDDS_HEARTBEAT`) when no profile is named, the file cannot
    be read, or it sets no heartbeat.
    """
    path = (os.environ if env is None else env).get(ENV)
    if not path:
        return FASTDDS_HEARTBEAT
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return FASTDDS_HEARTBEAT
    for w in root.iter():
        if not (w.tag.endswith('data_writer') and w.get('is_default_profile') == 'true'):
            continue
        hb = w.find('{*}times/{*}heartbeatPeriod')     # {*}: any namespace, or none
        if hb is None:
            continue
        parts = {c.tag.rsplit('}', 1)[-1]: (c.text or '').strip() for c in hb}
        try:
            t = float(parts.get('sec') or 0) + float(parts.get('nanosec') or 0) * 1e-9
        except ValueError:
            return FASTDDS_HEARTBEAT
        if math.isfinite(t) and t > 0:
            return t
    return FASTDDS_HEARTBEAT
