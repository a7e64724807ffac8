"""Peak/valley control in process (ros_ehs.core.control.pvc): waveforms, blocks, jumps, input."""

import math

import numpy as np
import pytest
from ros_ehs.core.control.pvc import Block, PeakValleyControl
from ros_ehs.core.errors import InputError
from ros_ehs.core.params import preset
from ros_ehs.core.sim.closed_loop import run_closed_loop


@pytest.mark.parametrize('waveform,f,blocks', [
    ('triangle', 5.0, [Block(0.005, -0.005)]),
    ('haversine', 10.0, [Block(0.004, 0.0)]),
    ('triangle', 2.0, [Block(0.01, -0.01, 4), Block(0.02, 0.0, 4)]),   # block loading
])
def test_each_cycle_reaches_its_peak_and_valley_on_the_full_model_rig(waveform, f, blocks):
    p = preset('table1_estimated')
    pvc = PeakValleyControl(blocks, f, waveform)
    r = run_closed_loop(p, pvc, 40 / f, model='full')
    assert pvc.converged_at <= 30
    last = pvc.history[-5:]                               # and there it stays
    assert max(h['error'] for h in last) <= 0.005, last  # within 0.5 % of the block's range
    first = pvc.history[0]['error']
    assert first > 0.005                                  # uncorrected, the loop misses them
    # no jump: the command never moves more in a period than its fastest slope allows (a
    # cycle's, or a transition's: from a block's valley to the next one's peak in half a cycle)
    spans = [b.peak - b.valley for b in blocks] + [
        abs(nxt.peak - b.valley) for b, nxt in zip(blocks, blocks[1:] + blocks[:1])]
    slope = max(spans) * math.pi * f * 1.05   # haversine's
    assert np.abs(np.diff(r.z_ref)).max() <= slope * 1e-3


def test_freeze_keeps_the_corrections():
    pvc = PeakValleyControl([Block(0.005, -0.005)], 5.0)
    for k in range(2000):
        t = k * 1e-3
        if k == 1000:
            pvc.freeze()
            kept = (list(pvc.amp), list(pvc.mean))
        pvc.measure(t, 0.8 * pvc.reference(t)[0])
    assert (pvc.amp, pvc.mean) == kept and pvc.amp[0] > 0.005 * 1.1


@pytest.mark.parametrize('make,match', [
    (lambda: Block(0.0, 0.01), 'above'), (lambda: Block(0.01, 0.0, 0), 'cycles'),
    (lambda: PeakValleyControl([], 1.0), 'blocks'),
    (lambda: PeakValleyControl([Block(1e-3, 0.0)], 1.0, 'square'), 'waveform'),
    (lambda: PeakValleyControl([Block(1e-3, 0.0)], math.nan), 'frequency')])
def test_bad_settings_name_the_argument(make, match):
    with pytest.raises(InputError, match=match):
        make()


def test_a_correction_changes_no_sample_computed_before_its_latency():
    """
    What a node sends ahead (up to ``latency`` into the next cycle) stays as it was sent.

    Samples up to 0.02 s past each cycle's end are computed before that cycle is measured,
    then again after: the same, and the corrections are really made (the loop at 0.8).
    """
    pvc = PeakValleyControl([Block(0.005, -0.005, 2), Block(0.008, 0.0, 2)], 5.0,
                            latency=0.02)
    dt, ahead = 1e-3, 20
    early = {}
    for k in range(int(6.0 / dt)):
        for j in range(ahead + 1):                     # the window a node sends at k
            t = (k + j) * dt
            early.setdefault(k + j, pvc.reference(t))
        assert pvc.reference(k * dt) == early[k]
        pvc.measure(k * dt, 0.8 * pvc.reference(k * dt)[0])
    assert pvc.amp[0] > 0.005 * 1.15 and pvc.converged_at is not None
    # and with no latency the in-process loop is as before: corrections from the next cycle
    with pytest.raises(InputError, match='latency'):
        PeakValleyControl([Block(0.005, -0.005)], 5.0, latency=0.1)


def test_blocks_are_read_from_text_and_a_wrong_block_is_named():
    from ros_ehs.core.control.pvc import Cyclic, parse_blocks
    from ros_ehs.core.control.waveforms import make
    want = [Block(0.01, -0.01, 4), Block(0.02, 0.0, 2)]
    assert parse_blocks('0.01 -0.01 4; 0.02, 0, 2;') == want
    for bad, what in (('0.01 -0.01', 'block 1'), ('0.01 -0.01 4; 0.02 0 2.5', 'block 2'),
                      ('0.01 -0.01 x', 'block 1'), ('  ;  ', 'at least one'),
                      ('0 0.01 3', 'above')):
        with pytest.raises(InputError, match=what):
            parse_blocks(bad)
    # the reference kinds: offset -+ amplitude, or the blocks; the waveform's own samples
    tri = make({'kind': 'triangle', 'amplitude': 0.004, 'offset': 0.001, 'frequency': 2.0})
    z, v = tri(np.array([0.0, 0.125, 0.25, 0.375]))
    np.testing.assert_allclose(z, [-0.003, 0.001, 0.005, 0.001], atol=1e-15)
    np.testing.assert_allclose(v, [0.032, 0.032, -0.032, -0.032], atol=1e-12)
    hav = make({'kind': 'haversine', 'frequency': 1.0}, blocks='0.02 0 1; 0.01 0 1')
    assert isinstance(hav, Cyclic)
    z, _ = hav(np.array([0.0, 0.5, 1.5]))
    np.testing.assert_allclose(z, [0.0, 0.02, 0.01], atol=1e-15)
    from ros_ehs.core.errors import ParameterError
    with pytest.raises(ParameterError, match='amplitude'):
        make({'kind': 'triangle', 'amplitude': 0.0})


def test_between_blocks_the_command_stays_within_the_two_blocks_levels():
    """The step from the last block's end decays while the new cycle rises: no overshoot."""
    from ros_ehs.core.control.pvc import Block, PeakValleyControl
    blocks = [Block(0.003, 0.001, 3), Block(0.004, 0.0, 2), Block(0.012, 0.008, 2)]
    for kind in ('triangle', 'haversine', 'sine'):
        c = PeakValleyControl(blocks, 5.0, kind, latency=0.0, learn_from=0.0)
        c.freeze()
        n = 200                                       # samples a cycle
        z = []
        for k in range(14 * n):                       # a perfect axis: it measures the command
            t = k / (5.0 * n)
            z.append(c.reference(t)[0])
            c.measure(t, z[-1])
        end = z[0]                    # where the last cycle ended: its block's valley
        for k in range(14):
            seg = z[k * n:(k + 1) * n]
            b = blocks[[0, 0, 0, 1, 1, 2, 2][k % 7]]
            assert max(seg) <= max(b.peak, end) + 1e-12, (kind, k, max(seg))
            assert min(seg) >= min(b.valley, end) - 1e-12, (kind, k, min(seg))
            assert abs(seg[0] - end) < 1e-12 or k == 0          # no jump
            assert max(seg) == pytest.approx(max(b.peak, end), abs=1e-9)    # no more
            end = b.valley


@pytest.mark.parametrize('kind', ['pvc', 'apc'])
def test_a_correction_is_bounded_by_its_limit_and_counts_the_cycles_it_met_it(kind):
    """A rig that answers a tenth of the command: the correction stops at its bound."""
    from ros_ehs.core.control.apc import AmplitudePhaseControl
    f = 10.0
    if kind == 'pvc':
        c = PeakValleyControl([Block(0.001, -0.001, 1)], f, 'sine')
    else:
        c = AmplitudePhaseControl(0.001, f, 0.0)
    c.limit = 0.5
    t = 0.0
    for _ in range(20 * 100):                 # 20 cycles at 1 kHz
        c.measure(t, 0.1 * c.reference(t)[0])
        t += 1e-3
    peak = max(c.reference(2.0 + j * 1e-3)[0] for j in range(100))
    assert peak <= 1.5 * 0.001 * (1.0 + 1e-9)           # never beyond (1 + limit) A
    assert peak > 1.4 * 0.001                            # and at it
    assert c.limited_cycles >= 10
