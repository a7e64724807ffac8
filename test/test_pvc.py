"""Peak/valley control in process (ros_ehs.control.pvc): waveforms, blocks, no jumps, input."""

import math

import numpy as np
import pytest
from ros_ehs.control.pvc import Block, PeakValleyControl
from ros_ehs.errors import InputError
from ros_ehs.params import preset
from ros_ehs.sim.closed_loop import run_closed_loop


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
    # no jump: the command never moves more in a period than its fastest slope allows
    slope = max(b.peak - b.valley for b in blocks) * math.pi * f * 1.05   # haversine's
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
