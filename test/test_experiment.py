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
"""Experiments read from bags: which current the fit replays, and on which grid."""

from dataclasses import replace

import numpy as np
import pytest
from ros_ehs.core.errors import DataError
from ros_ehs.core.identify.experiment import (experiment_from_arrays, experiments_from_series,
                                              resample, takeover_times)
from ros_ehs.data.bag import BagWriter
from ros_ehs.data.experiments import load_experiment
import ros_ehs_msgs_py as c


def test_identification_prefers_the_applied_current_over_the_command(tmp_path):
    """A watchdog zeroing shows in the applied current, not in the command topic."""
    n = 600
    applied = 0.002 * np.sin(np.arange(n) * 0.05)
    applied[300:310] = 0.0                       # the valve was zeroed here
    with BagWriter(tmp_path / 'b') as w:
        for tp in (c.STATE, c.COMMAND):
            w.add_topic('/' + tp.name, tp.msg_type, tp.qos)
        for k in range(n):
            ns = 10**9 + k * 10**6
            w.write_msg('/state', c.fill_state(c.empty_msg(c.STATE.msg_type), c.AxisState(
                ns, 0.001 * k, 0.1, 0.0, 0.0, float(applied[k]))), ns)
            w.write_msg('/servo_current', c.fill_command(
                c.empty_msg(c.COMMAND.msg_type), c.Command(ns, 0.005)), ns)
    e = load_experiment(tmp_path / 'b')
    np.testing.assert_array_equal(e.i[:-1], applied[1:])   # period k: reported at k + 1
    assert np.all(e.i[299:309] == 0.0)


P = 4e-3                  # a 250 Hz driver
RX = 0.15e-3              # its command arrives this long after the state it answers


def _jittered_cycles(n, seed=1):
    """Return a driver's cycle stamps [s]: it wakes late by up to a fifth of its period."""
    return np.arange(n) * P + np.random.default_rng(seed).uniform(0.0, 0.2 * P, n)


def test_a_delay_is_counted_along_a_drivers_jittered_cycles():
    """A command received after cycle k and applied at cycle k + 1 takes over at its stamp."""
    cycles = _jittered_cycles(400)
    tc = cycles[:-1] + RX
    on = takeover_times(tc, P - RX, cycles)
    assert np.max(np.abs(on - cycles[1:])) < 0.02 * P
    # the wall-clock delay is as far off as the jitter: what the cycles put right
    assert np.max(np.abs(tc + P - RX - cycles[1:])) > 0.1 * P
    # continuous and increasing in the delay (the delay scan's cost stays continuous)
    d = P - RX + np.linspace(-0.5, 0.5, 41) * P
    moved = np.array([takeover_times(tc[200:201], x, cycles)[0] for x in d])
    assert np.all(np.diff(moved) > 0) and np.max(np.diff(moved)) < 0.1 * P
    # uniform cycles, or none: the delay on the clock
    uniform = np.arange(400) * P
    np.testing.assert_allclose(takeover_times(tc, 0.01, uniform), tc + 0.01, atol=1e-12)
    np.testing.assert_array_equal(takeover_times(tc, 0.01, None), tc + 0.01)


def test_jittered_samples_are_resampled_by_a_spline():
    """A straight line between jittered samples errs by the curvature; a spline does not."""
    ts = _jittered_cycles(400)
    t = np.arange(400) * (ts[-1] - ts[0]) / 399 + ts[0]

    def z(x):
        return 0.02 * np.sin(2 * np.pi * 3.0 * x)

    spline = np.max(np.abs(resample(ts, z(ts), t) - z(t)))
    line = np.max(np.abs(np.interp(t, ts, z(ts)) - z(t)))
    assert spline < 0.05 * line and spline < 0.1e-6
    # repeated or too few stamps: a straight line, as np.interp
    np.testing.assert_array_equal(resample([0.0, 1.0, 1.0, 2.0, 3.0], [0, 1, 2, 3, 4], [0.5]),
                                  np.interp([0.5], [0.0, 1.0, 1.0, 2.0, 3.0], [0, 1, 2, 3, 4]))


def test_a_jittered_drivers_commands_are_averaged_as_the_valve_got_them():
    """The current of each grid period is the mean of the command the valve held in it."""
    n = 700
    cycles = _jittered_cycles(n, seed=3)
    rng = np.random.default_rng(4)
    cmd = 0.002 * rng.standard_normal(n)          # command k answers state k
    ts = np.round((1.0 + cycles) * 1e9).astype(np.int64)
    z = 0.02 * np.sin(2 * np.pi * 1.0 * cycles)
    tc = ts + int(RX * 1e9)
    (e,) = experiments_from_series('rig', ts, z, np.full(n, np.nan), commands=(tc, cmd),
                                   delay=P - RX)
    # the truth, on a 1 us grid: command k held from cycle k + 1 to cycle k + 2
    fine = np.arange(0.0, cycles[-1] - cycles[0], 1e-6)
    held = cmd[np.clip(np.searchsorted(cycles - cycles[0], fine, side='right') - 2, 0, n - 1)]
    cut = np.searchsorted(fine, e.t + (e.t0_ns - ts[0]) * 1e-9)
    truth = np.array([held[a:b].mean() for a, b in zip(cut[:-1], cut[1:])])
    inner = slice(5, n - 5)
    err = np.abs(e.i[:-1] - truth)[inner]
    wall = np.abs(replace(e, cycles=None).with_delay(e.delay).i[:-1] - truth)[inner]
    # (not exact: the arrival's fraction of its period is measured in a jittered period)
    assert np.max(err) < 0.1 * np.std(cmd) and np.max(err) < 0.1 * np.max(wall)
    assert np.max(wall) > 0.5 * np.std(cmd)


def test_a_jittered_drivers_commands_are_held_in_pieces_where_they_took_over():
    """Cut in pieces, a period's current changes where the command took over, not on average."""
    n, per = 700, 8
    cycles = _jittered_cycles(n, seed=3)
    cmd = 0.002 * np.random.default_rng(4).standard_normal(n)
    ts = np.round((1.0 + cycles) * 1e9).astype(np.int64)
    (e,) = experiments_from_series('rig', ts, 0.02 * np.sin(2 * np.pi * cycles),
                                   np.full(n, np.nan), commands=(ts + int(RX * 1e9), cmd),
                                   delay=P - RX)
    fine = np.arange(0.0, cycles[-1] - cycles[0], 1e-6)
    held = cmd[np.clip(np.searchsorted(cycles - cycles[0], fine, side='right') - 2, 0, n - 1)]
    edges = np.interp(np.arange((e.t.size - 1) * per + 1) / per, np.arange(e.t.size), e.t)
    cut = np.searchsorted(fine, edges + (e.t0_ns - ts[0]) * 1e-9)
    truth = np.array([held[a:b].mean() for a, b in zip(cut[:-1], cut[1:])])
    inner = slice(5 * per, -5 * per)
    pieces = e.held(per)
    err = np.abs(pieces - truth)[inner]
    whole = np.abs(np.repeat(e.i[:-1], per) - truth)[inner]
    # (a piece holding a takeover errs by the takeover's error, as test_a_jittered... above)
    assert np.mean(err) < 0.05 * np.mean(whole) and np.max(err) < 0.2 * np.max(whole)
    # the pieces' mean is the period's current; one piece is the period; a current the valve
    # got (no command series) is repeated
    np.testing.assert_allclose(pieces.reshape(-1, per).mean(axis=1), e.i[:-1], rtol=0,
                               atol=1e-12 * np.max(np.abs(cmd)))
    np.testing.assert_array_equal(e.held(1), e.i[:-1])
    np.testing.assert_array_equal(replace(e, commands=None).held(4), np.repeat(e.i[:-1], 4))


def test_a_missed_state_or_two_are_bridged_three_split_the_run():
    """A driver's lost states: the run goes on over one or two, on its cycles; three cut it."""
    n = 2400
    cycles = _jittered_cycles(n, seed=5)
    cmd = 0.002 * np.random.default_rng(6).standard_normal(n)

    def z(x):
        return 0.02 * np.sin(2 * np.pi * 1.0 * x)

    ts = np.round((1.0 + cycles) * 1e9).astype(np.int64)
    kept = np.ones(n, bool)
    kept[[400, 900, 901, 1700, 1701, 1702]] = False       # one, two, then three in a row
    first, second = experiments_from_series(
        'rig', ts[kept], z(cycles[kept]), np.full(kept.sum(), np.nan),
        commands=(ts + int(RX * 1e9), cmd), delay=P - RX)
    assert (first.name, second.name) == ('rig [1/2]', 'rig [2/2]') and second.after_gap
    # the first run holds every cycle up to the three missed, the missed ones on its grid
    k0 = round((first.t0_ns - ts[0]) * 1e-9 / P)          # the samples before the first command
    assert first.t.size == 1700 - k0 and second.t.size == n - 1703
    assert first.cycles.size == 1700 and abs(first.dt / P - 1.0) < 1e-3
    at = np.interp(first.t + (first.t0_ns - ts[0]) * 1e-9, cycles - cycles[0], cycles)
    assert np.max(np.abs(first.z - z(at))) < 0.2e-6         # a spline over the missed states
    # the missed cycles sit between their neighbours; the rest are the stamps
    c = first.cycles - first.cycles[0] + cycles[0]
    assert np.max(np.abs(np.delete(c - cycles[:1700], [400, 900, 901]))) < 1e-9
    assert np.max(np.abs(c - cycles[:1700])) < 0.2 * P
    # the current of each period as the valve got it, over the missed states too
    fine = np.arange(0.0, cycles[1699] - cycles[0], 1e-6)
    held = cmd[np.clip(np.searchsorted(cycles - cycles[0], fine, side='right') - 2, 0, n - 1)]
    cut = np.searchsorted(fine, first.t + (first.t0_ns - ts[0]) * 1e-9)
    truth = np.array([held[a:b].mean() for a, b in zip(cut[:-1], cut[1:])])
    err = np.abs(first.i[:-2] - truth[:-1])[5:]
    assert np.median(err) < 0.02 * np.std(cmd) and np.max(err) < 0.3 * np.std(cmd)
    # a state-rate grid without jitter (our plant's, with the current it applied): one missed
    exact = np.arange(1200) * 10**6 + 10**9
    i = 0.002 * np.sin(np.arange(1200) * 0.01)
    keep = np.arange(1200) != 600
    (e,) = experiments_from_series('own', exact[keep], z(exact[keep] * 1e-9),
                                   np.full(1199, np.nan), applied=i[keep])
    assert e.t.size == 1200 and e.dt == 1e-3 and e.cycles is None and e.commands is None
    assert abs(e.z[600] - z(1.6)) < 1e-9 and abs(e.i[599] - i[600]) < 1e-7


def test_a_value_that_is_not_finite_in_jittered_states_is_named_not_splined():
    """A NaN position among a driver's jittered states: the loader's own error, at its time."""
    n = 700
    cycles = _jittered_cycles(n, seed=3)
    ts = np.round((1.0 + cycles) * 1e9).astype(np.int64)
    z = 0.02 * np.sin(2 * np.pi * 1.0 * cycles)
    z[300] = np.nan
    cmd = (ts + int(RX * 1e9), 0.002 * np.sin(np.arange(n) / 20.0))
    with pytest.raises(DataError, match=r'rig: `z` is not finite at t = 1\.19'):
        experiments_from_series('rig', ts, z, np.full(n, np.nan), commands=cmd, delay=P - RX)
    # a pressure's or a load cell's NaN is named too, at its time: a straight line leaves it
    # where it was (a spline would spread it over the run, or fail in scipy)
    z[300] = 0.0
    p = 1e6 * (1.0 + 0.1 * np.sin(cycles))
    bad = p.copy()
    bad[300] = np.nan
    for kw, signal in [({'pressures': [(ts, p), (ts, bad)]}, 'p_b'),
                       ({'pressures': [(ts, bad)], 'load': True}, 'p_load'),
                       ({'pressures': [(ts, p), (ts, p)], 'cell': (ts, bad)}, 'load_cell')]:
        with pytest.raises(DataError, match=rf'rig: `{signal}` is not finite at t = 1\.19'):
            experiments_from_series('rig', ts, z, np.full(n, np.nan), commands=cmd,
                                    delay=P - RX, **kw)
    # and the same record without the NaN is read (the checks above name nothing else)
    (e,) = experiments_from_series('rig', ts, z, np.full(n, np.nan), commands=cmd,
                                   delay=P - RX, pressures=[(ts, p), (ts, p)], cell=(ts, p))
    assert np.all(np.isfinite(e.p_a)) and np.all(np.isfinite(e.load_cell))


def test_a_run_that_does_not_move_is_skipped_whatever_its_pressures_hold():
    """The hold before a test, its transducer dropping out: skipped as still, not an error."""
    n = 1200
    ts = 10**9 + np.arange(2 * n) * 10**6
    ts[n:] += 50 * 10**6                                   # a gap: two runs
    k = np.arange(2 * n)
    moving = k >= n
    z = np.where(moving, 0.02 * np.sin(2 * np.pi * (k - n) / 1000.0), 0.0)
    i = np.where(moving, 0.002 * np.cos(2 * np.pi * (k - n) / 1000.0), 0.0)
    p = np.full(2 * n, 1e7)
    p[300] = np.nan                                         # in the hold
    (e,) = experiments_from_series('rig', ts, z, np.full(2 * n, np.nan), applied=i,
                                   pressures=[(ts, p), (ts, p)])
    assert e.name == 'rig [2/2]' and np.all(np.isfinite(e.p_a))
    p[n + 300] = np.nan                                     # and in the moving run: named
    with pytest.raises(DataError, match=r'rig \[2/2\]: `p_a` is not finite at t = 0\.3 s'):
        experiments_from_series('rig', ts, z, np.full(2 * n, np.nan), applied=i,
                                pressures=[(ts, p), (ts, p)])


def test_an_experiment_names_a_sample_not_finite_a_misshapen_signal_and_an_irregular_grid():
    t = np.arange(1000) * 1e-3
    i = 1e-3 * np.sin(t * 6.28)
    z = 0.04 * np.sin(t * 6.28)
    v = np.gradient(z, t)
    v_nan = v.copy()
    v_nan[500] = np.nan
    with pytest.raises(DataError, match=r'x: `v` is not finite at t = 0\.5 s'):
        experiment_from_arrays('x', t, i, z, v_nan)
    p = np.full(t.shape, 1e7)
    p_inf = p.copy()
    p_inf[500] = np.inf
    with pytest.raises(DataError, match=r'x: `p_a` is not finite at t = 0\.5 s'):
        experiment_from_arrays('x', t, i, z, v, p_inf, p)
    with pytest.raises(DataError, match=r'x: `p_b` has shape \(999,\), `t` has \(1000,\)'):
        experiment_from_arrays('x', t, i, z, v, p, p[1:])
    t_gap = t.copy()
    t_gap[600:] += 0.05
    with pytest.raises(DataError, match='not on a uniform grid'):
        experiment_from_arrays('x', t_gap, i, z, v)
    e = experiment_from_arrays('x', t, i, z, v, p, p)
    assert e.dt == pytest.approx(1e-3) and e.p_a is not None and e.p_b is not None
