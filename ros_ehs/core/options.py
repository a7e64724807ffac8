# Copyright 2026 ros_ehs contributors
#
# Licensed under the Apache License, Version 2.0 (the 'License');
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an 'AS IS' BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""
Every node's options and every ``ehs_sim`` option, declared once as :class:`Setting` s.

The model and controller parameters are :mod:`ros_ehs.core.params`; the reference's waveform
settings :data:`ros_ehs.core.control.waveforms.WAVEFORM`. :data:`NODE_OPTIONS` names each
node's table (what ``ros2 run ros_ehs <node>`` declares), :data:`CLI_OPTIONS` each
``ehs_sim`` command's; an option shared by several (``rate_hz``, ``diagnostics_period``,
``cpu_affinity``, ...) is one object in each table. The identify node and ``ehs_sim
identify`` take the same options.
"""

from __future__ import annotations

from ros_ehs.core.control.apc import MAX_HARMONICS
from ros_ehs.core.control.feedforward import MODEL_PARAMS
from ros_ehs.core.control.modes import SPECIMEN_IN_CONTROLLER
from ros_ehs.core.params import CONTROL_SPECS, ESTIMATED, PLANT_SPECS, SAFETY_SPECS, spec
from ros_ehs.core.procedure.envelope import RIG_NAMES
from ros_ehs.core.settings import Setting
from ros_ehs.core.sim.faults import FAULTS
import ros_ehs_msgs_py as contract

__all__ = ['CAMPAIGN', 'CLI_OPTIONS', 'CLI_POSITIONAL', 'COMPRESSIONS', 'CONTROLLER',
           'CONTROLLER_SPECS',
           'CPU_AFFINITY', 'DIAGNOSTICS_PERIOD', 'IDENTIFY', 'MODEL', 'NODE_OPTIONS', 'STATION',
           'NODE_PARAMS', 'PLANT', 'PLAYER', 'RATE_HZ', 'RECORDER', 'REF_RT_PRIORITY', 'REFERENCE',
           'RT_PRIORITY']

#: MCAP chunk compressions a recorder can write.
COMPRESSIONS = ('zstd', 'lz4', 'none')
_MODELS = ('full', 'reduced', 'simplified')

# -- shared by several nodes ----------------------------------------------------------------
RATE_HZ = Setting('rate_hz', 'Hz', 1000.0, 1.0, 5000.0, "the loop's period rate: the plant "
                  'steps, the controller answers and a lock-step reference samples at it; a '
                  'real-time reference publishes at it (the controller carries each sample '
                  "to its states' instants)")
DIAGNOSTICS_PERIOD = Setting('diagnostics_period', 's', 1.0, 0.05, 60.0,
                             'period of the diagnostics message')
CPU_AFFINITY = Setting('cpu_affinity', '', -2, -2, 1023, 'keep the threads of the node that '
                       "carry the loop on this CPU, the middleware's discovery and timed "
                       'events on the others; -1: anywhere; -2 (automatic): the plant and the '
                       "controller on the loop's CPU, every other node on another (the first "
                       'two CPUs the process may use, or ROS_EHS_LOOP_CPUS=LOOP,OTHER), '
                       'anywhere with one CPU')
#: the setpoint's source (reference, procedure): under the loop's priority, above the rest
REF_RT_PRIORITY = Setting('rt_priority', '', -1, -1, 99, 'real time: SCHED_FIFO priority of all '
                          'the threads of the node (1-99), so that a browser or a refit on '
                          "its CPU cannot starve the loop's setpoints (the controller carries "
                          'a silent reference on a straight line, which a curve leaves); 0: '
                          "the default scheduler; -1 (automatic): 40, under the loop's 50, in "
                          'real time when the process may, else the default scheduler and a '
                          'warning; none in lock-step')
RT_PRIORITY = Setting('rt_priority', '', -1, -1, 99, 'real time: SCHED_FIFO priority of all the '
                      'threads of the node (1-99), so that other work on the machine cannot '
                      'delay a period; 0: the default scheduler; -1 (automatic): 50 in real '
                      'time when the process may (CAP_SYS_NICE or ulimit -r), else the '
                      'default scheduler and a warning of what that risks; none in lock-step')
MODEL = Setting('model', '', 'simplified', meaning='model: full (10 states), reduced (6: the '
                "simplified with the full model's valve dynamics: for a real rig) or "
                'simplified (4 states, the paper)', choices=_MODELS)
_WAIT_SUBSCRIBERS = ('wait_subscribers', '', 0, 0, 1000)
# where the load cell comes from (the controller, the reference's force corrections)
LOAD_TOPIC = Setting('load_topic', '', '', meaning='the load cell from its own topic, a '
                     "geometry_msgs/WrenchStamped (ros2_control's force_torque_sensor_"
                     'broadcaster: <name>/wrench) read on load_axis; empty: from the state '
                     '(joint load_joint, its effort), as the plant sends it')
LOAD_AXIS = Setting('load_axis', '', 'force.z', meaning="load_topic: the wrench's component "
                    'that is the specimen force (tension positive)',
                    choices=contract.WRENCH_AXES)
LOAD_JOINT = Setting('load_joint', '', contract.JOINT_LOAD, meaning='the joint of the state '
                     'whose effort is the load cell (a rig driver may name its own)')

# -- nodes ------------------------------------------------------------------------------------
PLANT = (
    MODEL,
    Setting('mode', '', 'realtime', meaning='realtime: step on a timer; lockstep: one step per '
            'command, publish /clock', choices=('realtime', 'lockstep')),
    RATE_HZ,
    Setting('timing', '', 'timer', meaning='real time: an executor timer (one thread: no GIL '
            'handover; less CPU and a shorter round trip, measured) or a thread sleeping to '
            'each period', choices=('timer', 'thread')),
    Setting('watchdog_periods', '', 20, 1, 10000, 'a command is never applied over a period '
            'ending more than this many periods after it arrived: then the valve current is '
            "zero (a controller that died). 20 (20 ms at 1 kHz, the loop_timing detector's "
            'limit): a stall the detector accepts rides through on the last command, as a DAC '
            'holds it; closing the valve on a moving piston is a hydraulic shock '
            '(docs/nodes.md, Watchdog)', live=True),
    Setting('initial_z', 'm', 0.0, -2.0, 2.0, 'initial piston position'),
    Setting('start_time', 's', 0.0, 0.0, 1.0e9, 'lock-step: sim time of the first state'),
    Setting('duration', 's', 0.0, 0.0, 1.0e9, 'lock-step: stop advancing at this sim time after '
            'start (0: never)'),
    Setting('wait_subscribers', '', 1, 0, 100, 'start when `state` has this many subscribers '
            '(the controller; one more for a recorder, one more for a reference running APC '
            'or PVC): lock-step, the first step; real time, the first state (time restarts '
            'there), so a recorder has the loop from its first period and the middleware '
            'opens its ports to every subscriber before a watchdog guards the loop'),
    Setting('start_delay', 's', 0.5, 0.0, 60.0, 'lock-step: then wait this long, so every node '
            'has matched every other before the first step'),
    Setting('clock_period', 's', 0.01, 0.0, 10.0, 'lock-step: publish /clock every this much '
            "sim time (0: every period); keep it below the reference's preview"),
    Setting('resend_period', 's', 0.05, 1.0e-3, 10.0, 'lock-step: republish the state after '
            'this much silence'),
    Setting('real_time_factor', '', 0.0, 0.0, 1000.0, 'lock-step: advance at most this much '
            'sim time per wall second (1: as fast as the rig would, to watch a virtual test '
            'or spare the CPU while waiting on something else; 0: as fast as the loop runs)'),
    Setting('paused', '', False, meaning='lock-step: hold the loop still from the next state '
            'on, until false (a service called on a still loop acts at a known period); no '
            'process is stopped. Real time: refused', live=True),
    Setting('noise_z', 'm', 0.0, 0.0, 0.01, 'white noise (1 sigma) on the published position; '
            'the bench sets 5e-6'),
    Setting('noise_v', 'm/s', 0.0, 0.0, 1.0, 'white noise on the published velocity'),
    Setting('noise_p', 'Pa', 0.0, 0.0, 1.0e6, 'white noise on the published chamber '
            'pressures'),
    Setting('seed', '', 0, 0, 2**31 - 1, 'seed of the sensor noise'),
    Setting('fault', '', 'none', meaning='inject a fault from fault_time on (tests, '
            'demonstrations): frozen_sensor, nan_sensor, stuck_valve (the current at the start '
            'stays applied), lost_pressure (supply to 1 MPa), frozen_load_cell (the load cell '
            "repeats its reading of the fault's start), nan_load_cell, drifting_load_cell (its "
            'reading drifts 100 N/s from the truth)', choices=FAULTS,
            live=True),
    Setting('fault_time', 's', 0.0, 0.0, 1.0e9, 'sim time after the start at which `fault` '
            'begins', live=True),
    DIAGNOSTICS_PERIOD,
    Setting('figures_file', '', '', meaning='at exit, write the figures (loop timing, watchdog '
            'trips, late commands) there as JSON (empty: not written)'),
    RT_PRIORITY,
    CPU_AFFINITY,
)

CONTROLLER = (
    RATE_HZ,
    Setting('lockstep', '', False, meaning='lock-step bench: answer a state only with the '
            'reference of the same stamp; commands over reliable QoS'),
    Setting('reference_timeout', 's', 0.1, 1.0e-3, 100.0, 'a reference older than this is held '
            'at zero velocity; when references come back the axis ramps onto them over '
            'ramp_time', live=True),
    DIAGNOSTICS_PERIOD,
    Setting('future_tolerance', 's', 0.05, 1.0e-4, 3600.0, 'real time: a state stamped further '
            "ahead of this node's clock is dropped and counted", live=True),
    Setting('start_enabled', '', True, meaning='hydraulics on at start (ramp-on from the first '
            'measured position); false: 0 A until ~/enable'),
    Setting('state_topic', '', contract.STATE.name, meaning='sensor_msgs/JointState with the '
            "axis's joint: the contract's `state`, or a rig driver's /joint_states"),
    Setting('joint', '', contract.JOINT_PISTON, meaning="the axis's joint in the state (a rig's "
            'own name; position required, velocity optional)'),
    Setting('command_interface', '', 'joint_state', meaning="joint_state: the contract's "
            'servo_current (JointState, stamped with the state it answers); forward_command: '
            "a ros2_control forward command controller's Float64MultiArray (no header)",
            choices=('joint_state', 'forward_command')),
    Setting('command_topic', '', '', meaning='where commands go (default: servo_current, or '
            'servo_valve_controller/commands for forward_command)'),
    Setting('command_index', '', 0, 0, 255, "forward_command: this axis's element of the "
            'array'),
    Setting('command_size', '', 1, 1, 256, 'forward_command: length of the array (the '
            "controller's joints; the others get 0 A)"),
    Setting('command_scale', '', 1.0, 1.0e-6, 1.0e6, 'forward_command: units per A the driver '
            'takes (1000: mA)'),
    LOAD_TOPIC,
    LOAD_AXIS,
    LOAD_JOINT,
    RT_PRIORITY,
    CPU_AFFINITY,
)

REFERENCE = (
    RATE_HZ,
    Setting('control_mode', '', 'displacement', meaning='what the waveform commands: a position '
            '[m] (displacement, and specimen protect) or a force [N] (force control: '
            "amplitude, offset and blocks in N, sent as the reference's effort; APC and PVC "
            'correct it from the load cell)', choices=('displacement', 'force')),
    Setting('preview', 's', 0.02, 0.0, 1.0, 'use_sim_time: each /clock t is answered with the '
            "samples up to t + preview; must exceed the plant's clock_period"),
    Setting('duration', 's', 0.0, 0.0, 1.0e9, 'hold the last position after this time (0: '
            'never)'),
    Setting('csv_path', '', '', meaning='trajectory file for kind = csv (columns t [s], z [m])'),
    DIAGNOSTICS_PERIOD,
    Setting('wait_loop', '', False, meaning='real time: start the trajectory (time zero) only '
            "once the plant's diagnostics report its loop closed (status ros_ehs/plant at "
            'level OK)'),
    Setting(*_WAIT_SUBSCRIBERS, 'real time: start the trajectory (time zero) only once '
            '`reference` has this many subscribers; publish nothing until then'),
    Setting('blocks', '', '', meaning='kind triangle or haversine: a block-loading sequence, '
            '`peak valley cycles` per block [m, m, -] (N, N, - in force control), blocks apart '
            "by ';' (empty: offset -+ amplitude)"),
    Setting('amplitude_phase_control', '', False, meaning='kind sine or chirp: correct the '
            "command's amplitude, phase and mean each cycle from the measured position (APC); "
            'frozen while a safety trip acts or states are lost'),
    Setting('peak_valley_control', '', False, meaning='kind triangle or haversine: correct '
            "each block's command each cycle so that its peaks and valleys reach their "
            'targets (PVC); frozen as APC is'),
    Setting('ramp_time', 's', 1.0, 0.0, 60.0, "APC, PVC: the controller's ramp_time: no cycle "
            'that overlaps a ramp-on (the first one, and the one after a reset) is learnt '
            'from'),
    Setting('apc_harmonics', '', 5, 1, MAX_HARMONICS, 'APC of a sine: the harmonics corrected, '
            'the fundamental included (1: amplitude and phase only; 2 and up also cancel the '
            'distortion at 2 f, 3 f, ...); a chirp corrects the fundamental only'),
    LOAD_TOPIC,
    LOAD_AXIS,
    LOAD_JOINT,
    REF_RT_PRIORITY,
    CPU_AFFINITY,
)

RECORDER = (
    Setting('out', '', '', meaning='bag directory to create (default bags/ehs_<UTC time>)'),
    Setting('topics', '', [], meaning='topics to record (default: every contract topic)'),
    Setting('flush_period', 's', 0.05, 0.005, 10.0, 'close the open chunk and flush at least '
            'this often: the most a crash can lose'),
    Setting('fsync', '', False, meaning='also fsync on every flush (survives power loss)'),
    Setting('depth', '', 10000, 1, 100000, 'subscription queue depth: what a stalled recorder '
            "can catch up on (as the lock-step writers' LOCKSTEP_QOS keeps)"),
    Setting('discovery_period', 's', 0.2, 0.05, 60.0, 'how often to look for listed topics not '
            'yet seen'),
    Setting('max_bag_size', 'bytes', 0, 0, 2**62, 'split to a new file once the open one holds '
            'this many bytes (0: no split by size)'),
    Setting('max_bag_duration', 's', 600.0, 0.0, 1.0e9, 'split to a new file once the open one '
            'spans this long (0: no split by duration)'),
    Setting('compression', '', 'zstd', meaning='MCAP chunk compression', choices=COMPRESSIONS),
    Setting('min_free_space', 'bytes', 100_000_000, 0, 2**62, 'refuse to start, and stop '
            'recording cleanly, with less free space than this on the filesystem of the bag'),
    Setting('warn_free_space', 'bytes', 1_000_000_000, 0, 2**62, 'warn (once a minute) with '
            'less free space than this'),
    DIAGNOSTICS_PERIOD,
)

_START = Setting('start', 's', 0.0, 0.0, 1.0e9, "from this time on [s from each bag's first "
                 'message]')
_END = Setting('end', 's', 0.0, 0.0, 1.0e9, 'up to this time (0: to the end) [s from each '
               "bag's first message]")
_TOPIC_MAP = Setting('topic_map', '', '', meaning="a rig's topic map (YAML: "
                     'docs/identification.md); the topic options override its entries',
                     flags=('--topics',))

PLAYER = (
    Setting('bag', '', '', meaning='bag directory or .mcap file to replay'),
    Setting('rate', '', 1.0, 0.01, 1000.0, 'playback speed factor'),
    Setting('topics', '', [], meaning='topics to replay (default: all)'),
    Setting('loop', '', False, meaning='start over at the end'),
    Setting('clock', '', True, meaning='publish /clock with the bag time'),
    Setting('clock_hz', 'Hz', 100.0, 1.0, 10000.0, '/clock rate in bag time, besides one before '
            'each message'),
    Setting(*_WAIT_SUBSCRIBERS, 'before the first message, wait until every replayed topic has '
            'this many subscribers'),
    Setting('start_delay', 's', 0.5, 0.0, 60.0, 'then wait this long, so the subscribers have '
            'matched too'),
    _START,
    _END,
    Setting('topic_map', '', '', meaning="a rig's topic map (YAML): replay its signals as the "
            "contract's topics (see the node's docstring)"),
)

#: the identify node's options, and ``ehs_sim identify``'s
IDENTIFY = (
    Setting('bags', '', [], meaning='bags to fit jointly (directories, split or not, or '
            '.mcap/.db3 files)'),
    Setting('holdout', '', [], meaning='bags scored with the fitted values, not fitted'),
    Setting('out', '', 'out/identification', meaning='report folder'),
    Setting('free', '', list(ESTIMATED), meaning='parameters to fit (default the seven of '
            'Table 1)'),
    MODEL,
    Setting('cost', '', 'sae', meaning='sae (the paper) or sse', choices=('sae', 'sse')),
    Setting('initial', '', '', meaning='parameters YAML to start from (default Table 1 initial '
            'values)'),
    _TOPIC_MAP,
    Setting('state_topic', '', '', meaning="sensor_msgs/JointState (default: the map's, or "
            'state)'),
    Setting('joint', '', '', meaning="the axis's joint in the state (default: the map's, or "
            'piston)'),
    Setting('command_topic', '', '', meaning='JointState, Float64 or Float64MultiArray (default: '
            "the map's, or servo_current)"),
    Setting('command_index', '', -1, -1, 255, "Float64MultiArray commands: this axis's element "
            "(-1: the map's, or 0)"),
    Setting('pressure_p_topic', '', '', meaning="chamber P pressure topic (default: the map's, "
            'or pressure/chamber_p)', flags=('--pressure-p',)),
    Setting('pressure_t_topic', '', '', meaning="chamber T pressure topic (default: the map's, "
            'or pressure/chamber_t)', flags=('--pressure-t',)),
    Setting('use_pressures', '', True, meaning='fit the chamber pressures when the bags have '
            'them', flags=('--no-pressures',)),
    Setting('load_topic', '', '', meaning="the load cell, a WrenchStamped (default: the map's, "
            'or load_cell: fitted when it reads a load, which makes k_L identifiable)'),
    Setting('input_delay', 's', -1.0, -1.0, 0.5, 'from a command to the valve acting on it; '
            '-1 (auto): the map says, or estimated where the bags record commands',
            words=(('auto', -1.0),)),
    Setting('max_nfev', '', 100, 1, 100000, 'most model evaluations'),
    Setting('starts', '', 0, 0, 1000, 'also refit from this many seeded random starts and '
            'report how many reach the same optimum'),
    Setting('seed', '', 0, 0, 2**31 - 1, 'seed of the random starts'),
    Setting('advise', '', True, meaning='name the parameters the bags do not pin down and the '
            'reference trajectory that would', flags=('--no-advice',)),
    _START,
    _END,
    Setting('workers', '', 0, 0, 64, 'threads for the Jacobian columns (0: 2 on a machine with '
            '2 or more CPUs)'),
    Setting('figures', '', True, meaning='write the PNG figures'),
    Setting('push', '', False, meaning='set the fitted values on the running controller'),
    Setting('controller', '', 'controller', meaning='name of the controller node to push to'),
    Setting('push_timeout', 's', 10.0, 0.1, 600.0, 'wait this long for the controller'),
    Setting('live', '', False, meaning='refit the running loop continuously instead of bags'),
    Setting('window', 's', 10.0, 1.0, 600.0, 'live: the last seconds refitted'),
    Setting('period', 's', 5.0, 0.5, 3600.0, 'live: a refit every this many seconds of the '
            'state clock'),
    Setting('push_period', 's', 30.0, 0.0, 1.0e6, 'live: at most one push per this many '
            'seconds'),
    Setting('sigmas', '', 3.0, 0.0, 100.0, 'live: push only a change beyond this many standard '
            'errors'),
    Setting('rel_change', '', 0.02, 0.0, 10.0, 'live: and beyond this fraction of the '
            "controller's value"),
    Setting('max_rate', 'Hz', 4000.0, 10.0, 100000.0, 'live: the fastest state rate to buffer '
            'for'),
    Setting('refit_priority', '', 'idle', meaning='live: the refit thread runs at SCHED_IDLE '
            "(idle: only CPU time nobody else wants, the rig's setting), nice 19 (nice: a "
            'small share on a busy machine), or as the node (normal)',
            choices=('idle', 'nice', 'normal')),
    DIAGNOSTICS_PERIOD,
    CPU_AFFINITY,
)

#: the procedure node's options
PROCEDURE = (
    Setting('file', '', '', meaning='the procedure file (YAML, docs/procedures.md); set while '
            'the test is idle or finished, the next test (checked whole first: a bad file is '
            'refused, the old one stays)', live=True),
    Setting('checkpoint', '', '', meaning="the test's checkpoint (JSON, rewritten atomically at "
            'every state change and every 10 s of the stamps; default: the file with '
            '`.checkpoint.json`); found at start (or with a new `file`), the test is '
            'restored, interrupted, for ~/resume', live=True),
    Setting('recover_bag', '', '', meaning='a restart: the bag being recorded (its '
            '`procedure/cycles`); cycles it holds beyond the checkpoint are counted'),
    Setting('autostart', '', False, meaning='start the test at the first state (else ~/start)'),
    RATE_HZ,
    Setting('preview', 's', 0.02, 0.0, 1.0, 'use_sim_time: each /clock t is answered with the '
            "samples up to t + preview (the reference node's); a decision taken on a state "
            'acts this long after its stamp (real time too): no sample sent changes'),
    Setting('controller', '', 'controller', meaning='the controller node: a step in the other '
            'control mode sets its `control_mode`'),
    Setting('apc_harmonics', '', 5, 1, MAX_HARMONICS, 'cyclic sine steps with APC: the '
            'harmonics corrected (the fundamental included)'),
    Setting('rig_params', '', '', meaning="the rig's parameters (a ROS 2 parameters file: "
            '`ehs_sim identify` writes one): a procedure the rig cannot follow is refused when '
            'it loads, each step named with the limit it breaks (empty: checked at start '
            'against the values the controller holds, nominal or identified; the '
            "compensation's bound still stops a test whose levels are not reached)"),
    Setting('ramp_time', 's', 1.0, 0.0, 600.0, "the controller's ramp_time: a waveform step "
            'waits for its ramp-on, and the compensation does not learn from cycles it '
            "attenuates (from this node's first state, each reset and each hydraulics on; a "
            'restarted procedure node waits once more)'),
    LOAD_TOPIC,
    LOAD_AXIS,
    LOAD_JOINT,
    DIAGNOSTICS_PERIOD,
    REF_RT_PRIORITY,
    CPU_AFFINITY,
)

#: the operator's station's options (docs/station.md)
STATION = (
    Setting('host', '', '127.0.0.1', meaning='the address the page is served on: 127.0.0.1 '
            'this machine only; another interface (0.0.0.0: all) shows the page read-only to '
            'other machines unless they give the token'),
    Setting('port', '', 8080, 0, 65535, 'the TCP port of the page (0: a free one, said in the '
            'status as `url`)'),
    Setting('token', '', '', meaning='the token a page from another machine must give to act '
            '(at least 8 characters; empty: other machines only watch)'),
    Setting('controller', '', 'controller', meaning='the controller node: its `~/reset`, '
            '`~/enable`, status and events'),
    Setting('procedure', '', 'procedure', meaning='the procedure node: its `~/start`, '
            '`~/hold`, `~/resume`, `~/stop` and status'),
    Setting('campaign', '', 'campaign', meaning='the campaign node: its status and results '
            "(the page's campaign panel) and its `~/next` (the page's next specimen)"),
    Setting('push_rate', 'Hz', 25.0, 1.0, 60.0, 'frames a second sent to each open page'),
    Setting('scope_samples', '', 131072, 1000, 2000000, "the scope's memory: the newest "
            'states kept at full rate (131072: 2 min at 1 kHz)'),
    Setting('scope_buckets', '', 400, 50, 4000, "the slots of a frame's scope trace (min and "
            'max of each): what a page receives, whatever the time base and the loop rate'),
    Setting('lost_after', 's', 3.0, 0.5, 60.0, 'no controller status for this long: the page '
            'says the ROS graph is lost'),
    LOAD_JOINT,
    DIAGNOSTICS_PERIOD,
    CPU_AFFINITY,
)

#: the campaign node's options (docs/campaigns.md)
CAMPAIGN = (
    Setting('campaign', '', '', meaning='the campaign file (YAML, docs/campaigns.md)'),
    Setting('store', '', '', meaning='the results store: a SQLite file, or a database URL '
            '(postgresql+psycopg://user@host/db); empty: campaign.db in `out`. A campaign '
            'already in it goes on from its records'),
    Setting('out', '', 'campaign', meaning="the campaign's folder: each specimen's procedure, "
            'checkpoint and cycle records, and the specimen under way (current.json)'),
    Setting('procedure', '', 'procedure', meaning='the procedure node the specimens are '
            'loaded into (its `file` and `checkpoint` are set)'),
    Setting('controller', '', 'controller', meaning='the controller node ~/next switches to '
            'specimen protect (`protect`)'),
    Setting('protect', '', True, meaning='~/next switches the controller to specimen protect '
            '(control_mode displacement_force_limited: the load held within protect_force) '
            'while the operator installs the coupon; the procedure switches it to its first '
            "step's mode at its start"),
    Setting('specimen', '', '', meaning="the next specimen's id (on the coupon), taken by "
            "~/next; empty: the plan's (S01, S02...)", live=True),
    DIAGNOSTICS_PERIOD,
    CPU_AFFINITY,
)

#: each node's options: what ``ros2 run ros_ehs <node>`` declares (besides its parameters)
NODE_OPTIONS = {'plant': PLANT, 'controller': CONTROLLER, 'reference': REFERENCE,
                'recorder': RECORDER, 'player': PLAYER, 'identify': IDENTIFY,
                'procedure': PROCEDURE, 'station': STATION, 'campaign': CAMPAIGN}

#: the parameters the controller declares: its own, the safety layer's, the plant values its
#: feedforward uses and the rest of the rig's envelope (a procedure node reads them from it)
CONTROLLER_SPECS = CONTROL_SPECS + SAFETY_SPECS + tuple(spec(n) for n in MODEL_PARAMS) + \
    tuple(spec(n) for n in SPECIMEN_IN_CONTROLLER)
CONTROLLER_SPECS += tuple(spec(n) for n in RIG_NAMES
                          if n not in {s.name for s in CONTROLLER_SPECS})
#: each node's parameters (model, controller, safety), declared with its options
NODE_PARAMS = {'plant': PLANT_SPECS, 'controller': CONTROLLER_SPECS}

# -- ehs_sim ----------------------------------------------------------------------------------
#: what only the identify node does: push to a running controller, refit live, placement
_NODE_ONLY = ('push', 'controller', 'push_timeout', 'live', 'window', 'period', 'push_period',
              'sigmas', 'rel_change', 'max_rate', 'refit_priority', 'diagnostics_period',
              'cpu_affinity')
_OUT = ('out', '')
_PRESET = ('preset', '', 'table1_estimated')
#: the rig a campaign's virtual coupons are tested on (ehs_sim campaign, campaign-rehearse)
_COUPONS_RIG = (
    Setting(*_PRESET, meaning='the rig model: a parameter preset, under `params`'),
    Setting('params', '', '', meaning='parameters YAML over the preset: the rig identified, '
            "its gains, and the coupons' specimen model (specimen_*)"),
    Setting('set', '', [], meaning='values over those, NAME=VALUE each, e.g. k_L=1e7 '
            'specimen_scatter=0.15; repeat for more'))
_DURATION = Setting('duration', 's', 3.0, 1.0e-3, 1.0e6, 'simulated time')
_AMPLITUDE = Setting('amplitude', 'm', 0.04, -2.0, 2.0, 'sine amplitude')
_FREQUENCY = Setting('frequency', 'Hz', 1.0, 1.0e-3, 500.0, 'sine frequency')
_FULL_MODEL = Setting('model', '', 'full', meaning='plant model', choices=_MODELS)
_SIMPLE_MODEL = Setting('model', '', 'simplified', meaning='plant model', choices=_MODELS)

#: each ``ehs_sim`` command's options (positional: :data:`CLI_POSITIONAL`)
CLI_OPTIONS = {
    'main': (_FULL_MODEL, Setting(*_PRESET, meaning='parameter preset of plant and controller'),
             _DURATION, _AMPLITUDE, _FREQUENCY),
    'figures': (Setting(*_OUT, 'out/figures', meaning='folder of the PNG figures'),
                _SIMPLE_MODEL, _DURATION),
    'params-doc': (Setting(*_OUT, 'docs/parameters.md', meaning='the file to write'),),
    'record': (Setting(*_OUT, '', meaning='bag directory to create (required)'),
               Setting('plant', '', 'table1_estimated', meaning='plant parameter preset'),
               Setting('controller', '', 'table1_initial', meaning='controller preset'),
               _SIMPLE_MODEL,
               Setting('duration', 's', 10.0, 1.0e-3, 1.0e6, 'simulated time'),
               _AMPLITUDE, _FREQUENCY,
               Setting('seed', '', 0, 0, 2**31 - 1, 'seed of the sensor noise'),
               Setting('noise', '', True, meaning='add the bench sensor noise')),
    'drive': (Setting('target', '', '', meaning='target CSV (header t,z; seconds, metres)'),
              Setting(*_OUT, 'out/drive', meaning='folder for the bags and drive files'),
              Setting('frf_bag', '', '', meaning='a recorded broadband run (reference and '
                      'state) to take the FRF from (default: play and record one)'),
              Setting('band', 'Hz', [], meaning='the FRF run: its band, F_LO F_HI, or auto (the '
                      "band the target's spectrum needs: outside it under a tenth of --rms); "
                      'default 0.2-40 Hz'),
              Setting('iterations', '', 6, 1, 1000, 'most iterations'),
              Setting('rms', '%', 1.0, 1.0e-3, 100.0, 'stop at this RMS error'),
              Setting('plant', '', 'table1_estimated', meaning='the rig: a parameter preset'),
              Setting('controller', '', 'table1_estimated', meaning='controller preset'),
              Setting('set', '', [], meaning='controller values over its preset, NAME=VALUE '
                      'each, e.g. dp_gain=1.5e-7 (delta-P stabilisation); repeat for more'),
              _FULL_MODEL,
              Setting('bench', '', 'none', meaning="play each run on the bench's nodes over "
                      'DDS (none: in process)', choices=('none', 'lockstep', 'realtime')),
              RT_PRIORITY,
              Setting('max_trips', '', 2, 0, 1000, '--bench: a run whose plant watchdog zeroed '
                      'the valve more often is played again (twice at most)'),
              Setting('domain_id', '', -1, -1, 232, 'ROS_DOMAIN_ID of the bench runs (-1: the '
                      "environment's)")),
    'identify': tuple(s for s in IDENTIFY if s.name not in _NODE_ONLY) + (
        Setting('quiet', '', False, meaning='do not print each iteration'),),
    'tune': (Setting(*_PRESET, meaning='the model: a parameter preset, under `params`'),
             Setting('params', '', '', meaning='parameters YAML over the preset: an identified '
                     'model (ehs_sim identify writes one), with the specimen (k_L) fitted'),
             Setting('set', '', [], meaning='values over those, NAME=VALUE each, e.g. '
                     'k_L=5e7; repeat for more'),
             Setting('loop', '', 'both', meaning='the loop to tune',
                     choices=('displacement', 'force', 'both')),
             Setting('bandwidth', 'Hz', 10.0, 0.01, 250.0, "the closed loop's -3 dB bandwidth "
                     'asked for (the margins may lower it: said so)'),
             Setting('phase_margin', 'deg', 45.0, 1.0, 90.0, 'the least phase margin'),
             Setting('gain_margin', 'dB', 10.0, 1.0, 40.0, 'the least gain margin'),
             Setting('step', 'm or N', 0.0, 0.0, 1.0e7, "the square wave's peak to peak: the "
                     'valve is linearised over the opening it commands (0: 2 mm or 4 kN)'),
             Setting('model', '', 'reduced', meaning='the model the gains are computed from',
                     choices=_MODELS),
             Setting('check', '', True, meaning='check the prediction with a square wave on '
                     'the full model in process, as a rig engineer tunes with one'),
             Setting(*_OUT, '', meaning='write the gains as a ROS 2 parameters file for the '
                     'controller (empty: not written)')),
    'procedure': (Setting('file', '', '', meaning='the procedure file (YAML, docs/procedures.md)'),
                  Setting(*_PRESET, meaning='the model: a parameter preset, under `params`'),
                  Setting('params', '', '', meaning='parameters YAML over the preset: an '
                          'identified model with its specimen, and the gains'),
                  Setting('set', '', [], meaning='values over those, NAME=VALUE each, e.g. '
                          'k_L=1e7 specimen_life=2e5; repeat for more'),
                  Setting('model', '', 'simplified', meaning='the plant model',
                          choices=_MODELS),
                  RATE_HZ,
                  Setting('max_time', 's', 1.0e6, 1.0e-3, 1.0e9, 'simulated time at most'),
                  Setting('observe', '', True, meaning='the failure detectors report when they '
                          'would trip and the test goes on (to the fracture, the run-out or its '
                          'end); --no-observe: the first to trip ends it, as on the rig'),
                  Setting('exact', '', False, meaning='simulate every period of every cycle '
                          '(default: a settled constant-amplitude step jumps the cycles that '
                          'repeat, the specimen carrying them by its own law; '
                          'docs/procedures.md)'),
                  Setting(*_OUT, '', meaning='write the cycle table (the last 10^5 cycles) as '
                          'CSV here (empty: not written)')),
    'fatigue-report': (Setting('bags', '', [], meaning="the test's bags, in order (a "
                               'restarted test spans several)'),
                       Setting(*_OUT, 'out/fatigue', meaning='the report folder: cycles.csv, '
                               'captures.csv, events.csv and the plots')),
    'campaign': (Setting('file', '', '', meaning='the campaign file (YAML, docs/campaigns.md)'),
                 Setting('store', '', 'campaign.db', meaning='the results store: a SQLite file, '
                         'or a database URL (postgresql+psycopg://user@host/db); a campaign '
                         'already in it goes on from its records'),
                 *_COUPONS_RIG,
                 Setting('seed', '1', 1, 0, 2**31 - 1, "the virtual coupons' seed (each "
                         "coupon's specimen_seed is drawn from it and its place)"),
                 Setting('model', '', 'simplified', meaning='the plant model', choices=_MODELS),
                 RATE_HZ,
                 Setting('max_specimens', '1', 0, 0, 10**6, 'test at most this many specimens '
                         'in this run (0: until the campaign ends)'),
                 Setting('exact', '', False, meaning="simulate every period of every coupon's "
                         'cycles (default: the settled cycles are jumped)')),
    'campaign-rehearse': (
        Setting('file', '', '', meaning='the campaign file (YAML, docs/campaigns.md)'),
        Setting('replicates', '1', 200, 1, 10**6, 'campaigns drawn afresh per plan'),
        *_COUPONS_RIG,
        Setting('seed', '1', 1, 0, 2**31 - 1, 'the rehearsal seed (each replicate draws its '
                'coupons from it and its number)'),
        Setting('lives', '', 'virtual', meaning="each coupon's end: virtual (a jumped virtual "
                'test of its procedure) or law (its specimen model in closed form)',
                choices=('virtual', 'law')),
        Setting('plans', '', 'all', meaning="the campaign's plan only (given), or it and the "
                'other plans at its specimen count (all)', choices=('given', 'all')),
        Setting('scheduler', '', '', meaning="a Dask scheduler's address (tcp://host:8786; "
                'empty: a local cluster)'),
        Setting('workers', '1', 0, 0, 1024, "the local cluster's worker processes (0: one "
                'per CPU)'),
        Setting('in_process', '', False, meaning='run every replicate in this process, '
                'without the engine'),
        Setting(*_OUT, '', meaning="write each plan's summary and replicates as JSON here "
                '(empty: not written)')),
    'campaign-report': (Setting('store', '', 'campaign.db', meaning='the results store (a '
                                'SQLite file or a database URL)'),
                        Setting('campaign', '', '', meaning="the campaign's name (empty: the "
                                "store's only one)"),
                        Setting('confidence', '1', 0.9, 0.5, 0.999, "the fit's intervals"),
                        Setting(*_OUT, 'out/campaign', meaning='the report folder: '
                                'specimens.csv, specimens_pylife.csv, fit.json, sn.png, '
                                'report.html')),
    'trend': (Setting('bag', '', '', meaning='the bag (directory, .mcap or .db3)'),
              Setting(*_OUT, '', meaning='PNG of each parameter against time, with its band'),
              Setting('sigmas', '', 3.0, 0.0, 100.0, 'band width in standard errors')),
}

#: the options of each ``ehs_sim`` command given without a flag, in order
CLI_POSITIONAL = {'drive': ('target',), 'identify': ('bags',), 'trend': ('bag',),
                  'procedure': ('file',), 'fatigue-report': ('bags',), 'campaign': ('file',),
                  'campaign-report': ('store',), 'campaign-rehearse': ('file',)}
