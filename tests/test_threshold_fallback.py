"""Tests of mdft.threshold_probabilities's hand-over to simulation: the fallback when the
chain refuses, simulating from the start where trials cost less than the chain's passes, the
cut pilot's probe, and the fallback's own budget and prediction of its work
(``docs/threshold_exact.md``, sections 4 and 9)."""

import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from mdft import MDFTModel, _plane_passes, threshold_exact, threshold_probabilities
from threshold_models import SETS, assert_within_stated_error, canonical, drawn


def test_refused_chain_falls_back_to_a_simulation_within_its_stated_error(monkeypatch):
    # max_states=10 makes the chain refuse at once; the fallback simulates until three
    # standard errors meet atol and rt_rtol, and an independent simulation agrees
    model = canonical(SETS["compromise"])
    res = threshold_probabilities(model, 6.0, max_states=10, atol=0.004, rt_rtol=0.01)
    assert res.engine == "simulation" and res.method == "simulation" and res.n_states == 0
    assert res.error_probabilities <= 0.004 and res.error_mean_rt <= 0.01
    assert res.n_iter >= 100_000 and "trials" in res.summary()
    np.testing.assert_allclose(res.rt_pmf.sum(axis=0), res.probabilities, atol=1e-12)
    assert res.probabilities.sum() + res.p_undecided == pytest.approx(1.0, abs=1e-12)
    assert_within_stated_error(res, model, 6.0, 200_000, 11)
    # repeatable by default, and a different rng gives a different (equally good) answer
    again = threshold_probabilities(model, 6.0, max_states=10, atol=0.004, rt_rtol=0.01)
    np.testing.assert_array_equal(res.probabilities, again.probabilities)
    other = threshold_probabilities(model, 6.0, max_states=10, atol=0.004, rt_rtol=0.01, rng=3)
    assert not np.array_equal(res.probabilities, other.probabilities)
    # over its work budget, the fallback raises and says why the chain refused
    from mdft import _threshold_fallback

    monkeypatch.setattr(_threshold_fallback, "MAX_WORK", 1e5)
    with pytest.raises(ValueError, match=r"the chain refused \(.*max_states.*\), and its "
                                         r"simulation fallback would need .*Raise atol"):
        threshold_probabilities(model, 6.0, max_states=10)


def _no_early_simulation(monkeypatch):
    # the first pilot's check (test_simulates_from_the_start_...) aside: the chain's passes
    monkeypatch.setattr(threshold_exact, "_simulated_if_cheaper", lambda *a, **k: None)


def test_simulation_answers_when_it_costs_less_than_a_finer_grid(monkeypatch):
    # with simulation counted as free, a chain that needs a refinement hands over to it, and
    # the reason says so; counted as dear, the chain refines instead. Both paths are
    # deterministic (counted work, not timings).
    model = canonical(SETS["compromise"])
    loose = dict(atol=0.004, rt_rtol=0.01)
    _no_early_simulation(monkeypatch)
    monkeypatch.setattr(threshold_exact, "_SIM_STEP_WORK", 0.0)
    monkeypatch.setattr(threshold_exact, "_FIRST_PAIR_FACTOR", 1e6)  # always refine
    res = threshold_probabilities(model, 6.0, **loose)
    assert res.engine == "simulation"
    assert_within_stated_error(res, model, 6.0, 200_000, 12)
    monkeypatch.setattr(threshold_exact, "_SIM_STEP_WORK", 1e12)
    res = threshold_probabilities(model, 6.0, **loose)
    assert res.engine == "plane" and res.resolution < 1.0


# a long, nearly certain deliberation (one option, about 52 steps, little noise): the pilots'
# chain has many states, while a hundred thousand short trials settle every tolerance
QUICK_TO_SIMULATE = dict(M=[[1.1, 0.9, 1.1], [3.5, 1.1, 0.5], [3.1, 3.0, 2.2]],
                         w=[0.22, 0.41, 0.37], phi1=0.0066, phi2=0.014, beta=7.0, sigma2=0.125)


def _count_builds(monkeypatch):
    built = []
    build = _plane_passes.build_moment_chain

    def counted(*args, **kwargs):
        built.append(args[2])  # the resolution
        return build(*args, **kwargs)

    monkeypatch.setattr(_plane_passes, "build_moment_chain", counted)
    return built


@pytest.mark.parametrize("walks", [True, False])
def test_simulates_from_the_start_where_the_first_chain_predicts_it_costs_less(monkeypatch,
                                                                              walks):
    # the answer of the first pass that counts (where the simulated walks fit the reference
    # sums) or of the first pilot predicts the trials; simulating them costs less than the
    # passes ahead, so the call simulates after that one chain, within its stated error of
    # the chain's own answer (which fallback="raise", what fitting uses, still gives)
    monkeypatch.setattr(_plane_passes, "WALK_FIT", walks)
    model = MDFTModel(**QUICK_TO_SIMULATE)
    built = _count_builds(monkeypatch)
    res = threshold_probabilities(model, 55.5)
    assert res.engine == "simulation" and len(built) == 1
    first = _plane_passes.KAPPA * (_plane_passes.REFINE if walks else 2.0)
    assert built[0] == pytest.approx(first)
    assert res.error_probabilities <= 1e-3 and res.error_mean_rt <= 3e-3
    built.clear()
    chain = threshold_probabilities(model, 55.5, fallback="raise")
    assert chain.engine == "plane" and len(built) > 3
    np.testing.assert_allclose(res.probabilities, chain.probabilities,
                               atol=res.error_probabilities + chain.error_probabilities)
    assert res.mean_response_times[2] == pytest.approx(
        chain.mean_response_times[2], rel=res.error_mean_rt + chain.error_mean_rt)
    # counted as dear, simulation waits for the chain as before
    monkeypatch.setattr(threshold_exact, "_SIM_STEP_WORK", 1e12)
    built.clear()
    assert threshold_probabilities(model, 55.5).engine == "plane" and len(built) > 3


def _counted_trials(monkeypatch):
    """Record the size of every batch of trials; plain trials only (no control variates),
    so that every answer rests on all the trials of its simulation."""
    from mdft import _threshold_fallback as fb

    monkeypatch.setattr(fb, "_controlled_trials", lambda *args: None)
    trials = []
    run = fb._fallback_trials

    def counted(model, n, *args):
        trials.append(n)
        return run(model, n, *args)

    monkeypatch.setattr(fb, "_fallback_trials", counted)
    return trials


@pytest.mark.parametrize("walks", [True, False])
def test_early_simulation_needing_more_than_predicted_goes_back_to_the_chain(monkeypatch,
                                                                            walks):
    # where the trials turn out to need more than _SIM_OVERRUN times the predicted chain
    # work, the simulation stops after its first batch and the chain goes on from its first
    # pass (its probes next) or its first pilot (the second pilot next)
    from mdft import _threshold_fallback as fb

    monkeypatch.setattr(_plane_passes, "WALK_FIT", walks)
    model = MDFTModel(**QUICK_TO_SIMULATE)
    trials = _counted_trials(monkeypatch)
    monkeypatch.setattr(fb, "FIRST_BATCH", 1_000)  # too few trials for the tolerances
    monkeypatch.setattr(threshold_exact, "_SIM_OVERRUN", 1e-3)
    built = _count_builds(monkeypatch)
    res = threshold_probabilities(model, 55.5)
    # one batch, then the chains built on the same grid and the passes that count
    assert trials[0] == 1_000 and len(built) > 3 and built[1] == built[0]
    assert res.error_probabilities <= 1e-3 and res.error_mean_rt <= 3e-3
    if res.engine == "simulation":
        # handed over later by the count after a comparison (the first batch is now small):
        # a simulation of its own, the abandoned batch not in it
        assert res.n_iter == sum(trials[1:])
    else:
        assert res.engine == "plane" and trials == [1_000]


# seed 9595 model 7 of the benchmark's draws: the first pilot's closure runs away after 125
# steps; every trial chooses option 3, in 174 steps on average
CUT_AND_QUICK = dict(M=[[2.7196687488469333, 1.151759138323227],
                        [3.709689878080767, 2.663116017406429],
                        [3.6968234920199317, 3.0311920274580832]],
                     w=[0.3176960180209522, 0.6823039819790477], phi1=0.005248373029023574,
                     phi2=0.01398695993376537, beta=13.737414153627238,
                     sigma2=0.24307505086571518)
CUT_AND_QUICK_THETA = 58.11452636317638


def test_a_cut_pilot_hands_over_to_trials_that_cost_less(monkeypatch):
    # a cut pilot's answer predicts nothing, so the first trials of the simulation predict
    # its work: within the share of the passes ahead (two refits, the first pass that
    # counts, its probes and the next), the call simulates after that one chain (it used to
    # refit and refine for 8.6 s, then refuse by the closure and simulate anyway)
    # (the pilots run where the walks cannot fit the reference sums: mdft._plane_spread)
    from mdft import _threshold_fallback as fb

    monkeypatch.setattr(_plane_passes, "WALK_FIT", False)
    model = drawn(**CUT_AND_QUICK)
    built = _count_builds(monkeypatch)
    trials = _counted_trials(monkeypatch)
    res = threshold_probabilities(model, CUT_AND_QUICK_THETA)
    assert res.engine == "simulation" and len(built) == 1
    assert trials[:2] == [fb.PROBE_BATCH, fb.FIRST_BATCH - fb.PROBE_BATCH]
    assert res.n_iter == sum(trials) >= fb.FIRST_BATCH
    assert res.error_probabilities <= 1e-3 and res.error_mean_rt <= 3e-3
    assert_within_stated_error(res, model, CUT_AND_QUICK_THETA, 100_000, 13)
    # counted as dear, the probe's prediction is over its budget: the chain goes on after
    # those trials alone (here to max_states, and the fallback of a refusal then simulates
    # a first batch of its own, whole)
    monkeypatch.setattr(threshold_exact, "_SIM_STEP_WORK", 1e12)
    built.clear()
    trials.clear()
    res = threshold_probabilities(model, CUT_AND_QUICK_THETA, max_states=12_000)
    assert res.engine == "simulation" and len(built) > 1
    assert trials[:2] == [fb.PROBE_BATCH, fb.FIRST_BATCH]
    assert res.n_iter == sum(trials[1:])


def test_a_simulation_on_a_budget_probes_before_its_first_batch(monkeypatch):
    # the first PROBE_BATCH trials predict the work; over max_work or probe_work nothing more
    # is simulated; every answer rests on at least FIRST_BATCH trials
    from mdft import _threshold_fallback as fb

    model = canonical(SETS["compromise"])
    trials = _counted_trials(monkeypatch)

    def result(*args):
        return args

    kw = dict(model=model, theta=6.0, max_steps=1_000, atol=0.01, rt_rtol=0.03, rng=1,
              reason="a test", make_result=result)
    for budget in (dict(max_work=1.0), dict(max_work=1e12, probe_work=1.0)):
        trials.clear()
        with pytest.raises(fb.OverBudget, match="would need about"):
            fb.simulated_answer(**kw, **budget)
        assert trials == [fb.PROBE_BATCH]
    trials.clear()
    out = fb.simulated_answer(**kw, max_work=1e12, probe_work=1e12)
    assert trials == [fb.PROBE_BATCH, fb.FIRST_BATCH - fb.PROBE_BATCH]
    # (loose tolerances: met by the first batch)
    assert out[4] == fb.FIRST_BATCH and out[5] <= 0.01 and out[6] <= 0.03
    # unbudgeted, the first batch is simulated whole
    trials.clear()
    assert fb.simulated_answer(**kw)[4] == fb.FIRST_BATCH and trials == [fb.FIRST_BATCH]


def test_the_first_pilots_prediction_decides_by_count_alone(monkeypatch):
    # _simulated_if_cheaper simulates exactly where the predicted work is below the share of
    # the chain's; the pilot's answer comes clipped of its closure's negative choices
    from mdft import _threshold_fallback as fb

    rt_pmf = np.zeros((200, 3))
    rt_pmf[99] = [1.0, 0.0, 0.0]  # every trial chooses option 0 at step 100
    answer = SimpleNamespace(probabilities=rt_pmf.sum(axis=0), p_undecided=0.0, rt_pmf=rt_pmf)
    work = threshold_exact._SIM_STEP_WORK * fb.predicted_work(1_000, answer.probabilities, 0.0,
                                                              rt_pmf, 1e-3, 3e-3)
    assert work == pytest.approx(threshold_exact._SIM_STEP_WORK * fb.FIRST_BATCH * 100)
    calls = []
    monkeypatch.setattr(threshold_exact, "simulated_answer",
                        lambda *a, **k: calls.append(k["max_work"]) or "simulated")
    kw = dict(model=None, theta=1.0, max_steps=1_000, atol=1e-3, rt_rtol=3e-3, rng=None)
    chain = work / threshold_exact._EARLY_SHARE  # the chain's work at the share exactly
    steps = 10
    nonzeros = chain / (threshold_exact._BUILD_WORK + steps)
    assert threshold_exact._simulated_if_cheaper(answer, 0.99 * nonzeros, steps, **kw) is None
    assert threshold_exact._simulated_if_cheaper(answer, 1.01 * nonzeros, steps,
                                                 **kw) == "simulated"
    assert calls == [pytest.approx(threshold_exact._SIM_OVERRUN * 1.01 * chain
                                   / threshold_exact._SIM_STEP_WORK)]
    # a prediction that is no number (negative shares) never simulates
    bad = SimpleNamespace(probabilities=np.array([-0.2, 0.7, 0.5]), p_undecided=0.0,
                          rt_pmf=rt_pmf)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert threshold_exact._simulated_if_cheaper(bad, 1e12, steps, **kw) is None


def test_fallback_far_over_its_budget_refuses_without_simulating(monkeypatch):
    # where the chain's last answer predicts more than twice the fallback's work budget, the
    # call refuses at once and says so; no trial is simulated
    from mdft import _threshold_fallback as fb

    model = canonical(SETS["compromise"])
    _no_early_simulation(monkeypatch)
    monkeypatch.setattr(threshold_exact, "_SIM_STEP_WORK", 0.0)  # hand over after one pair
    monkeypatch.setattr(threshold_exact, "_FIRST_PAIR_FACTOR", 1e6)

    def no_simulation(*args, **kwargs):
        raise AssertionError("the fallback simulated")

    monkeypatch.setattr(fb, "_fallback_trials", no_simulation)
    monkeypatch.setattr(fb, "MAX_WORK", 1e5)
    with pytest.raises(ValueError, match=r"the chain refused \(.*\), and its simulation "
                                         r"fallback would need .* \(predicted from the "
                                         r"chain's answer at \d+ states\).*Raise atol"):
        threshold_probabilities(model, 6.0, atol=0.004, rt_rtol=0.01)
    # near the budget the fallback's own first batch decides, as before
    exact = threshold_probabilities(model, 6.0, fallback="raise", atol=0.004, rt_rtol=0.01)
    work = fb.predicted_work(exact.max_steps, exact.probabilities, exact.p_undecided,
                             exact.rt_pmf, 0.004, 0.01)
    monkeypatch.setattr(fb, "MAX_WORK", 0.6 * work)
    with pytest.raises(AssertionError, match="simulated"):
        threshold_probabilities(model, 6.0, atol=0.004, rt_rtol=0.01)


def test_predicted_simulation_work_matches_what_the_fallback_uses(monkeypatch):
    # the plain trials the fallback ends up simulating (three standard errors within the
    # tolerances) are those predicted from the answer, within the growth of its batches;
    # with control variates, the answer rests on fewer
    from mdft import _threshold_fallback as fb

    model = canonical(SETS["compromise"])
    exact = threshold_probabilities(model, 6.0, fallback="raise", atol=0.004, rt_rtol=0.01)
    steps = float(np.arange(1, exact.max_steps + 1) @ exact.rt_pmf.sum(axis=1))
    for atol, rt_rtol in ((0.002, 0.01), (0.01, 0.002)):
        work = fb.predicted_work(exact.max_steps, exact.probabilities, exact.p_undecided,
                                 exact.rt_pmf, atol, rt_rtol)
        predicted = max(work / steps, fb.FIRST_BATCH)
        controlled = threshold_probabilities(model, 6.0, max_states=10, atol=atol,
                                             rt_rtol=rt_rtol)
        assert controlled.n_iter < 0.5 * predicted, (predicted, controlled.n_iter)
        with monkeypatch.context() as plain_only:
            plain_only.setattr(fb, "_controlled_trials", lambda *args: None)
            sim = threshold_probabilities(model, 6.0, max_states=10, atol=atol,
                                          rt_rtol=rt_rtol)
        assert 0.8 * predicted <= sim.n_iter <= 1.6 * predicted, (predicted, sim.n_iter)
