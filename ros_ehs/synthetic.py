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
benchmark fit. The controller sees the noisy position, as on a real bench; the plant is
stepped with the held current, as a plant node would. The README labels such bags synthetic.
"""

from __future__ import annotations

from dataclasses import dataclass
import os

import numpy as np

from ros_ehs.bag.writer import BagWriter
from ros_ehs.control.controller import Controller
from ros_ehs.errors import InputError
from ros_ehs.model.plant import Plant
from ros_ehs.params import Params, preset
from ros_ehs.reference import Sine
import ros_ehs_msgs_py as contract

__all__ = ['SensorNoise', 'record_experiment']

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


def record_experiment(out: str | os.PathLike, *, plant_params: Params | None = None,
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
    rng = np.random.default_rng(seed)
    noise = noise or SensorNoise(0.0, 0.0, 0.0)
    plant = Plant(plant_params, model)
    ctrl = Controller(controller_params, dt)
    names = plant.state_names
    iz, iv, ipa, ipb = (names.index(s) for s in ('z', 'z_dot', 'p_CP', 'p_CT'))
    ix = names.index('x') if 'x' in names else None
    x = plant.equilibrium()
    t = np.arange(n) * dt
    z_ref, v_ref = reference(t)
    u = np.zeros(2)
    err2 = 0.0
    topics = [contract.REFERENCE, contract.STATE, contract.COMMAND]
    if pressures:
        topics += [contract.PRESSURE_P, contract.PRESSURE_T]
    msg = {tp.name: contract.empty_msg(tp.msg_type) for tp in topics}
    with BagWriter(out) as w:
        for tp in topics:
            w.add_topic('/' + tp.name, tp.msg_type, tp.qos)
        for k in range(n):
            ns = T0_NS + int(round(t[k] * 1e9))
            zm = x[iz] + noise.z * rng.standard_normal()
            vm = x[iv] + noise.v * rng.standard_normal()
            xs = float(x[ix]) if ix is not None else float(plant_params['K_x'] * u[0])
            w.write_msg('/reference', contract.fill_reference(
                msg['reference'], contract.Reference(ns, z_ref[k], v_ref[k])), ns)
            w.write_msg('/state', contract.fill_state(
                msg['state'], contract.AxisState(ns, zm, vm, float(
                    plant_params['A_p'] * (x[ipa] - x[ipb])), xs)), ns)
            if pressures:
                for tp, j in ((contract.PRESSURE_P, ipa), (contract.PRESSURE_T, ipb)):
                    w.write_msg('/' + tp.name, contract.fill_pressure(
                        msg[tp.name], contract.Pressure(
                            ns, x[j] + noise.p * rng.standard_normal())), ns)
            u[0] = ctrl.step(float(z_ref[k]), float(v_ref[k]), float(zm))
            w.write_msg('/servo_current', contract.fill_command(
                msg['servo_current'], contract.Command(ns, u[0])), ns)
            err2 += (z_ref[k] - x[iz]) ** 2
            x = plant.step(x, u, dt)
    return {'samples': float(n), 'rms_error_m': float(np.sqrt(err2 / n))}
