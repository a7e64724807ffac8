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
Drive-file runs on the bench's nodes over DDS (``ehs_sim drive --bench``).

:class:`BenchPlayer` plays each run of a drive-file iteration
(:func:`ros_ehs.data.drive_files.iterate`) on the recorder, controller, reference and plant
node processes, and reads the response back from the run's bag.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from ros_ehs.core.errors import BagError, DataError, EhsError, InputError
from ros_ehs.data.bag import wait_for_counts
from ros_ehs.data.drive_files import lead_in, run_from_bag, save_drive
from ros_ehs.nodes.processes import NodeProcesses
import ros_ehs_msgs_py as contract

__all__ = ['BenchPlayer']


class BenchPlayer:
    """
    Play drives on the bench's nodes over DDS, each run a bag under ``out``.

    For each run the recorder, controller, reference (``kind: csv``, the drive's CSV) and
    plant start (:meth:`ros_ehs.nodes.processes.NodeProcesses.start_loop`), in ``mode`` lock-step
    (faster than real time, the in-process loop's figures to 1e-9 m) or real time; the
    response is read back from the run's bag. ``plant``, ``controller``: the nodes' parameters
    (e.g. a parameter preset and the plant's model). A run in which the plant's watchdog
    zeroed the valve more than ``max_trips`` times (real time: late commands; each moves the
    piston on for a few ms unheld, 0.2 mm at 0.08 m/s) is marked in ``disturbed``, and
    :func:`iterate` plays it again rather than learn from it.
    """

    def __init__(self, out: str | os.PathLike, *, mode: str = 'lockstep',
                 plant: dict | None = None, controller: dict | None = None,
                 domain_id: int | None = None, timeout: float = 120.0,
                 max_trips: int = 2) -> None:
        if mode not in ('lockstep', 'realtime'):
            raise InputError(f'`mode` = {mode!r} is not lockstep or realtime')
        self.out, self.mode = Path(out), mode
        self.plant, self.controller = dict(plant or {}), dict(controller or {})
        self.domain_id, self.timeout = domain_id, timeout
        self.max_trips = int(max_trips)
        #: per run: the plant's watchdog trips, and why its response is not the loop's or None
        self.trips: dict[str, int] = {}
        self.disturbed: dict[str, str | None] = {}

    def __call__(self, name: str, t: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Play drive ``x`` at times ``t`` as run ``name``; return the response on ``t``."""
        tt, xx, n = lead_in(np.asarray(t, dtype=float), np.asarray(x, dtype=float))
        csv = save_drive(self.out / f'{name}.csv', tt, xx)
        fs = 1.0 / float(np.median(np.diff(tt)))
        duration = tt.size / fs
        lock = self.mode == 'lockstep'
        bag = self.out / name
        with NodeProcesses(self.domain_id, self.out / 'logs' / name) as procs:
            procs.start_loop(self.mode, bag=bag,
                             plant={'duration': duration, **self.plant} if lock else self.plant,
                             controller=self.controller,
                             reference={'kind': 'csv', 'csv_path': str(csv), 'rate_hz': fs,
                                        'duration': duration},
                             timeout=self.timeout)
            if lock:
                done = procs.wait_status(contract.PLANT_STATUS,
                                         lambda st: 'complete' in st.message, self.timeout)
            else:
                done = procs.wait_status(
                    contract.REFERENCE_STATUS,
                    lambda st: float(st.values.get('time_s', 0)) > duration + 0.2,
                    duration + self.timeout)
            if done and lock:         # every state of the run in the bag, then stop
                try:
                    wait_for_counts(bag, {'/state': int(round(duration * fs)) + 1},
                                    self.timeout)
                    done = True
                except BagError:
                    done = False
            codes = procs.stop(['recorder', 'reference', 'controller', 'plant'])
            figures = procs['plant'].figures() if codes.get('plant') == 0 else {}
        if not done or any(codes.values()):
            raise EhsError(f'run {name}: the bench did not finish it (exit codes {codes}; '
                           f'logs in {self.out / "logs" / name})')
        trips = int(figures.get('watchdog_trips', 0))
        self.trips[name] = trips
        self.disturbed[name] = (f"the plant's watchdog zeroed the valve {trips} times (at "
                                f'most {self.max_trips})' if trips > self.max_trips else None)
        tr, _, y = run_from_bag(bag)
        if tr[-1] < tt[-1] - 0.5 / fs:
            raise DataError(f'{bag}: the run covers {tr[-1]:.3f} s of the {tt[-1]:.3f} s drive')
        return np.interp(tt, tr, y)[n:]
