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
Synthetic experiments: an in-process bench run recorded to a rosbag2 bag.

Plant + controller + reference, with sensor noise, on the contract topics.

This is what the sample bag in ``bags/`` is made from, and what the identification tests and
benchmark fit. The loop is :func:`ros_ehs.core.sim.closed_loop.run_closed_loop`: the controller
sees
the noisy position, as on a real bench; the plant is stepped with the held current. The
README labels such bags synthetic.
"""

from __future__ import annotations

from dataclasses import dataclass
import os

import numpy as np

from ros_ehs.core.control.waveforms import Sine
from ros_ehs.core.errors import InputError
from ros_ehs.core.params import Params, preset
from ros_ehs.core.sim.closed_loop import run_closed_loop
from ros_ehs.data.bag.writer import BagWriter
import ros_ehs_msgs_py as contract

__all__ = ['SensorNoise', 'record_synthetic_bag']

T0_NS = 1_700_000_000_000_000_000   # a fixed epoch, so equal inputs give equal bags


@dataclass(frozen=True)
class SensorNoise:
    """
    White sensor noise (1 sigma): position [m], velocity [m/s], chamber pressure [Pa].

    Defaults are a bench's: a magnetostrictive position sensor (5 um), velocity from an
    LVT or filtered differentiation (1 mm/s), 0.06 % of a 350 bar pressure transducer.
    """

    z: float = 5e-6
    v: float = 1e-3
    p: float = 2e4


def record_synthetic_bag(out: str | os.PathLike, *, plant_params: Params | None = None,
                         controller_params: Params | None = None, reference=None,
                         duration: float = 10.0, dt: float = 1e-3, model: str = 'simplified',
                         noise: SensorNoise | None = SensorNoise(), seed: int = 0,
                         pressures: bool = True) -> dict[str, float]:
    """
    Run plant + controller for ``duration`` s and record the contract topics to bag ``out``.

    ``plant_params`` default to Table 1's estimated values, ``controller_params`` to
    Table 1's initial values (an axis not yet identified), ``reference`` to the 1 Hz,
    0.04 m sine. Returns a summary (samples, RMS tracking error).
    """
    plant_params = plant_params or preset('table1_estimated')
    controller_params = controller_params or preset('table1_initial')
    reference = reference or Sine(0.04, 1.0)
    n = int(round(duration / dt))
    if n < 1:
        raise InputError(f'`duration` = {duration!r} s is shorter than one period {dt} s')
    noise = noise or SensorNoise(0.0, 0.0, 0.0)
    # per period: position, velocity[, chamber P, chamber T] noise, in that order
    w = np.random.default_rng(seed).standard_normal((n, 4 if pressures else 2))
    run = run_closed_loop(plant_params, reference, n * dt, model=model,
                          controller_params=controller_params, dt=dt, z_noise=noise.z * w[:, 0])
    x = run.x[:n]
    names = run.state_names
    v_meas = x[:, names.index('z_dot')] + noise.v * w[:, 1]
    p_a, p_b = x[:, names.index('p_CP')], x[:, names.index('p_CT')]
    force = plant_params['A_p'] * (p_a - p_b)
    # spool: the full model's state, else the static valve at the command being held
    held = np.concatenate([[0.0], run.i[:n - 1]])
    spool = x[:, names.index('x')] if 'x' in names else plant_params['K_x'] * held
    topics = [contract.REFERENCE, contract.STATE, contract.COMMAND]
    if pressures:
        topics += [contract.PRESSURE_P, contract.PRESSURE_T]
        p_meas = (p_a + noise.p * w[:, 2], p_b + noise.p * w[:, 3])
    msg = {tp.name: contract.empty_msg(tp.msg_type) for tp in topics}
    with BagWriter(out) as bag:
        for tp in topics:
            bag.add_topic('/' + tp.name, tp.msg_type, tp.qos)
        for k in range(n):
            ns = T0_NS + int(round(run.t[k] * 1e9))
            bag.write_msg('/reference', contract.fill_reference(
                msg['reference'], contract.Reference(ns, run.z_ref[k], run.v_ref[k])), ns)
            bag.write_msg('/state', contract.fill_state(msg['state'], contract.AxisState(
                ns, run.z_meas[k], v_meas[k], float(force[k]), float(spool[k]))), ns)
            if pressures:
                for tp, p in zip((contract.PRESSURE_P, contract.PRESSURE_T), p_meas):
                    bag.write_msg('/' + tp.name, contract.fill_pressure(
                        msg[tp.name], contract.Pressure(ns, p[k])), ns)
            bag.write_msg('/servo_current', contract.fill_command(
                msg['servo_current'], contract.Command(ns, run.i[k])), ns)
    err = run.z_ref[:n] - x[:, names.index('z')]
    return {'samples': float(n), 'rms_error_m': float(np.sqrt(np.mean(err ** 2)))}
