"""Tests of the simulation fallback's control variates: the controlled trials
(mdft/_control_kernels.py), the cross-fitted estimates (mdft/_control_variates.py) and their
use by mdft.threshold_probabilities (docs/threshold_exact.md, section 9)."""

import math
import sys

import numpy as np
import pytest

import mdft
from mdft import _control_kernels, _threshold_fallback as fb
from mdft._control_variates import ControlledSums
from mdft.simulate import _control_args, _controlled_trials, _fallback_trials
from threshold_models import assert_within_stated_error, drawn, random_model

K = _control_kernels.N_CONTROLS


def _model_with_start(rng, n_options):
    """A random model of the documented range, one to three attributes, ``P0`` off zero."""
    n_attributes = int(rng.integers(1, 4))
    model = drawn(rng.uniform(0.5, 4.0, (n_options, n_attributes)),
                  rng.dirichlet(np.full(n_attributes, 4.0)),
                  phi1=float(np.exp(rng.uniform(np.log(0.005), np.log(0.1)))),
                  phi2=float(rng.uniform(0.01, 0.1)), beta=float(rng.uniform(1, 15)),
                  sigma2=float(np.exp(rng.uniform(np.log(0.1), np.log(4.0)))),
                  P0=rng.uniform(-2.0, 2.0, n_options))
    return model, float(rng.uniform(3.0, 15.0))


@pytest.mark.parametrize("rich", [True, False])
@pytest.mark.parametrize("n_options", [2, 3])
def test_controlled_trials_are_the_fallback_trials(n_options, rich):
    # the same draws and arithmetic, with every control or the monomials alone: from the
    # same generator, the same choices and steps to the bit, and sums that count them
    rng = np.random.default_rng(11 + n_options)
    for draw in range(4):
        model, theta = _model_with_start(rng, n_options)
        choices, steps = _fallback_trials(model, 4_000, theta, 300, np.random.default_rng(draw))
        c2, s2, grams = _controlled_trials(model, 4_000, theta, 300,
                                           np.random.default_rng(draw), 50.0, rich)
        assert rich or not grams[:, 1 + _control_kernels.POLYNOMIAL_CONTROLS:1 + K].any()
        np.testing.assert_array_equal(choices, c2)
        np.testing.assert_array_equal(steps, s2)
        total = grams.sum(axis=0)
        np.testing.assert_array_equal(grams, np.transpose(grams, (0, 2, 1)))
        assert total[0, 0] == 4_000 and abs(grams[0, 0, 0] - grams[1, 0, 0]) <= 1
        y = 1 + K  # the targets: indicators, undecided, steps
        counts = np.bincount(choices + 1, minlength=n_options + 1)
        np.testing.assert_array_equal(np.diag(total)[y:y + n_options], counts[1:])
        assert total[y + n_options, y + n_options] == counts[0]
        for i in range(n_options):
            mine = steps[choices == i].astype(float)
            t = y + n_options + 1 + i
            assert total[0, t] == mine.sum() and total[t, t] == (mine**2).sum()
            assert total[y + i, t] == mine.sum()


@pytest.mark.parametrize("rich", [True, False])
@pytest.mark.parametrize("n_options", [2, 3])
def test_the_sums_are_those_of_each_trial_recorded_alone(n_options, rich):
    # the chunk's sums, products of control sums added a group of trials at a time and the
    # targets' products below the diagonal, against v v^T built trial by trial from the
    # trial kernels themselves, over chunks of every length modulo the group
    rng = np.random.default_rng(31 + n_options)
    model, theta = _model_with_start(rng, n_options)
    args, plane, opt = _control_args(model, theta, 300, 50.0)
    S, CM, L, cuts, P0, n_steps, th = args
    size = _control_kernels.gram_size(n_options)
    for n_trials in range(2 * _control_kernels.GROUP + 1, 4 * _control_kernels.GROUP + 1):
        seed = np.random.default_rng(n_trials).integers(0, 2**63, 4).astype(np.uint64)
        state = seed.copy()
        grams = np.zeros((2, size, size))
        choices = np.zeros(n_trials, dtype=np.int64)
        steps = np.zeros(n_trials, dtype=np.int64)
        _control_kernels.controlled_chunk(state, 0, n_trials, S, CM, L, cuts, P0, n_steps, th,
                                          plane, opt, rich, choices, steps, grams)
        state = seed.copy()
        expected = np.zeros((2, size, size))
        P = np.empty(n_options)
        for k in range(n_trials):
            acc = np.zeros(K)
            if rich:
                choice, step = _control_kernels.rich_trial(state, S, CM, L, cuts, P0, n_steps,
                                                           th, plane, opt, P, acc)
            else:
                choice, step = _control_kernels.controlled_trial(state, S, CM, L, cuts, P0,
                                                                 n_steps, th, plane, P, acc)
            assert (choice, step) == (choices[k], steps[k])
            v = np.zeros(size)
            v[0] = 1.0
            v[1:1 + K] = acc
            v[1 + K + (choice if choice >= 0 else n_options)] = 1.0
            if choice >= 0:
                v[1 + K + n_options + 1 + choice] = step
            expected[k % 2] += np.outer(v, v)
        np.testing.assert_allclose(_control_kernels.symmetric(grams), expected, rtol=1e-12,
                                   atol=1e-12 * np.abs(expected).max())


def test_controlled_trials_are_the_same_in_parallel_and_serially(monkeypatch):
    module = sys.modules["mdft.simulate"]
    model, theta = _model_with_start(np.random.default_rng(5), 3)
    runs = []
    for work in (0, 10**18):  # everything in parallel, then everything serial
        monkeypatch.setattr(module, "_PARALLEL_WORK", work)
        runs.append(_controlled_trials(model, 5_000, theta, 400, np.random.default_rng(2), 40.0))
    for a, b in zip(*runs):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("n_options", [2, 3])
def test_control_sums_have_mean_zero(n_options):
    # every control is a martingale stopped at a bounded time: on random models across the
    # documented range (P0 off zero, one to three attributes, trials that end undecided at
    # a short step limit too) each control's mean is within 4.5 standard errors of zero; a
    # position that has seen the step's own noise fails this by 60 errors
    rng = np.random.default_rng(70 + n_options)
    worst = 0.0
    for draw in range(6):
        model, theta = _model_with_start(rng, n_options)
        max_steps = 40 if draw % 2 else 2_000
        _, steps, grams = _controlled_trials(model, 40_000, theta, max_steps,
                                             np.random.default_rng(draw), 30.0)
        total = grams.sum(axis=0)
        n = total[0, 0]
        mean = total[0, 1:1 + K] / n
        var = np.diag(total)[1:1 + K] / n - mean**2
        live = var > 1e-20 * max(var.max(), 1e-300)
        z = np.abs(mean[live]) / np.sqrt(var[live] / n)
        worst = max(worst, float(z.max()))
    assert worst < 4.5, worst


def test_the_hazard_tail_is_a_normal_tail_to_its_stated_accuracy():
    # the hazards' normal tail: relative error below 1.2e-7 wherever a step may count and
    # beyond, both signs
    g = np.linspace(-9.0, 9.0, 3_601)
    tail = np.array([_control_kernels._upper_tail(v) for v in g])
    exact = np.array([0.5 * math.erfc(v / math.sqrt(2.0)) for v in g])
    assert np.max(np.abs(tail / exact - 1.0)) < 1.2e-7


def test_the_richer_controls_pay_for_a_rarely_chosen_option():
    # an option chosen in 0.7 % of the trials (a draw of the benchmark): the monomials alone
    # barely help its mean time; the functions near the thresholds and the hazards save
    # several times as many trials for it, and more for the probabilities too
    model = drawn([[2.2, 3.82], [2.17, 1.44], [3.87, 2.65]], [0.568, 0.432], phi1=0.0296,
                  phi2=0.0269, beta=2.24, sigma2=0.569)
    choices, steps, grams = _controlled_trials(model, 100_000, 27.93, 10_000,
                                               np.random.default_rng(0), 55.0)
    assert 0.004 < np.mean(choices == 0) < 0.01
    errors = {}
    for name, n_controls in (("none", 0), ("monomials", _control_kernels.POLYNOMIAL_CONTROLS),
                             ("all", K)):
        sums = ControlledSums(3, K)
        sums.add(grams)
        means, cov = sums.restricted(n_controls).estimate()
        c = np.zeros(7)
        c[4], c[0] = 1.0, -means[4] / means[0]  # option 0's mean time, by the delta method
        errors[name] = (math.sqrt(cov[0, 0]), math.sqrt(c @ cov @ c))
    saved = {k: ((errors["none"][0] / e[0]) ** 2, (errors["none"][1] / e[1]) ** 2)
             for k, e in errors.items()}
    assert saved["monomials"][1] < 4.0 and saved["all"][1] > 3.0 * saved["monomials"][1]
    assert saved["all"][0] > 2.0 * saved["monomials"][0]


def test_restricted_sums_are_those_of_fewer_controls():
    # dropping controls from the sums gives what sums of the same trials without them give
    rng = np.random.default_rng(8)
    grams = _synthetic_grams(rng, 2_000, rng.normal(0.0, 1.0, K), 0.5)
    sums = ControlledSums(1, K)
    sums.add(grams)
    keep = np.r_[0:1 + 10, 1 + K:grams.shape[-1]]
    direct = ControlledSums(1, 10)
    direct.add(grams[:, keep][:, :, keep])
    for a, b in zip(sums.restricted(10).estimate(), direct.estimate()):
        np.testing.assert_array_equal(a, b)


def _synthetic_grams(rng, n, beta, noise):
    """Two folds' sums for one option always chosen at a step ``10 + beta^T x + noise``,
    with controls ``x`` standard normal (mean zero, as the kernels' are)."""
    size = _control_kernels.gram_size(1)
    grams = np.zeros((2, size, size))
    for fold in (0, 1):
        m = n // 2
        v = np.zeros((m, size))
        v[:, 0] = 1.0
        x = rng.standard_normal((m, K))
        v[:, 1:1 + K] = x
        v[:, 1 + K] = 1.0
        v[:, 1 + K + 2] = 10.0 + x @ beta + noise * rng.standard_normal(m)
        grams[fold] = v.T @ v
    return grams


def test_cross_fitted_estimates_are_unbiased_with_their_stated_spread():
    # 400 replications of a mean with known controls: the estimates centre on the truth,
    # their spread matches the stated standard error, and it is the residual noise's, not
    # the controls'
    rng = np.random.default_rng(3)
    beta = rng.normal(0.0, 2.0, K)
    estimates, stated = [], []
    for _ in range(400):
        sums = ControlledSums(1, K)
        sums.add(_synthetic_grams(rng, 2_000, beta, 0.5))
        means, cov = sums.estimate()
        assert means[0] == pytest.approx(1.0) and means[1] == pytest.approx(0.0, abs=1e-12)
        estimates.append(means[2])
        stated.append(math.sqrt(cov[2, 2]))
    estimates = np.array(estimates)
    spread = estimates.std(ddof=1)
    assert abs(estimates.mean() - 10.0) < 4 * spread / math.sqrt(estimates.size)
    assert 0.85 < np.mean(stated) / spread < 1.15
    plain = math.sqrt((beta @ beta + 0.25) / 2_000)
    assert spread < 0.2 * plain


def test_a_control_without_variance_is_left_out():
    # controls that are zero (two options use one plane axis) or copies of others do not
    # break the fit
    rng = np.random.default_rng(4)
    grams = _synthetic_grams(rng, 4_000, np.zeros(K), 1.0)
    grams[:, 1:3, :] = 0.0  # two controls zero
    grams[:, :, 1:3] = 0.0
    grams[:, 3, :] = grams[:, 4, :]  # a copy of the next one
    grams[:, :, 3] = grams[:, :, 4]
    sums = ControlledSums(1, K)
    sums.add(grams)
    means, cov = sums.estimate()
    assert np.isfinite(means).all() and np.isfinite(cov).all()
    assert means[2] == pytest.approx(10.0, abs=0.1)


def _count_calls(monkeypatch, name, kinds=None):
    calls = []
    run = getattr(fb, name)

    def counted(model, n, *args):
        calls.append(n)
        if kinds is not None:
            kinds.append(args[-1])
        return run(model, n, *args)

    monkeypatch.setattr(fb, name, counted)
    return calls


def test_controlled_answers_agree_with_an_independent_simulation(monkeypatch):
    # random three-option models across the documented range, the chain refused at once
    # (max_states=10): where the first batch falls short, the controlled trials answer,
    # within their stated error of 200,000 independent trials
    controlled = _count_calls(monkeypatch, "_controlled_trials")
    rng = np.random.default_rng(2027)
    answered = 0
    for draw in range(5):
        model, theta = random_model(rng, 3, theta_range=(5.0, 15.0))
        controlled.clear()
        res = mdft.threshold_probabilities(model, theta, max_states=10, atol=0.001,
                                           rt_rtol=0.005)
        assert res.engine == "simulation" and res.n_iter >= fb.FIRST_BATCH
        assert res.error_probabilities <= 0.001 and res.error_mean_rt <= 0.005
        assert res.probabilities.sum() + res.p_undecided == pytest.approx(1.0, abs=1e-9)
        np.testing.assert_allclose(res.rt_pmf.sum(axis=0), res.probabilities, atol=1e-12)
        assert_within_stated_error(res, model, theta, 200_000, 100 + draw)
        answered += bool(controlled)
    assert answered >= 2


def test_controls_that_pay_less_than_the_monomials_alone_give_way_to_them(monkeypatch):
    # the first controlled batch records every control; where the monomials alone would
    # need fewer trials' time (here: the richer trials made dear), the batches that follow
    # record only theirs, and the answer rests on all the trials, within its stated error
    from threshold_models import SETS, canonical

    model = canonical(SETS["compromise"])
    monkeypatch.setattr(fb, "RICH_COST", 50.0)
    kinds = []
    controlled = _count_calls(monkeypatch, "_controlled_trials", kinds)
    res = mdft.threshold_probabilities(model, 6.0, max_states=10)
    assert kinds[0] is True and len(kinds) > 1 and not any(kinds[1:])
    assert controlled[0] == fb.RICH_PROBE and res.n_iter == sum(controlled)
    assert res.error_probabilities <= 1e-3 and res.error_mean_rt <= 3e-3
    assert_within_stated_error(res, model, 6.0, 200_000, 13)


def test_controls_that_do_not_pay_leave_the_trials_to_the_plain_estimates(monkeypatch):
    # a controlled batch that does not meet the tolerances, and whose controls save fewer
    # trials than they cost, joins the plain trials; the answer is the plain one over all of
    # them (counted as free when it is tried, as dear when it is judged)
    from threshold_models import SETS, canonical

    model = canonical(SETS["compromise"])
    costs = iter([0.0])
    monkeypatch.setattr(fb, "controlled_cost", lambda steps, rich=True: next(costs, 1e9))
    controlled = _count_calls(monkeypatch, "_controlled_trials")
    res = mdft.threshold_probabilities(model, 6.0, max_states=10, atol=0.001, rt_rtol=0.01)
    assert controlled == [fb.RICH_PROBE] and res.error_probabilities <= 0.001
    assert res.n_iter > 2 * fb.FIRST_BATCH
    counts = res.probabilities * res.n_iter
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert_within_stated_error(res, model, 6.0, 200_000, 12)


def test_invalid_controlled_estimates_give_the_plain_ones(monkeypatch):
    # a controlled probability below zero (or a mean time out of range) is not returned:
    # the same trials' plain estimates are
    from threshold_models import SETS, canonical

    model = canonical(SETS["compromise"])
    estimate = ControlledSums.estimate

    def negative(self):
        means, cov = estimate(self)
        means = means.copy()
        means[0] = -1e-6
        return means, cov

    monkeypatch.setattr(ControlledSums, "estimate", negative)
    res = mdft.threshold_probabilities(model, 6.0, max_states=10, atol=0.004, rt_rtol=0.01)
    counts = res.probabilities * res.n_iter
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert np.all(res.probabilities >= 0)


def test_a_large_predicted_simulation_starts_with_its_controls(monkeypatch):
    # where the refused chain's last answer predicts many plain trials, the controlled
    # trials start at once (no plain first batch); a small prediction keeps the plain batch
    from mdft import threshold_exact
    from threshold_models import SETS, canonical

    model = canonical(SETS["compromise"])
    plain = _count_calls(monkeypatch, "_fallback_trials")
    controlled = _count_calls(monkeypatch, "_controlled_trials")
    at_once = (fb.FIRST_BATCH * (1 + 1.1 * fb.CONTROLLED_AT_ONCE
                                 * fb.controlled_cost(12.0, rich=False)),
               12.0)
    res = threshold_exact._simulated(model, 6.0, 10_000, 1e-3, 3e-3, None, "a test",
                                     predicted=at_once)
    assert plain == [] and controlled[0] == fb.RICH_PROBE and res.n_iter == sum(controlled)
    assert res.error_probabilities <= 1e-3 and res.error_mean_rt <= 3e-3
    controlled.clear()
    threshold_exact._simulated(model, 6.0, 10_000, 1e-3, 3e-3, None, "a test",
                               predicted=(0.5 * at_once[0], 12.0))
    assert plain[0] == fb.FIRST_BATCH


def test_controlled_answers_on_unusual_models(monkeypatch):
    # models at the edges of what the controls assume: no noise (the attention alone moves
    # the walk), one attribute (the noise alone), a start far off zero, a feedback matrix
    # without a fixed point (S = I) and two options (one plane axis); batches of 20,000 so
    # that every call goes on to controlled trials, each within its stated error of 200,000
    # independent trials
    controlled = _count_calls(monkeypatch, "_controlled_trials")
    monkeypatch.setattr(fb, "FIRST_BATCH", 20_000)
    M3 = [[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]]
    canon = dict(phi1=0.022, phi2=0.05, beta=12.0)
    models = [drawn(M3, [0.5, 0.5], sigma2=0.0, **canon),
              drawn([[1.0], [1.2], [0.9]], [1.0], **canon),
              drawn(M3, [0.5, 0.5], P0=[4.0, -3.0, 1.5], **canon),
              mdft.MDFTModel.from_matrices(M3, [0.5, 0.5], S=np.eye(3)),
              drawn(M3[:2], [0.4, 0.6], **canon)]
    for k, model in enumerate(models):
        controlled.clear()
        res = mdft.threshold_probabilities(model, 6.0, max_states=10, atol=0.002,
                                           rt_rtol=0.008)
        assert controlled and res.n_iter == sum(controlled), k
        assert res.error_probabilities <= 0.002 and res.error_mean_rt <= 0.008
        assert_within_stated_error(res, model, 6.0, 200_000, 30 + k)


def test_controls_answer_on_the_budget_of_an_early_hand_over(monkeypatch):
    # on the budget of an early hand-over, the probe predicts plain trials: over the
    # budget, the simulation stops there (the chain would go on) even if controlled trials
    # might fit; within it, the controlled trials answer, on fewer trials than plain ones
    from mdft import threshold_exact
    from threshold_models import SETS, canonical

    model = canonical(SETS["compromise"])
    with pytest.raises(fb.OverBudget):
        threshold_exact._simulated(model, 6.0, 10_000, 1e-3, 3e-3, None, "a test",
                                   max_work=4e6)
    plain = _count_calls(monkeypatch, "_fallback_trials")
    controlled = _count_calls(monkeypatch, "_controlled_trials")
    res = threshold_exact._simulated(model, 6.0, 10_000, 1e-3, 3e-3, None, "a test",
                                     max_work=1e8)
    assert plain == [fb.PROBE_BATCH, fb.FIRST_BATCH - fb.PROBE_BATCH]
    assert controlled and res.n_iter == sum(controlled) < 1e6
    assert res.error_probabilities <= 1e-3 and res.error_mean_rt <= 3e-3


def _probe_kw(model, probe_work):
    # the early hand-over's budget: probe_work, and twice it in all; the result as a tuple
    return dict(model=model, theta=6.0, max_steps=10_000, atol=1e-3, rt_rtol=3e-3, rng=None,
                reason="a test", make_result=lambda *args: args, max_work=2.0 * probe_work,
                probe_work=probe_work, probe_controls=True)


def test_a_probe_of_controlled_trials_decides_a_budgeted_simulation(monkeypatch):
    # the compromise set at theta = 6: plain trials need about 2.9e7 trial-steps, controlled
    # ones about 1.7e7 at their cost. On a budget between the two, the plain probe is over
    # it and a probe of controlled trials goes on to answer; below both, that probe stops
    # the simulation; beyond CONTROLLED_REACH times the budget, or where the controlled
    # probe would cost more than CONTROLLED_PROBE_SHARE of it, no controlled trial is run
    from threshold_models import SETS, canonical

    model = canonical(SETS["compromise"])
    plain = _count_calls(monkeypatch, "_fallback_trials")
    controlled = _count_calls(monkeypatch, "_controlled_trials")
    out = fb.simulated_answer(**_probe_kw(model, 2.4e7))
    assert plain == [fb.PROBE_BATCH]
    assert controlled[:2] == [fb.CONTROLLED_PROBE, fb.FIRST_BATCH - fb.CONTROLLED_PROBE]
    assert out[4] == sum(controlled) >= fb.FIRST_BATCH and out[5] <= 1e-3 and out[6] <= 3e-3
    # what the controlled probe measured: controlled trials at their cost within the
    # budget, plain ones not
    for budget, ran in ((1e7, [fb.CONTROLLED_PROBE]), (1e6, []), (2e6, [])):
        plain.clear()
        controlled.clear()
        with pytest.raises(fb.OverBudget, match="would need about"):
            fb.simulated_answer(**_probe_kw(model, budget))
        assert plain == [fb.PROBE_BATCH] and controlled == ran, budget
    # 2e6 was within reach (20 times) but the probe's 4.4e5 trial-steps above its share;
    # a larger share lets it run
    monkeypatch.setattr(fb, "CONTROLLED_PROBE_SHARE", 0.5)
    controlled.clear()
    with pytest.raises(fb.OverBudget, match="with control variates"):
        fb.simulated_answer(**_probe_kw(model, 2e6))
    assert controlled == [fb.CONTROLLED_PROBE]
    # without probe_controls, the plain probe's prediction decides alone, as before
    controlled.clear()
    with pytest.raises(fb.OverBudget):
        fb.simulated_answer(**{**_probe_kw(model, 2.4e7), "probe_controls": False})
    assert controlled == []


def test_the_early_hand_over_probes_controls_where_plain_trials_cost_too_much(monkeypatch):
    # the first pilot predicts plain trials beyond the share of the chain's passes ahead,
    # but within reach of the controls: the call probes them and answers by them, within its
    # stated error of independent trials; the probe runs once per call
    from mdft import threshold_exact
    from threshold_models import SETS, canonical

    model = canonical(SETS["compromise"])
    monkeypatch.setattr(threshold_exact, "_PROBE_MIN_WORK", 0.0)  # a quick model
    answer = mdft.threshold_probabilities(model, 6.0, fallback="raise")
    sim_work = threshold_exact._simulation_work(answer, 10_000, 1e-3, 3e-3)
    steps = 20
    # passes ahead whose share the plain trials exceed by a fifth
    nonzeros = sim_work / 1.2 / threshold_exact._EARLY_SHARE / (threshold_exact._BUILD_WORK
                                                                  + steps)
    controlled = _count_calls(monkeypatch, "_controlled_trials")
    kw = dict(model=model, theta=6.0, max_steps=10_000, atol=1e-3, rt_rtol=3e-3, rng=None)
    probed = []
    res = threshold_exact._simulated_if_cheaper(answer, nonzeros, steps, **kw, probed=probed)
    assert res.engine == "simulation" and probed == [True]
    assert controlled[0] == fb.CONTROLLED_PROBE and res.n_iter == sum(controlled)
    assert res.error_probabilities <= 1e-3 and res.error_mean_rt <= 3e-3
    assert_within_stated_error(res, model, 6.0, 200_000, 41)
    # once per call; and without a record of probes (the count alone) none is run
    controlled.clear()
    assert threshold_exact._simulated_if_cheaper(answer, nonzeros, steps, **kw,
                                                 probed=probed) is None
    assert threshold_exact._simulated_if_cheaper(answer, nonzeros, steps, **kw) is None
    assert controlled == []


def test_whether_controls_may_pay_is_a_count(monkeypatch):
    # a probe where the chain's work is at least _PROBE_MIN_WORK, plain trials cost at most
    # CONTROLLED_REACH times it, and the probe (PROBE_BATCH plain and CONTROLLED_PROBE
    # controlled trials of 1,000 steps) at most CONTROLLED_PROBE_SHARE of it
    from types import SimpleNamespace

    from mdft import threshold_exact

    rt_pmf = np.zeros((2_000, 3))
    rt_pmf[999] = [0.5, 0.5, 0.0]
    answer = SimpleNamespace(probabilities=rt_pmf.sum(axis=0), p_undecided=0.0, rt_pmf=rt_pmf)
    probe = threshold_exact._SIM_STEP_WORK * (fb.PROBE_BATCH * 1_000
                                              + fb.controlled_probe_work(1_000.0))
    chain = probe / fb.CONTROLLED_PROBE_SHARE
    assert chain >= threshold_exact._PROBE_MIN_WORK
    may = threshold_exact._controls_may_pay
    assert not may(answer, 1.01 * fb.CONTROLLED_REACH * chain, chain, 10_000, [])
    assert not may(answer, chain, 0.99 * chain, 10_000, [])
    assert not may(answer, math.nan, chain, 10_000, [])
    probed = []
    assert may(answer, 0.99 * fb.CONTROLLED_REACH * chain, chain, 10_000, probed)
    assert probed == [True] and not may(answer, chain, chain, 10_000, probed)
    # below the least work worth a probe, none
    monkeypatch.setattr(threshold_exact, "_PROBE_MIN_WORK", 1.01 * chain)
    assert not may(answer, chain, chain, 10_000, [])


def test_a_pass_that_finds_controls_may_pay_probes_them_on_its_budget(monkeypatch):
    # after a comparison, where plain trials cost more than the next pass but controls may
    # pay, the call simulates on the next pass's budget, probing the controls; over that
    # budget the chain refines as before
    from mdft import threshold_exact
    from threshold_models import SETS, canonical

    model = canonical(SETS["compromise"])
    monkeypatch.setattr(threshold_exact, "_simulated_if_cheaper", lambda *a, **k: None)
    monkeypatch.setattr(threshold_exact, "_FIRST_PAIR_FACTOR", 1e6)  # always refine
    monkeypatch.setattr(threshold_exact, "_SIM_STEP_WORK", 1e12)  # plain trials dear
    asked = []
    monkeypatch.setattr(threshold_exact, "_controls_may_pay",
                        lambda answer, sim, chain, steps, probed: asked.append(chain) or True)
    calls = []

    def simulated(*args, **kwargs):
        calls.append(kwargs)
        raise fb.OverBudget("over")

    monkeypatch.setattr(threshold_exact, "_simulated", simulated)
    loose = dict(atol=0.004, rt_rtol=0.01)
    res = mdft.threshold_probabilities(model, 6.0, **loose)
    assert res.engine == "plane" and calls and len(calls) == len(asked)
    for chain, kwargs in zip(asked, calls):
        assert kwargs["probe_controls"]
        assert kwargs["probe_work"] == pytest.approx(chain / 1e12)
        assert kwargs["max_work"] == pytest.approx(threshold_exact._SIM_OVERRUN * chain / 1e12)
    monkeypatch.setattr(threshold_exact, "_simulated", lambda *a, **k: "simulated")
    assert mdft.threshold_probabilities(model, 6.0, **loose) == "simulated"


def test_controls_that_do_not_pay_after_a_probe_leave_their_trials_to_be_judged(monkeypatch):
    # a controlled probe whose trials do not pay joins them to the plain ones; those are
    # judged again, not thrown away: here they meet the (loose) tolerances, and answer
    from threshold_models import SETS, canonical

    model = canonical(SETS["compromise"])
    monkeypatch.setattr(fb, "CONTROLLED_PROBE_SHARE", 100.0)
    tried = []

    def not_paying(model, theta, max_steps, atol, rt_rtol, gen, reason, make_result,
                   max_work, time_scale, plain, probe_work=None):
        tried.append(probe_work)
        plain.add(*_fallback_trials(model, fb.FIRST_BATCH - plain.n, theta, max_steps, gen))
        return None

    monkeypatch.setattr(fb, "_controlled_answer", not_paying)
    kw = dict(_probe_kw(model, 1e5), max_steps=1_000, atol=0.01, rt_rtol=0.03)
    out = fb.simulated_answer(**kw)
    assert len(tried) == 1 and out[4] == fb.FIRST_BATCH and out[5] <= 0.01 and out[6] <= 0.03
