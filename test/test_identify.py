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
"""Identification from bags: recovery of Table 1, honest uncertainty, clear errors."""

import json
from pathlib import Path
import warnings

import numpy as np
import pytest
from ros_ehs.core.control.waveforms import Sine
from ros_ehs.core.errors import IdentificationWarning, InputError
from ros_ehs.core.identify import identify, score
from ros_ehs.core.params import ESTIMATED, preset
from ros_ehs.data.experiments import load_experiment
from ros_ehs.data.synthetic_bag import record_synthetic_bag
from ros_ehs.tools import cli

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / 'bags' / 'sample_sine_1hz'
FIXTURES = ROOT / 'test' / 'fixtures' / 'rosbag2'
TRUE = preset('table1_estimated')
TOL = {'d_c': 0.02, 'F_cc': 0.02, 'F_sc': 0.02, 'l_iac': 0.02, 'c_c': 0.02, 'r_c': 0.10}


@pytest.fixture(scope='module')
def fits(once):
    """Fit the sample bag (seed 0) and two more noise seeds from Table 1's initial values."""
    def fit(root):
        exps = {0: load_experiment(SAMPLE)}
        for seed in (1, 2):
            record_synthetic_bag(root / f'seed{seed}', seed=seed)
            exps[seed] = load_experiment(root / f'seed{seed}')
        with warnings.catch_warnings():
            warnings.simplefilter('error', IdentificationWarning)
            return {seed: (e, identify(e)) for seed, e in exps.items()}

    return once('fits', fit)


def test_sample_bag_is_what_the_readme_says():
    e = load_experiment(SAMPLE)
    assert e.t.size == 10000 and e.dt == pytest.approx(1e-3)
    assert np.ptp(e.z) == pytest.approx(0.08, rel=0.05)        # 0.04 m sine
    assert e.p_a is not None and e.p_b is not None


def test_refit_recovers_table1_estimated(fits):
    _, r = fits[0]
    # 16 on the committed sample bag (the paper took 24; `python -m ros_ehs.benchmarks identify`
    # measures it on a fresh bag); this guards against a regression
    assert r.success and r.iterations <= 24
    for n, tol in TOL.items():
        assert r.x[n] == pytest.approx(TRUE[n], rel=tol), n
    assert abs(r.x['x_bias'] - TRUE['x_bias']) <= 2.0 * r.stderr['x_bias']
    assert r.metrics['sample_sine_1hz']['z_dot']['r2'] > 0.999
    # started from Table 1's initial values, which are far off
    assert r.x0 == {n: preset('table1_initial')[n] for n in ESTIMATED}
    assert len(r.history) == r.iterations + (r.history[-1]['iteration'] > r.iterations)
    assert r.history[-1]['cost'] < r.history[0]['cost'] / 10


def test_standard_errors_match_the_spread_over_seeds(fits):
    z = np.array([[(r.x[n] - TRUE[n]) / r.stderr[n] for n in ESTIMATED]
                  for _, r in fits.values()])
    # normalised errors of an honest uncertainty are ~N(0, 1): none far out, rms near 1
    assert np.all(np.abs(z) < 4.0), z
    rms = float(np.sqrt(np.mean(z ** 2)))
    assert 0.3 < rms < 2.0, rms
    xs = np.array([[r.x[n] for n in ESTIMATED] for _, r in fits.values()])
    se = np.array([[r.stderr[n] for n in ESTIMATED] for _, r in fits.values()]).mean(axis=0)
    spread = xs.std(axis=0, ddof=1)
    assert np.all(spread < 4.0 * se) and np.all(spread > 0.1 * se), (spread, se)


def test_correlation_matrix_is_a_correlation_matrix(fits):
    c = fits[0][1].correlation
    assert c.shape == (7, 7)
    np.testing.assert_allclose(np.diag(c), 1.0, atol=1e-9)
    np.testing.assert_allclose(c, c.T, atol=1e-12)
    assert np.all(np.abs(c) <= 1.0 + 1e-9)


def test_held_out_bag_scored_with_fitted_params(fits):
    (_, r0), (e1, _) = fits[0], fits[1]
    m = score(r0.params, [e1])
    assert m[e1.name]['z_dot']['r2'] > 0.999
    bad = score(preset('table1_initial'), [e1])
    assert bad[e1.name]['z_dot']['nrmse'] > 5 * m[e1.name]['z_dot']['nrmse']


def test_joint_fit_of_two_bags_and_sse_option(fits):
    (e0, _), (e1, _) = fits[0], fits[1]
    free = ('F_cc', 'F_sc', 'c_c')
    base = preset('table1_estimated', F_cc=500.0, F_sc=900.0, c_c=9000.0)
    # on a 1 Hz sine the Coulomb level and the viscous slope move the force alike: flagged
    with pytest.warns(IdentificationWarning, match='F_cc and c_c are correlated'):
        r = identify([e0, e1], free=free, base=base, cost='sse', workers=1)
    assert set(r.metrics) == {e0.name, e1.name}
    for n in free:
        assert r.x[n] == pytest.approx(TRUE[n], rel=0.01), n


def test_result_carries_the_fitted_traces_keyed_by_unique_names(fits):
    e0 = fits[0][0]
    r = identify([e0, e0], free=('c_c',), base=TRUE, workers=1, max_nfev=3)
    names = ['sample_sine_1hz', 'sample_sine_1hz #2']
    assert list(r.metrics) == list(r.fitted) == names
    for n in names:
        fit = r.fitted[n]
        assert fit['z_dot'].shape == fit['z'].shape == e0.t.shape
        # the traces are the ones the metrics were computed on
        sse = float(np.sum((fit['z_dot'] - e0.v) ** 2))
        sst = float(np.sum((e0.v - e0.v.mean()) ** 2))
        assert 1.0 - sse / sst == pytest.approx(r.metrics[n]['z_dot']['r2'], rel=1e-12)
        # position: fitted up to one offset per 1 s segment, so each segment's mean matches
        for a in range(0, e0.t.size - 1000, 1000):
            assert abs(np.mean(fit['z'][a:a + 1000] - e0.z[a:a + 1000])) < 1e-12
    assert 'fitted' not in r.summary()


def test_unidentifiable_parameter_is_warned(fits):
    e = fits[0][0]
    # B_a (torque-motor damping) exists only in the full model
    with pytest.warns(IdentificationWarning):
        r = identify(e, free=('B_a', 'c_c'), base=TRUE.replace(c_c=15000.0),
                     signals=('z_dot',), workers=1, max_nfev=10)
    assert any('B_a is not identifiable' in w for w in r.warnings)
    assert r.stderr['B_a'] == np.inf and np.isfinite(r.stderr['c_c'])


@pytest.mark.parametrize('kwargs, match', [
    ({'free': ('nope',)}, '`free`'),
    ({'free': ()}, '`free` is empty'),
    ({'model': 'linear'}, '`model`'),
    ({'cost': 'l2'}, '`cost`'),
    ({'signals': ('z',)}, '`signals`'),
    ({'workers': 0}, '`workers`'),
    ({'segment': -1.0}, '`segment`'),
    ({'x0': {'K_x': 1.0}}, '`x0`'),
])
def test_inputs_are_validated_first(fits, kwargs, match):
    with pytest.raises(InputError, match=match):
        identify(fits[0][0], **kwargs)
    with pytest.raises(InputError, match='`experiments`'):
        identify([])


def test_cli_writes_params_report_and_json(tmp_path, capsys):
    rc = cli.main(['identify', str(SAMPLE), '--out', str(tmp_path / 'rep'), '--quiet',
                   '--holdout', str(SAMPLE)])
    out = capsys.readouterr().out
    assert rc == 0, out
    files = sorted(p.name for p in (tmp_path / 'rep').iterdir())
    assert files == ['correlation.png', 'fit_sample_sine_1hz.png', 'history.png',
                     'identified_params.yaml', 'summary.json']
    s = json.loads((tmp_path / 'rep' / 'summary.json').read_text())
    assert s['parameters']['F_sc']['value'] == pytest.approx(TRUE['F_sc'], rel=0.02)
    assert 'held-out sample_sine_1hz' in s['fit']
    # the paper's 1 Hz / 40 mm sine with pressures pins all seven down: no advice to record
    assert s['excitation']['identifiability']['weak'] == []
    assert s['excitation']['recommended'] is None
    assert 'excitation: every parameter is pinned down' in out
    from ros_ehs.core.params import load_yaml
    p = load_yaml(tmp_path / 'rep' / 'identified_params.yaml')
    assert p['c_c'] == pytest.approx(TRUE['c_c'], rel=0.02)


def _cli_error(capsys, *argv):
    rc = cli.main(['identify', *map(str, argv), '--quiet', '--no-figures'])
    err = capsys.readouterr().err
    assert rc == 2 and 'Traceback' not in err
    return err


def test_cli_clear_errors(tmp_path, capsys):
    assert 'no bag at' in _cli_error(capsys, tmp_path / 'missing', '--out', tmp_path / 'o')
    err = _cli_error(capsys, FIXTURES / 'talker.mcap', '--out', tmp_path / 'o')
    assert "no topic 'state'" in err and '/rosout (rcl_interfaces/msg/Log' in err
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes((SAMPLE / 'sample_sine_1hz_0.mcap').read_bytes()[:300])
    assert 'truncated' in _cli_error(capsys, cut, '--out', tmp_path / 'o')
    short = tmp_path / 'short'
    record_synthetic_bag(short, duration=0.3)
    assert 'too little data' in _cli_error(capsys, short, '--out', tmp_path / 'o')
    still = tmp_path / 'still'
    from ros_ehs.core.control.waveforms import Sine
    from ros_ehs.data.synthetic_bag import SensorNoise
    record_synthetic_bag(still, duration=1.0, reference=Sine(1e-6, 1.0),
                         noise=SensorNoise(0, 0, 0))
    assert 'no excitation' in _cli_error(capsys, still, '--out', tmp_path / 'o')


# -- model adequacy ------------------------------------------------------------------------------
def test_an_adequate_fit_says_so_with_its_noise_ratios(fits, tmp_path):
    e, r = fits[0]
    assert r.adequate and r.inadequacy == [] and r.advice == [] and r.stderr_widening == 1.0
    for m in r.metrics['sample_sine_1hz'].values():
        assert 0.9 < m['noise_ratio'] < 1.1 and abs(m['acf1']) < 0.1
    from ros_ehs.data.report import write_report
    summary = json.loads(write_report(r, e, tmp_path, figures=False)['summary'].read_text())
    assert summary['adequate'] is True and summary['inadequacy'] == []
    assert summary['failed_rules'] == []


def test_data_from_another_model_is_flagged_inadequate_with_advice(tmp_path, capsys):
    """A full-model bag fitted with the simplified model: its values are not even valid."""
    bag = tmp_path / 'full'
    record_synthetic_bag(bag, model='full', seed=3)
    e = load_experiment(bag)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)
        r = identify(e)
    assert not r.adequate
    # the simplified valve makes up for the full one's lag with friction: F_cc above F_sc
    assert any('not a valid parameter set' in w and 'F_cc' in w for w in r.inadequacy)
    assert any('--model full' in a for a in r.advice)
    assert r.metrics['full']['z_dot']['noise_ratio'] > 3.0
    # correlated residuals: the standard errors are widened for them, and said so
    assert r.stderr_widening > 3.0
    assert any('standard errors widened' in w for w in r.warnings)
    # the command says it, writes it to summary.json, and exits 1
    rc = cli.main(['identify', str(bag), '--out', str(tmp_path / 'rep'), '--quiet'])
    out = capsys.readouterr().out
    assert rc == 1 and 'verdict: NOT ADEQUATE' in out and 'advice: fit the reduced model' in out
    summary = json.loads((tmp_path / 'rep' / 'summary.json').read_text())
    assert summary['adequate'] is False and summary['advice']
    # each reason with the rule it failed, for a program to read
    assert 'invalid' in r.failed and len(r.failed) == len(r.inadequacy)
    assert 'invalid' in summary['failed_rules']
    assert len(summary['failed_rules']) == len(summary['inadequacy'])
    assert (tmp_path / 'rep' / 'fit_full.png').stat().st_size > 10000


def test_a_stop_at_the_evaluation_limit_is_flagged(fits, tmp_path):
    e, _ = fits[0]
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)
        r = identify(e, max_nfev=2)
    assert r.status == 0 and not r.adequate
    assert any('evaluation limit (max_nfev = 2)' in w for w in r.inadequacy)
    assert any('max_nfev' in a for a in r.advice)


def test_random_starts_report_how_many_reach_the_same_optimum(fits):
    from ros_ehs.core.identify.estimator import multistart
    e, r = fits[0]
    with pytest.raises(InputError, match='`starts`'):
        multistart(e, r, starts=0)
    ms = multistart(e, r, starts=3, seed=5)
    assert ms['starts'] == 3 and len(ms['runs']) == 3
    assert ms['same_optimum'] == sum(x['same_optimum'] for x in ms['runs'])
    assert f'{ms["same_optimum"]} of 3 random starts' in ms['message']
    lo, hi = {'d_c': 1e-6, 'F_cc': 50.0, 'l_iac': 0.105}, {'x_bias': 6e-6}
    for run in ms['runs']:
        assert all(run['x0'][n] >= v for n, v in lo.items())
        assert abs(run['x0']['x_bias']) <= hi['x_bias'] and run['x0']['F_cc'] <= run['x0']['F_sc']
        if run['same_optimum']:          # the same optimum: the same cost, to within 1 %
            assert run['cost'] <= 1.01 * r.cost
    assert multistart(e, r, starts=3, seed=5)['runs'][0]['x0'] == ms['runs'][0]['x0']   # seeded


@pytest.mark.parametrize('seed', [21, 22, 23])
def test_a_rig_that_is_not_the_model_is_recovered_or_flagged(tmp_path, seed):
    """
    Fit full-model bags from parameter sets drawn away from Table 1 (seeded).

    The default (simplified) fit recovers d_c, F_cc, F_sc, l_iac and c_c within 5 %, or
    says it cannot and names the model to fit instead; that one gets them within 2 %.
    """
    rng = np.random.default_rng(seed)
    est = preset('table1_estimated')
    # 15-25 % off Table 1's estimates, within Table 1's bounds (l_iac >= 0.105 m: up only)
    factors = {n: float((1 if n == 'l_iac' else rng.choice([-1, 1])) * rng.uniform(0.15, 0.25)
                        + 1.0) for n in ('d_c', 'F_cc', 'F_sc', 'l_iac', 'c_c')}
    truth = est.replace(**{n: est[n] * f for n, f in factors.items()})
    record_synthetic_bag(tmp_path / 'rig', plant_params=truth, model='full', seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)
        r = identify(load_experiment(tmp_path / 'rig'))
    errors = {n: abs(r.x[n] / truth[n] - 1.0) for n in factors}
    if r.adequate:
        assert max(errors.values()) <= 0.05, errors
        return
    assert r.inadequacy and '--model reduced' in r.advice[0]
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)
        r = identify(load_experiment(tmp_path / 'rig'), model='reduced')
    errors = {n: abs(r.x[n] / truth[n] - 1.0) for n in factors}
    assert r.adequate, r.inadequacy
    assert max(errors.values()) <= 0.02, errors


def test_the_report_names_what_the_bag_cannot_pin_down_and_an_excitation_that_does(
        tmp_path, capsys):
    """
    A 4 Hz / 40 mm bag (the valve saturates) leaves the rounding radius r_c loose.

    The report says so and recommends a trajectory for the reference node; a bag recorded
    with it, fitted jointly from the first fit (the command's own workflow), pins r_c down.
    """
    from ros_ehs.core.identify.design import trajectory, PINNED
    bag = tmp_path / 'fast'
    record_synthetic_bag(bag, reference=Sine(0.04, 4.0), seed=3)
    rc = cli.main(['identify', str(bag), '--out', str(tmp_path / 'rep'), '--quiet',
                   '--no-figures'])
    out = capsys.readouterr().out
    summary = json.loads((tmp_path / 'rep' / 'summary.json').read_text())
    ident = summary['excitation']['identifiability']
    assert rc == 0 and ident['weak'] == ['r_c'], ident
    first = summary['parameters']['r_c']
    assert first['rel_stderr'] > 2 * PINNED
    rec = summary['excitation']['recommended']
    assert rec['rel_stderr']['r_c'] <= PINNED and 'ros2 run ros_ehs reference' in rec['command']
    assert 'excitation: this excitation does not pin down r_c' in out
    # the advice, followed
    record_synthetic_bag(tmp_path / 'advised', reference=trajectory(rec['reference']), seed=9)
    rc = cli.main(['identify', str(bag), str(tmp_path / 'advised'), '--out',
                   str(tmp_path / 'rep2'), '--initial',
                   str(tmp_path / 'rep' / 'identified_params.yaml'), '--quiet', '--no-figures'])
    joint = json.loads((tmp_path / 'rep2' / 'summary.json').read_text())
    assert rc == 0 and joint['adequate']
    assert joint['excitation']['identifiability']['weak'] == []
    assert joint['parameters']['r_c']['rel_stderr'] <= PINNED
    truth = TRUE['r_c']
    assert abs(joint['parameters']['r_c']['value'] / truth - 1) < 0.02
    assert abs(first['value'] / truth - 1) > 0.02         # it was loose before
    assert 'every parameter is pinned down' in joint['excitation']['message']


def test_excitation_advice_validates_its_inputs(fits):
    from dataclasses import replace

    from ros_ehs.core.identify.design import identifiability, recommend
    e, r = fits[0]
    with pytest.raises(InputError, match='`candidates` is empty'):
        recommend(r, [e], candidates=())
    with pytest.raises(InputError, match='no valid parameter set'):
        recommend(replace(r, params=None), [e])
    ident = identifiability(r)
    assert set(ident['parameters']) == set(r.free) and ident['weak'] == []
    loose = identifiability(r, pinned=1e-9)        # a threshold nothing meets: all loose
    assert loose['weak'] == list(r.free)


def test_a_derived_velocity_is_compared_through_the_derivative_that_derived_it():
    """
    Where the data's velocity was derived from the position, so is the model's.

    Per replay segment, the model's velocity is the same derivative of its position (a replay's
    position jumps where a segment restarts); within half the filter's width of a segment's
    ends it is the measured one (no residual). A measured velocity meets the model's own.
    """
    from dataclasses import replace

    from ros_ehs.core.identify.experiment import derivative_coefficients, experiment_from_arrays
    from ros_ehs.core.identify.problem import Problem, SIGNALS
    t = np.arange(2500) * 1e-3
    w = 2 * np.pi
    e = experiment_from_arrays('sine', t, 1e-3 * np.cos(w * t), 0.01 * np.sin(w * t),
                               0.01 * w * np.cos(w * t))
    base = preset('table1_estimated')
    measured, derived = (Problem([x], base, ESTIMATED, 'simplified', SIGNALS, 1.0, None)
                         for x in (e, replace(e, derived=('z_dot',))))
    theta = np.array([base[n] for n in ESTIMATED]) / measured.scale
    om, od = measured.simulate(theta)[0], derived.simulate(theta)[0]
    iz, iv = measured.iz, measured.iv
    np.testing.assert_array_equal(od[:, iz], om[:, iz])
    c = derivative_coefficients(1e-3)
    h = c.size // 2
    segments = list(derived.exps[0].segments())
    assert len(segments) == 3 and c.size == 5
    for a, b in segments:
        np.testing.assert_allclose(od[a + h:b - h, iv], np.convolve(om[a:b, iz], c, 'valid'),
                                   rtol=0, atol=1e-12)
        np.testing.assert_array_equal(od[[a, a + 1, b - 2, b - 1], iv],
                                      e.v[[a, a + 1, b - 2, b - 1]])
    # the measured velocity's experiment: the model's own velocity, which the derivative is not
    assert np.max(np.abs(om[h:-h, iv] - od[h:-h, iv])) > 1e-6


def test_a_jittered_drivers_command_is_replayed_from_where_it_took_over(monkeypatch):
    """
    The replay holds each 4 ms sample's command in 0.5 ms pieces (``problem.PIECE``).

    A 250 Hz driver that wakes up to a fifth of a period late applies each command at its
    cycle; held as the sample's mean, the rig's own model replays it worse than cut in
    pieces where the takeover fell: at the truth, on the derived velocity and the position.
    """
    from ros_ehs.core.identify import problem as pr
    from ros_ehs.core.identify.experiment import experiments_from_series
    from ros_ehs.core.model import Plant
    period, rx, h, n = 4e-3, 0.15e-3, 1e-4, 1000
    rng = np.random.default_rng(8)
    cycles = np.arange(n) * period + rng.uniform(0.0, 0.2 * period, n)
    cmd = 0.006 * np.sin(2 * np.pi * cycles) + 0.002 * rng.standard_normal(n)
    # the rig, 0.1 ms steps: command k acts from cycle k + 1
    k = np.searchsorted(cycles, np.arange(int(cycles[-1] / h)) * h, side='right') - 2
    rig = Plant(TRUE, 'reduced', h=h)
    x = rig.simulate(h, np.where(k >= 0, cmd[np.clip(k, 0, n - 1)], 0.0)).x
    z = np.interp(cycles, np.arange(x.shape[0]) * h, x[:, rig.state_names.index('z')])
    ts = np.round((1.0 + cycles) * 1e9).astype(np.int64)
    (e,) = experiments_from_series('rig', ts[:-2], z[:-2], np.full(n - 2, np.nan),
                                   commands=(ts + int(rx * 1e9), cmd), delay=period - rx)

    def replay():
        p = pr.Problem([e], TRUE, ESTIMATED, 'reduced', ('z_dot', 'z'), 1.0, None)
        r = p.residual_parts(np.array([TRUE[n] for n in ESTIMATED]) / p.scale)[0]
        return p.exps[0].per, np.sqrt(np.mean(r[50:] ** 2, axis=0)) * p.exps[0].sigma

    per, pieces = replay()
    monkeypatch.setattr(pr, 'PIECE', 1.0)
    assert per == 8 and replay()[0] == 1
    assert np.all(pieces < 0.6 * replay()[1]), (pieces, replay()[1])


def test_a_segment_restarts_from_measured_pressures_where_a_record_has_them():
    from dataclasses import replace

    from ros_ehs.core.identify.experiment import experiment_from_arrays
    from ros_ehs.core.identify.problem import Problem, SIGNALS
    t = np.arange(500) * 1e-3
    e = experiment_from_arrays('sine', t, 1e-3 * np.cos(t), 0.01 * np.sin(t), 0.01 * np.cos(t))
    p = np.full(t.size, 1e7)

    def restarts(*x, signals=SIGNALS):
        return Problem(x, TRUE, ESTIMATED, 'reduced', signals, 1.0, None).restarts_pressures()

    assert not restarts(e)
    assert restarts(replace(e, p_a=p, p_b=p))
    assert not restarts(replace(e, p_a=p, p_b=p), signals=('z_dot', 'z'))   # not fitted
    assert restarts(replace(e, p_load=p))
    assert restarts(e, replace(e, name='b', p_a=p, p_b=p))       # one run of two has them


@pytest.mark.parametrize('settles', [True, False])
def test_a_second_start_stopped_at_its_limit_is_kept_only_when_its_values_settled(
        monkeypatch, settles):
    """
    A second start stopped at ``max_nfev`` replaces a poorer first fit when it settled.

    As one that converged does (the verdict benchmark's rig 158 stopped at its limit, with
    cost 612 against 767); stopped before its values settled, it is not taken.

    The sample bag's two starts reach one optimum; here the first fit's cost is raised by
    1 % and the second start's status set to "stopped at the limit", its history either
    ending in settled iterations or not.
    """
    from ros_ehs.core.identify import estimator
    from ros_ehs.core.identify.verdict import SETTLE_ITERATIONS
    real, calls = estimator._solve, []

    def solve(*args):
        sol, J, history, njev = real(*args)
        calls.append(sol)
        if len(calls) == 1:           # the first fit: as if in a poorer optimum
            sol.cost *= 1.01
        elif len(calls) == 3:         # the second start's fit on the 1 s segments
            sol.status = 0
            history = history + [history[-1]] * (SETTLE_ITERATIONS + 1) if settles \
                else history[-2:]
        return sol, J, history, njev

    monkeypatch.setattr(estimator, '_solve', solve)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always', IdentificationWarning)
        r = identify(load_experiment(SAMPLE), verdict=False)
    said = [str(w.message) for w in caught if 'second start' in str(w.message)]
    assert len(calls) == 3
    if settles:
        assert r.status == 0 and r.settled and r.cost == calls[2].cost and len(said) == 1
    else:
        assert r.status != 0 and r.cost == calls[0].cost and not said


def test_a_cold_fit_with_pressures_takes_a_second_start_through_short_segments(
        monkeypatch, tmp_path):
    """
    A 250 Hz driver's bag with pressures, a rig away from Table 1 (the verdict benchmark's 45).

    The cold fit on 1 s segments stops with F_sc 12 % low; the second start, from its values
    through 0.1 s segments and then on the 1 s ones, reaches a lower cost with all five within
    5 %.
    """
    from ros_ehs.benchmarks.verdict import draw_rig, JUDGED
    from ros_ehs.core.identify import estimator
    from ros_ehs.data.experiments import load_experiments
    from ros_ehs.data.rig_bag import record_rig_bag
    rig = draw_rig(45, 8.0)
    lay = rig['layout']
    assert lay.rate_hz == 250.0 and lay.pressures == 'fluid'
    rec = record_rig_bag(tmp_path / 'rig', lay, plant_params=rig['truth'],
                         reference=rig['reference'], duration=8.0, seed=45)
    runs = load_experiments(tmp_path / 'rig', topics=lay.topic_map(rec['input_delay']))

    def fit():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter('always', IdentificationWarning)
            r = identify(runs, model='reduced', verdict=False)
        worst = max(abs(r.x[n] / rig['truth'][n] - 1.0) for n in JUDGED)
        return r, worst, [str(w.message) for w in caught if 'second start' in str(w.message)]

    r, worst, said = fit()
    monkeypatch.setattr(estimator, 'SHORT_SEGMENT', 1.0)    # not shorter: no second start
    first, first_worst, first_said = fit()
    assert first_worst > 0.10 and abs(first.x['F_sc'] / rig['truth']['F_sc'] - 1.0) > 0.10
    assert worst < 0.05, r.x
    assert r.cost < (1.0 - estimator._SAME_COST) * first.cost
    assert len(said) == 1 and f'from {first.cost:.6g} to {r.cost:.6g}' in said[0], said
    assert not first_said and r.nfev > first.nfev
    assert said[0] in r.warnings


def test_a_fit_runs_its_linear_algebra_on_one_blas_thread(monkeypatch):
    """
    Whatever the process set, a fit's solve and standard errors run on ``BLAS_THREADS``.

    How OpenBLAS splits a product over its threads depends on the process's history: the same
    bag fitted in two processes came out 2.6 % apart on F_cc (docs/identification.md). The
    limit is given back after, and the fit's warnings still name the caller's line.
    """
    from threadpoolctl import threadpool_info, threadpool_limits
    from ros_ehs.core.identify import estimator, uncertainty
    seen = []

    def blas():
        return {i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas'}

    def spy(real):
        def call(*args, **kwargs):
            seen.append((real.__name__, blas()))
            return real(*args, **kwargs)
        return call

    monkeypatch.setattr(estimator, 'least_squares', spy(estimator.least_squares))
    monkeypatch.setattr(estimator, 'standard_errors', spy(uncertainty.standard_errors))
    e = load_experiment(SAMPLE)
    with threadpool_limits(limits=2, user_api='blas'):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter('always', IdentificationWarning)
            identify(e, verdict=False, max_nfev=3)
        after = blas()
    assert {name for name, _ in seen} == {'least_squares', 'standard_errors'}, seen
    assert all(threads == {estimator.BLAS_THREADS} for _, threads in seen), seen
    assert after == {2}
    assert caught and all(w.filename == __file__ for w in caught), \
        [(w.filename, str(w.message)[:40]) for w in caught]


def _warm_pair(monkeypatch):
    """Return a cold fit of the sample bag's first half and two warm refits of its second."""
    from ros_ehs.core.identify import estimator
    from ros_ehs.core.identify.verdict import halves
    first, second = halves([load_experiment(SAMPLE)])
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)
        cold = identify(first, verdict=False)
        warm = identify(second, x0=cold.x, warm=True, verdict=False, workers=1)
        monkeypatch.setattr(estimator, 'STEP_SETTLED', 0.0)     # run to _TOL, as before
        tight = identify(second, x0=cold.x, warm=True, verdict=False, workers=1)
    return cold, warm, tight


def test_a_warm_fit_stops_when_the_step_left_is_under_a_tenth_of_each_standard_error(
        monkeypatch):
    """
    ``STEP_SETTLED``: the warm solve takes the small Gauss-Newton step left and stops.

    Against the same refit run to the tolerance: every value within 0.15 of its standard
    error, the cost within 1e-6, fewer Jacobians; its status and message say why it stopped.
    """
    cold, warm, tight = _warm_pair(monkeypatch)
    assert warm.status == 3 and 'Gauss-Newton step left' in warm.message, warm.message
    assert tight.message != warm.message
    assert warm.iterations < tight.iterations, (warm.iterations, tight.iterations)
    for n in warm.free:
        assert abs(warm.x[n] - tight.x[n]) < 0.15 * tight.stderr[n], n
        assert warm.stderr[n] == pytest.approx(tight.stderr[n], rel=0.01), n
    assert warm.cost == pytest.approx(tight.cost, rel=1e-6)


def test_the_verdicts_refit_lands_where_a_refit_to_the_tolerance_does(monkeypatch):
    """
    ``_refit`` (the verdict's, values only): the warm solve and its settle rule, nothing else.

    Its values are those of :func:`identify`'s warm refit of the same half run to the
    tolerance, within 0.15 of their standard errors, in fewer Jacobians, and it computes no
    standard errors.
    """
    from ros_ehs.core.identify import estimator, problem
    from ros_ehs.core.identify.verdict import halves
    r = identify(load_experiment(SAMPLE), verdict=False)
    part = halves([load_experiment(SAMPLE)])[0]
    real, calls = estimator._fd_jacobian, []

    def counted(*args):
        calls.append(1)
        return real(*args)

    monkeypatch.setattr(estimator, '_fd_jacobian', counted)
    monkeypatch.setattr(estimator, 'standard_errors', None)      # called: a TypeError
    v = estimator._refit(part, r.params, r.free, r.model, problem.SIGNALS, r.cost_kind, 1.0,
                         None, 1, 100)
    used = len(calls)
    monkeypatch.undo()
    monkeypatch.setattr(estimator, 'STEP_SETTLED', 0.0)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)
        full = identify(part, base=r.params, warm=True, verdict=False, workers=1)
    assert used < full.iterations, (used, full.iterations)
    for n in r.free:
        assert abs(v.x[n] - full.x[n]) < 0.15 * full.stderr[n], (n, v.x[n], full.x[n])
    assert v.params is not None and v.params['F_cc'] == v.x['F_cc']


@pytest.mark.parametrize('cost', ['sse', 'sae'])
def test_the_gauss_newton_step_of_a_linear_problem_lands_on_its_solution(cost):
    """On residuals linear in the values, the step is scipy's solution minus the start."""
    from scipy.optimize import least_squares
    from ros_ehs.core.identify.estimator import _F_SCALE, _gauss_newton_step
    rng = np.random.default_rng(3)
    A = rng.normal(size=(400, 3))
    b = A @ np.array([1.0, -2.0, 0.5]) + 0.05 * rng.normal(size=400)
    start = np.array([1.1, -1.9, 0.45])
    step = _gauss_newton_step(A, A @ start - b, cost)
    if cost == 'sse':
        best = least_squares(lambda t: A @ t - b, start, xtol=1e-14, ftol=1e-14).x
        assert np.allclose(start + step, best, atol=1e-10)
    else:   # one reweighted step from near the optimum comes close to soft_l1's
        best = least_squares(lambda t: A @ t - b, start, loss='soft_l1', f_scale=_F_SCALE,
                             xtol=1e-14, ftol=1e-14).x
        assert np.abs(start + step - best).max() < 0.2 * np.abs(start - best).max()


def test_a_warm_fit_without_pressures_runs_to_the_tolerance(monkeypatch):
    """Without pressures the cost has a valley along the friction: no settle rule there."""
    from ros_ehs.core.identify import estimator
    from ros_ehs.core.identify.verdict import halves
    first, second = halves([load_experiment(SAMPLE)])
    signals = ('z_dot', 'z')
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', IdentificationWarning)
        cold = identify(first, signals=signals, verdict=False)
        warm = identify(second, x0=cold.x, warm=True, verdict=False, workers=1,
                        signals=signals)
        settled = identify(second, x0=cold.x, warm=True, verdict=False, workers=1,
                           signals=signals, settle=True)
        monkeypatch.setattr(estimator, 'STEP_SETTLED', 0.0)
        tight = identify(second, x0=cold.x, warm=True, verdict=False, workers=1,
                         signals=signals)
    assert 'Gauss-Newton step left' not in warm.message
    assert warm.x == tight.x and warm.iterations == tight.iterations
    assert 'Gauss-Newton step left' in settled.message       # asked for: it does
