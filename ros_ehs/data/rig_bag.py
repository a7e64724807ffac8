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
Synthetic rig bags: what a ros2_control rig driver's recording looks like, written by rosbags.

The rig is the full model (Table 1 estimated by default) in closed loop with this package's
controller (as its node runs it: ramp-on from rest); the bag is written by another writer
(rosbags' MCAP or sqlite3 writer), in a driver's layout (:class:`RigLayout`):
``/joint_states`` with the axis's joint among others, position only or with velocity;
commands as a forward-command controller's ``Float64MultiArray`` (or ``Float64``, or a
``JointState`` effort); pressures per chamber as ``FluidPressure`` [Pa] or ``Float64``
[bar], as one load pressure, or none, at their own rate; a load cell (a specimen's force)
as a force/torque broadcaster's ``WrenchStamped`` on ``force.x``, or none; the driver's
stamps jittered, on its own clock, with lost samples; ``/rosout`` and ``/tf`` beside. The
driver applies each command ``delay_periods`` cycles after the state it answers. Used by
the tests and ``bench identify`` to read a bag that is neither our layout nor our writer;
labelled synthetic wherever it is used.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import os
from pathlib import Path

import numpy as np

from ros_ehs.core.control.supervised import AxisController
from ros_ehs.core.control.waveforms import Sine
from ros_ehs.core.errors import InputError
from ros_ehs.core.model.plant import Plant
from ros_ehs.core.params import Params, preset
from ros_ehs.data.mapping import TopicMap

__all__ = ['LOAD_TOPIC', 'RigLayout', 'record_rig_bag']

#: where the driver's force/torque broadcaster publishes the load cell
LOAD_TOPIC = '/fts_broadcaster/wrench'
#: the driver's clock at the first sample, and the recorder's (another machine's) [ns]
DRIVER_T0 = 1_700_000_100_000_000_000
RECORDER_T0 = DRIVER_T0 - 3_217_000_000


@dataclass(frozen=True)
class RigLayout:
    """How the driver publishes and what the recorder kept (see the module docstring)."""

    rate_hz: float = 2000.0
    joint: str = 'actuator_z'
    others: tuple[str, ...] = ('table_pitch', 'table_roll')
    velocity: bool = False
    command: str = 'float64_array'           # 'float64_array' | 'float64' | 'joint_state'
    command_index: int = 1                    # in the forward controller's array
    command_scale: float = 1.0e-3             # A per unit: the driver commands mA
    pressures: str = 'fluid'                  # 'fluid' | 'float64_bar' | 'load' | 'none'
    pressure_rate_hz: float = 1000.0
    jitter: float = 0.25                      # stamp jitter, fraction of the period
    lost: int = 3                             # states the recorder lost
    delay_periods: int = 1
    storage: str = 'mcap'                     # 'mcap' | 'sqlite3'
    noise_z: float = 5e-6
    quantum_z: float = 0.0                    # the encoder's resolution [m] (0: none)
    noise_v: float = 1e-3
    noise_p: float = 2e4
    load_cell: bool = False                   # a force/torque broadcaster's wrench (force.x)
    noise_f: float = 20.0

    def topic_map(self, input_delay: float | None = None) -> TopicMap:
        """Return the mapping a user writes for this layout."""
        press = {'fluid': ('/hydraulics/chamber_a', '/hydraulics/chamber_b', None),
                 'float64_bar': ('/hydraulics/chamber_a', '/hydraulics/chamber_b', None),
                 'load': (None, None, '/hydraulics/load_pressure'),
                 'none': (None, None, None)}[self.pressures]
        return TopicMap(state='/joint_states', joint=self.joint,
                        command='/servo_valve_controller/commands',
                        command_joint=self.joint, command_index=self.command_index,
                        command_scale=self.command_scale, pressure_p=press[0],
                        pressure_t=press[1], pressure_load=press[2],
                        pressure_unit='bar' if self.pressures == 'float64_bar' else 'Pa',
                        load_cell=LOAD_TOPIC if self.load_cell else None, load_axis='force.x',
                        input_delay=input_delay)


def record_rig_bag(out: str | os.PathLike, layout: RigLayout = RigLayout(), *,
                   plant_params: Params | None = None, controller_params: Params | None = None,
                   reference=None, duration: float = 6.0, model: str = 'full',
                   seed: int = 0) -> dict:
    """
    Simulate the rig and write its bag to ``out`` with rosbags; return the truth.

    The truth: ``input_delay`` [s] from a command's receive time, on the state's clock, to the
    valve acting on it; ``samples``; the plant parameters.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores
    if not 250.0 <= layout.rate_hz <= 4000.0:
        raise InputError(f'`rate_hz` = {layout.rate_hz} must be in [250, 4000] Hz')
    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    plant_params = plant_params or preset('table1_estimated')
    controller_params = controller_params or preset('table1_estimated')
    reference = reference or Sine(0.04, 1.0)
    rng = np.random.default_rng(seed)
    q = layout.quantum_z

    def encoder(z):
        """Return what the encoder reads at ``z`` (noise added): its nearest count."""
        return np.round(z / q) * q if q > 0 else z

    dt = 1.0 / layout.rate_hz
    n = int(round(duration / dt))
    sub = 8
    plant = Plant(plant_params, model)
    ctrl = AxisController(controller_params, dt)     # as the controller node: ramp-on
    names = plant.state_names
    iz, iv, ipa, ipb = (names.index(s) for s in ('z', 'z_dot', 'p_CP', 'p_CT'))
    # the driver wakes late by up to `jitter` of a period: its samples are taken (and
    # stamped) then; the plant runs on a fine grid between
    jit = rng.uniform(0.0, layout.jitter, n) * dt
    jit_steps = np.round(jit / (dt / sub)).astype(int)
    x = plant.equilibrium()
    queue = deque([0.0] * layout.delay_periods)
    fine = np.empty((n * sub + 1, 4))
    fine[0] = x[[iz, iv, ipa, ipb]]
    u = np.zeros(2)
    t = np.arange(n) * dt
    z_ref, v_ref = reference(t)
    cmds = np.empty(n)
    for k in range(n):
        for s in range(sub):
            if s == jit_steps[k]:
                # the driver's cycle k wakes: it samples, the controller answers (received
                # 0.3 ms on), and it writes the command of cycle k - delay_periods
                cmds[k] = ctrl.step(int(round(t[k] * 1e9)), float(encoder(
                    x[iz] + layout.noise_z * rng.standard_normal())), np.nan, np.nan,
                    float(z_ref[k]), float(v_ref[k]))
                queue.append(cmds[k])
                u[0] = queue.popleft()
            if not plant.advance(x, u, dt / sub):     # in place: the unchecked fast path
                raise InputError(f'the rig left its model at {t[k]:.6g} s (a non-finite '
                                 'state, or the piston outside the cylinder)')
            fine[k * sub + s + 1] = x[[iz, iv, ipa, ipb]]
    samp = fine[np.arange(n) * sub + jit_steps]
    z = encoder(samp[:, 0] + layout.noise_z * rng.standard_normal(n))
    stamps = DRIVER_T0 + np.round((t + jit_steps * dt / sub) * 1e9).astype(np.int64)
    lat = rng.uniform(0.1e-3, 0.2e-3, n)             # driver -> recorder, states
    recv = RECORDER_T0 + (stamps - DRIVER_T0) + np.round(lat * 1e9).astype(np.int64)
    # the controller answers 0.3 ms after the sample; the recorder receives it then
    c_recv = RECORDER_T0 + (stamps - DRIVER_T0) + int(0.3e-3 * 1e9)
    lost = set(rng.choice(np.arange(50, n - 50), layout.lost, replace=False).tolist()) \
        if layout.lost else set()
    # on the state's clock a command takes over at its receive time less the states'
    # median latency; the valve acts when the driver writes it, delay_periods cycles on
    # (its cycles jitter alike: this is the mean)
    true_delay = layout.delay_periods * dt - (0.3e-3 - float(np.median(lat)))
    if layout.command == 'joint_state':      # stamped with the state it answers
        true_delay = layout.delay_periods * dt

    storage = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}[layout.storage]
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    hdr, tm = T['std_msgs/msg/Header'], T['builtin_interfaces/msg/Time']

    def header(ns):
        return hdr(stamp=tm(sec=int(ns // 10**9), nanosec=int(ns % 10**9)), frame_id='')

    def ser(msg):
        return ts.serialize_cdr(msg, msg.__msgtype__)

    JS, F64 = T['sensor_msgs/msg/JointState'], T['std_msgs/msg/Float64']
    F64A, FP = T['std_msgs/msg/Float64MultiArray'], T['sensor_msgs/msg/FluidPressure']
    LAY, DIM = T['std_msgs/msg/MultiArrayLayout'], T['std_msgs/msg/MultiArrayDimension']
    joints = [*layout.others[:1], layout.joint, *layout.others[1:]]
    ja = joints.index(layout.joint)
    with Writer(out, version=9, storage_plugin=storage) as w:
        c_js = w.add_connection('/joint_states', JS.__msgtype__, typestore=ts)
        ctype = {'float64_array': F64A, 'float64': F64, 'joint_state': JS}[layout.command]
        c_cmd = w.add_connection('/servo_valve_controller/commands', ctype.__msgtype__,
                                 typestore=ts)
        c_log = w.add_connection('/rosout', 'rcl_interfaces/msg/Log', typestore=ts)
        c_tf = w.add_connection('/tf', 'tf2_msgs/msg/TFMessage', typestore=ts)
        ptype = {'fluid': FP, 'float64_bar': F64, 'load': F64}.get(layout.pressures)
        c_p = []
        if layout.pressures in ('fluid', 'float64_bar'):
            c_p = [w.add_connection(tp, ptype.__msgtype__, typestore=ts)
                   for tp in ('/hydraulics/chamber_a', '/hydraulics/chamber_b')]
        elif layout.pressures == 'load':
            c_p = [w.add_connection('/hydraulics/load_pressure', ptype.__msgtype__,
                                    typestore=ts)]
        every = max(1, int(round(layout.rate_hz / layout.pressure_rate_hz)))
        c_f = None
        if layout.load_cell:
            WS = T['geometry_msgs/msg/WrenchStamped']
            V3, WR = T['geometry_msgs/msg/Vector3'], T['geometry_msgs/msg/Wrench']
            c_f = w.add_connection(LOAD_TOPIC, WS.__msgtype__, typestore=ts)
            k_l, c_l, z_l = (float(plant_params[n]) for n in ('k_L', 'c_L', 'z_L'))
        log = T['rcl_interfaces/msg/Log'](stamp=tm(sec=0, nanosec=0), level=20,
                                          name='driver', msg='cycle ok', file='d.cpp',
                                          function='f', line=1)
        tf = T['tf2_msgs/msg/TFMessage'](transforms=[])
        for k in range(n):
            if k not in lost:
                pos = np.zeros(len(joints))
                pos[ja] = z[k]
                vel = np.zeros(len(joints)) if layout.velocity else np.zeros(0)
                if layout.velocity:
                    vel[ja] = samp[k, 1] + layout.noise_v * rng.standard_normal()
                w.write(c_js, int(recv[k]), ser(JS(header=header(stamps[k]), name=joints,
                                                   position=pos, velocity=vel,
                                                   effort=np.zeros(0))))
            value = cmds[k] / layout.command_scale
            if layout.command == 'float64_array':
                arr = np.zeros(max(3, layout.command_index + 1))
                arr[layout.command_index] = value
                msg = F64A(layout=LAY(dim=[DIM(label='joints', size=arr.size,
                                               stride=arr.size)], data_offset=0), data=arr)
            elif layout.command == 'float64':
                msg = F64(data=float(value))
            else:
                msg = JS(header=header(stamps[k]), name=[layout.joint],
                         position=np.zeros(0), velocity=np.zeros(0),
                         effort=np.array([value]))
            w.write(c_cmd, int(c_recv[k]), ser(msg))
            if c_p and k % every == 0:
                pa = samp[k, 2] + layout.noise_p * rng.standard_normal()
                pb = samp[k, 3] + layout.noise_p * rng.standard_normal()
                vals = [pa, pb] if len(c_p) == 2 else [pa - pb]
                for con, p in zip(c_p, vals):
                    if layout.pressures == 'fluid':
                        m = FP(header=header(stamps[k]), fluid_pressure=float(p), variance=0.0)
                    else:
                        m = F64(data=float(p / (1e5 if layout.pressures == 'float64_bar'
                                                else 1.0)))
                    w.write(con, int(recv[k]) + 20_000, ser(m))
            if c_f is not None and k not in lost:
                f = k_l * (samp[k, 0] - z_l) + c_l * samp[k, 1] + \
                    layout.noise_f * rng.standard_normal()
                hd = hdr(stamp=tm(sec=int(stamps[k] // 10**9), nanosec=int(stamps[k] % 10**9)),
                         frame_id='load_cell_link')
                w.write(c_f, int(recv[k]) + 10_000, ser(WS(
                    header=hd, wrench=WR(force=V3(x=float(f), y=0.0, z=0.0),
                                         torque=V3(x=0.0, y=0.0, z=0.0)))))
            if k % 100 == 0:
                w.write(c_log, int(recv[k]), ser(log))
                w.write(c_tf, int(recv[k]), ser(tf))
    return {'input_delay': true_delay, 'samples': n - len(lost), 'params': plant_params,
            'dt': dt}
