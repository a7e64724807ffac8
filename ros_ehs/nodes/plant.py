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
The plant node: the servo valve and cylinder model on the bench network.

``mode: realtime`` steps the model on a steady timer at ``rate_hz`` (zero-order hold of the
latest command), from the tick at which ``state`` has ``wait_subscribers`` subscribers on (time
restarts there: a recorder gets the loop from its first period, and the middleware's first
message to each subscriber, which can hold the process for milliseconds, goes out before the
watchdog guards the loop). States are stamped on the sim grid ``t0 + k / rate_hz``: a late tick
steps (and publishes) every period it missed, so sim time stays locked to wall time and a bag
has no gaps. The watchdog never applies a command over a period that ends more than
``watchdog_periods`` periods after the command arrived: from the tick where that would happen
the valve current is zero (the hydraulic fail-safe: spool to null) until fresh commands return.
So the valve is at zero within ``watchdog_periods`` periods of the last fresh command (plus the
lateness of that tick). A trip at a tick so late that an on-time one would have applied the
command is also counted apart (``watchdog_trips_late_tick``: the machine did not run the plant
in time; the controller was not late), unless a later on-time tick finds the command too old as
well (a controller that stopped).

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

Stamp policy for commands (the controller stamps each command with the state it answers): a
command stamped after the latest state this plant published answers none (a stray publisher,
another clock) and is ignored and counted (``future_commands``); one no newer than the last
applied, or any before a real-time plant's first state, is ignored and counted
(``stale_commands``); in lock-step only the answer to the current state counts. A restarted
controller therefore needs nothing: its first answer is newer than the last applied. States
are stamped on the plant's own grid.

The chamber pressures (only when someone listens) carry the stamp of the state they belong
to. In real time they go out once that state's command has come, or at the next tick if none
came: off the loop's path, so the controller, which shares the plant's CPU and priority, gets
the state without waiting behind them.

Every state message also carries the current applied over the period that ended at its stamp
(joint ``servo_valve``), so a bag shows exactly what the valve got. ``noise_*`` add white
sensor noise to what is published (the model's own state stays exact).

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
import math
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.node import Node
from ros_ehs.launch import FIGURES
from ros_ehs.model.plant import Plant
from ros_ehs.nodes.loop_stats import LoopStats
from ros_ehs.nodes.options import (declare_options, declare_specs, node_params, Option,
                                   update_options, validate_changes)
from ros_ehs.nodes.ros_common import (diagnostics, ERROR, OK, PLANT_STATUS, qos_profile, read_msg,
                                      run, steady_clock, WARN)
from ros_ehs.nodes.scheduling import CPU_AFFINITY, RT_PRIORITY
from ros_ehs.params import Params, PLANT_SPECS
import ros_ehs_msgs_py as contract
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, JointState

__all__ = ['OPTIONS', 'PlantNode', 'main']

#: The faults the plant can inject (option ``fault``).
FAULTS = ('none', 'frozen_sensor', 'nan_sensor', 'stuck_valve', 'lost_pressure')
#: The supply pressure of the ``lost_pressure`` fault [Pa] (the lowest p_s allows).
LOST_SUPPLY = 1.0e6

OPTIONS = (
    Option('model', 'simplified', 'plant model: full (10 states), reduced (6: the simplified '
           "with the full model's valve dynamics) or simplified (4 states)",
           choices=('full', 'reduced', 'simplified')),
    Option('mode', 'realtime', 'realtime: step on a timer; lockstep: one step per command, '
           'publish /clock', choices=('realtime', 'lockstep')),
    Option('rate_hz', 1000.0, 'control period rate [Hz]', 10.0, 5000.0),
    Option('timing', 'timer', 'real time: an executor timer (one thread: no GIL handover; '
           'less CPU and a shorter round trip, measured) or a thread sleeping to each period',
           choices=('timer', 'thread')),
    Option('watchdog_periods', 3, 'a command is never applied over a period ending more '
           'than this many periods after it arrived: then the valve current is zero', 1, 10000,
           read_only=False),
    Option('initial_z', 0.0, 'initial piston position [m]', -2.0, 2.0),
    Option('start_time', 0.0, 'lock-step: sim time of the first state [s]', 0.0, 1.0e9),
    Option('duration', 0.0, 'lock-step: stop advancing at this sim time after start [s] '
           '(0: never)', 0.0, 1.0e9),
    Option('wait_subscribers', 1, 'start when `state` has this many subscribers (2 with a '
           'recorder): lock-step, the first step; real time, the first state (time restarts '
           'there), so a recorder has the loop from its first period and the middleware opens '
           'its ports to every subscriber before a watchdog guards the loop', 0, 100),
    Option('start_delay', 0.5, 'lock-step: then wait this long, so every node has matched '
           'every other before the first step [s]', 0.0, 60.0),
    Option('clock_period', 0.01, 'lock-step: publish /clock every this much sim time (0: '
           "every period); keep it below the reference's preview [s]", 0.0, 10.0),
    Option('resend_period', 0.05, 'lock-step: republish the state after this much silence '
           '[s]', 1.0e-3, 10.0),
    Option('noise_z', 0.0, 'white noise (1 sigma) on the published position [m]; the bench '
           'sets 5e-6', 0.0, 0.01),
    Option('noise_v', 0.0, 'white noise on the published velocity [m/s]', 0.0, 1.0),
    Option('noise_p', 0.0, 'white noise on the published chamber pressures [Pa]', 0.0, 1.0e6),
    Option('seed', 0, 'seed of the sensor noise', 0, 2**31 - 1),
    Option('fault', 'none', 'inject a fault from fault_time on (tests, demonstrations): '
           'frozen_sensor, nan_sensor, stuck_valve (the current at the start stays applied), '
           'lost_pressure (supply to 1 MPa)', choices=FAULTS, read_only=False),
    Option('fault_time', 0.0, 'sim time after the start at which `fault` begins [s]', 0.0,
           1.0e9, read_only=False),
    Option('diagnostics_period', 1.0, 'period of the diagnostics message [s]', 0.05, 60.0),
    RT_PRIORITY,
    CPU_AFFINITY,
)

_MAX_CATCHUP = 50      # periods a late tick may step before the loop is resynchronised
#: periods the diagnostics rank for their percentiles (2 s at 1 kHz): ranking all 20000
#: took 0.45 ms of the executor and made the next tick late (Window.p50_p99_max)
DIAGNOSTICS_WINDOW = 2000
_RING = 1024           # send times kept for round-trip measurement
_ZEROS = (0.0, 0.0, 0.0, 0.0)
TRIP_LOG = 100         # watchdog trips listed at exit (the newest)


class PlantNode(Node):
    """The model behind the contract topics (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('plant', **kwargs)
        self.opt = declare_options(self, OPTIONS)
        self.rt_priority = int(self.opt['rt_priority'])     # applied by run()
        self.cpu_affinity = int(self.opt['cpu_affinity'])   # applied by run()
        declare_specs(self, PLANT_SPECS, Params())
        self.params = node_params(self, Params(), PLANT_SPECS)
        self.plant = Plant(self.params, self.opt['model'])
        self.x = self.plant.equilibrium(z=float(self.opt['initial_z']))
        self._x_next = self.x.copy()
        # compile the kernels now, on a throw-away copy (the loop's plant starts fresh)
        Plant(self.params, self.opt['model']).step(self.x, np.zeros(2), 1e-3)
        self._iz = self.plant.state_names.index('z')
        self._iv = self.plant.state_names.index('z_dot')
        self._ipa, self._ipb = (self.plant.state_names.index(s) for s in ('p_CP', 'p_CT'))
        self._ixv = self.plant.state_names.index('x') if 'x' in self.plant.state_names else -1
        self.dt = 1.0 / float(self.opt['rate_hz'])
        self._dt_ns = int(round(self.dt * 1e9))
        self.lockstep = self.opt['mode'] == 'lockstep'
        self._clock_every = max(1, int(round(float(self.opt['clock_period']) / self.dt)))
        self._duration = float(self.opt['duration']) if self.lockstep else 0.0
        self._A_p = float(self.params['A_p'])
        self.i_limit = 2.0 * float(self.params['i_rated'])
        self.u = np.zeros(2)
        self.i_cmd = 0.0
        self.applied = 0.0       # current applied over the last period [A]
        self.k = 0
        self.armed = False       # a first command has come
        self.tripped = False
        self.trips = 0
        self.trips_late_tick = 0     # of those, trips that an on-time tick would not have had
        self._trip_late = False
        #: the newest trips, [time.monotonic(), tick lateness ms, command age ms, at a late
        #: tick alone], printed at exit (launch_scripts/bench.py matches them with its machine
        #: probes); bounded
        self._trip_log: deque[list] = deque(maxlen=TRIP_LOG)
        self.trip_latency_ms = math.nan
        self.trip_tick_late_ms = math.nan
        self.bad_commands = 0
        self.stale_commands = 0
        self.future_commands = 0
        self.faults = 0
        self.overruns = 0
        self.resends = 0
        self.finished = False
        self._t_first = self._t_last = math.nan
        self._fresh = False
        self._last_cmd_stamp = -1
        self._last_rx = 0.0
        self._sent_stamp = [-1] * _RING       # plain lists: the per-period path stays in
        self._sent_time = [0.0] * _RING       # Python floats, no numpy scalars
        self.stats = LoopStats()
        self._rng = np.random.default_rng(int(self.opt['seed']))
        self._noise = tuple(float(self.opt[k]) for k in ('noise_z', 'noise_v', 'noise_p'))
        self._pending: Params | None = None
        self._fault_on = False          # the fault is active
        self._fault_hold = (0.0, 0.0, 0.0)    # frozen z, z_dot; stuck current

        self._listen_check = 0.0
        self._listening = [False, False]
        # real time: the pressures of the latest state, sent once its command has come (or at
        # the next tick), off the loop's path: the controller shares the plant's CPU and
        # priority, so work after the state's publish delays the answer
        self._unsent: deque[tuple[int, float, float]] = deque(maxlen=1)

        def out(t):      # lock-step: the loop topics go out reliable (see LOCKSTEP_QOS)
            return qos_profile(t.qos_in(self.lockstep))

        self.pub_state = self.create_publisher(JointState, contract.STATE.name,
                                               out(contract.STATE))
        self.pub_p = self.create_publisher(FluidPressure, contract.PRESSURE_P.name,
                                           out(contract.PRESSURE_P))
        self.pub_t = self.create_publisher(FluidPressure, contract.PRESSURE_T.name,
                                           out(contract.PRESSURE_T))
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
            self.t0_ns = int(round(float(self.opt['start_time']) * 1e9))
            self._last_progress = time.monotonic()
            self._first_due: float | None = None     # when the first state goes out
            self._sent_first = False
            self.create_timer(float(self.opt['resend_period']), self._resend, clock=clock)
        else:
            self.t0_ns = self.get_clock().now().nanoseconds
            self._t0_wall = time.monotonic_ns()
            self._started = False      # until `state` has wait_subscribers subscribers
            if self.opt['timing'] == 'thread':
                self._stop = threading.Event()
                self._loop = threading.Thread(target=self._run_loop, daemon=True)
                self._loop.start()
            else:
                self.create_timer(self.dt, self._tick, clock=clock)
        self.create_timer(float(self.opt['diagnostics_period']), self._diagnose, clock=clock)
        self.get_logger().info(
            f'{self.opt["model"]} model, {self.opt["mode"]} at {self.opt["rate_hz"]:g} Hz, '
            f'watchdog {self.opt["watchdog_periods"]} periods')

    # -- time --------------------------------------------------------------------------------
    def stamp_ns(self, k: int | None = None) -> int:
        """Return the stamp of period ``k`` (default: the current one) [ns]."""
        return self.t0_ns + (self.k if k is None else k) * self._dt_ns

    # -- commands ----------------------------------------------------------------------------
    def _on_command(self, data: bytes) -> None:
        now = time.monotonic()     # on arrival, as the bare ping-pong's round trip ends
        c = read_msg(self, contract.command_from_cdr, data, 'command')
        if c is None:
            self.bad_commands += 1
            return
        if not math.isfinite(c.i):
            self.bad_commands += 1
            self.get_logger().warning(f'ignored a non-finite command i = {c.i!r} A',
                                      throttle_duration_sec=1.0)
            return
        if c.stamp_ns > self.stamp_ns():
            # a command answers a state: one stamped after the latest state answers none
            # (a stray publisher, another clock); adopting it would make every true
            # command look stale until the watchdog zeroes the valve for good
            self.future_commands += 1
            self.get_logger().warning(
                f'ignored a command stamped {(c.stamp_ns - self.stamp_ns()) * 1e-9:.6g} s '
                'after the latest state', throttle_duration_sec=1.0)
            return
        if c.stamp_ns <= self._last_cmd_stamp or (self.k == 0 and not self.lockstep):
            # older than the last applied, or before this real-time plant's first state (it
            # answers none: a controller's answer to another run must not arm the watchdog)
            self.stale_commands += 1
            return
        j = (c.stamp_ns - self.t0_ns) // self._dt_ns % _RING
        if self._sent_stamp[j] == c.stamp_ns:
            self.stats.rtt.add(now - self._sent_time[j])
        if self.lockstep and (c.stamp_ns != self.stamp_ns() or self.finished):
            self.stale_commands += 1       # lock-step: only the answer to this state counts
            return
        self._last_cmd_stamp = c.stamp_ns
        self.i_cmd = min(max(c.i, -self.i_limit), self.i_limit)
        self._last_rx = now     # before arming: the loop thread may tick in between
        self._fresh = True
        self._send_pressures()
        if not self.armed:
            self.armed = True
            self._t_first = now
            what = 'lock-step running' if self.lockstep else 'watchdog armed'
            self.get_logger().info(f'first command received; {what}')
        if self.lockstep:
            self.stats.tick(now, True)
            self._step(self.i_cmd)
            self._last_progress = now
            self._publish(clock=self.finished or self.k % self._clock_every == 0)
            if self.finished:
                self._t_last = now
                self.get_logger().info(f'lock-step run complete: {self.k} steps, '
                                       f'{self.figures()["steps_per_s"]:.0f} steps/s')
            return

    # -- stepping ----------------------------------------------------------------------------
    def _fault_check(self) -> None:
        """Start or end the injected fault at this period (``fault``, ``fault_time``)."""
        want = self.opt['fault'] != 'none' and self.k * self.dt >= float(self.opt['fault_time'])
        if want == self._fault_on:
            return
        self._fault_on = want
        xs = self.x.tolist()
        self._fault_hold = (xs[self._iz], xs[self._iv], self.applied)
        fault = self.opt['fault']
        p = self.params
        if fault == 'lost_pressure' or self.plant.params['p_s'] != p['p_s']:
            sup = LOST_SUPPLY if want and fault == 'lost_pressure' else p['p_s']
            self.plant = Plant(p.replace(p_s=sup, p_t=min(p['p_t'], 0.5 * sup)),
                               self.opt['model'])
        self.get_logger().warning(f'fault {fault} injected at {self.k * self.dt:.6g} s' if want
                                  else 'injected fault ended')

    def _step(self, i: float) -> None:
        if self.opt['fault'] != 'none' or self._fault_on:
            self._fault_check()
            if self._fault_on and self.opt['fault'] == 'stuck_valve':
                i = self._fault_hold[2]
        self.u[0] = self.applied = i
        nxt = self._x_next
        nxt[:] = self.x
        if self.plant.advance(nxt, self.u, self.dt):      # the unchecked fast path
            self.x, self._x_next = nxt, self.x
        else:      # diverged or left the cylinder: keep the last state
            self.faults += 1
            self.i_cmd = 0.0
            self.get_logger().error(f'model step failed at i = {i!r} A (the state left the '
                                    'model: non-finite, or the piston outside the '
                                    'cylinder), state held', throttle_duration_sec=1.0)
        self.k += 1
        if self._duration > 0:      # lock-step only
            self.finished = self.k * self.dt >= self._duration - 1e-12

    def _start(self, now_ns: int) -> bool:
        """
        Real time: start once ``state`` has ``wait_subscribers`` subscribers; say if started.

        Sim time restarts there, on the timer's grid (the first state is stamped a period
        after the last whole period). Fast DDS opens its shared-memory port to a new
        subscriber at the first message it sends there and meanwhile holds every send of the
        process (up to a third of the port's healthy-check timeout: 10 ms with
        fastdds_rt.xml): after the loop closed, that was a watchdog trip (docs/nodes.md).
        """
        have = self.pub_state.get_subscription_count()
        if have < self.opt['wait_subscribers']:
            return False
        self._started = True
        # whole periods on: the timer's phase stays the grid's (a grid started at this tick's
        # wake-up would put the next on-time wake-ups a little before their period's end)
        periods = (now_ns - self._t0_wall) // self._dt_ns
        self._t0_wall += periods * self._dt_ns
        self.t0_ns += periods * self._dt_ns
        self.get_logger().info(f'{have} subscriber(s) on state: stepping from now')
        return True

    def _tick(self) -> None:
        now_ns = time.monotonic_ns()
        if not self._started:
            self._start(now_ns)
            return
        n = (now_ns - self._t0_wall) // self._dt_ns - self.k
        if n <= 0:
            return
        due_ns = self._t0_wall + (self.k + 1) * self._dt_ns     # before any resync below
        if n > _MAX_CATCHUP:      # far behind: resynchronise (a gap in the stamps)
            self.overruns += 1
            self._t0_wall += (n - 1) * self._dt_ns
            self.t0_ns += (n - 1) * self._dt_ns
            n = 1
        now = now_ns * 1e-9     # the same clock as time.monotonic()
        fresh = self._fresh
        self._fresh = False
        if self.armed:
            self.stats.tick(now, fresh)
        # the command would be this old at the end of the coming period
        age = now + self.dt - self._last_rx
        wd = self.opt['watchdog_periods'] * self.dt
        i = self.i_cmd
        if not self.armed:
            i = 0.0
        elif age > wd:
            i = 0.0
            # would an on-time tick have applied the command? Then the plant's own lateness
            # (the machine) tripped it, not a late controller: counted apart, until a tick
            # finds the command too old on time as well (a controller that has stopped)
            late_only = due_ns * 1e-9 + self.dt - self._last_rx <= wd
            if not self.tripped:
                self.tripped = True
                self.trips += 1
                self.trip_latency_ms = (now - self._last_rx) * 1e3
                self.trip_tick_late_ms = (now_ns - due_ns) * 1e-6   # this tick's lateness
                self._trip_late = late_only
                self.trips_late_tick += late_only
                self._trip_log.append([round(now, 6), round(self.trip_tick_late_ms, 4),
                                       round(self.trip_latency_ms, 4), late_only])
                self.get_logger().warning(
                    f'watchdog: no fresh command for {self.trip_latency_ms:.2f} ms (this tick '
                    f'{self.trip_tick_late_ms:.2f} ms late), valve current zeroed '
                    f'({self.trips} trips so far, {self.trips_late_tick} at late ticks)',
                    throttle_duration_sec=1.0)
            elif self._trip_late and not late_only:
                self._trip_late = False
                self.trips_late_tick -= 1
                self._trip_log[-1][3] = False
        elif self.tripped:
            self.tripped = False
            self.get_logger().debug('watchdog: commands are back')
        self._send_pressures()       # no command came for the latest state: send them now
        for _ in range(int(n)):
            self._step(i)
            self._publish()

    def _run_loop(self) -> None:
        nxt = time.monotonic_ns()
        while not self._stop.is_set():
            nxt += self._dt_ns
            d = nxt - time.monotonic_ns()
            if d > 0:
                time.sleep(d * 1e-9)
            else:
                nxt = time.monotonic_ns()
            self._tick()

    def _resend(self) -> None:
        """Lock-step housekeeping: wait for subscribers, send the first state, resend."""
        now = time.monotonic()
        if self._first_due is None:
            if self.pub_state.get_subscription_count() >= self.opt['wait_subscribers']:
                self._first_due = now + float(self.opt['start_delay'])
                self.get_logger().info('subscribers matched; lock-step starts in '
                                       f'{self.opt["start_delay"]:g} s')
        elif not self._sent_first:
            if now >= self._first_due:
                self._sent_first = True
                self._last_progress = now
                self._publish(clock=True)
        elif now - self._last_progress >= float(self.opt['resend_period']) and \
                not self.finished:
            self.resends += 1
            self._publish(clock=True)

    # -- publishing --------------------------------------------------------------------------
    def _publish(self, clock: bool = False) -> None:
        st = self.stamp_ns()
        x = self.x
        xs = x.tolist()
        xv = xs[self._ixv] if self._ixv >= 0 else math.nan
        nz, nv, npr = self._noise
        e = self._rng.standard_normal(4).tolist() if (nz or nv or npr) else _ZEROS
        z, v = xs[self._iz] + nz * e[0], xs[self._iv] + nv * e[1]
        if self._fault_on:
            fault = self.opt['fault']
            if fault == 'frozen_sensor':
                z, v = self._fault_hold[0], self._fault_hold[1]
            elif fault == 'nan_sensor':
                z = v = math.nan
        data = contract.state_to_cdr(contract.AxisState(
            st, z, v, self._A_p * (xs[self._ipa] - xs[self._ipb]), xv, self.applied))
        j = (st - self.t0_ns) // self._dt_ns % _RING
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
                               for pub in (self.pub_p, self.pub_t)]
        if self._listening[0] or self._listening[1]:       # only when someone listens
            if self._unsent:         # a late tick's catch-up: the earlier state's go now
                self._send_pressures()
            self._unsent.append((st, xs[self._ipa] + npr * e[2], xs[self._ipb] + npr * e[3]))
            if self.lockstep:
                self._send_pressures()

    def _send_pressures(self) -> None:
        try:
            st, pa, pb = self._unsent.popleft()     # atomic: the loop thread may tick meanwhile
        except IndexError:
            return
        for pub, p, listening in ((self.pub_p, pa, self._listening[0]),
                                  (self.pub_t, pb, self._listening[1])):
            if listening:
                pub.publish(contract.pressure_to_cdr(contract.Pressure(st, p)))

    # -- parameters and diagnostics ----------------------------------------------------------
    def _check_params(self, changes):
        res, self._pending = validate_changes(self.params, changes, PLANT_SPECS, OPTIONS)
        return res

    def _apply_params(self, changes) -> None:
        new, self._pending = self._pending, None
        if new is not None and new != self.params:
            self.params = new
            self.plant = Plant(new, self.opt['model'])
            self._A_p = float(new['A_p'])
            self.i_limit = 2.0 * float(new['i_rated'])
            self.get_logger().info('plant parameters changed; model rebuilt, state kept')
        update_options(self.opt, changes, OPTIONS)

    def figures(self, last: int | None = None) -> dict:
        """
        Return the loop and watchdog figures: at exit, and in the diagnostics.

        Percentiles over the whole window (the last 20000 periods), or its ``last`` newest.
        """
        f = self.stats.as_dict(last)
        f.update(steps=self.k, sim_time_s=self.k * self.dt,
                 watchdog=('tripped' if self.tripped else 'ok' if self.armed else 'waiting'),
                 watchdog_trips=self.trips, watchdog_trips_late_tick=self.trips_late_tick,
                 watchdog_latency_ms=self.trip_latency_ms,
                 watchdog_tick_late_ms=self.trip_tick_late_ms,
                 current_a=float(self.u[0]), bad_commands=self.bad_commands,
                 stale_commands=self.stale_commands, future_commands=self.future_commands,
                 model_faults=self.faults,
                 overruns=self.overruns, resends=self.resends, finished=self.finished,
                 fault=self.opt['fault'] if self._fault_on else 'none')
        if self.lockstep:
            end = self._t_last if self.finished else time.monotonic()
            f['steps_per_s'] = (self.k - 1) / (end - self._t_first) if self.k > 1 else math.nan
        return f

    def close(self) -> None:
        """Stop the loop thread; log the figures once (one JSON line after ``figures``)."""
        if self._loop is not None:
            self._stop.set()
            self._loop.join(timeout=1.0)
        f = {**self.figures(), 'watchdog_trip_log': list(self._trip_log)}
        print(FIGURES + json.dumps(f), flush=True)

    def _diagnose(self) -> None:
        f = self.figures(DIAGNOSTICS_WINDOW)
        level, msg = OK, 'running'
        if self.faults:
            level, msg = ERROR, f'{self.faults} model step failures'
        elif self.tripped:
            level, msg = WARN, 'watchdog tripped: valve current zero'
        elif not self.lockstep and not self._started:
            have, need = self.pub_state.get_subscription_count(), self.opt['wait_subscribers']
            level, msg = WARN, f'waiting for {need} subscribers on state ({have} now)'
        elif not self.armed and not self.lockstep:
            level, msg = WARN, 'waiting for the first command'
        self.pub_diag.publish(diagnostics(self, PLANT_STATUS, level, msg, f))


def main(args=None) -> int:
    """Entry point of ``ros2 run ros_ehs plant``."""
    return run(PlantNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
