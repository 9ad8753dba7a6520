"""Fitting MDFT to choice data: data containers, recovery, standard errors, bad input,
the thesis data sets and SUSHI."""

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hst

import mdft
from mdft import ChoiceData, fit
from mdft.datasets import load_sushi, load_thesis_set

# Many fits here take one start for speed; a single start is never called converged and says
# so (tests/test_fit_optimum.py checks that), which is expected in the tests of this module.
pytestmark = pytest.mark.filterwarnings(
    "ignore:the fit may not have found the maximum. a single start:mdft.FitConvergenceWarning")

M5 = np.array([[1.0, 3.0], [3.0, 1.0], [2.0, 2.0], [0.9, 3.1], [0.5, 2.5]])
TRUTH = dict(w=np.array([0.55, 0.45]), phi1=0.03, phi2=0.06, beta=8.0, sigma2=0.8)
SUBSETS = [[0, 1], [0, 1, 2], [0, 1, 3], [0, 1, 4], [1, 2, 4]]
T = 60


def probabilities(M, subsets, params, T):
    out = []
    for s in subsets:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
            m = mdft.MDFTModel(M[s], params["w"], phi1=params["phi1"], phi2=params["phi2"],
                               beta=params["beta"], sigma2=params["sigma2"])
        out.append(mdft.choice_probabilities(m, T, method="normal"))  # the fit's likelihood
    return out


def synthetic(rng, n_trials=5000, subsets=SUBSETS, params=TRUTH, M=M5, T=T):
    probs = probabilities(M, subsets, params, T)
    return ChoiceData(subsets, [rng.multinomial(n_trials, p) for p in probs])


def others(*names):
    return {k: v for k, v in TRUTH.items() if k not in names}


# ============================================================== ChoiceData
def test_choice_data_counts_and_shares():
    d = ChoiceData([[0, 1], [2, 0, 1]], [[3, 1], [0, 5, 5]])
    assert d.n_options == 3 and d.n_subsets == 2
    assert d.n_trials.tolist() == [4, 10]
    np.testing.assert_allclose(d.shares[1], [0.0, 0.5, 0.5])
    assert d.response_times is None and d.mean_response_times is None
    with pytest.raises(ValueError, match="read-only"):
        d.counts[0][0] = 7


def test_choice_data_from_trials_groups_by_set_and_keeps_times():
    d = ChoiceData.from_trials([[0, 1], [1, 0], [0, 1, 2], [0, 1]], [0, 1, 2, 0],
                               response_times=[10.0, 20.0, 30.0, 14.0], n_options=4)
    assert [s.tolist() for s in d.subsets] == [[0, 1], [0, 1, 2]]
    assert [c.tolist() for c in d.counts] == [[2, 1], [0, 0, 1]]
    assert d.n_options == 4
    np.testing.assert_allclose(d.mean_response_times[0], [12.0, 20.0])
    np.testing.assert_array_equal(np.isnan(d.mean_response_times[1]), [True, True, False])


def test_choice_data_from_shares():
    d = ChoiceData.from_shares([[0, 1, 2], [1, 2]], [[0.2, 0.3, 0.5], [0.25, 0.75]], [10, 4])
    assert [c.tolist() for c in d.counts] == [[2, 3, 5], [1, 3]]


@pytest.mark.parametrize(
    "args, kwargs, exc, match",
    [
        (([], []), {}, ValueError, "subsets is empty"),
        (([[0, 1]], [[1, 2], [3, 4]]), {}, ValueError, "one row per subset: got 2 rows"),
        (([[0, 1]], [[1, 2, 3]]), {}, ValueError, r"counts\[0\] must hold one count per option"),
        (([[0, 1]], [[1, -2]]), {}, ValueError, "non-negative whole numbers"),
        (([[0, 1]], [[1.5, 2]]), {}, ValueError, "non-negative whole numbers"),
        (([[0, 1]], [[0, 0]]), {}, ValueError, "sums to 0"),
        (([[0]], [[3]]), {}, ValueError, "at least two options"),
        (([[0, 0]], [[1, 1]]), {}, ValueError, "distinct options"),
        (([[0, -1]], [[1, 1]]), {}, ValueError, "non-negative option indices"),
        (([[0, 3]], [[1, 1]]), {"n_options": 3}, ValueError, "refers to option 3"),
        (([["a", "b"]], [[1, 1]]), {}, TypeError, "option indices"),
        (("ab", [[1, 1]]), {}, TypeError, "subsets must be a sequence"),
        (([[0, 1]], 5), {}, TypeError, "counts must be a sequence"),
        (([[0, 1]], [[True, False]]), {}, TypeError, r"counts\[0\] must hold counts .*not booleans"),
        (([[0, 1]], [[1e30, 3]]), {}, ValueError, r"counts\[0\] must hold counts that sum to at most 2\*\*53"),
        (([[0, 1]], [[2**53, 1]]), {}, ValueError, "sum to at most 2\\*\\*53"),
    ],
)
def test_choice_data_bad_input(args, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        ChoiceData(*args, **kwargs)


def test_choice_data_from_trials_bad_input():
    with pytest.raises(ValueError, match="no trials"):
        ChoiceData.from_trials([], [])
    with pytest.raises(ValueError, match="one entry per trial: got 1 choices for 2 trials"):
        ChoiceData.from_trials([[0, 1], [0, 1]], [0])
    with pytest.raises(ValueError, match=r"choices\[1\] = 2 is not one of the options"):
        ChoiceData.from_trials([[0, 1], [0, 1]], [0, 2])
    with pytest.raises(ValueError, match="response_times must have one entry per trial"):
        ChoiceData.from_trials([[0, 1], [0, 1]], [0, 1], response_times=[1.0])
    with pytest.raises(ValueError, match="response_times must be >= 0"):
        ChoiceData.from_trials([[0, 1], [0, 1]], [0, 1], response_times=[1.0, -1.0])
    with pytest.raises(TypeError, match="choices must be a 1-d sequence"):
        ChoiceData.from_trials([[0, 1]], [[0]])


def test_choice_data_from_shares_bad_input():
    with pytest.raises(ValueError, match="sum to 1"):
        ChoiceData.from_shares([[0, 1]], [[0.2, 0.3]], 10)
    with pytest.raises(ValueError, match="not a whole number of choices"):
        ChoiceData.from_shares([[0, 1]], [[0.25, 0.75]], 10)
    with pytest.raises(ValueError, match="n_trials must be a positive integer"):
        ChoiceData.from_shares([[0, 1]], [[0.5, 0.5]], 0)
    with pytest.raises(ValueError, match="one row per subset"):
        ChoiceData.from_shares([[0, 1]], [[0.5, 0.5], [0.5, 0.5]], 10)


# ============================================================== recovery
def test_recovers_attention_and_feedback_parameters():
    rng = np.random.default_rng(1)
    data = synthetic(rng, n_trials=5000)
    res = fit(data, M5, stopping=T, params=["w", "phi1", "phi2", "beta"],
              fixed=others("w", "phi1", "phi2", "beta"), n_starts=2, rng=0)
    assert res.converged and res.engine == "closed_form"
    for name in ("phi1", "phi2", "beta"):
        se = res.standard_errors[name]
        assert np.isfinite(se) and se > 0
        assert abs(res.params[name] - TRUTH[name]) < 4 * se, (name, res.params[name], se)
    assert abs(res.params["w"][0] - 0.55) < 4 * res.standard_errors["w"][0]
    assert res.n_params == 4 and res.n_observations == 5000 * len(SUBSETS)
    assert np.isclose(res.aic, 2 * 4 - 2 * res.log_likelihood)
    assert np.isclose(res.bic, 4 * np.log(res.n_observations) - 2 * res.log_likelihood)
    # sampling alone gives a mean squared share error of about mean(p (1 - p)) / 5000 = 4e-5
    assert res.mse < 1e-4
    assert len(res.labels) == res.covariance.shape[0] == 5  # w[0], w[1], phi1, phi2, beta


def test_standard_error_of_w_matches_spread_over_replicates():
    """The Hessian standard error agrees with the sampling spread (20 data sets)."""
    rng = np.random.default_rng(7)
    est, ses = [], []
    for _ in range(20):
        data = synthetic(rng, n_trials=800, subsets=SUBSETS[:3])
        r = fit(data, M5, stopping=T, params=["w"], fixed=others("w"), n_starts=1, rng=0)
        est.append(r.params["w"][0])
        ses.append(r.standard_errors["w"][0])
    spread = np.std(est, ddof=1)
    assert 0.6 < np.mean(ses) / spread < 1.6, (np.mean(ses), spread)
    assert abs(np.mean(est) - 0.55) < 3 * spread / np.sqrt(20) + 0.005


def test_recovers_evaluations_M():
    rng = np.random.default_rng(3)
    M = np.array([[1.0, 3.0], [3.0, 1.0], [2.0, 2.0], [1.5, 2.8]])
    subsets = [[0, 1], [0, 2], [1, 2], [0, 3], [2, 3], [0, 1, 2], [1, 2, 3]]
    params = dict(w=np.array([0.5, 0.5]), phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
    data = synthetic(rng, n_trials=20_000, subsets=subsets, params=params, M=M, T=40)
    start = M.copy()
    start[1:] += rng.normal(0, 0.2, size=(3, 2))
    res = fit(data, start, stopping=40, params=["M"], fixed={k: v for k, v in params.items()},
              n_starts=1, rng=0)
    assert res.n_params == 6
    # C M and the distances are unchanged by shifting a column of M; row 0 anchors it.
    np.testing.assert_array_equal(res.params["M"][0], M[0])
    se = res.standard_errors["M"][1:]
    assert np.all(np.isfinite(se)) and np.all(se > 0)
    assert np.all(np.abs(res.params["M"][1:] - M[1:]) < 3.5 * se), (res.params["M"], se)
    # sampling alone gives a mean squared share error of about mean(p (1 - p)) / 20000 = 1.1e-5
    assert res.mse < 3e-5


def test_boundary_estimate_has_no_standard_error():
    # Choices that favour option 0 entirely push w to its bound.
    data = ChoiceData([[0, 1]], [[100, 0]])
    with pytest.warns(mdft.FitConvergenceWarning, match="w on a bound"):
        res = fit(data, [[2.0, 0.0], [0.0, 2.0]], stopping=20, params=["w"],
                  fixed=dict(phi1=0.02, phi2=0.05, beta=1.0, sigma2=1.0), rng=0, n_starts=2)
    assert res.params["w"][0] > 0.99
    assert np.isnan(res.standard_errors["w"]).all()
    assert "bound" in res.se_notes["w"]


def test_unidentified_parameter_has_no_standard_error():
    # With a single option pair and phi2 = 0 the feedback is the identity: phi1 and beta
    # do not change the likelihood at all.
    data = ChoiceData([[0, 1]], [[60, 40]])
    res = fit(data, [[1.0, 3.0], [3.0, 1.0]], stopping=10, params=["w", "phi1"],
              fixed=dict(phi2=0.0, beta=5.0, sigma2=1.0), start=dict(phi1=0.3),
              n_starts=1, rng=0)
    assert np.isnan(res.standard_errors["phi1"])
    assert "not identified" in res.se_notes["phi1"]
    # w is still identified and keeps its standard error.
    assert np.all(np.isfinite(res.standard_errors["w"])) and res.se_notes["w"] == ""


def test_predict_and_result_is_frozen():
    rng = np.random.default_rng(5)
    data = synthetic(rng, n_trials=3000, subsets=SUBSETS[:2])
    res = fit(data, M5, stopping=T, params=["w"], fixed=others("w"), n_starts=1, rng=0)
    pred = res.predict([[0, 1, 2], [3, 4]])
    truth = probabilities(M5, [[0, 1, 2], [3, 4]], TRUTH, T)
    for a, b in zip(pred, truth):
        np.testing.assert_allclose(a, b, atol=0.02)
    with pytest.raises(ValueError, match="refers to option 9"):
        res.predict([[0, 9]])
    with pytest.raises(AttributeError, match="cannot assign to field 'mse'"):
        res.mse = 0.0
    assert isinstance(res.model, mdft.MDFTModel)


def test_same_seed_same_fit():
    rng = np.random.default_rng(11)
    data = synthetic(rng, n_trials=1000, subsets=SUBSETS[:2])
    kw = dict(stopping=T, params=["w", "phi2"], fixed=others("w", "phi2"), n_starts=3)
    a = fit(data, M5, rng=4, **kw)
    b = fit(data, M5, rng=4, **kw)
    assert a.log_likelihood == b.log_likelihood
    np.testing.assert_array_equal(a.params["w"], b.params["w"])


def test_fit_from_trials_matches_fit_from_counts():
    rng = np.random.default_rng(2)
    subsets, choices = [], []
    for s in ([0, 1], [0, 1, 2]):
        p = probabilities(M5, [s], TRUTH, T)[0]
        ch = rng.choice(s, size=400, p=p)
        subsets += [s] * 400
        choices += ch.tolist()
    d1 = ChoiceData.from_trials(subsets, choices)
    d2 = ChoiceData([s.tolist() for s in d1.subsets], [c.tolist() for c in d1.counts])
    kw = dict(stopping=T, params=["w"], fixed=others("w"), n_starts=1, rng=0)
    assert fit(d1, M5[:3], **kw).log_likelihood == fit(d2, M5[:3], **kw).log_likelihood


def test_fixed_time_stopping_object():
    if not hasattr(mdft, "FixedTime"):
        pytest.skip("mdft.FixedTime not available")
    rng = np.random.default_rng(5)
    data = synthetic(rng, n_trials=500, subsets=SUBSETS[:2])
    a = fit(data, M5, stopping=mdft.FixedTime(T), params=["w"], fixed=others("w"), rng=0)
    b = fit(data, M5, stopping=T, params=["w"], fixed=others("w"), rng=0)
    assert a.log_likelihood == b.log_likelihood


def test_threshold_fit_by_simulation():
    if not (hasattr(mdft, "simulate") and hasattr(mdft, "Threshold")):
        pytest.skip("mdft.simulate not available")
    M = np.array([[1.0, 3.0], [3.0, 1.0]])
    params = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
    model = mdft.MDFTModel(M, [0.7, 0.3], **params)
    stop = mdft.Threshold(5.0, max_steps=2000)
    sim = mdft.simulate(model, 4000, stopping=stop, rng=1)
    data = ChoiceData([[0, 1]], [sim.counts])
    res = fit(data, M, stopping=stop, params=["w"], fixed=params, method="simulation",
              n_samples=4000, n_starts=1, rng=0)
    assert res.engine == "simulation"
    # Near w = 0.7, dP(A)/dw[0] is about -1.25 (mdft.threshold_probabilities) and P(A) about
    # 0.14, so 4000 trials give w a standard error of about 0.0045; the simulated likelihood
    # (4000 samples) adds as much again: 4 combined standard errors are about 0.025.
    assert abs(res.params["w"][0] - 0.7) < 0.025
    assert "simulated" in res.se_notes["w"]


# ============================================================== bad input
FIXED_ALL = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)


@pytest.fixture(scope="module")
def small_data():
    return ChoiceData([[0, 1]], [[6, 4]])


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        (dict(params=["w", "gamma"]), ValueError, r"params has unknown parameter name\(s\) \['gamma'\]"),
        (dict(params=[]), ValueError, "params is empty"),
        (dict(params=["w", "w"]), ValueError, "lists a parameter twice"),
        (dict(fixed=dict(phi1=0.02, phi2=0.05, beta=12.0)), ValueError, r"missing \['sigma2'\]"),
        (dict(fixed={**FIXED_ALL, "w": [0.5, 0.5]}), ValueError, "both fitted and given in fixed"),
        (dict(fixed={**FIXED_ALL, "tau": 1}), ValueError, r"fixed has unknown parameter name\(s\) \['tau'\]"),
        (dict(params=["phi1"], fixed={**FIXED_ALL, "w": [0.5, 0.5], "phi1": None}),
         ValueError, "both fitted and given in fixed"),
        (dict(params=["phi1"], fixed={"w": [0.5, 0.5], "phi2": 0.05, "beta": 12.0, "sigma2": 1.0},
              start=dict(phi1=2.0)), ValueError, r"start\['phi1'\] = 2.0 lies outside bounds"),
        (dict(params=["phi1"], fixed={"w": [0.5, 0.5], "phi2": 0.05, "beta": 12.0, "sigma2": 1.0},
              bounds=dict(phi1=(0.1, 0.5)), start=dict(phi1=0.05)),
         ValueError, r"start\['phi1'\] = 0.05 lies outside bounds \[0.1, 0.5\]"),
        (dict(params=["phi1"], fixed={"w": [0.5, 0.5], "phi2": 0.05, "beta": 12.0, "sigma2": 1.0},
              bounds=dict(phi1=(0.5, 0.1))), ValueError, "lower < upper"),
        (dict(params=["phi1"], fixed={"w": [0.5, 0.5], "phi2": 0.05, "beta": 12.0, "sigma2": 1.0},
              bounds=dict(phi1=(-1.0, 0.1))), ValueError, r"bounds\['phi1'\]\[0\] must be >= 0"),
        (dict(bounds=dict(w=(0, 1))), ValueError, "bounds cannot be given for w"),
        (dict(start=dict(phi2=0.1)), ValueError, "not being fitted"),
        (dict(start=dict(w=[0.5, 0.6])), ValueError, r"start\[.w.\] must sum to 1"),
        (dict(n_starts=0), ValueError, "n_starts must be an integer >= 1"),
        (dict(max_iter=0), ValueError, "max_iter must be an integer >= 1"),
        (dict(stopping=0), ValueError, "stopping must be an integer >= 1"),
        (dict(stopping="long"), TypeError, "stopping must be mdft.FixedTime"),
        (dict(fixed={**FIXED_ALL, "phi1": -0.5}), ValueError, r"fixed\['phi1'\] must be >= 0"),
        (dict(fixed={**FIXED_ALL, "sigma2": "x"}), TypeError, r"fixed\['sigma2'\] must be a real"),
        (dict(n_screen_per_start=0), ValueError, "n_screen_per_start must be an integer >= 1"),
        (dict(method="magic"), ValueError, "method must be 'auto'"),
        (dict(params="M", fixed={**FIXED_ALL, "w": [0.5, 0.5]}, bounds=dict(M=(0.0, 2.0))),
         ValueError, r"M lies outside bounds\['M'\]"),
        (dict(params="M", fixed={**FIXED_ALL, "w": [0.5, 0.5]}, bounds=dict(M=([0, 0, 0], 5))),
         ValueError, r"bounds\['M'\]\[0\] must be a number or an array of shape \(2, 2\)"),
        (dict(params="M", fixed={**FIXED_ALL, "w": [0.5, 0.5]}, bounds=dict(M=3.0)),
         ValueError, r"bounds\['M'\] must be a pair \(lower, upper\) \(got 3.0\)"),
        (dict(params=["phi1"], fixed={"w": [0.5, 0.5], "phi2": 0.05, "beta": 12.0, "sigma2": 1.0},
              bounds=dict(phi1=1)), ValueError, r"bounds\['phi1'\] must be a pair"),
        (dict(params=["phi1"], fixed={"w": [0.5, 0.5], "phi2": 0.05, "beta": 12.0, "sigma2": 1.0},
              bounds=dict(phi1=(0, 1, 2))), ValueError, r"bounds\['phi1'\] must be a pair"),
        (dict(rng="abc"), TypeError, "rng must be None, a non-negative int seed"),
        (dict(rng=-3), ValueError, "rng must be None, a non-negative int seed"),
    ],
)
def test_fit_bad_input(small_data, kwargs, exc, match):
    args = dict(stopping=10, params=["w"], fixed=FIXED_ALL, n_starts=1, rng=0)
    args.update(kwargs)
    with pytest.raises(exc, match=match):
        fit(small_data, [[1.0, 3.0], [3.0, 1.0]], **args)


def test_an_unstable_fitted_model_is_not_called_converged():
    # phi2 = 3 gives rho(S) = 6.3: over 20 steps preferences grow by 9e15 along S's leading
    # direction, so the triple's shares hardly depend on w; the fit warns and says why
    data = ChoiceData([[0, 1], [0, 1, 2]], [[55, 45], [30, 28, 42]])
    M = [[1, 3], [3, 1], [2, 2]]
    with pytest.warns(mdft.FitConvergenceWarning, match="feedback matrix S is unstable"):
        res = fit(data, M, stopping=20, params=["w"], rng=0,
                  fixed=dict(phi1=0.022, phi2=3.0, beta=12.0, sigma2=1.0))
    assert not res.converged and "spectral radius 6.269" in res.message
    # the same data with a stable fixed phi2 converge
    stable = fit(data, M, stopping=20, params=["w"], rng=0, fixed=FIXED_ALL)
    assert stable.converged


def test_fit_bad_data_and_M(small_data):
    with pytest.raises(TypeError, match="data must be an mdft.ChoiceData"):
        fit([[6, 4]], [[1.0, 3.0], [3.0, 1.0]], stopping=10, fixed=FIXED_ALL)
    with pytest.raises(ValueError, match="data refers to 3 options but M has only 2 rows"):
        fit(ChoiceData([[0, 2]], [[1, 1]]), [[1.0, 3.0], [3.0, 1.0]], stopping=10,
            fixed=FIXED_ALL)
    with pytest.raises(ValueError, match="M must contain only finite values"):
        fit(small_data, [[1.0, np.nan], [3.0, 1.0]], stopping=10, fixed=FIXED_ALL)
    with pytest.raises(ValueError, match="w cannot be fitted with a single attribute"):
        fit(small_data, [[1.0], [3.0]], stopping=10, fixed=FIXED_ALL)


def test_non_convergence_warns(small_data):
    with pytest.warns(mdft.FitConvergenceWarning, match="did not converge"):
        fit(small_data, [[1.0, 3.0], [3.0, 1.0]], stopping=10, params=["w", "phi2"],
            fixed=dict(phi1=0.022, beta=12.0, sigma2=1.0), max_iter=1, n_starts=1, rng=0)


# ============================================================== real data (smoke)
def test_thesis_time_based_recovery(shared_data):
    problems = load_thesis_set(
        shared_data / "mdft-thesis" / "time_based" / "set_nopts10_ncomb5_nproblem50_no3.mat")
    assert len(problems) == 50
    for p in problems[:2]:
        assert p.time_based and p.n_steps == 50 and p.data.n_subsets == 5
        res = fit(p.data, p.M, stopping=p.n_steps, params=["w"],
                  fixed={k: v for k, v in p.true_params.items() if k != "w"}, n_starts=2, rng=0)
        assert res.mse < 2e-4
        se = res.standard_errors["w"][0]
        assert np.isfinite(se) and abs(res.params["w"][0] - p.w[0]) < 4 * se


def test_thesis_conventions_sd_noise(shared_data):
    """The thesis's sig2 is a standard deviation: sigma2 = sig2**2 fits its data."""
    problems = load_thesis_set(
        shared_data / "mdft-thesis" / "time_based" / "set_nopts7_ncomb10_nproblem50_no3.mat")
    p = problems[0]
    assert p.sigma2 == pytest.approx(p.sig2**2)
    pred = probabilities(p.M, p.data.subsets, p.true_params, p.n_steps)
    mse = np.mean(np.concatenate([(a - b) ** 2 for a, b in zip(pred, p.data.shares)]))
    assert mse < 1e-4


def test_sushi_loads(shared_data):
    s = load_sushi(shared_data / "mdft-thesis" / "pref_based" / "sushi.json")
    assert s.M.shape == (10, 2)
    assert s.train.n_subsets == 10 and s.test.n_subsets == 5
    assert set(s.train.n_trials.tolist()) == {5000}
    assert s.params["theta"] == 10.0


def test_loader_bad_path(tmp_path):
    with pytest.raises(FileNotFoundError, match="path must be an existing .mat file"):
        load_thesis_set(tmp_path / "missing.mat")
    bad = tmp_path / "bad.json"
    bad.write_text('{"M": [[1, 2]]}')
    with pytest.raises(ValueError, match="lacks the field 'idx'"):
        load_sushi(bad)


def test_threshold_fit_exact_two_options():
    fn = getattr(mdft, "threshold_probabilities", None)
    if fn is None or not hasattr(mdft, "Threshold"):
        pytest.skip("mdft.threshold_probabilities not available")
    M = np.array([[1.0, 3.0], [3.0, 1.0]])
    params = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
    stop = mdft.Threshold(5.0, max_steps=2000)
    p = fn(mdft.MDFTModel(M, [0.65, 0.35], **params), 5.0, max_steps=2000).probabilities
    data = ChoiceData([[0, 1]], [np.round(p / p.sum() * 10_000).astype(int)])
    res = fit(data, M, stopping=stop, params=["w"], fixed=params, n_starts=1, rng=0,
              threshold_options=dict(n_cells=60))
    assert res.engine == "threshold_exact"
    # the data are the model's own probabilities rounded to 1e-4: w comes back to about
    # that precision, far inside its standard error (0.0026 for 10,000 trials)
    assert abs(res.params["w"][0] - 0.65) < 1e-3


def test_screening_finds_the_better_optimum():
    # Data generated at w = 0.7; the first start (w = 0.5) sits where every subset's
    # prediction is near-deterministic; several screened starts reach the optimum.
    M = np.array([[6.96, 6.16], [1.84, 9.58], [9.76, 2.34]])
    params = dict(phi1=0.0535, phi2=0.0646, beta=10.0, sigma2=1.018)
    p = probabilities(M, [[0, 1, 2]], dict(w=np.array([0.7, 0.3]), **params), 25)[0]
    data = ChoiceData([[0, 1, 2]], [np.round(p * 10_000).astype(int)])
    res = fit(data, M, stopping=25, params=["w"], fixed=params, n_starts=4, rng=0)
    # the data are the model's own probabilities rounded to 1e-4: the optimum is w = 0.7
    assert abs(res.params["w"][0] - 0.7) < 1e-3


@settings(deadline=None, max_examples=10)
@given(seed=hst.integers(0, 10_000))
def test_property_log_likelihood_ignores_option_order(seed):
    """Listing the options of each subset in another order changes nothing."""
    rng = np.random.default_rng(seed)
    subsets = [list(rng.permutation(5)[:k]) for k in (2, 3, 3)]
    counts = [rng.integers(0, 50, size=len(s)) + 1 for s in subsets]
    perms = [rng.permutation(len(s)) for s in subsets]
    d1 = ChoiceData(subsets, counts)
    d2 = ChoiceData([np.array(s)[p] for s, p in zip(subsets, perms)],
                    [np.array(c)[p] for c, p in zip(counts, perms)], n_options=d1.n_options)
    kw = dict(stopping=20, params=["w"], fixed=others("w"), n_starts=1, max_iter=3, rng=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.FitConvergenceWarning)
        a, b = fit(d1, M5, **kw), fit(d2, M5, **kw)
    assert abs(a.log_likelihood - b.log_likelihood) < 1e-8 * max(1.0, abs(a.log_likelihood))
    for p, q, perm in zip(a.predicted, b.predicted, perms):
        np.testing.assert_allclose(q, p[perm], atol=1e-6)
