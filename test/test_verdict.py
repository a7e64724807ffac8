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
The verdict of a fit, rule by rule (``ros_ehs.core.identify.verdict``), and end to end.

End to end on a bag a ros2_control driver would record of a rig that is not the fitted model,
written by rosbags.
"""

import copy
from dataclasses import replace
import json
import math
from pathlib import Path
import warnings

import numpy as np
import pytest
from ros_ehs.core.errors import DataError, IdentificationWarning
from ros_ehs.core.identify import identify
from ros_ehs.core.identify.experiment import experiment_from_arrays, state_rate
from ros_ehs.core.identify.problem import SIGNALS
from ros_ehs.core.identify.verdict import (added_residual, adequacy, AGREEMENT, halves,
                                           jackknife, JACKKNIFE_LIMIT, judged_on_jackknife,
                                           judged_rate, LEAD_IN, leave_one_out,
                                           median_noise_ratios, MIN_RATE_HZ, PREDICTION_LIMIT,
                                           PREDICTION_RATIO, QUARTERS, RESTART, restart,
                                           RULES, SENSED_LIMIT, SETTLE_ITERATIONS, SETTLED,
                                           settled, SLOW_RATE_HZ, spread, why_adequate)
from ros_ehs.core.params import preset

FIVE = ('d_c', 'F_cc', 'F_sc', 'l_iac', 'c_c')


def _run(name, n, t0=0.0):
    t = t0 + np.arange(n) * 1e-3
    w = 2 * np.pi
    return experiment_from_arrays(name, t, 1e-3 * np.cos(w * t), 0.01 * np.sin(w * t),
                                  0.01 * w * np.cos(w * t))


# -- the halves ----------------------------------------------------------------------------------
def test_halves_take_alternate_quarters_of_a_single_run_each_after_a_cut_mid_motion():
    e = _run('a', 1001)
    first, second = halves([e])
    lead = round(LEAD_IN / 1e-3)
    assert QUARTERS == 4 and lead == 200
    # each piece after a cut is replayed from LEAD_IN before it, its warm-up not compared
    assert [x.name for x in first] == ['a[0:250]', 'a[300:750]']
    assert [x.name for x in second] == ['a[50:500]', 'a[550:1001]']
    assert [x.warmup for x in first] == [0, lead] and [x.warmup for x in second] == [lead] * 2
    assert first[0].t[0] == 0.0 and second[0].t[0] == 0.0        # each on its own clock
    assert second[0].z[lead] == e.z[250] and second[0].t0_ns == e.t0_ns + 50_000_000
    assert not first[0].after_gap and all(x.after_gap for x in first[1:] + second)
    # the compared samples are the quarters
    assert [sum(x.t.size - x.warmup for x in h) for h in (first, second)] == [500, 501]


def test_halves_keep_whole_runs_and_cut_only_those_holding_a_quarter():
    runs = [_run('a', 600), _run('b', 600), _run('c', 600)]
    first, second = halves(runs)
    # a lead-in goes back at most to its run's start (150 samples in c)
    assert [(x.name, x.warmup) for x in first] == [('a[0:450]', 0), ('b[100:600]', 200),
                                                   ('c[0:150]', 0)]
    assert [(x.name, x.warmup) for x in second] == [('a[250:600]', 200), ('b[0:300]', 0),
                                                    ('c[0:600]', 150)]
    assert sum(x.t.size - x.warmup for x in first) == \
        sum(x.t.size - x.warmup for x in second) == 900
    first, second = halves([_run(k, 500) for k in 'abcd'])
    assert [x.name for x in first] == ['a', 'c'] and [x.name for x in second] == ['b', 'd']
    assert not any(x.after_gap or x.warmup for x in first + second)


def test_the_record_without_each_quarter_joins_the_quarters_around_the_gap():
    e = _run('a', 1000)
    parts = leave_one_out([e])
    lead = round(LEAD_IN / 1e-3)
    assert len(parts) == QUARTERS
    assert [[(x.name, x.warmup) for x in p] for p in parts] == [
        [('a[50:1000]', lead)],                          # after the gap, from its lead-in
        [('a[0:250]', 0), ('a[300:1000]', lead)],
        [('a[0:500]', 0), ('a[550:1000]', lead)],
        [('a[0:750]', 0)]]                               # from the run's start: no lead-in
    assert all(sum(x.t.size - x.warmup for x in p) == 750 for p in parts)
    # whole runs stay whole; only a run holding an edge of the gap is cut
    parts = leave_one_out([_run(k, 500) for k in 'abcd'])
    assert [[x.name for x in p] for p in parts] == [
        ['b', 'c', 'd'], ['a', 'c', 'd'], ['a', 'b', 'd'], ['a', 'b', 'c']]


def test_the_jackknife_is_the_spread_of_the_refits_without_each_quarter():
    values = [{'F_cc': v, 'r_c': 1.0} for v in (1.0, 1.0, 1.0, 1.4)]
    got = jackknife(values, {'F_cc': 1.1, 'r_c': 0.0})
    # sqrt((K - 1) / K * sum((v - mean)^2)) over the whole value: sqrt(0.75 * 0.12) / 1.1
    assert got['stderr']['F_cc'] == pytest.approx(0.3 / 1.1)
    assert got['stderr']['r_c'] == float('inf')             # a whole value of 0
    assert got['values'] == values and got['values'][0] is not values[0]


def test_a_piece_cut_mid_motion_reaches_its_cut_with_the_pressures_its_lead_in_carried():
    """
    Without pressure sensors a replay carries the pressures open-loop from its start.

    Started at the cut, a piece of the reduced model's own record, replayed at the truth,
    begins from the equilibrium guess and its velocity is off by mm/s (5 mm/s RMS over its
    first 50 ms); replayed from its lead-in, the pressures reach the cut as the model carried
    them, and the piece replays as its record (0.01 mm/s). The lead-in is not compared.
    """
    from ros_ehs.core.identify.problem import Problem
    from ros_ehs.core.model import Plant
    truth, dt, sub = preset('table1_estimated'), 1e-3, 10
    t = np.arange(2001) * dt
    i = 0.006 * np.sin(2 * np.pi * 2 * t)
    rig = Plant(truth, 'reduced', h=dt / sub)
    x = rig.simulate(dt / sub, np.repeat(i[:-1], sub)).x[::sub]
    z, v = (x[:, rig.state_names.index(n)] for n in ('z', 'z_dot'))
    e = experiment_from_arrays('rig', t, i, z, v)
    _, (piece, _) = halves([e])              # the second quarter, after the cut at 500
    assert piece.warmup == round(LEAD_IN / dt) and piece.z[piece.warmup] == z[500]

    def first_velocity_residual(ex):
        p = Problem([ex], truth, ('c_c',), 'reduced', ('z_dot', 'z'), 1.0, None)
        r = p.residual_parts(np.array([truth['c_c']]) / p.scale)[0]
        assert r.shape[0] == ex.t.size - ex.warmup       # the lead-in is not compared
        return float(np.sqrt(np.mean(r[:50, 0] ** 2))) * p.exps[0].sigma[0]

    led = first_velocity_residual(piece)
    guessed = first_velocity_residual(e.window(500, 1000))
    assert guessed > 1e-3 and led < 0.01 * guessed, (led, guessed)


def test_a_window_of_a_run_is_refused_when_it_holds_fewer_than_two_samples():
    with pytest.raises(DataError, match=r'a: samples 5:6 of 600 are not a run'):
        _run('a', 600).window(5, 6)


def test_a_window_keeps_what_is_left_of_a_warm_up_and_a_problem_refuses_one_too_long():
    from dataclasses import replace

    from ros_ehs.core.identify.problem import Problem
    e = replace(_run('a', 600), warmup=100)
    assert e.window(40, 600).warmup == 60 and e.window(100, 600).warmup == 0
    truth = preset('table1_estimated')
    Problem([replace(e, warmup=598)], truth, ('c_c',), 'reduced', SIGNALS, 1.0, None)
    with pytest.raises(DataError, match=r'a: a warm-up of 599 samples leaves fewer than 2 of '
                                        r'600 to compare'):
        Problem([replace(e, warmup=599)], truth, ('c_c',), 'reduced', SIGNALS, 1.0, None)
    with pytest.raises(DataError, match=r'a: `warmup` = -1 samples must be >= 0'):
        Problem([replace(e, warmup=-1)], truth, ('c_c',), 'reduced', SIGNALS, 1.0, None)


def test_a_window_moves_the_command_series_onto_its_own_clock():
    e = _run('a', 600)
    from dataclasses import replace
    e = replace(e, commands=(np.array([0.02, 0.05]), np.array([1e-3, 2e-3])), delay=0.0)
    w = e.window(40, 600)
    assert np.allclose(w.commands[0], [-0.02, 0.01]) and w.t[0] == 0.0


# -- the rules, as data --------------------------------------------------------------------------
def _check(prediction=None, disagreement=None, ratio=None):
    prediction = prediction or {'z_dot': 0.001, 'z': 0.3}
    ratio = ratio or dict.fromkeys(prediction, 1.0)
    free = ('d_c', 'r_c', 'F_cc')
    disagreement = dict.fromkeys(free, 0.01) | (disagreement or {})
    return {'prediction': prediction, 'prediction_ratio': ratio,
            'judged': [n for n in prediction if n != 'z'],
            'halves': [{'values': dict.fromkeys(free, 1.0), 'samples': 500, 'runs': 1},
                       {'values': dict.fromkeys(free, 1.1), 'samples': 500, 'runs': 1}],
            'joint': dict.fromkeys(free, 1.05), 'disagreement': disagreement}


def _metrics(**ratios):
    ratios = {'z_dot': 9.0, 'z': 30.0, **ratios}
    return {'run': {n: {'noise_ratio': r} for n, r in ratios.items()}}


def test_a_fit_that_predicts_held_out_data_and_whose_halves_agree_is_adequate():
    """Position and velocity far above their noise do not count: drift and a fine encoder."""
    why, advice, failed = adequacy(1, 100, 'reduced', '', _check(), _metrics())
    assert why == [] and advice == [] and failed == []


def test_a_sensed_signal_whose_residual_ratio_has_no_value_fails_its_rule():
    """A NaN ratio (a noise with no value) is not under the limit: the rule fails, named."""
    why, _, failed = adequacy(1, 100, 'simplified', '', _check(),
                              _metrics(p_CP=math.nan, p_CT=1.0))
    assert failed == ['sensed:p_CP'] and 'p_CP residual is nanx' in why[0], why


def test_the_noise_of_a_signal_with_a_repeated_sample_time_is_refused_by_name():
    from ros_ehs.core.noise import noise_sigma
    t = np.arange(100) * 1e-3
    y = np.random.default_rng(0).normal(0.0, 1.0, 100)
    assert noise_sigma(y, t) == pytest.approx(1.0, rel=0.3)
    t[50] = t[49]                                            # a resend, not deduplicated
    with pytest.raises(DataError, match=r'sample times must increase: sample 50 at 0.049'):
        noise_sigma(y, t)


def test_a_fit_that_does_not_predict_the_other_half_is_not_adequate_and_names_the_model():
    why, advice, failed = adequacy(1, 100, 'simplified', '',
                                   _check(prediction={'z_dot': PREDICTION_LIMIT + 0.001,
                                                      'z': 0.0},
                                          ratio={'z_dot': PREDICTION_RATIO + 0.01, 'z': 1.0}),
                                   _metrics())
    assert len(why) == 1 and failed == ['prediction:z_dot']
    assert (f"leaves a z_dot residual {PREDICTION_RATIO + 0.01:.2f}x its own fit's, adding "
            f"{100 * PREDICTION_LIMIT + 0.1:.1f} % of the signal's spread (medians of the "
            f'replay segments; limits {PREDICTION_RATIO:g}x and {100 * PREDICTION_LIMIT:g} %)'
            in why[0]), why
    assert any('--model reduced' in a for a in advice)
    _, advice, _ = adequacy(1, 100, 'reduced', '', _check(prediction={'z_dot': 0.2},
                                                          ratio={'z_dot': 2.0}), _metrics())
    assert any('--model full' in a for a in advice)


@pytest.mark.parametrize('added, ratio, flagged', [
    (0.003, 1.4, False),     # a close fit predicted 1.4x worse: 0.3 % of the signal added
    (0.05, 1.03, False),     # a loose fit (own 20 % of the signal) 1.03x worse: 5 % added
    (0.05, 1.4, True),       # both: the other half's values predict it worse, and it matters
])
def test_a_prediction_fails_only_when_it_is_both_noticeably_and_materially_worse(added, ratio,
                                                                                 flagged):
    _, _, failed = adequacy(1, 100, 'reduced', '',
                            _check(prediction={'z_dot': added}, ratio={'z_dot': ratio}),
                            _metrics())
    assert (failed == ['prediction:z_dot']) is flagged


def test_an_adequate_fit_says_how_well_it_predicts_the_other_half_and_how_the_halves_agree():
    check = _check(prediction={'z_dot': 0.004, 'p_CP': 0.002, 'z': 0.5},
                   ratio={'z_dot': 1.08, 'p_CP': 1.3, 'z': 4.0},
                   disagreement={'F_cc': 0.031, 'r_c': 0.4})
    assert why_adequate(check) == ('held out: predicts the other half within 0.4 % of the '
                                   'signal, 1.08x its own fit (z_dot); halves agree within '
                                   '3.1 % (F_cc)')


def test_the_position_is_reported_but_not_judged_on_held_out_data():
    why, _, _ = adequacy(1, 100, 'reduced', '', _check(prediction={'z_dot': 0.0, 'z': 0.9}),
                         _metrics())
    assert why == []


def test_the_added_residual_is_what_the_other_values_add_in_quadrature_to_the_own_fit():
    """A close own fit that the other half's values predict 1.4x worse adds little."""
    # own 0.3 % of the signal, other 0.42 %: 1.4x, adds 0.29 % (a good fit of a clean record)
    assert added_residual(0.003, 0.0042) == pytest.approx(0.00294, rel=1e-3)
    assert added_residual(0.003, 0.0042) < PREDICTION_LIMIT
    # own 10 % of the signal (a model error), other 11 %: only 1.1x, yet adds 4.6 %
    assert added_residual(0.10, 0.11) == pytest.approx(0.0458, rel=1e-3)
    assert added_residual(0.10, 0.11) > PREDICTION_LIMIT
    # the other values fit as well or better: nothing added
    assert added_residual(0.05, 0.04) == 0.0
    assert added_residual(0.05, float('nan')) == float('inf')


def test_the_spread_counts_halves_that_agree_with_each_other_but_not_with_the_whole():
    assert spread(1.0, 1.1, 1.05) == pytest.approx(0.1 / 1.05)
    assert spread(0.89, 0.90, 1.0) == pytest.approx(0.11)      # both 10 % below the whole
    assert spread(1.0, 1.0, 0.0) == float('inf')


def test_halves_that_disagree_beyond_the_limit_and_their_errors_name_the_parameter():
    why, advice, failed = adequacy(1, 100, 'reduced', '',
                                   _check(disagreement={'F_cc': AGREEMENT + 0.01}), _metrics())
    assert len(why) == 1 and (f'give F_cc = 1 and 1.1, the whole 1.05: '
                              f'{100 * AGREEMENT + 1:.1f} % apart (limit {100 * AGREEMENT:g} %)'
                              in why[0]), why
    assert failed == ['agreement:F_cc']
    assert any('record the chamber pressures' in a for a in advice)   # friction, no pressures
    assert any('each half of the record shows F_cc' in a for a in advice)
    # with pressures recorded, the advice is more excitation only
    _, advice, _ = adequacy(1, 100, 'reduced', '', _check(disagreement={'F_cc': AGREEMENT + 0.01}),
                            _metrics(p_CP=1.0, p_CT=1.0))
    assert not any('pressures' in a for a in advice)


def test_the_valves_null_shape_is_not_judged_by_the_halves_agreement():
    why, _, _ = adequacy(1, 100, 'reduced', '', _check(disagreement={'r_c': 0.9}), _metrics())
    assert why == []


def _halves(monkeypatch, errors):
    """
    Return the held-out check of two halves whose replays' segment errors ``errors`` gives.

    ``errors(half, own)``: that half's per-segment errors {signal: array} replayed with its
    own values (``own``) or with the other half's. Returns the check and the replays asked
    for, as (the half's experiments, the values replayed).
    """
    from types import SimpleNamespace

    from ros_ehs.core.identify import verdict
    base = preset('table1_estimated')
    free = ('F_cc', 'r_c', 'x_bias')
    fits = [base.replace(F_cc=base['F_cc'] * f, r_c=base['r_c'] * g, x_bias=b)
            for f, g, b in ((1.0, 1.0, 1e-8), (1.02, 0.06, -2e-8))]
    refits = [SimpleNamespace(params=p, x=p.subset(free)) for p in fits]
    parts = [[SimpleNamespace(t=np.zeros(n), warmup=0)] for n in (600, 700)]
    replayed = []

    def problem_of(exps, params):
        replayed.append((exps, params.subset(free)))
        half = next(i for i, p in enumerate(parts) if p is exps)
        return SimpleNamespace(free=free, scale=np.ones(len(free)), half=half,
                               own=params.subset(free) == fits[half].subset(free))

    monkeypatch.setattr(verdict, 'segment_errors',
                        lambda problem, theta: {'run': errors(problem.half, problem.own)})
    check = verdict.halves_check(parts, refits, fits[0].subset(free), problem_of)
    return check, replayed, parts, fits, free


def test_each_half_is_predicted_with_the_other_halves_values_and_its_own_null_shape(
        monkeypatch):
    """A half's r_c far off (few samples near the null) does not fail the other's prediction."""
    check, replayed, parts, fits, free = _halves(
        monkeypatch, lambda half, own: {'z_dot': np.array([0.01])})
    assert replayed == [(parts[0], fits[0].subset(free)),
                        (parts[0], {**fits[0].subset(free), 'F_cc': fits[1]['F_cc']}),
                        (parts[1], fits[1].subset(free)),
                        (parts[1], {**fits[1].subset(free), 'F_cc': fits[0]['F_cc']})]
    assert check['prediction'] == {'z_dot': 0.0}
    # the null shape the halves disagree on is reported, not judged
    assert check['disagreement']['r_c'] > AGREEMENT
    assert adequacy(1, 100, 'reduced', '', check, _metrics()) == ([], [], [])


def test_the_prediction_is_judged_per_replay_segment_not_per_run(monkeypatch):
    """
    One segment far worse (a breakaway from rest moved by a hair of F_sc) does not fail it.

    Rig 45 of the verdict benchmark (250 Hz, pressures, from rest): a half's replay with the
    other half's values, 1.7 % apart on F_sc, was 16x worse in its first segment and 0.8-1.0x
    in the others: 8.6x its own fit over the run. Values that replay most segments worse fail.
    """
    def one_bad_segment(half, own):
        return {'z_dot': np.array([0.01, 0.01, 0.01] if own else [0.16, 0.008, 0.0099])}

    check, *_ = _halves(monkeypatch, one_bad_segment)
    assert check['prediction']['z_dot'] == 0.0
    assert check['prediction_ratio']['z_dot'] == pytest.approx(0.99)
    assert adequacy(1, 100, 'reduced', '', check, _metrics())[2] == []

    def most_segments_worse(half, own):
        return {'z_dot': np.array([0.01, 0.01, 0.01] if own else [0.02, 0.018, 0.009])}

    check, *_ = _halves(monkeypatch, most_segments_worse)
    assert check['prediction_ratio']['z_dot'] == pytest.approx(1.8)
    assert check['prediction']['z_dot'] == pytest.approx(math.sqrt(0.018 ** 2 - 0.01 ** 2))
    assert adequacy(1, 100, 'reduced', '', check, _metrics())[2] == ['prediction:z_dot']

    # a segment with nothing compared (a derived velocity's segment shorter than its filter)
    # does not count; one the other values do not replay (NaN) counts as infinitely worse
    check, *_ = _halves(monkeypatch, lambda half, own: {
        'z_dot': np.array([0.01, 0.0, 0.01, 0.01] if own else [0.01, 0.0, math.nan, 0.01])})
    assert check['prediction'] == {'z_dot': 0.0} and check['prediction_ratio'] == {'z_dot': 1.0}
    check, *_ = _halves(monkeypatch, lambda half, own: {
        'z_dot': np.array([0.01, 0.0, 0.01] if own else [0.01, 0.0, math.nan])})
    assert check['prediction'] == {'z_dot': math.inf}
    assert adequacy(1, 100, 'reduced', '', check, _metrics())[2] == ['prediction:z_dot']


def test_a_pressure_residual_beyond_its_sensors_noise_is_a_model_error():
    why, advice, failed = adequacy(1, 100, 'simplified', '', _check(),
                                   _metrics(p_CP=SENSED_LIMIT + 0.5, p_CT=1.0))
    assert len(why) == 1 and 'p_CP residual is 2.5x its sensor noise' in why[0]
    assert failed == ['sensed:p_CP']
    assert any('--model reduced' in a for a in advice)
    # the median of the runs: one run's start does not decide
    m = {'a': {'p_CP': {'noise_ratio': 9.0}}, 'b': {'p_CP': {'noise_ratio': 1.0}},
         'c': {'p_CP': {'noise_ratio': 1.2}}}
    assert adequacy(1, 100, 'reduced', '', _check(), m)[0] == []


def test_an_invalid_set_and_a_stop_at_the_limit_are_not_adequate_without_a_check():
    why, advice, failed = adequacy(0, 7, 'reduced', 'F_cc above F_sc', None, _metrics())
    assert any('evaluation limit (max_nfev = 7)' in w for w in why)
    assert any('not a valid parameter set (F_cc above F_sc)' in w for w in why)
    assert failed == ['solver', 'invalid']
    assert any('max_nfev' in a for a in advice)


def _spread_of(**stderr):
    stderr = {'d_c': 0.01, 'r_c': 0.9, 'F_cc': 0.01, **stderr}
    return {'stderr': stderr, 'values': [dict.fromkeys(stderr, 1.0 + 0.01 * k)
                                         for k in range(QUARTERS)]}


def test_each_reason_comes_with_the_rule_it_failed_in_its_order():
    check = _check(prediction={'z_dot': 0.2, 'p_CP': 0.2}, ratio={'z_dot': 2.0, 'p_CP': 2.0},
                   disagreement={'F_cc': 0.5, 'd_c': 0.5, 'r_c': 0.9})
    why, _, failed = adequacy(0, 7, 'reduced', 'F_cc above F_sc', check,
                              _metrics(p_CP=SENSED_LIMIT + 1.0, p_CT=1.0),
                              rate_hz=0.5 * MIN_RATE_HZ, spread_of=_spread_of(F_cc=0.5, d_c=0.5))
    assert failed == ['rate', 'solver', 'invalid', 'sensed:p_CP', 'prediction:z_dot',
                      'prediction:p_CP', 'jackknife:d_c', 'jackknife:F_cc']
    assert len(why) == len(failed)
    assert {f.split(':')[0] for f in failed} <= set(RULES)
    assert 'p_CP' in why[3] and 'z_dot' in why[4] and 'd_c' in why[6] and 'F_cc' in why[7]


def test_a_slow_record_without_pressures_is_judged_on_its_jackknife_not_its_halves():
    """Below SLOW_RATE_HZ without pressures the jackknife is read, the halves' agreement not."""
    assert MIN_RATE_HZ < SLOW_RATE_HZ and judged_on_jackknife(MIN_RATE_HZ)
    apart = _check(disagreement={'F_cc': 2 * AGREEMENT, 'r_c': 0.9})
    over = _spread_of(F_cc=2 * JACKKNIFE_LIMIT)
    why, advice, failed = adequacy(1, 100, 'reduced', '', apart, _metrics(),
                                   rate_hz=MIN_RATE_HZ, spread_of=over)
    assert failed == ['jackknife:F_cc']
    assert 'F_cc = 1 to 1.03, the whole 1.05: a standard error of ' \
        f'{200 * JACKKNIFE_LIMIT:.1f} % (jackknife; limit {100 * JACKKNIFE_LIMIT:g} %, ' \
        f'states at {MIN_RATE_HZ:.0f} Hz without pressures)' in why[0], why
    assert any('record the chamber pressures' in a and f'or the states at {SLOW_RATE_HZ:.0f} '
               'Hz or faster' in a for a in advice), advice
    assert any('each quarter of the record shows F_cc' in a for a in advice), advice
    # halves far apart do not fail a slow record whose jackknife is within its limit; the
    # null shape is not judged, and a standard error that is not a number fails
    assert adequacy(1, 100, 'reduced', '', apart, _metrics(), rate_hz=MIN_RATE_HZ,
                    spread_of=_spread_of(F_cc=0.9 * JACKKNIFE_LIMIT)) == ([], [], [])
    assert adequacy(1, 100, 'reduced', '', apart, _metrics(), rate_hz=MIN_RATE_HZ,
                    spread_of=_spread_of(F_cc=math.nan))[2] == ['jackknife:F_cc']
    # a slow record with a held-out check must bring its jackknife
    with pytest.raises(ValueError, match='judged on its jackknife: pass `spread_of`'):
        adequacy(1, 100, 'reduced', '', apart, _metrics(), rate_hz=MIN_RATE_HZ)


def test_a_faster_record_or_one_with_pressures_is_judged_on_its_halves():
    assert not judged_on_jackknife(0.99 * SLOW_RATE_HZ)     # a driver's period a hair off
    apart = _check(disagreement={'F_cc': 2 * AGREEMENT})
    for rate in (0.99 * SLOW_RATE_HZ, 2 * SLOW_RATE_HZ, math.inf):
        assert not judged_on_jackknife(rate)
        _, advice, failed = adequacy(1, 100, 'reduced', '', apart, _metrics(), rate_hz=rate,
                                     spread_of=_spread_of())
        assert failed == ['agreement:F_cc']
        # ... and is not told to record faster
        assert any('record the chamber pressures' in a for a in advice), advice
        assert not any('Hz or faster' in a for a in advice), advice
        assert adequacy(1, 100, 'reduced', '', _check(), _metrics(), rate_hz=rate,
                        spread_of=_spread_of(F_cc=2 * JACKKNIFE_LIMIT)) == ([], [], [])


def test_an_adequate_slow_record_says_its_jackknife_not_its_halves():
    why = why_adequate(_check(disagreement={'F_cc': 0.3}), _spread_of(F_cc=0.021))
    assert why.endswith('standard errors within 2.1 % (F_cc, jackknife)'), why
    assert 'halves agree' not in why


def test_halves_that_both_leave_the_whole_for_one_side_say_where_to_refit_it():
    whole = {'F_cc': 1000.0, 'F_sc': 2000.0, 'r_c': 1e-6}
    apart = 1000.0 * (1 + 1.2 * RESTART)
    assert restart({**whole, 'F_cc': apart + 10}, {**whole, 'F_cc': apart - 10},
                   whole) == pytest.approx({**whole, 'F_cc': apart})
    # halves on either side of the whole, or near it, say nothing; nor does the null shape
    assert restart({**whole, 'F_cc': 1100.0}, {**whole, 'F_cc': 900.0}, whole) is None
    near = 1000.0 * (1 + 0.8 * RESTART)
    assert restart({**whole, 'F_cc': near}, {**whole, 'F_cc': near}, whole) is None
    assert restart({**whole, 'r_c': 3e-6}, {**whole, 'r_c': 3e-6}, whole) is None


def test_a_record_slower_than_the_verdicts_rate_is_not_adequate_and_says_to_record_faster():
    slow = 0.5 * MIN_RATE_HZ
    why, advice, failed = adequacy(1, 100, 'reduced', '', None, _metrics(), rate_hz=slow)
    assert any(f'recorded at {slow:.0f} Hz, below {MIN_RATE_HZ:.0f} Hz' in w and 'F_sc' in w
               for w in why), why
    assert any(f'{MIN_RATE_HZ:.0f} Hz or faster' in a for a in advice), advice
    assert failed == ['rate']
    # a driver's mean period a little off its nominal rate is that rate
    assert adequacy(1, 100, 'reduced', '', None, _metrics(),
                    rate_hz=0.999 * MIN_RATE_HZ) == ([], [], [])
    # the rate judged is the slowest run's: one slow run in a fast record is enough
    s = np.sin(np.arange(600) / 30.0)
    runs = [experiment_from_arrays(f'r{k}', np.arange(600) / rate, 0.01 * s, 0.02 * s, s)
            for k, rate in enumerate((2000.0, 250.0))]
    assert state_rate(runs) == pytest.approx(250.0)
    assert judged_rate(runs, SIGNALS) == pytest.approx(250.0)


def test_the_rate_is_judged_on_the_runs_fitted_without_pressures():
    """A run whose replay restarts from measured pressures is judged at any rate."""
    s = np.sin(np.arange(600) / 30.0)
    p = 1e6 * (1.0 + 0.1 * s)

    def run(rate, **kw):
        return experiment_from_arrays(f'r{rate:g}', np.arange(600) / rate, 0.01 * s, 0.02 * s,
                                      s, **kw)

    slow_p = run(250.0, p_a=p, p_b=p)
    fast = run(2000.0)
    assert judged_rate([slow_p], SIGNALS) == math.inf
    assert judged_rate([slow_p, fast], SIGNALS) == pytest.approx(2000.0)
    # pressures the fit does not use do not count; nor does one chamber
    assert judged_rate([slow_p], ('z_dot', 'z')) == pytest.approx(250.0)
    assert judged_rate([run(250.0, p_a=p)], SIGNALS) == pytest.approx(250.0)
    # a load pressure counts where p_L is fitted
    load = replace(run(250.0), p_load=p)
    assert judged_rate([load], SIGNALS) == math.inf
    assert judged_rate([load], ('z_dot', 'z', 'p_CP', 'p_CT')) == pytest.approx(250.0)


def _history(moves: dict, n: int = SETTLE_ITERATIONS + 1) -> list:
    """Return ``n`` iterations of a history in which each value moves ``moves[name]`` in all."""
    return [{'x': {k: 1.0 + v * j / (n - 1) for k, v in moves.items()}} for j in range(n)]


def test_a_stop_at_the_limit_with_settled_values_is_converged():
    se = {'F_cc': 10.0, 'r_c': 1e-7}
    assert settled(_history({'F_cc': 0.9 * SETTLED * 10.0, 'r_c': 0.0}), se)
    assert not settled(_history({'F_cc': 1.1 * SETTLED * 10.0, 'r_c': 0.0}), se)
    # the moves of the last SETTLE_ITERATIONS count, not those before them
    early = _history({'F_cc': 0.0, 'r_c': 0.0}, SETTLE_ITERATIONS + 1)
    assert settled([{'x': {'F_cc': -50.0, 'r_c': 1.0}}] + early, se)
    assert not settled(early[1:], se)                         # too few iterations to tell
    # a value without a finite standard error must not move at all
    assert settled(_history({'F_cc': 0.0, 'r_c': 0.0}), {'F_cc': math.inf, 'r_c': math.nan})
    assert not settled(_history({'F_cc': 1e-9, 'r_c': 0.0}), {'F_cc': math.inf, 'r_c': 1.0})
    why, _, _ = adequacy(0, 100, 'reduced', '', None, _metrics(), is_settled=True)
    assert not any('evaluation limit' in w for w in why)
    why, _, _ = adequacy(0, 100, 'reduced', '', None, _metrics())
    assert any('evaluation limit (max_nfev = 100)' in w for w in why)


# -- end to end ----------------------------------------------------------------------------------
@pytest.fixture(scope='module')
def driver_bag(tmp_path_factory):
    """Record the full model away from Table 1 as a ros2_control driver would (rosbags)."""
    from ros_ehs.data.experiments import load_experiments
    from ros_ehs.data.rig_bag import record_rig_bag, RigLayout
    base = preset('table1_estimated')
    truth = base.replace(d_c=base['d_c'] * 1.15, F_cc=base['F_cc'] * 0.8,
                         F_sc=base['F_sc'] * 1.2, l_iac=base['l_iac'] * 1.1,
                         c_c=base['c_c'] * 0.85)
    # 2 kHz JointState position only, a 1 um encoder with 2 um noise, 20 us jitter, 0.2 %
    # of the states lost, Float64MultiArray commands, pressures at 1 kHz
    lay = RigLayout(rate_hz=2000.0, quantum_z=1e-6, noise_z=2e-6, jitter=0.04, lost=16,
                    pressure_rate_hz=1000.0)
    path = tmp_path_factory.mktemp('driver') / 'rig'
    rec = record_rig_bag(path, lay, plant_params=truth, duration=4.0, seed=5)
    return load_experiments(path, topics=lay.topic_map(rec['input_delay'])), truth


def test_a_good_reduced_fit_of_a_drivers_bag_is_adequate(driver_bag):
    """The issue's case: a driver's bag of a rig away from Table 1, the values right."""
    runs, truth = driver_bag
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)
        r = identify(runs, model='reduced')
    err = {n: r.x[n] / truth[n] - 1.0 for n in FIVE}
    assert max(abs(v) for v in err.values()) < 0.05, err
    # (cut at each lost state, its runs' position residuals were 2.7-9.9x the encoder's
    # noise; on one run over the lost states, 1.6x)
    assert len(runs) == 1
    assert r.adequate, r.inadequacy
    assert r.halves['judged'] == ['z_dot', 'p_CP', 'p_CT']
    assert not any(r.halves['prediction'][n] > PREDICTION_LIMIT and
                   r.halves['prediction_ratio'][n] > PREDICTION_RATIO for n in r.halves['judged'])


def test_the_simplified_fit_of_the_same_bag_is_caught_with_the_model_to_fit(driver_bag):
    runs, truth = driver_bag
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)
        r = identify(runs)
    err = {n: r.x[n] / truth[n] - 1.0 for n in FIVE}
    assert max(abs(v) for v in err.values()) > 0.10, err       # a bad fit ...
    assert not r.adequate                                      # ... is not called adequate
    assert any('--model reduced' in a for a in r.advice), r.advice


def test_median_noise_ratios_are_per_signal_over_the_runs_that_have_it():
    metrics = {'r0': {'z': {'noise_ratio': 1.0}, 'p_CP': {'noise_ratio': 3.0}},
               'r1': {'z': {'noise_ratio': 2.0}},
               'r2': {'z': {'noise_ratio': 9.0}, 'p_CP': {'noise_ratio': 1.0}}}
    assert median_noise_ratios(metrics) == {'z': 2.0, 'p_CP': 2.0}
    assert median_noise_ratios({}) == {}


@pytest.mark.parametrize('start, first_cost, kept', [
    ('apart', 1.01, True),      # the first fit had stopped in a poorer optimum
    ('apart', 0.99, False),     # the first fit was the better optimum
    ('invalid', 1.01, False),   # the halves' mean is not a valid set: no second fit
])
def test_the_second_start_from_the_halves_is_recorded_whether_kept_or_not(
        monkeypatch, start, first_cost, kept):
    """
    ``restart`` holds where the second start began, both fits and which one is the result.

    So that a program counts how often it ran and what it changed, without reading warnings.
    The sample bag's halves agree with the whole record; here they are made to point 3 %
    above its F_cc (or to a mean with F_cc above F_sc), and the first fit's cost is raised or
    lowered by 1 % so that the second fit, which reaches the same optimum, is kept or not.
    """
    from ros_ehs.core.identify import estimator
    from ros_ehs.data.experiments import load_experiment
    exps = load_experiment(Path(__file__).resolve().parents[1] / 'bags' / 'sample_sine_1hz')
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)
        r = identify(exps, verdict=False)
    first = dict(r.x)
    r.cost *= first_cost
    cost = r.cost
    f_cc = first['F_sc'] * 2 if start == 'invalid' else first['F_cc'] * 1.03
    monkeypatch.setattr(estimator, 'restart', lambda a, b, whole: {**whole, 'F_cc': f_cc})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always', IdentificationWarning)
        j = estimator.judge(r, exps)
    rec = j.restart
    assert rec['start'] == {**first, 'F_cc': f_cc}
    assert rec['first'] == {'cost': cost, 'values': first}
    assert rec['kept'] is kept
    if start == 'invalid':
        assert rec['second'] is None
    else:
        assert set(rec['second']) == {'cost', 'values', 'status', 'settled'}
        assert (rec['second']['cost'] < cost) is kept
    assert dict(j.x) == (rec['second']['values'] if kept else first)
    said = [str(w.message) for w in caught if 'mean of the halves' in str(w.message)]
    assert len(said) == int(kept)
    assert j.summary()['restart'] == rec
    assert json.loads(json.dumps(j.summary()['restart'], default=float)) == rec


def test_a_slow_record_without_pressures_is_refitted_without_each_quarter(monkeypatch):
    """
    ``judge`` runs the jackknife where the verdict reads it, and stops at a refit not valid.

    The sample bag (with pressures) is made to read as a slow record without them
    (``judged_on_jackknife``), so that its four refits run on a record the test owns.
    """
    from ros_ehs.core.identify import estimator
    from ros_ehs.data.experiments import load_experiment
    exps = load_experiment(Path(__file__).resolve().parents[1] / 'bags' / 'sample_sine_1hz')
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)
        r = identify(exps, verdict=False)
    assert not copy.deepcopy(r).jackknife
    monkeypatch.setattr(estimator, 'judged_on_jackknife', lambda rate_hz: True)
    monkeypatch.setattr(estimator, 'restart', lambda a, b, whole: None)
    j = estimator.judge(copy.deepcopy(r), exps)
    assert [len(v) for v in j.jackknife['values']] == [len(r.free)] * QUARTERS
    assert j.jackknife['stderr'] == jackknife(j.jackknife['values'], j.x)['stderr']
    assert not any(f.startswith('agreement') for f in j.failed)
    assert j.summary()['jackknife'] == j.jackknife
    # a refit without one quarter that is not a valid set is a reason of its own
    real, calls = estimator._refit, []

    def third_invalid(*args, **kwargs):
        out = real(*args, **kwargs)
        calls.append(out)
        if len(calls) == 3:         # the two halves, then the record without its first quarter
            out.params = None
        return out

    monkeypatch.setattr(estimator, '_refit', third_invalid)
    j = estimator.judge(copy.deepcopy(r), exps)
    assert j.failed[-1] == 'jackknife_invalid' and not j.adequate
    assert 'without its quarter 1 of 4 is not a valid parameter set' in j.inadequacy[-1]
    assert len(calls) == 3 and not j.jackknife
