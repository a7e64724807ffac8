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
Run a launch script or a command that starts nodes, from a test.

``subprocess.run`` kills only the command it started when its timeout runs out: the nodes a
launch script started then run on, orphaned, on a domain the coordinator hands to the next
test (a bench that timed out under load once left its recorder, controller and reference
running, and the tests after it on that domain failed).
"""

import os
import signal
import subprocess


class ScriptTimeout(subprocess.TimeoutExpired):
    """A timeout whose message ends with the tail of what the command wrote (for the log)."""

    def __str__(self) -> str:
        tail = []
        for name, text in (('stdout', self.stdout), ('stderr', self.stderr)):
            if text:
                tail.append(f'--- {name}, its last 3000 characters ---\n{text[-3000:]}')
        return '\n'.join([super().__str__(), *tail])


def run_script(cmd: list[str], *, timeout: float, **kwargs) -> subprocess.CompletedProcess:
    """
    Run ``cmd`` as ``subprocess.run(cmd, capture_output=True, text=True, timeout=...)`` does.

    It runs in a session of its own; on timeout the whole session (the command and every
    process it started) is killed, then :class:`ScriptTimeout` (a
    :class:`subprocess.TimeoutExpired`) is raised with what the command had written, its
    tail in the message.
    """
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True, **kwargs)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, err = p.communicate()
        raise ScriptTimeout(cmd, timeout, out, err) from None
    return subprocess.CompletedProcess(cmd, p.returncode, out, err)
