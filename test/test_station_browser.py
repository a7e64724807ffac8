"""
The operator's station in a real browser (Debian's Chromium, headless) against a running bench.

Playwright drives the page as an operator would, against the real nodes in lock-step (the
loop waits for every node, so what the page sees does not depend on the machine's timing):
the scope and meters update; a tripped limit shows, Reset is refused with its reason while
the piston is beyond the limit and clears the latch once the limit is raised; Disable and
Enable (each confirmed in the page's own dialog, which keeps the scope live; Escape
cancels) turn the hydraulics off and ramp them on; the buttons stay where they are while the
numbers change; a procedure's Start, Hold and Resume; a controller that goes away shows as
a lost graph; ``bench.py --station``. Every action is in the bag (``station/events``, read
by rosbags) with where it came from. Every wait is on the page's content, a status or the bag.
"""

from pathlib import Path
import shutil

import pytest
from ros_ehs.nodes.processes import NodeProcesses
from ros_ehs.nodes.ros_common import qos_profile
import ros_ehs_msgs_py as c
from waits import BOUND, rosbags_read, set_parameter, status_value, wait_value

pytestmark = pytest.mark.ros
FAST = {'diagnostics_period': 0.05}
#: the plant's lock-step at the rig's speed: the page's waits are on the page, and a loop as
#: fast as it runs would spend the CPU the browser needs
PACED = {'real_time_factor': 1.0}
CHROMIUM = '/usr/bin/chromium'
#: Chromium on a machine with no network (the flags keep it from calling home)
ARGS = ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
        '--disable-background-networking', '--disable-component-update', '--disable-sync']
WAIT_MS = BOUND * 1000


@pytest.fixture
def browser():
    from playwright.sync_api import sync_playwright
    assert Path(CHROMIUM).is_file(), \
        f'{CHROMIUM} is missing: `bash scripts/test.sh` installs Debian chromium'
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        yield b
        b.close()


def _station(procs, **settings):
    """Start the station on a free port; return its url (from its status)."""
    procs.start('station', {'port': 0, **FAST, **settings})
    assert procs.wait_status(c.STATION_STATUS, lambda st: 'url' in st.values, BOUND), \
        procs['station'].output()[-3000:]
    return procs.status(c.STATION_STATUS).values['url']


def _page(browser):
    page = browser.new_page(viewport={'width': 1400, 'height': 1000})
    page.set_default_timeout(WAIT_MS)       # a click is bounded as every other wait is
    errors = []
    page.on('pageerror', lambda e: errors.append(str(e)))
    # the page asks in its own dialog; a browser dialog (which stops the page) is an error
    page.on('dialog', lambda d: (errors.append(f'a browser dialog: {d.message}'), d.dismiss()))
    page.errors = errors
    return page


def _said(page):
    """Return what the page shows and logged (for a failure's message)."""
    try:
        log = page.evaluate('window.station.log')
        return (f'the answer is {page.inner_text("#answer")!r}, the link '
                f'{page.inner_text("#link")!r}; the page logged:\n  ' + '\n  '.join(log)
                + (f'\npage errors: {page.errors}' if page.errors else ''))
    except Exception as e:         # a page that cannot say is itself the finding
        return f'the page cannot say ({e})'


def _wait(page, js, arg=None):
    """Wait (bounded) until ``js`` holds in the page, return its value; on timeout say why."""
    from playwright.sync_api import TimeoutError as PageTimeout
    try:
        return page.wait_for_function(js, arg=arg, timeout=WAIT_MS).json_value()
    except PageTimeout:
        raise AssertionError(f'waited {BOUND} s for {js!r} ({arg}); {_said(page)}') from None


#: what the page logged about a press on ``action`` since it had logged ``noted`` lines
PRESSED = """([noted, action]) => {
  const s = window.station;
  return s.log.slice(Math.max(0, s.log.length - (s.noted - noted))).find((line) =>
    line.endsWith(`click ${action}`) || line.endsWith(`press on ${action} (disabled)`)) || null;
}"""


def _press(page, action, tries=5):
    """
    Press ``action``'s button as an operator would: again if the press found it off.

    Playwright waits until the button is enabled, then presses; the page may turn it off in
    between (its link dropped, the controller not heard for a while). The page logs such a
    press, and the operator, seeing nothing happen, presses again.
    """
    for _ in range(tries):
        noted = page.evaluate('window.station.noted')
        page.click(f'[data-testid={action}]')
        line = _wait(page, PRESSED, [noted, action])
        if line.endswith(f'click {action}'):
            return
    raise AssertionError(f'{tries} presses on {action} found it off; {_said(page)}')


def _confirmed(page, action, *words):
    """Press ``action``; the page asks in its own dialog (naming ``words``); confirm it."""
    _press(page, action)
    _wait(page, 'document.getElementById("confirm").open')
    text = page.inner_text('[data-testid=confirm-text]')
    assert all(w in text for w in words), text
    page.click('[data-testid=confirm-ok]')


def _answer(page, *words):
    """Wait until the page's answer line says every one of ``words``; return it."""
    _wait(page, 'words => { const a = document.getElementById("answer");'
                ' return !a.hidden && words.every(w => a.textContent.includes(w)); }',
          list(words))
    return page.inner_text('#answer')


def _refit():
    """Return a live refit that failed two rules, as an identify node sends it."""
    from foreign import estimate
    return estimate({'F_cc': '310.0', 'F_cc.stderr': '4.0', 'adequate': 'false',
                     'pushed': 'false', 'reason': 'not adequate', 'window_s': '10.0',
                     'wall_s': '1.0', 'iterations': '9',
                     'failed_rules': 'prediction:z_dot,agreement:F_cc'},
                    False, 'NOT ADEQUATE: the halves disagree')


def _station_events(bag):
    return rosbags_read(bag, '/station/events', c.station_event_from_msg)


def test_the_page_shows_the_axis_a_trip_and_its_reset_and_ramps_on(dom, tmp_path, ros, browser):
    bag = tmp_path / 'bag'
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        # ramp_time 1 s: the enable below lands at any phase of the 40 mm, 1 Hz sine, and a
        # ramp-on from its valley to its peak must stay within the valve's speed (0.2 s asked
        # up to 1 m/s of a rig that gives some 0.6: the tracking error tripped, then the hold)
        procs.start_loop('lockstep', bag=bag, plant={'duration': 600.0, **PACED, **FAST},
                         controller={'limit_position_max': 0.03, 'ramp_time': 1.0,
                                     'limit_position_max_action': 'hold', **FAST})
        page = _page(browser)
        page.goto(_station(procs))
        # the scope and the meters update: the scope's newest time moves on, frame to frame
        _wait(page, 'window.station.last && window.station.last.scope.end > 0.5')
        end = page.evaluate('window.station.last.scope.end')
        _wait(page, f'window.station.last.scope.end > {end} + 0.2')
        assert page.inner_text('[data-meter="position.max"]') != '-'
        # the trip shows, with its limit and action
        _wait(page, "document.querySelector('tr.latched[data-detector=limit_position_max]')")
        row = page.query_selector('tr.latched[data-detector="limit_position_max"]')
        assert '0.03' in row.inner_text() and 'hold' in row.inner_text()
        _wait(page, 'document.getElementById("axis").textContent.includes("interlock hold")')
        # Reset while the piston is held at the limit: refused, and the page says why
        _press(page, 'reset')
        text = _answer(page, 'refused', 'limit_position_max')
        assert 'limit 0.03 m' in text, text
        assert page.query_selector('tr.latched[data-detector="limit_position_max"]')
        # the engineer raises the limit (the station does not edit limits); Reset clears it
        res = set_parameter(ros, '/controller', 'limit_position_max', 0.05)
        assert res.successful, res.reason
        _press(page, 'reset')
        _answer(page, 'reset: done')
        _wait(page, "document.querySelector('tr[data-detector=limit_position_max]:not(.latched)')")
        # hydraulics off (confirmed), then on: the controller ramps on from where it is
        # the page asks first; Cancel (or Escape) does nothing
        _press(page, 'disable')
        _wait(page, 'document.getElementById("confirm").open')
        page.keyboard.press('Escape')
        _wait(page, '!document.getElementById("confirm").open')
        assert page.inner_text('#hyd') == 'on'
        _confirmed(page, 'disable', 'OFF')
        _answer(page, 'disable: done')
        _wait(page, 'document.getElementById("hyd").textContent === "off"')
        _confirmed(page, 'enable', 'ON', 'ramps on')
        _answer(page, 'enable: done', 'ramping on')
        _wait(page, 'document.getElementById("hyd").textContent === "on" && '
                    'document.getElementById("ramp").value === 1')
        _wait(page, 'document.getElementById("events").textContent.includes("enabled")')
        # a live refit, sent as an identify node sends it (built field by field, not by our
        # encoder): its verdict's failed rules show as tags beside NOT ADEQUATE
        refit = _refit()
        pub = ros.create_publisher(type(refit), c.ESTIMATES.name, qos_profile(c.ESTIMATES.qos))
        pub.publish(refit)          # kept for late joiners (transient local) while pub lives
        _wait(page, 'document.querySelector("[data-testid=failed-rules]") && document.'
                    'querySelector("[data-testid=failed-rules]").textContent.includes('
                    '"agreement:F_cc")')
        assert 'NOT ADEQUATE' in page.inner_text('#estimate')
        tags = page.query_selector_all('[data-testid=failed-rules] .tag')
        assert [t.inner_text() for t in tags] == ['prediction:z_dot', 'agreement:F_cc']
        assert page.errors == []
        page.close()
        # a closed page changes nothing on the axis: the loop runs on, no action after it
        steps = status_value(procs, c.PLANT_STATUS, 'steps')
        wait_value(procs, c.PLANT_STATUS, 'steps', steps + 500)
        assert procs.status(c.CONTROLLER_STATUS).message == 'running'
        procs.stop(['station', 'recorder', 'reference', 'controller', 'plant'])
    events = _station_events(bag)
    assert [(e['action'], e['result']) for e in events] == [
        ('reset', 'refused'), ('reset', 'done'), ('disable', 'done'), ('enable', 'done')]
    assert all(e['origin'].startswith('127.0.0.1 (') and 'Chrome' in e['origin']
               for e in events), events


def test_the_page_starts_holds_and_resumes_a_procedure(dom, tmp_path, browser):
    proc = tmp_path / 'test.yaml'
    shutil.copy(Path(__file__).parent / 'fixtures' / 'procedure_long.yaml', proc)
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start_loop('lockstep', bag=tmp_path / 'bag',
                         plant={'duration': 1.0e5, 'k_L': 1.0e6, 'specimen_life': 1.0e12,
                                **PACED, **FAST},
                         controller={'ramp_time': 0.05, **FAST},
                         procedure={'file': str(proc), 'autostart': False, **FAST})
        page = _page(browser)
        page.goto(_station(procs))
        _wait(page, 'document.querySelector("[data-testid=proc-state]") && '
                    'document.querySelector("[data-testid=proc-state]").textContent === "idle"')
        _press(page, 'start')
        _answer(page, 'start: done')

        def cycles_past(n):
            _wait(page, 'n => Number(document.querySelector("[data-testid=total-cycles]")'
                        '.textContent) > n', n)
            return int(page.inner_text('[data-testid=total-cycles]'))

        cycles_past(3)
        # the buttons stay put while the numbers change (a meter's width once moved them by a
        # line several times a second): the same place over 60 frames, a second at least
        tops = page.evaluate("""() => new Promise((done) => {
            const b = document.querySelector('[data-testid=hold]');
            const tops = [];
            (function frame() {
              tops.push(b.getBoundingClientRect().top);
              if (tops.length < 60) requestAnimationFrame(frame); else done(tops);
            })(); })""")
        assert len(set(tops)) == 1, tops
        _press(page, 'hold')
        _answer(page, 'hold: done')
        _wait(page, 'document.querySelector("[data-testid=proc-state]").textContent === "held"')
        held = int(status_value(procs, c.PROCEDURE_STATUS, 'total_cycles'))
        steps = status_value(procs, c.PLANT_STATUS, 'steps')
        wait_value(procs, c.PLANT_STATUS, 'steps', steps + 300)      # 3 cycles' time, held
        assert int(status_value(procs, c.PROCEDURE_STATUS, 'total_cycles')) == held
        _press(page, 'resume')
        _answer(page, 'resume: done')
        assert cycles_past(held + 2) > held + 2
        # the controller goes away: the page says the graph is lost and disables its buttons
        procs.stop(['controller'])
        _wait(page, 'document.getElementById("link").textContent.includes("graph is lost")')
        assert page.is_disabled('[data-testid=reset]') and page.is_disabled('[data-testid=hold]')
        # a press on a disabled button sends nothing, and the page says why
        page.click('[data-testid=hold]', force=True)
        _answer(page, 'hold: not sent:', 'graph is lost')
        assert page.errors == []
        procs.stop(['station', 'procedure', 'recorder', 'plant'])


def test_bench_py_starts_the_station_beside_the_bench_and_stops_it_cleanly(
        dom, tmp_path, browser):
    import os
    import re
    import signal
    import subprocess
    import sys
    from ros_ehs.nodes.processes import launch_script
    cmd = [sys.executable, str(launch_script('bench.py')), '--mode', 'lockstep', '--duration',
           '600', '--out', str(tmp_path / 'bag'), '--log-dir', str(tmp_path / 'logs'),
           '--no-cpu-affinity', '--station', '0', '--plant-param', 'real_time_factor=1']
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                         env={**os.environ, 'ROS_DOMAIN_ID': str(dom)})
    try:
        said = []
        for line in p.stdout:                     # its own words: where the page is
            said.append(line)
            m = re.match(r'bench: station on (http://127\.0\.0\.1:\d+/)', line)
            if m or 'loop running' in line:
                break
        assert m, ''.join(said)
        page = _page(browser)
        page.goto(m.group(1))
        _wait(page, 'window.station.last && window.station.last.scope.end > 0.5 '
                    '&& window.station.last.controller')
        assert page.inner_text('[data-testid=link]') == 'connected'
        acting = 'button.act, #meters-reset'
        _wait(page, f'!document.getElementById("meters-reset").disabled && '
                    f'document.querySelectorAll("{acting}").length > 5')
        p.send_signal(signal.SIGINT)
        out, _ = p.communicate(timeout=BOUND)
        # the page hears that the station went; the open page did not hold the web server
        # (it once did, until the 5 s the station waits for it); every button goes off
        _wait(page, 'window.station.connected === false')
        assert 'station disconnected' in page.inner_text('[data-testid=link]')
        assert page.evaluate(f'[...document.querySelectorAll("{acting}")].every(b => b.disabled)')
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, ''.join(said) + out
    assert 'bench: done' in out, out
    station_log = (tmp_path / 'logs' / 'station.log').read_text()
    assert 'the web server did not stop' not in station_log, station_log


def test_the_page_shows_the_campaign_and_loads_the_operators_next_specimen(
        dom, tmp_path, browser):
    """
    A campaign under way on the rig: the store holds four specimens, the campaign node fits.

    The page draws what the campaign node published (its store's records at its start, its
    fit in its status), and its Next specimen sets the typed id and calls ``~/next`` as a
    ROS client does: the campaign node's own status says the specimen is under way.
    """
    import yaml
    from ros_ehs.benchmarks.campaign import BENCH_CAMPAIGN
    from ros_ehs.data.store import ResultStore, SpecimenRecord
    plan = tmp_path / 'campaign.yaml'
    plan.write_text(yaml.safe_dump(BENCH_CAMPAIGN))
    out, bag = tmp_path / 'out', tmp_path / 'bag'
    out.mkdir()
    store = ResultStore(out / 'campaign.db')
    try:
        cid = store.campaign(BENCH_CAMPAIGN['name'])
        for sid, level, result, n in (('S01', 9000.0, 'failed', 61), ('S02', 9000.0, 'failed',
                                                                      83),
                                      ('S03', 7000.0, 'failed', 190),
                                      ('S04', 7000.0, 'run_out', 250)):
            store.record(cid, SpecimenRecord(sid, level, result, n, peak=level,
                                             valley=0.1 * level))
    finally:
        store.close()
    with NodeProcesses(dom, tmp_path / 'logs', bound=BOUND) as procs:
        procs.start('recorder', {'out': str(bag), 'discovery_period': 0.05})
        procs.start('controller', FAST)       # heard: the page's buttons act only then
        procs.start('campaign', {'campaign': str(plan), 'out': str(out), **FAST})
        assert procs.wait_status(c.CAMPAIGN_STATUS, lambda st: st.values.get('state') ==
                                 'ready', BOUND), procs['campaign'].output()[-3000:]
        st = procs.status(c.CAMPAIGN_STATUS).values
        assert st['next_level'] == '5000' and float(st['fit_k']) > 0, st
        page = _page(browser)
        page.goto(_station(procs))
        # the campaign panel: 3 failures, 1 run-out, the fit's curves, the next level (the
        # points come with the results, the fit with the campaign node's next status)
        _wait(page, '!document.getElementById("campaign").hidden && document.querySelectorAll('
                    '"#chart-sn [data-result]").length === 4 && '
                    'document.querySelector("[data-testid=sn-p10]") !== null')
        assert len(page.query_selector_all('#chart-sn [data-result=failed]')) == 3
        assert len(page.query_selector_all('#chart-sn [data-result=run_out]')) == 1
        for curve in ('sn-p10', 'sn-p50', 'sn-p90', 'sn-band'):
            assert page.query_selector(f'[data-testid={curve}]'), curve
        assert page.inner_text('[data-testid=next-level]') == '5000'
        rows = page.query_selector_all('#specimens tr')
        assert [r.get_attribute('data-specimen') for r in rows] == ['S01', 'S02', 'S03', 'S04']
        # the operator types the coupon's id and presses Next specimen
        page.fill('[data-testid=specimen-id]', 'C-0117')
        _press(page, 'next')
        text = _answer(page, 'next: done', 'C-0117 at 5000')
        assert procs.wait_status(c.CAMPAIGN_STATUS, lambda st: st.values.get('specimen') ==
                                 'C-0117', BOUND), text
        assert procs.status(c.CAMPAIGN_STATUS).values['state'] == 'under_way'
        _wait(page, 'document.querySelector("[data-testid=campaign-phase]").textContent === '
                    '"under_way" && document.querySelector("[data-testid=next]").disabled')
        assert page.input_value('[data-testid=specimen-id]') == ''
        assert page.errors == []
        page.close()
        procs.stop(['station', 'campaign', 'controller', 'recorder'])
    events = _station_events(bag)
    assert [(e['action'], e['result']) for e in events] == [('next', 'done')], events
    assert 'C-0117 at 5000' in events[0]['reason'], events
