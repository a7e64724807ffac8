"""
The operator's station without ROS: scope, meters, access, board, and the web server's rules.

Every rule of ``ros_ehs.core.station`` and of ``ros_ehs.web.app`` in process, the clock passed
in; the web server is the real aiohttp application on a real socket, driven by aiohttp's
client (a client we did not write), with a recording desk in place of the ROS node.
"""

import asyncio
import base64
import json
import math
import socket
import time

import aiohttp
from foreign import diagnostic_array
import numpy as np
import pytest
from ros_ehs.core.station.access import Access
from ros_ehs.core.station.board import Board
from ros_ehs.core.station.campaign import CampaignPanel, Z90
from ros_ehs.core.station.meters import Meter
from ros_ehs.core.station.scope import Scope, TIME_BASES
from ros_ehs.core.station.station import Station
from ros_ehs.web.app import make_app, Pacer, StationServer
import ros_ehs_msgs_py as c
from ros_ehs_msgs_py.values import AxisState, NodeStatus, ParameterEstimate, Reference
from waits import BOUND


# -- scope -------------------------------------------------------------------------------------
def test_the_scope_envelope_keeps_a_peak_shorter_than_a_slot():
    s = Scope(10_000, ('position',))
    for k in range(5000):                         # 5 s at 1 kHz, a 1 ms spike at 2.5005 s
        s.add(k * 1e-3, {'position': 1.0 if k == 2500 else 0.0})
    v = s.view(5.0, 50)                           # 100 samples a slot
    hi = v['position'][1]
    assert len(v['t']) == 50 and hi.max() == 1.0 and (hi == 1.0).sum() == 1
    assert v['t'][0] == pytest.approx(-5.0) and v['end'] == pytest.approx(4.999)


def test_the_scope_is_a_ring_and_drops_what_goes_back_in_time():
    s = Scope(100, ('position',))
    for k in range(1000):
        s.add(k * 1e-3, {'position': float(k)})
    assert len(s) == 100
    v = s.view(60.0, 10)                          # more than it holds: only what it has
    assert np.nanmin(v['position'][0]) == 900.0 and np.nanmax(v['position'][1]) == 999.0
    assert not s.add(0.5, {'position': 1.0}) and s.out_of_order == 1
    assert not s.add(math.nan, {'position': 1.0}) and s.out_of_order == 2


def test_the_scope_shows_a_gap_for_nan_and_empty_slots_and_rejects_a_bad_view():
    s = Scope(100, ('position', 'force'))
    s.add(0.0, {'position': 1.0, 'force': math.nan})
    s.add(1.0, {'position': 2.0})
    v = s.view(1.0, 4)
    assert np.isnan(v['force'][0]).all() and np.isnan(v['force'][1]).all()
    assert np.isnan(v['position'][1][1:3]).all()       # nothing in the middle slots
    for span, buckets in ((0.0, 4), (math.inf, 4), (1.0, 0)):
        with pytest.raises(ValueError):
            s.view(span, buckets)
    assert Scope(10).view(1.0, 4)['end'] is None


def test_a_page_gets_the_scope_packed_as_float32_rows_that_decode_to_the_view():
    s = Scope(1000, ('position', 'force'))
    for k in range(500):
        s.add(k * 1e-3, {'position': math.sin(k / 50), 'force': math.nan if k < 250 else k})
    v, p = s.view(0.5, 20), s.packed(0.5, 20)
    rows = np.frombuffer(base64.b64decode(p['data']), '<f4').reshape(len(p['rows']), p['n'])
    assert p['rows'] == ['t', 'position.min', 'position.max', 'force.min', 'force.max']
    assert np.allclose(rows[2], v['position'][1], rtol=1e-6, equal_nan=True)
    assert np.allclose(rows[3], v['force'][0], rtol=1e-6, equal_nan=True)
    assert np.isnan(rows[3][:10]).all() and p['end'] == pytest.approx(0.499)


# -- meters ------------------------------------------------------------------------------------
def test_a_meter_finds_each_cycles_peak_and_valley_above_the_noise():
    rng = np.random.default_rng(0)
    m = Meter(floor=5e-5)          # the station's floor: above 8 sigma of a 5 um noise
    t = np.arange(0, 3.0, 1e-3)
    for x in 0.04 * np.sin(2 * np.pi * t) + 5e-6 * rng.standard_normal(t.size):
        m.add(float(x))
    assert m.peak == pytest.approx(0.04, abs=3e-5) and \
        m.valley == pytest.approx(-0.04, abs=3e-5)
    assert m.as_dict()['cycles'] in (2, 3)
    held = Meter(floor=5e-5)
    for x in 5e-6 * rng.standard_normal(2000):    # a held axis: noise only, no cycle
        held.add(float(x))
    assert held.cycles == 0 and math.isnan(held.peak)


def test_the_noise_on_a_large_cycle_makes_no_cycles_of_its_own():
    """A 4 kN sine of hydraulic force with 300 N of noise: 10 cycles in 2 s, no more."""
    rng = np.random.default_rng(1)
    m = Meter(floor=50.0)                     # the station's force floor [N]
    t = np.arange(0, 3.0, 1e-3)
    for k, x in enumerate(4000 * np.sin(2 * np.pi * 5 * t) + 300 * rng.standard_normal(t.size)):
        if k == 1000:
            m.reset()                         # the meter's range stays: it is the signal's
        m.add(float(x))
    assert m.as_dict()['cycles'] == 10
    assert m.peak == pytest.approx(4000, abs=1200) and m.valley == pytest.approx(-4000, abs=1200)


def test_a_meter_ignores_non_finite_values_and_reset_keeps_the_value():
    m = Meter(floor=1.0)
    for x in (0.0, 5.0, math.nan, math.inf, -5.0, 5.0):
        m.add(x)
    assert m.invalid == 2 and m.max == 5.0 and m.min == -5.0 and m.peak == 5.0
    m.reset()
    assert m.value == 5.0 and math.isnan(m.min) and m.as_dict()['peak'] is None
    with pytest.raises(ValueError):
        Meter(floor=0.0)


# -- access ------------------------------------------------------------------------------------
def test_access_lets_this_machine_act_and_others_only_with_the_token():
    a = Access('s3cret-token')
    assert a.decide('127.0.0.1', None).allowed and a.decide('::1', None).allowed
    assert a.decide('127.0.0.5', None).allowed
    no = a.decide('192.0.2.7', None)
    assert not no.allowed and 'no token' in no.why and '192.0.2.7' in no.why
    assert 'wrong token' in a.decide('192.0.2.7', 'guess').why
    assert a.decide('192.0.2.7', 's3cret-token').allowed
    assert not a.decide('not an address', 's3cret-token').allowed is False   # parsed as remote
    open_ = Access('')
    assert not open_.decide('192.0.2.7', '').allowed
    assert 'without a token' in open_.decide('192.0.2.7', 'anything').why
    with pytest.raises(ValueError):
        Access('short')


# -- board -------------------------------------------------------------------------------------
def _controller_status(**extra):
    """Return the controller's status, serialized by rosbags and read by the contract."""
    v = {'tripped': 'limit_position_max', 'trips_limit_position_max': '1', 'enabled': 'True',
         'limit_position_max.limit': '0.03', 'limit_position_max.action': 'hold',
         'trips_limit_velocity': 'garbled'}
    v.update(extra)
    back = diagnostic_array([(c.CONTROLLER_STATUS, 2, 'interlock hold', list(v.items()))],
                            sec=1)
    return c.statuses_from_msg(back)[0]


def test_the_board_says_the_graph_is_lost_when_the_controller_is_not_heard():
    b = Board(lost_after=3.0)
    assert 'waiting for the controller' in b.lost(0.0)
    b.take_status('controller', 10.0, _controller_status())
    assert b.lost(12.9) is None
    assert 'for 3.5 s' in b.lost(13.5)
    with pytest.raises(ValueError):
        b.take_status('somebody', 0.0, _controller_status())


def test_the_board_lists_every_detector_with_its_limit_action_and_latch():
    b = Board()
    b.take_status('controller', 0.0, _controller_status())
    d = {x['name']: x for x in b.detectors()}
    assert d['limit_position_max'] == {'name': 'limit_position_max', 'limit': 0.03, 'unit': 'm',
                                       'action': 'hold', 'latched': True, 'trips': 1}
    assert not d['limit_velocity']['latched'] and d['limit_velocity']['limit'] is None
    assert d['limit_velocity']['trips'] == 0              # a garbled count is not a crash
    snap = b.snapshot(1.0)
    assert 'limit_position_max.limit' not in snap['controller']['values']   # in the table only
    json.dumps(snap, allow_nan=False)


def test_the_board_keeps_a_bounded_log_and_trend():
    b = Board(events=5, trend=3)
    for k in range(12):
        b.take_event(float(k), 'controller', 'trip', 2, f'trip {k}')
        b.take_estimate(float(k), ParameterEstimate(k, {'d_c': 100.0 + k}, {'d_c': 1.0}, True,
                                                    'adequate', pushed=k % 2 == 0))
    snap = b.snapshot(12.0)
    assert [e['message'] for e in snap['events']] == [f'trip {k}' for k in range(7, 12)]
    assert snap['events_total'] == 12
    assert snap['trend']['d_c'] == [[-3.0, 109.0], [-2.0, 110.0], [-1.0, 111.0]]
    assert snap['estimate']['params']['d_c'] == {'value': 111.0, 'stderr': 1.0}
    assert snap['estimate']['failed'] == []
    b.take_estimate(13.0, ParameterEstimate(13, {'d_c': 90.0}, {'d_c': 1.0}, False,
                                            'NOT ADEQUATE', failed=('rate', 'agreement:d_c')))
    assert b.snapshot(13.0)['estimate']['failed'] == ['rate', 'agreement:d_c']


# -- the station: scope and meters from states ------------------------------------------------
def test_the_station_scope_takes_states_and_restarts_with_a_new_run():
    st = Station(scope_samples=1000, buckets=10)
    st.take_reference(Reference(10**9, 0.01, 0.0))
    for k in range(100):
        st.take_state(AxisState(10**9 + k * 10**6, 0.009, 0.0, force=100.0, i=0.001))
    f = st.frame(0.0, 0.1)
    assert f['meters']['error']['value'] == pytest.approx(0.001)
    assert f['force_source'] == 'hydraulic' and f['states'] == 100
    assert f['meters']['reference']['value'] == pytest.approx(0.01)
    # a reference 4 ms old is carried to the state's stamp with its velocity; 60 ms old is not
    st.take_reference(Reference(10**9, 0.01, 0.5))
    st.take_state(AxisState(10**9 + 4 * 10**6, 0.012, 0.0))
    assert st.meters['reference'].value == pytest.approx(0.012)
    assert st.meters['error'].value == pytest.approx(0.0, abs=1e-12)
    st.take_state(AxisState(10**9 + 60 * 10**6, 0.012, 0.0))
    assert st.meters['reference'].value == pytest.approx(0.01)
    st.take_state(AxisState(5 * 10**6, 0.0, 0.0, load=50.0))       # stamps start again
    assert len(st.scope) == 1 and st.force_source == 'load cell'
    with pytest.raises(ValueError):
        st.frame(0.0, 3.0)
    json.dumps(st.frame(0.0, TIME_BASES[0]), allow_nan=False)
    assert 'board' not in st.frame(0.0, 1.0, board=False)


# -- the campaign panel ------------------------------------------------------------------------
#: a campaign's specimens as its node records them: (id, level [N], result, cycles)
SPECIMENS = [('S01', 9000.0, 'failed', 61_000), ('S02', 9000.0, 'failed', 83_000),
             ('S03', 7000.0, 'failed', 420_000), ('S04', 7000.0, 'run_out', 1_000_000),
             ('S05', 8000.0, 'invalid', 1_200), ('S06', 8000.0, 'failed', 190_000)]


def _record(sid, level, result, cycles, **extra):
    """Return one specimen's record as the campaign node publishes it (values as text)."""
    vals = {'specimen': sid, 'level': f'{level:.9g}', 'result': result, 'cycles': str(cycles),
            'reason': 'stopped by the operator' if result == 'invalid' else '',
            'mean': '4950', 'amplitude': '4050', 'r_ratio': '0.1', 'peak': f'{level:.9g}',
            'valley': f'{0.1 * level:.9g}', 'started': '2026-12-05T10:00:00Z',
            'ended': '2026-12-05T11:00:00Z', **extra}
    return NodeStatus(0, f'ros_ehs/campaign/{sid}', 1 if result == 'invalid' else 0,
                      result, vals)


def _campaign_status(**values):
    vals = {'state': 'ready', 'specimen': '', 'level': 'nan', 'tested': '6',
            'next_level': '8000', 'verdict': '', 'unit': 'N', 'name': 'bench',
            'run_out_cycles': '1000000', 'fit_a': 'nan', 'fit_k': 'nan', 'fit_s': 'nan', **values}
    return NodeStatus(0, c.CAMPAIGN_STATUS, 0, 'ready: ~/next gives a specimen at 8000', vals)


def test_the_campaign_panel_plots_failures_and_run_outs_and_lists_every_specimen_once():
    panel = CampaignPanel()
    assert panel.snapshot(0.0) is None                       # no campaign heard: no panel
    for r in SPECIMENS:
        panel.take_result(_record(*r))
    panel.take_result(_record(*SPECIMENS[0]))             # a replay (transient-local): one row
    snap = panel.snapshot(0.0)
    ids = [r['specimen'] for r in snap['specimens']]
    assert ids == ['S02', 'S03', 'S04', 'S05', 'S06', 'S01']
    assert snap['records'] == 7 and snap['heard'] is False
    assert snap['counts'] == {'failed': 4, 'run_out': 1, 'invalid': 1}
    # an invalid specimen is listed, never plotted: its life says nothing of its level
    assert sorted(zip(*snap['points']['failed'])) == [(61_000, 9000.0), (83_000, 9000.0),
                                                      (190_000, 8000.0), (420_000, 7000.0)]
    assert snap['points']['run_out'] == [[1_000_000], [7000.0]]
    assert snap['fit'] is None and snap['curves'] is None  # the node has not fitted yet
    panel.take_status(_campaign_status(), 0.0)
    snap = panel.snapshot(0.0)
    assert (snap['state'], snap['unit'], snap['next_level'], snap['run_out_cycles']) == \
        ('ready', 'N', 8000.0, 1e6)
    assert snap['under_way_level'] is None and snap['lost'] == ''
    json.dumps(snap, allow_nan=False)
    # a campaign node that stops: said after lost_after (3 s), the page then offers no next
    assert panel.snapshot(3.0)['lost'] == ''
    assert panel.snapshot(3.5)['lost'] == 'no status from the campaign node for 3.5 s'
    assert CampaignPanel().snapshot(0.0) is None
    only = CampaignPanel()
    only.take_result(_record(*SPECIMENS[0]))               # its records, never its status
    assert only.snapshot(0.0)['lost'] == 'no status from the campaign node yet'


def test_the_campaign_panel_draws_the_campaign_nodes_own_fit_at_10_50_and_90_percent():
    from ros_ehs.core.campaign.sn import fit_basquin, SNData
    from scipy.stats import norm
    assert Z90 == pytest.approx(norm.ppf(0.9), rel=1e-12)
    plotted = [r for r in SPECIMENS if r[2] != 'invalid']
    fit = fit_basquin(SNData.of([r[1] for r in plotted], [r[3] for r in plotted],
                                [r[2] == 'failed' for r in plotted]), slope_interval=False)
    panel = CampaignPanel()
    for r in SPECIMENS:
        panel.take_result(_record(*r))
    panel.take_status(_campaign_status(fit_a=f'{fit.a:.9g}', fit_k=f'{fit.k:.9g}',
                                       fit_s=f'{fit.s:.9g}'), 0.0)
    cv = panel.snapshot(0.0)['curves']
    loads = np.array(cv['load'])
    assert loads[0] == pytest.approx(7000.0 / 1.1) and loads[-1] == pytest.approx(9000 * 1.1)
    for name, p in (('p10', 0.1), ('p50', 0.5), ('p90', 0.9)):
        np.testing.assert_allclose(cv[name], fit.life(loads, p), rtol=1e-7)
    # a fit no page can draw is not drawn (and never breaks the frame's JSON)
    panel.take_status(_campaign_status(fit_a='900', fit_k='1', fit_s='0.1'), 0.0)
    assert panel.snapshot(0.0)['curves'] is None and panel.snapshot(0.0)['fit'] is not None
    panel.take_status(_campaign_status(fit_a='12', fit_k='-3', fit_s='0.1'), 0.0)
    assert panel.snapshot(0.0)['fit'] is None


def test_the_campaign_panel_refuses_a_record_it_cannot_place_and_stays_bounded():
    panel = CampaignPanel(max_specimens=3)
    with pytest.raises(ValueError, match='names no specimen'):
        panel.take_result(_record('', 9000.0, 'failed', 10))
    with pytest.raises(ValueError, match="S09: result 'broken'"):
        panel.take_result(_record('S09', 9000.0, 'broken', 10))
    rec = _record('S10', 9000.0, 'failed', 10)
    panel.take_result(rec._replace(values={**rec.values, 'level': 'nan', 'cycles': 'lots'}))
    row = panel.snapshot(0.0)['specimens'][0]
    assert row['level'] is None and row['cycles'] is None       # said as unknown, not plotted
    assert panel.snapshot(0.0)['points']['failed'] == [[], []]
    for k in range(5):
        panel.take_result(_record(f'S2{k}', 9000.0, 'failed', 1000 + k))
    assert [r['specimen'] for r in panel.snapshot(0.0)['specimens']] == ['S22', 'S23', 'S24']
    with pytest.raises(ValueError, match='max_specimens'):
        CampaignPanel(0)
    with pytest.raises(ValueError, match='lost_after'):
        CampaignPanel(lost_after=math.nan)


def test_the_station_sends_the_campaign_panel_with_the_board():
    st = Station(1000, 20)
    assert st.frame(0.0, 1.0)['board']['campaign'] is None
    st.take_campaign_result(_record(*SPECIMENS[0]))
    st.take_campaign_status(0.0, _campaign_status(state='under_way', specimen='S07',
                                                  level='8000'))
    board = st.frame(0.0, 1.0)['board']
    assert board['campaign']['under_way_level'] == 8000.0
    assert board['campaign']['specimens'][0]['specimen'] == 'S01'
    assert 'board' not in st.frame(0.0, 1.0, board=False)


# -- the web server ----------------------------------------------------------------------------
class FakeDesk:
    """Records what the web server asks; answers actions as a node would."""

    def __init__(self, answer=(True, 'done')):
        self.station = Station(1000, 20)
        self.answer = answer
        self.acted, self.logged, self.pages = [], [], 0

    def frame(self, span, board=True):
        return self.station.frame(0.0, span, board)

    async def act(self, action, specimen=None):
        self.acted.append(action if specimen is None else (action, specimen))
        if self.answer is None:
            raise asyncio.TimeoutError
        return self.answer

    def log_action(self, action, origin, result, reason):
        self.logged.append((action, origin.split(' ')[0], result, reason))

    def page_count(self, delta):
        self.pages += delta

    def reset_meters(self):
        self.station.reset_meters()


def _serve(desk, token='', host='127.0.0.1', push_rate=25.0):
    server = StationServer(make_app(desk, Access(token), push_rate), host, 0)
    return server, server.start()


def _post(url, body, headers=None):
    async def go():
        async with aiohttp.ClientSession() as s:
            async with s.post(url, json=body, headers=headers or {}) as r:
                return r.status, await r.json()
    return asyncio.run(go())


def test_an_action_goes_to_the_desk_and_is_logged_with_its_origin():
    desk = FakeDesk((False, 'reset refused: limit_position_max still beyond its limit'))
    server, port = _serve(desk)
    try:
        url = f'http://127.0.0.1:{port}/api/action/'
        status, body = _post(url + 'reset', {})
        assert status == 200 and body == {'ok': False, 'message': desk.answer[1]}
        assert desk.acted == ['reset']
        assert desk.logged == [('reset', '127.0.0.1', 'refused', desk.answer[1])]
        # hydraulics only with confirm; an unknown action is named; a foreign page refused
        status, body = _post(url + 'enable', {})
        assert status == 403 and 'confirm' in body['message'] and desk.acted == ['reset']
        desk.answer = (True, 'hydraulics on: ramping on')
        assert _post(url + 'enable', {'confirm': True}) == (200, {'ok': True,
                                                                  'message': desk.answer[1]})
        status, body = _post(url + 'explode', {})
        assert status == 404 and "'explode'" in body['message']
        status, body = _post(url + 'hold', {}, {'Origin': 'http://evil.example'})
        assert status == 403 and 'evil.example' in body['message']
        desk.answer = None                          # the node does not answer
        status, body = _post(url + 'hold', {})
        assert status == 504 and 'no answer' in body['message']
        results = [x[2] for x in desk.logged]
        assert results == ['refused', 'refused', 'done', 'refused', 'unanswered']
        assert desk.acted == ['reset', 'enable', 'hold']
    finally:
        server.stop()


def test_the_next_specimen_takes_the_typed_id_under_the_access_rule():
    desk = FakeDesk((True, 'C-0117 at 9000: loading it into the procedure node'))
    server, port = _serve(desk)
    try:
        url = f'http://127.0.0.1:{port}/api/action/next'
        assert _post(url, {'specimen': ' C-0117 '}) == (200, {'ok': True,
                                                              'message': desk.answer[1]})
        assert _post(url, {})[0] == 200                     # no id: the plan's
        assert desk.acted == [('next', 'C-0117'), ('next', '')]
        for bad in (17, 'x' * 65, None):
            status, body = _post(url, {'specimen': bad})
            assert status == 403 and '"specimen" must be a text' in body['message'], bad
        status, body = _post(url, {'specimen': 'C-1'}, {'Origin': 'http://evil.example'})
        assert status == 403 and len(desk.acted) == 2
        assert [x[2] for x in desk.logged] == ['done', 'done', 'refused', 'refused', 'refused',
                                               'refused']
    finally:
        server.stop()


def _remote_address():
    """Return this machine's first non-loopback IPv4 address (None when it has none)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(('192.0.2.1', 9))            # no packet is sent: picks the interface
            addr = s.getsockname()[0]
        except OSError:
            return None
    return None if addr.startswith('127.') else addr


def test_another_machine_watches_read_only_and_acts_only_with_the_token():
    addr = _remote_address()
    assert addr, 'this test needs a non-loopback interface (a page from "another machine")'
    desk = FakeDesk()
    server, port = _serve(desk, token='s3cret-token', host='0.0.0.0')
    try:
        url = f'http://{addr}:{port}'

        async def frame(q=''):
            async with aiohttp.ClientSession() as s:
                async with s.get(f'{url}/api/frame?span=1{q}') as r:
                    return await r.json()
        assert not asyncio.run(frame())['may_act']['allowed']
        assert asyncio.run(frame('&token=s3cret-token'))['may_act']['allowed']
        status, body = _post(f'{url}/api/action/reset', {})
        assert status == 403 and 'read-only' in body['message'] and desk.acted == []
        assert desk.logged[0][1] == addr           # the refusal names where it came from
        status, body = _post(f'{url}/api/action/reset', {'token': 's3cret-token'})
        assert status == 200 and desk.acted == ['reset']
    finally:
        server.stop()


def test_a_page_that_has_not_drawn_gets_no_more_than_the_window():
    p = Pacer(window=2, board_every=5)
    assert [p.tick() for _ in range(4)] == [(True, True), (True, False), (False, False),
                                            (False, False)]
    assert (p.sent, p.ticks) == (2, 4)
    assert p.take_drawn(1)                  # one drawn: one more may go, the newest
    assert p.tick() == (True, False)        # tick 4
    assert p.tick() == (False, False)       # tick 5: two undrawn again; its board waits
    assert p.take_drawn(3)
    assert p.tick() == (True, True)         # tick 6 brings the board of tick 5


def test_the_pacer_sends_on_as_the_page_draws_and_keeps_its_board_for_the_next_frame():
    p = Pacer(window=1, board_every=3)
    assert p.tick() == (True, True)             # tick 0: the first frame has the board
    assert p.tick() == (False, False)           # tick 1: not drawn yet
    assert p.tick() == (False, False)           # tick 2
    assert p.tick() == (False, False)           # tick 3: a board tick, nothing sent
    assert p.take_drawn(1)
    assert p.tick() == (True, True)             # tick 4: the board the skipped tick owed
    assert p.take_drawn(2)
    assert p.tick() == (True, False)            # tick 5
    assert p.take_drawn(3)
    assert p.tick() == (True, True)             # tick 6: a board tick


def test_the_pacer_ignores_a_drawn_count_it_cannot_believe():
    p = Pacer(window=2)
    p.tick(), p.tick()
    for bad in (3, 0, -1, 1.5, '2', True, None, [2]):     # beyond the sent, back, not a count
        assert not p.take_drawn(bad), bad
    assert p.drawn == 0 and p.take_drawn(2) and not p.take_drawn(1) and p.drawn == 2
    with pytest.raises(ValueError, match='`window` = 0 must be an int >= 1'):
        Pacer(window=0)
    with pytest.raises(ValueError, match='`board_every` = 2.0 must be an int >= 1'):
        Pacer(board_every=2.0)


def test_a_page_gets_frames_at_its_rate_and_changes_its_time_base():
    desk = FakeDesk()
    server, port = _serve(desk, push_rate=50.0)
    try:
        async def go():
            async with aiohttp.ClientSession() as s:
                async with s.ws_connect(f'http://127.0.0.1:{port}/ws?span=1') as ws:
                    drawn = 0

                    async def draw():          # a page says when it has drawn each frame
                        nonlocal drawn
                        f = json.loads((await ws.receive()).data)
                        drawn += 1
                        await ws.send_str(json.dumps({'drawn': drawn}))
                        return f
                    first = await draw()
                    # the board 5 times a second: every tenth tick of 50 a second. A tick
                    # the page is two frames behind on sends nothing and hands the board to
                    # the next frame (a loaded machine), so it is never more than ten frames
                    # without it, and not in every frame (quiet: frames 9 and 19 exactly)
                    boards = ['board' in await draw() for _ in range(20)]
                    at = [k for k, b in enumerate(boards) if b]
                    assert at and at[0] <= 9 and at[-1] >= 10 and len(at) <= 10, at
                    assert all(b - a <= 10 for a, b in zip(at, at[1:])), at
                    await ws.send_str(json.dumps({'span': 0.1}))
                    await ws.send_str('not json')           # ignored, the page goes on
                    await ws.send_str(json.dumps({'drawn': 'all'}))    # ignored too
                    for _ in range(50):
                        f = await draw()
                        if f['span'] == 0.1:
                            break
                    pages = desk.pages
                    return first, f, pages
        first, last, pages = asyncio.run(go())
        assert first['span'] == 1.0 and last['span'] == 0.1 and pages == 1
        assert first['may_act']['allowed'] and first['board']['lost'].startswith('waiting')
        end = time.monotonic() + BOUND                    # the closed page is counted out
        while desk.pages and time.monotonic() < end:
            time.sleep(0.02)
        assert desk.pages == 0 and desk.acted == []       # a closed page did nothing
    finally:
        server.stop()


def test_a_bad_time_base_is_refused_naming_the_choices():
    desk = FakeDesk()
    server, port = _serve(desk)
    try:
        async def go():
            async with aiohttp.ClientSession() as s:
                async with s.get(f'http://127.0.0.1:{port}/api/frame?span=3') as r:
                    return r.status, await r.text()
        status, text = asyncio.run(go())
        assert status == 400 and '3' in text and '0.1' in text

        async def ws_bad():                    # refused before the upgrade, as plain HTTP
            async with aiohttp.ClientSession() as s:
                with pytest.raises(aiohttp.WSServerHandshakeError) as err:
                    await s.ws_connect(f'http://127.0.0.1:{port}/ws?span=3')
                return err.value.status
        assert asyncio.run(ws_bad()) == 400
        # the meters' reset passes the same gate as an action: JSON from this page only
        assert _post(f'http://127.0.0.1:{port}/api/meters/reset', {}) == (
            200, {'ok': True, 'message': 'meters reset'})

        async def form():
            async with aiohttp.ClientSession() as s:
                async with s.post(f'http://127.0.0.1:{port}/api/meters/reset',
                                  data='x=1') as r:
                    return r.status, await r.json()
        status, body = asyncio.run(form())
        assert status == 403 and 'JSON' in body['message']
    finally:
        server.stop()


def test_the_page_and_its_charting_library_are_shipped_in_the_package():
    from ros_ehs.web.app import STATIC
    assert (STATIC / 'index.html').is_file()
    lib = (STATIC / 'vendor' / 'uPlot.iife.min.js').read_text()
    pinned = json.loads((STATIC / 'vendor' / 'package.json').read_text())
    version = pinned['dependencies']['uplot']
    assert lib.startswith(f'/*! https://github.com/leeoniya/uPlot (v{version})')
    html = (STATIC / 'index.html').read_text()
    assert 'http://' not in html and 'https://' not in html      # no CDN: rigs are offline


def test_a_station_on_a_port_in_use_says_so():
    desk = FakeDesk()
    server, port = _serve(desk)
    try:
        with pytest.raises(OSError, match=f'127.0.0.1:{port}'):
            StationServer(make_app(desk, Access(), 25.0), '127.0.0.1', port).start()
    finally:
        server.stop()


def test_a_procedure_event_reads_back_with_its_level_through_rosbags():
    """The station's event log takes the level from the contract's decoder, any message kind."""
    msg = c.fill_procedure_event(c.empty_msg('diagnostic_msgs/msg/DiagnosticArray'), 5, 1,
                                 'held', 'cycles', 3.0, 3, 1, 'held at cycle 3')
    st = msg['status'][0]
    back = diagnostic_array([(st['name'], st['level'][0], st['message'],
                              [(kv['key'], kv['value']) for kv in st['values']])], nanosec=5)
    e = c.procedure_event_from_msg(back)
    assert (e['kind'], e['level'], e['total_cycles'], e['stamp_ns']) == ('held', 1, 3, 5)
    assert c.procedure_event_from_msg(msg)['level'] == 1           # a dict message too
