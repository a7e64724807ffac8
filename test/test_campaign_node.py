"""
The campaign node on the lock-step bench: the operator's next specimen, recorded once.

Its rules are tested in ``test_campaign_rig.py``; here the node's part over DDS, against the
procedure node it loads (plant, controller, procedure node, recorder: the bench a rig's
nodes make): ``~/next`` loads the specimen, the operator starts it at the procedure node, the
campaign node killed during the test and started again records it once in the store and on
``campaign/results``, and the next specimen, on a new coupon, runs and is recorded too;
``~/next`` puts the controller in specimen protect for each coupon's installation. Every
wait is on a status, a reply or the store.
"""

from pathlib import Path
import time

import pytest
from ros_ehs.benchmarks.campaign import BENCH_CAMPAIGN, BENCH_RIG
from ros_ehs.core.options import CONTROLLER_SPECS
from ros_ehs.core.params import ALL_SPECS, PLANT_SPECS, preset
from ros_ehs.core.settings import parse_assignment
from ros_ehs.data.store import ResultStore
from ros_ehs.nodes.processes import NodeProcesses
import ros_ehs_msgs_py as c
from waits import BOUND, call_service, set_parameter

import yaml

pytestmark = pytest.mark.ros
FIXTURE = Path(__file__).parent / 'fixtures' / 'procedure_short.yaml'
FAST = {'diagnostics_period': 0.1}


def _trigger(ros, name):
    from std_srvs.srv import Trigger
    return call_service(ros, Trigger, name, Trigger.Request())


def _set(ros, node, **values):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    req = SetParameters.Request(parameters=[Parameter(name=k, value=ParameterValue(
        type=ParameterType.PARAMETER_STRING, string_value=str(v))) for k, v in values.items()])
    return call_service(ros, SetParameters, f'/{node}/set_parameters', req).results[0]


def _status(procs, name, pred):
    """Wait for status ``name`` to meet ``pred`` (a node that exits ends the wait)."""
    running = [p for p in procs.procs.values() if p.alive()]

    def met(st):
        return pred(st.values) or any(not p.alive() for p in running)
    ok = procs.wait_status(name, met, BOUND * 2)
    st = procs.status(name)
    assert ok and pred(st.values), (st, {n: p.output()[-1500:] for n, p in procs.procs.items()})
    return st.values


def test_the_operators_specimens_are_loaded_run_and_recorded_once_through_a_restart(
        dom, tmp_path, ros):
    rig = preset('fatigue_actuator').replace(**dict(parse_assignment(v, ALL_SPECS)
                                                    for v in BENCH_RIG))
    plan = tmp_path / 'campaign.yaml'
    plan.write_text(yaml.safe_dump(BENCH_CAMPAIGN))
    out, bag = tmp_path / 'out', tmp_path / 'bag'
    camp = {'campaign': str(plan), 'out': str(out), **FAST}
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start_loop(
            'lockstep', bag=bag,
            procedure={**FAST, 'file': str(FIXTURE), 'checkpoint': str(tmp_path / 'cp.json')},
            controller={**FAST, **{s.name: rig[s.name] for s in CONTROLLER_SPECS}},
            plant={'duration': 1.0e7, **FAST, **{s.name: rig[s.name] for s in PLANT_SPECS}})
        procs.start('campaign', camp)
        _status(procs, c.CAMPAIGN_STATUS, lambda v: v['state'] == 'ready')
        # the coupon's own id; a second ~/next while it is under way is refused
        assert _set(ros, 'campaign', specimen='C-0117').successful
        r = _trigger(ros, '/campaign/next')
        assert r.success and r.message.startswith('C-0117 at 9000'), r.message
        r = _trigger(ros, '/campaign/next')
        assert not r.success and 'C-0117 is under way' in r.message
        # specimen protect while the coupon is installed; the procedure's start leaves it
        _status(procs, c.CAMPAIGN_STATUS, lambda v: v['protect'] == 'on')
        _status(procs, c.CONTROLLER_STATUS,
                lambda v: v['control_mode'] == 'displacement_force_limited')
        first = str(out / 'C-0117' / 'procedure.yaml')
        _status(procs, c.PROCEDURE_STATUS, lambda v: v['file'] == first and
                v['state'] == 'idle' and v['controller_mode'])
        assert _trigger(ros, '/procedure/start').success
        _status(procs, c.CONTROLLER_STATUS, lambda v: v['control_mode'] == 'force')
        # the campaign node killed while the test runs, and started again: it waits for the
        # same test's end and records it once
        # (held meanwhile, so that it is still under way when the new node comes)
        _status(procs, c.PROCEDURE_STATUS, lambda v: int(v['total_cycles']) >= 20)
        assert _trigger(ros, '/procedure/hold').success
        procs.kill('campaign')
        t0 = time.time_ns()
        procs.start('campaign', camp, name='campaign2')
        assert procs.wait_status(c.CAMPAIGN_STATUS, lambda st: st.stamp_ns > t0 and
                                 st.values['specimen'] == 'C-0117', BOUND)
        assert _trigger(ros, '/procedure/resume').success
        st = _status(procs, c.CAMPAIGN_STATUS, lambda v: v['tested'] == '1')
        assert st['state'] == 'ready' and st['next_level'] == '9000'
        # the plan's id next, loaded into the procedure node; the operator installs a new
        # coupon (the plant's specimen: a change of its seed installs one) and starts it
        assert _set(ros, 'campaign', specimen='').successful
        r = _trigger(ros, '/campaign/next')
        assert r.success and r.message.startswith('S02 at 9000'), r.message
        second = str(out / 'S02' / 'procedure.yaml')
        _status(procs, c.PROCEDURE_STATUS, lambda v: v['file'] == second and
                v['state'] == 'idle')
        st = _status(procs, c.CAMPAIGN_STATUS, lambda v: v['state'] == 'under_way')
        assert st['specimen'] == 'S02'
        _status(procs, c.CONTROLLER_STATUS,
                lambda v: v['control_mode'] == 'displacement_force_limited')
        assert set_parameter(ros, '/plant', 'specimen_seed', 2.0).successful
        assert _trigger(ros, '/procedure/start').success
        # the campaign node killed, and its coupon's test ends while it is down: started
        # again it records that test (loaded again, the procedure node would put it aside)
        _status(procs, c.PROCEDURE_STATUS, lambda v: int(v['total_cycles']) >= 5)
        procs.kill('campaign2')
        _status(procs, c.PROCEDURE_STATUS, lambda v: v['state'] == 'finished')
        procs.start('campaign', camp, name='campaign3')
        st = _status(procs, c.CAMPAIGN_STATUS, lambda v: v['tested'] == '2')
        assert st['state'] == 'ready' and st['next_level'] == '7000', st
        assert int(st['failed']) + int(st['run_out']) == 2 and st['run_out_cycles'] == '250'
        procs.stop(['campaign3', 'procedure', 'plant', 'controller', 'recorder'])
    store = ResultStore(out / 'campaign.db')
    try:
        recs = store.results(store.campaign(BENCH_CAMPAIGN['name']))
    finally:
        store.close()
    assert [r.specimen for r in recs] == ['C-0117', 'S02']
    assert recs[1].result in ('failed', 'run_out') and recs[1].cycles > 20, recs[1]
    r = recs[0]
    assert r.result in ('failed', 'run_out') and r.cycles > 20, r
    assert abs(r.peak - 9000.0) < 0.02 * 8100.0, r
    # the records published while the campaign node was down came again (the topic keeps
    # them for a subscriber that comes late; the test's end waited for them)
    assert r.note.endswith(f'from {r.cycles} of {r.cycles} cycle records'), r.note
    # the results on the contract topic, read from the recorder's bag by rosbags
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    names = []
    with Reader(bag) as rd:
        conns = [x for x in rd.connections if x.topic == '/' + c.CAMPAIGN_RESULTS.name]
        for conn, _, raw in rd.messages(conns):
            m = ts.deserialize_cdr(raw, conn.msgtype)
            names += [s.name for s in m.status]
    # C-0117 as recorded, again as the third node republished the store at its start, S02
    assert names == ['ros_ehs/campaign/C-0117'] * 2 + ['ros_ehs/campaign/S02']
