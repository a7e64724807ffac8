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
The plant node: the simulated axis (:class:`ros_ehs.core.sim.axis.SimulatedAxis`) on the bench.

The axis decides the stamp policy, the watchdog, when time starts, the lock-step protocol, the
faults and the sensor noise (its docstring states each rule); this node converts messages,
calls it and publishes.

``mode: realtime`` steps the model on a steady timer at ``rate_hz`` (zero-order hold of the
latest command), from the tick at which ``state`` has ``wait_subscribers`` subscribers on (time
restarts there: a recorder gets the loop from its first period, and the middleware's first
message to each subscriber, which can hold the process for milliseconds, goes out before the
watchdog guards the loop). States are stamped on the sim grid ``t0 + k / rate_hz``: a late tick
steps (and publishes) every period it missed, so sim time stays locked to wall time and a bag
has no gaps. The valve is at zero within ``watchdog_periods`` periods of the last fresh command
(plus the lateness of that tick); trips at a tick so late that an on-time one would have
applied the command are counted apart (``watchdog_trips_late_tick``).

``mode: lockstep`` publishes the state, then waits for the command stamped with that state's
stamp and steps exactly one period: a closed loop over DDS that is deterministic and runs as
fast as the messages go. ``/clock`` goes out after the state every ``clock_period`` of sim
time, with the first and the last state and with every resend: the reference answers each
clock with the references up to its ``preview`` ahead, so a period needs only the state and
the command, as a bare ping-pong does (sim-time nodes see time in ``clock_period`` steps, as
under gazebo_ros's ``publish_rate``; 0 publishes every period). A lost message is recovered
by republishing the state after ``resend_period`` of silence (the controller answers a
repeated stamp with the same command). Its topics go out over the contract's
``LOCKSTEP_QOS`` (reliable, depth 10000), so a recorder that the OS pauses still gets every
sample; the subscriptions stay best effort and match any publisher.

The chamber pressures and the load cell (``load_cell``, a ``WrenchStamped`` as ros2_control's
force_torque_sensor_broadcaster publishes it; only when someone listens) carry the stamp of
the state they belong to; with a specimen installed (``k_L`` > 0) the state also carries the
load cell's reading (joint ``load_cell``, its effort), so a controller has it with the state.
In real time they go out once that state's command has come, or at the next tick if none
came: off the loop's path, so the controller, which shares the plant's CPU and priority, gets
the state without waiting behind them.

Every state message also carries the current applied over the period that ended at its stamp
(joint ``servo_valve``), so a bag shows exactly what the valve got. ``noise_*`` add white
sensor noise to what is published (the model's own state stays exact).

Readiness and figures are in the diagnostics (``watchdog``: waiting, ok or tripped; the loop
figures); at exit the figures, with the newest watchdog trips, are also written as JSON to
``figures_file`` when it is set (what the benchmarks read).

Faults for tests and demonstrations (``fault``, from ``fault_time`` of sim time after the
start, or at once when set live): ``frozen_sensor`` publishes the position and velocity of
the fault's start from then on (a driver repeating its last sample); ``nan_sensor`` publishes
NaN position and velocity; ``stuck_valve`` applies the current of the fault's start whatever
the commands say (a spool stuck open); ``lost_pressure`` drops the supply to 1 MPa (a pump
trip or burst hose). ``none`` ends a fault.
"""

from __future__ import annotations

from collections import deque
import json
from pathlib import Path
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from ros_ehs.core.errors import InputError
from ros_ehs.core.options import PLANT
from ros_ehs.core.params import Params, PLANT_SPECS
from ros_ehs.core.sim.axis import SimulatedAxis
from ros_ehs.nodes.loop_stats import LoopStats
from ros_ehs.nodes.parameters import (declare_settings, node_params, update_settings,
                                      validate_changes)
from ros_ehs.nodes.ros_common import (diagnostics, ERROR, OK, PLANT_STATUS, qos_profile, read_msg,
                                      run, steady_clock, WARN)
import ros_ehs_msgs_py as contract
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, JointState

__all__ = ['OPTIONS', 'PlantNode', 'main']

#: the node's options (declared in :mod:`ros_ehs.core.options`)
OPTIONS = PLANT

#: periods the diagnostics rank for their percentiles (2 s at 1 kHz): ranking all 20000
#: took 0.45 ms of the executor and made the next tick late (Ring.p50_p99_max)
DIAGNOSTICS_WINDOW = 2000
_RING = 1024           # send times kept for round-trip measurement


class PlantNode(Node):
    """The simulated axis behind the contract topics (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('plant', **kwargs)
        self.opt = declare_settings(self, OPTIONS)
        self.rt_priority = int(self.opt['rt_priority'])     # applied by run()
        self.cpu_affinity = int(self.opt['cpu_affinity'])   # applied by run()
        declare_settings(self, PLANT_SPECS, Params())
        self.params = node_params(self, Params(), PLANT_SPECS)
        self.lockstep = self.opt['mode'] == 'lockstep'
        self.realtime, self.carries_loop = not self.lockstep, True     # for run()'s placement
        o = self.opt
        if self.lockstep:
            t0_ns, wall0_ns = int(round(float(o['start_time']) * 1e9)), 0
        else:
            t0_ns, wall0_ns = self.get_clock().now().nanoseconds, time.monotonic_ns()
        self.axis = SimulatedAxis(
            self.params, o['model'], float(o['rate_hz']), lockstep=self.lockstep,
            watchdog_periods=int(o['watchdog_periods']), initial_z=float(o['initial_z']),
            t0_ns=t0_ns, wall0_ns=wall0_ns, duration=float(o['duration']),
            wait_subscribers=int(o['wait_subscribers']), start_delay=float(o['start_delay']),
            clock_period=float(o['clock_period']), resend_period=float(o['resend_period']),
            noise=(float(o['noise_z']), float(o['noise_v']), float(o['noise_p'])),
            seed=int(o['seed']), fault=o['fault'], fault_time=float(o['fault_time']),
            real_time_factor=float(o['real_time_factor']))
        # compile the kernels now, on a throw-away copy (the loop's axis starts fresh)
        SimulatedAxis(self.params, o['model']).step(0.0)
        self.dt = self.axis.dt
        self.undecodable = 0
        self._sent_stamp = [-1] * _RING       # plain lists: the per-period path stays in
        self._sent_time = [0.0] * _RING       # Python floats, no numpy scalars
        self.stats = LoopStats()
        self._pending: Params | None = None
        self._listen_check = 0.0
        self._listening = [False, False, False]
        # real time: the pressures of the latest state, sent once its command has come (or at
        # the next tick), off the loop's path: the controller shares the plant's CPU and
        # priority, so work after the state's publish delays the answer
        self._unsent: deque[tuple[int, float, float, float]] = deque(maxlen=1)

        def out(t):      # lock-step: the loop topics go out reliable (see LOCKSTEP_QOS)
            return qos_profile(t.qos_in(self.lockstep))

        self.pub_state = self.create_publisher(JointState, contract.STATE.name,
                                               out(contract.STATE))
        self.pub_p = self.create_publisher(FluidPressure, contract.PRESSURE_P.name,
                                           out(contract.PRESSURE_P))
        self.pub_t = self.create_publisher(FluidPressure, contract.PRESSURE_T.name,
                                           out(contract.PRESSURE_T))
        self.pub_load = self.create_publisher(WrenchStamped, contract.LOAD_CELL.name,
                                              out(contract.LOAD_CELL))
        self.pub_diag = self.create_publisher(
            DiagnosticArray, contract.DIAGNOSTICS.name,
            qos_profile(contract.DIAGNOSTICS.qos))
        self.pub_clock = None
        self._loop: threading.Thread | None = None
        if self.lockstep:
            self.pub_clock = self.create_publisher(Clock, contract.CLOCK.name, out(contract.CLOCK))
        # raw: the command's CDR bytes are read directly (ros_ehs_msgs_py.wire, the fast path)
        self.create_subscription(JointState, contract.COMMAND.name, self._on_command,
                                 qos_profile(contract.COMMAND.qos), raw=True)
        self.add_on_set_parameters_callback(self._check_params)
        self.add_post_set_parameters_callback(self._apply_params)
        clock = steady_clock()
        if self.lockstep:
            self.create_timer(self.axis.poll_period, self._poll, clock=clock)
        elif o['timing'] == 'thread':
            self._stop = threading.Event()
            self._loop = threading.Thread(target=self._run_loop, daemon=True)
            self._loop.start()
        else:
            self.create_timer(self.dt, self._tick, clock=clock)
        self.create_timer(float(o['diagnostics_period']), self._diagnose, clock=clock)
        self.get_logger().info(
            f'{o["model"]} model, {o["mode"]} at {o["rate_hz"]:g} Hz, '
            f'watchdog {o["watchdog_periods"]} periods')

    # -- commands ----------------------------------------------------------------------------
    def _on_command(self, data: bytes) -> None:
        now = time.monotonic()     # on arrival, as the bare ping-pong's round trip ends
        c = read_msg(self, contract.command_from_cdr, data, 'command')
        if c is None:
            self.undecodable += 1
            return
        ax = self.axis
        armed, latest = ax.armed, ax.stamp_ns()
        verdict = ax.command(c.stamp_ns, c.i, now)
        if verdict == 'non_finite':
            self.get_logger().warning(f'ignored a non-finite command i = {c.i!r} A',
                                      throttle_duration_sec=1.0)
            return
        if verdict == 'future':
            self.get_logger().warning(
                f'ignored a command stamped {(c.stamp_ns - latest) * 1e-9:.6g} s after the '
                'latest state', throttle_duration_sec=1.0)
            return
        if verdict == 'stale':
            return
        j = (c.stamp_ns - ax.t0_ns) // ax.dt_ns % _RING
        if self._sent_stamp[j] == c.stamp_ns:
            self.stats.rtt.add(now - self._sent_time[j])
        if verdict == 'not_current':
            return
        self._send_pressures()
        if not armed:
            what = 'lock-step running' if self.lockstep else 'watchdog armed'
            self.get_logger().info(f'first command received; {what}')
        if self.lockstep:
            self.stats.tick(now, True)
            if ax.notes:
                self._log_notes()
            if not ax.held:        # held (paused, or ahead of its pace): _poll sends it
                self._send_stepped()

    def _send_stepped(self) -> None:
        """Lock-step: send the state a step made (and say so when it was the run's last)."""
        ax = self.axis
        self._publish(clock=ax.clock_due())
        if ax.finished:
            self.get_logger().info(f'lock-step run complete: {ax.k} steps, '
                                   f'{ax.figures(time.monotonic())["steps_per_s"]:.0f} steps/s')
            self._diagnose()

    # -- real time ---------------------------------------------------------------------------
    def _tick(self) -> None:
        now_ns = time.monotonic_ns()
        ax = self.axis
        if not ax.started:
            have = self.pub_state.get_subscription_count()
            if ax.start(now_ns, have):
                self.get_logger().info(f'{have} subscriber(s) on state: stepping from now')
            return
        trips = ax.trips
        n = ax.tick(now_ns)
        if n <= 0:
            return
        if ax.armed:
            self.stats.tick(now_ns * 1e-9, ax.tick_fresh)
        if ax.trips != trips:
            t = ax.trip_log[-1]
            self.get_logger().warning(
                f'watchdog: no fresh command for {t.command_age_ms:.2f} ms (this tick '
                f'{t.tick_late_ms:.2f} ms late), valve current zeroed ({ax.trips} trips so '
                f'far, {ax.trips_late_tick} at late ticks)', throttle_duration_sec=1.0)
        self._send_pressures()       # no command came for the latest state: send them now
        for _ in range(n):
            ax.step()
            self._publish()
        if ax.notes:
            self._log_notes()

    def _run_loop(self) -> None:
        nxt = time.monotonic_ns()
        dt_ns = self.axis.dt_ns
        while not self._stop.is_set():
            nxt += dt_ns
            d = nxt - time.monotonic_ns()
            if d > 0:
                time.sleep(d * 1e-9)
            else:
                nxt = time.monotonic_ns()
            self._tick()

    # -- lock-step ---------------------------------------------------------------------------
    def _poll(self) -> None:
        """Lock-step housekeeping: wait for subscribers, send the first state, resend."""
        what = self.axis.poll(time.monotonic(), self.pub_state.get_subscription_count())
        if what == 'matched':
            self.get_logger().info('subscribers matched; lock-step starts in '
                                   f'{self.opt["start_delay"]:g} s')
        elif what == 'release':
            self._send_stepped()
        elif what is not None:
            self._publish(clock=True)

    # -- publishing --------------------------------------------------------------------------
    def _publish(self, clock: bool = False) -> None:
        s = self.axis.sample()
        st = s.state.stamp_ns
        data = contract.state_to_cdr(s.state)
        j = (st - self.axis.t0_ns) // self.axis.dt_ns % _RING
        self._sent_stamp[j] = st
        # the round trip starts here, at the publish, as the bare ping-pong's does: the
        # model step before it is the plant's compute, not the loop's transport
        now = self._sent_time[j] = time.monotonic()
        self.pub_state.publish(data)      # serialized: no message object to convert
        if clock and self.pub_clock is not None:     # after the state: off the loop's path
            self.pub_clock.publish(contract.clock_to_cdr(st))      # serialized
        if now >= self._listen_check:      # who listens to the pressures, every 50 ms
            self._listen_check = now + 0.05
            self._listening = [pub.get_subscription_count() > 0
                               for pub in (self.pub_p, self.pub_t, self.pub_load)]
        if any(self._listening):       # only when someone listens
            if self._unsent:         # a late tick's catch-up: the earlier state's go now
                self._send_pressures()
            self._unsent.append((st, s.p_cp, s.p_ct, s.load))
            if self.lockstep:
                self._send_pressures()

    def _send_pressures(self) -> None:
        try:
            st, pa, pb, f = self._unsent.popleft()   # atomic: the loop thread may tick meanwhile
        except IndexError:
            return
        for pub, p, listening in ((self.pub_p, pa, self._listening[0]),
                                  (self.pub_t, pb, self._listening[1])):
            if listening:
                pub.publish(contract.pressure_to_cdr(contract.Pressure(st, p)))
        if self._listening[2]:
            self.pub_load.publish(contract.load_to_cdr(contract.Load(st, f)))

    def _log_notes(self) -> None:
        """Log what the axis noted (a fault starting or ending, a failed model step), once."""
        notes = self.axis.notes
        while notes:
            level, text = notes.pop(0)
            (self.get_logger().error if level == 'error' else self.get_logger().warning)(text)

    # -- parameters and diagnostics ----------------------------------------------------------
    def _check_params(self, changes):
        res, self._pending = validate_changes(self.params, changes, PLANT_SPECS, OPTIONS)
        if res.successful and not self.lockstep and any(
                c.name == 'paused' and c.value for c in changes):
            try:
                self.axis.pause(True, time.monotonic())     # the axis's rule: it refuses
            except InputError as e:
                self._pending = None
                res.successful, res.reason = False, str(e)
        return res

    def _apply_params(self, changes) -> None:
        new, self._pending = self._pending, None
        if new is not None and new != self.params:
            self.params = new
            self.axis.set_params(new)
            self.get_logger().info('plant parameters changed; model rebuilt, state kept')
        update_settings(self.opt, changes, OPTIONS)
        self.axis.configure(watchdog_periods=int(self.opt['watchdog_periods']),
                            fault=self.opt['fault'], fault_time=float(self.opt['fault_time']))
        self.axis.pause(bool(self.opt['paused']), time.monotonic())

    def figures(self, last: int | None = None) -> dict:
        """
        Return the loop and watchdog figures: at exit, and in the diagnostics.

        Percentiles over the whole window (the last 20000 periods), or its ``last`` newest.
        """
        f = self.stats.as_dict(last)
        f.update(self.axis.figures(time.monotonic()))
        f['bad_commands'] += self.undecodable
        return f

    def close(self) -> None:
        """Stop the loop thread; write the figures to ``figures_file`` (when set)."""
        if self._loop is not None:
            self._stop.set()
            self._loop.join(timeout=1.0)
        f = {**self.figures(), 'watchdog_trip_log': [t.as_list() for t in self.axis.trip_log],
             'late_log': [t.as_list() for t in self.axis.late.log]}
        path = self.opt['figures_file']
        if path:
            try:
                Path(path).write_text(json.dumps(f) + '\n')
            except OSError as e:
                self.get_logger().error(f'could not write the figures to {path}: {e}')

    def _diagnose(self) -> None:
        self._log_notes()
        f = self.figures(DIAGNOSTICS_WINDOW)
        ax = self.axis
        level, msg = OK, 'running'
        if ax.model_faults:
            level, msg = ERROR, f'{ax.model_faults} model step failures'
        elif ax.tripped:
            level, msg = WARN, 'watchdog tripped: valve current zero'
        elif not ax.started:
            have, need = self.pub_state.get_subscription_count(), self.opt['wait_subscribers']
            level, msg = WARN, f'waiting for {need} subscribers on state ({have} now)'
        elif not ax.armed:
            level, msg = WARN, 'waiting for the first command'
        elif self.lockstep and ax.finished:
            msg = 'lock-step run complete'
        self.pub_diag.publish(diagnostics(self, PLANT_STATUS, level, msg, f))


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs plant``."""
    return run(PlantNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
