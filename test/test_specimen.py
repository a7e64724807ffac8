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
The specimen: its damage law against its closed form, its reversals, its fracture.

And the simulated axis that carries it: the load cell, its noise stream, a fracture noted once.
"""

import math

import numpy as np
import pytest
from ros_ehs.core.errors import InputError
from ros_ehs.core.model.specimen import REVERSAL_FRACTION, Specimen
from ros_ehs.core.params import Params
from ros_ehs.core.sim.axis import SimulatedAxis


def _cycle(sp: Specimen, n: float, mean: float = 5e3, amp: float = 5e3, per: int = 40) -> None:
    """Feed ``n`` cycles of a force sine (``per`` samples a cycle) until done or broken."""
    for k in range(int(n * per)):
        sp.update(mean + amp * math.sin(2 * math.pi * k / per))
        if sp.broken:
            return


def test_no_specimen_carries_nothing_and_never_breaks():
    sp = Specimen(Params())
    assert not sp.present and sp.force(0.01, 0.1) == 0.0
    assert not sp.update(1e6) and not sp.update(-1e6) and sp.cycles == 0 and not sp.broken


@pytest.mark.parametrize('m', [2.0, 3.0, 4.0])
def test_at_the_life_range_it_breaks_at_the_life(m):
    p = Params().replace(k_L=5e7, specimen_life=400.0, specimen_paris_m=m)
    sp = Specimen(p)
    assert sp.cycles_to(1.0) == pytest.approx(400.0)
    _cycle(sp, 1000)        # a 10 kN range: the life range
    assert sp.broken and sp.stiffness == 0.0 and sp.force(0.01, 0.1) == 0.0
    # the growth integrated exactly over each half cycle: the closed form's life, broken at
    # the peak of its last cycle
    assert sp.cycles == pytest.approx(400.0, abs=1.0)
    assert not sp.update(0.0) and not sp.update(1e4)          # broken: nothing more counts


def test_the_stiffness_falls_with_the_crack_as_its_closed_form_says():
    p = Params().replace(k_L=5e7, specimen_life=2000.0, specimen_compliance=4.0)
    sp = Specimen(p)
    k_installed = sp.stiffness
    assert k_installed == pytest.approx(5e7 / (1 + 4.0 * 0.01))
    n10 = sp.cycles_to_drop(0.10)
    assert 0 < n10 < 2000
    while sp.stiffness > 0.9 * k_installed:
        _cycle(sp, 1)
    assert sp.cycles == pytest.approx(n10, abs=max(2.0, 0.01 * n10))
    assert sp.stiffness == pytest.approx(5e7 / (1 + 4.0 * sp.a ** 2))
    # a drop it cannot reach before it breaks: never
    assert math.isinf(Specimen(p.replace(specimen_compliance=0.05)).cycles_to_drop(0.5))
    with pytest.raises(InputError, match='drop'):
        sp.cycles_to_drop(1.5)


def test_half_the_range_lives_two_to_the_m_times_longer():
    p = Params().replace(k_L=5e7, specimen_life=100.0)
    sp = Specimen(p)
    assert sp.cycles_to(1.0, 5e3) == pytest.approx(100.0 * 2 ** 3)
    _cycle(sp, 1000, mean=2.5e3, amp=2.5e3)
    assert sp.cycles == pytest.approx(800.0, abs=1.0)


def test_a_ripple_within_the_hysteresis_is_no_cycle():
    sp = Specimen(Params().replace(k_L=5e7))
    h = REVERSAL_FRACTION * 1e4
    for k in range(200):
        sp.update(5e3 + 0.4 * h * math.sin(k))          # ripple on a mean
    assert sp.cycles == 0 and sp.a == sp.a0
    sp.update(float('nan'))                               # a NaN is no force
    assert sp.cycles == 0
    _cycle(sp, 3)
    assert sp.cycles == pytest.approx(3.0, abs=0.5)


def test_the_life_scatters_with_the_seed_and_is_deterministic():
    p = Params().replace(k_L=5e7, specimen_scatter=0.3)
    lives = [Specimen(p.replace(specimen_seed=s)).life for s in range(20)]
    assert lives[3] == Specimen(p.replace(specimen_seed=3)).life
    assert len(set(lives)) == 20
    assert 0.1 < np.std(np.log10(lives)) < 0.6
    assert Specimen(p.replace(specimen_scatter=0.0)).life == 1e6


def test_below_its_fatigue_limit_a_specimen_runs_out_above_it_lives_as_without():
    p = Params().replace(k_L=5e7, specimen_life=400.0, specimen_fatigue_limit=6e3)
    below = Specimen(p)
    _cycle(below, 2000, mean=2.9e3, amp=2.9e3)   # 0-5.8 kN: under the 6 kN limit
    assert not below.broken and below.a == below.a0 and below.cycles == pytest.approx(2000, abs=1)
    assert below.cycles_to(1.0, 5.8e3) == math.inf and below.crack_after(1e9, 5.8e3) == below.a0
    above, free = Specimen(p), Specimen(p.replace(specimen_fatigue_limit=0.0))
    assert above.cycles_to(1.0) == free.cycles_to(1.0) == pytest.approx(400.0)
    _cycle(above, 1000)
    _cycle(free, 1000)
    assert above.broken and above.cycles == free.cycles
    # the threshold is the stress intensity's: it falls as the crack grows, so a crack grown
    # at 10 kN goes on growing at a range that would not have started it
    grown = Specimen(p)
    _cycle(grown, 200)
    a = grown.a
    assert a > 2 * grown.a0 and 6e3 * math.sqrt(grown.a0 / a) < 5.8e3
    _cycle(grown, 50, amp=2.9e3)
    assert grown.a > a


def test_the_fatigue_limit_scatters_with_the_seed_and_leaves_the_life_draw_alone():
    p = Params().replace(k_L=5e7, specimen_scatter=0.3, specimen_fatigue_limit=6e3,
                         specimen_limit_scatter=0.1)
    limits = [Specimen(p.replace(specimen_seed=s)).limit for s in range(20)]
    assert limits[4] == Specimen(p.replace(specimen_seed=4)).limit and len(set(limits)) == 20
    assert 0.03 < np.std(np.log10(limits)) < 0.2
    assert [Specimen(p.replace(specimen_seed=s)).life for s in range(5)] == \
        [Specimen(p.replace(specimen_seed=s, specimen_fatigue_limit=0.0)).life for s in range(5)]
    assert Specimen(p.replace(specimen_limit_scatter=0.0)).limit == 6e3


def _loaded_axis(**changes) -> SimulatedAxis:
    p = Params().replace(k_L=5e6, **changes)
    return SimulatedAxis(p, 'simplified', rate_hz=1000.0, lockstep=True)


def _hold(a: SimulatedAxis, z_ref, n: int, kp: float = 2.0) -> list:
    """Close a P loop on position for ``n`` periods (``z_ref(t)``); return the samples."""
    out = []
    for k in range(n):
        s = a.sample()
        out.append(s)
        i = kp * (z_ref(k * a.dt) - s.state.z)
        a.command(a.stamp_ns(), i, 0.0)
    return out


def test_the_load_cell_reads_the_specimen_force_in_the_state_and_its_own_message():
    a = _loaded_axis(z_L=-0.001)
    s = _hold(a, lambda t: 0.001, 600)[-1]
    k = a.specimen.stiffness
    assert s.load == pytest.approx(k * (s.state.z + 0.001) + 0.0, rel=1e-9)
    assert s.state.load == s.load and s.load == pytest.approx(1e4, rel=0.05)
    msg = a.load(s)
    assert (msg.stamp_ns, msg.force) == (s.state.stamp_ns, s.load)
    # no specimen: the load cell reads 0 N and the state carries no load
    free = SimulatedAxis(Params(), rate_hz=1000.0, lockstep=True).sample()
    assert free.load == 0.0 and math.isnan(free.state.load)


def test_load_cell_noise_has_its_own_stream():
    def run(noise):
        a = _loaded_axis(load_cell_noise=noise)
        a._noise = (1e-6, 0.0, 0.0)
        samples = _hold(a, lambda t: 0.001, 100)
        return [(s.state.z, s.load - a.specimen.stiffness * (s.state.z - 0.0)) for s in samples]
    quiet, noisy = run(0.0), run(50.0)
    assert [z for z, _ in quiet] != [] and len(quiet) == len(noisy)
    # the position's noise and the loop's path are the same with or without load noise...
    # (the loop closes on the noisy position: it is the same draw in both runs)
    assert [z for z, _ in quiet] == [z for z, _ in noisy]
    e = np.array([f for _, f in noisy[1:]]) - np.array([f for _, f in quiet[1:]])
    assert 25 < e.std() < 100                  # ...and the load cell's noise is as set
    assert run(50.0) == noisy                  # deterministic


def test_the_specimen_breaks_in_the_loop_at_a_peak_and_is_noted_once():
    # a constant stiffness (no compliance growth): the force range stays as the loop sets it
    a = _loaded_axis(specimen_life=40.0, specimen_life_range=8e3, specimen_compliance=0.0)
    samples = _hold(a, lambda t: 0.001 + 0.0008 * math.sin(2 * math.pi * 5 * t), 12000)
    sp = a.specimen
    assert sp.broken and a.plant._c is not None
    broke = next(k for k, s in enumerate(samples) if s.load == 0.0 and k > 10)
    assert max(abs(s.load) for s in samples[broke - 20:broke]) > 4e3     # at a peak
    assert all(s.load == 0.0 for s in samples[broke:])                   # force path lost
    notes = [n for n in a.notes if 'fractured' in n[1]]
    assert len(notes) == 1 and notes[0][0] == 'warning'
    f = a.figures(0.0)
    assert f['specimen_broken'] and f['specimen_stiffness_n_per_m'] == 0.0
    # the life at the range the loop applied (its second cycle on), to the next peak
    steady = [s.load for s in samples[200:broke - 5]]
    life = sp.cycles_to(1.0, max(steady) - min(steady))
    assert life * 0.995 <= f['specimen_cycles'] <= life * 1.005 + 1.0


def test_a_live_parameter_change_keeps_the_crack_unless_the_specimen_changes():
    a = _loaded_axis(specimen_life=50.0, specimen_life_range=8e3)
    _hold(a, lambda t: 0.001 + 0.0008 * math.sin(2 * math.pi * 5 * t), 1000)
    crack = a.specimen.a
    assert crack > a.specimen.a0
    a.set_params(a.params.replace(F_cc=900.0))
    assert a.specimen.a == crack
    a.set_params(a.params.replace(k_L=2e6))               # a new specimen installed
    assert a.specimen.a == a.specimen.a0 and a.specimen.k0 == 2e6


@pytest.mark.parametrize('m', [2.0, 3.5])
def test_an_aged_coupon_has_the_cycles_left_that_the_original_has_after_its_cycles(m):
    """``Specimen.aged``: a plant started again mid-test installs the coupon as it was."""
    p = Params().replace(k_L=1e7, specimen_life=800.0, specimen_life_range=9000.0,
                         specimen_paris_m=m, specimen_scatter=0.2, specimen_seed=17.0)
    sp = Specimen(p)
    again = Specimen(p.replace(**sp.aged(p, 300.0, 8000.0)))
    assert again.a0 == pytest.approx(sp.crack_after(300.0, 8000.0))
    for rng in (8000.0, 9000.0):            # the same growth law at any range after it
        assert again.cycles_to(1.0, rng) == pytest.approx(
            sp.cycles_to(1.0, rng) - 300.0 * (8000.0 / rng) ** m, rel=1e-9)
    # fed through its half cycles (the plant's way), it breaks where the original would
    fresh = Specimen(p.replace(**sp.aged(p, 300.0, 9000.0)))
    _cycle(fresh, 2000, mean=4500.0, amp=4500.0)
    assert fresh.cycles == pytest.approx(sp.cycles_to(1.0, 9000.0) - 300.0, abs=1.0)
    with pytest.raises(InputError, match='fractures within 5000 cycles'):
        sp.aged(p, 5000.0, 9000.0)
