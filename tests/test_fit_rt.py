"""Response times in the likelihood of mdft.fit: the joint likelihood of choice and
decision step, binned times, identification of theta and sigma2, bad input."""

import re
import warnings

import numpy as np
import pytest

import mdft
from mdft.likelihood import INFEASIBLE, LOOSER_TOLERANCES, PLANE_NOISE, Likelihood

M2 = np.array([[1.0, 3.0], [3.0, 1.0]])
KNOWN = dict(phi1=0.022, phi2=0.05, beta=12.0)
TRUTH = dict(w=np.array([0.6, 0.4]), sigma2=1.5, theta=6.0)
MAX_STEPS = 400


def model(w=TRUTH["w"], sigma2=TRUTH["sigma2"]):
    return mdft.MDFTModel(M2, w, sigma2=sigma2, **KNOWN)


def _joint_log_likelihood(ref, times):
    """``sum log f(i, t)`` over trials, straight from a ``threshold_probabilities`` result:
    ``times[i]`` the decision steps of the trials that chose option ``i``."""
    decided = 1.0 - ref.p_undecided
    return sum(np.log(ref.rt_pmf[t.astype(int) - 1, i] / decided).sum()
               for i, t in enumerate(times))


@pytest.fixture(scope="module")
def trials():
    sim = mdft.simulate(model(), 400, stopping=mdft.Threshold(TRUTH["theta"], MAX_STEPS),
                        rng=11)
    assert sim.n_undecided == 0
    return mdft.ChoiceData.from_trials([[0, 1]] * 400, sim.choices,
                                       response_times=sim.decision_steps)


@pytest.fixture(scope="module")
def rt_fit(trials):
    return mdft.fit(trials, M2, stopping=mdft.Threshold(4.0, MAX_STEPS),
                    params=["sigma2", "theta"], fixed=dict(w=TRUTH["w"], **KNOWN),
                    bounds=dict(sigma2=(0.2, 6.0), theta=(2.0, 20.0)), n_starts=2,
                    n_screen_per_start=4, tol=1e-7, rng=0)


def test_joint_log_likelihood_is_the_sum_over_trials_of_the_exact_pmf(trials, rt_fit):
    assert rt_fit.likelihood == "choices and decision steps"
    assert rt_fit.engine == "threshold_exact"
    for s2, th in ((1.0, 5.0), (2.5, 8.0)):
        ref = mdft.threshold_probabilities(model(sigma2=s2), th, max_steps=MAX_STEPS)
        direct = _joint_log_likelihood(ref, trials.response_times[0])
        got = rt_fit.log_likelihood_at(dict(sigma2=s2, theta=th))
        assert got == pytest.approx(direct, rel=1e-10)


# three iterations from one start on purpose: the fit only has to carry the binned likelihood
@pytest.mark.filterwarnings("ignore::mdft.FitConvergenceWarning")
def test_binned_log_likelihood_sums_the_pmf_over_bins(trials):
    edges = [0, 5, 10, 20, 40, MAX_STEPS]
    res = mdft.fit(trials, M2, stopping=mdft.Threshold(6.0, MAX_STEPS), params=["sigma2"],
                   fixed=dict(w=TRUTH["w"], **KNOWN), rt_bins=edges, n_starts=1, max_iter=3,
                   rng=0)
    assert res.likelihood == "choices and binned decision steps"
    np.testing.assert_array_equal(res.rt_bins, edges)
    ref = mdft.threshold_probabilities(model(sigma2=2.0), 6.0, max_steps=MAX_STEPS)
    cum = np.vstack([np.zeros(2), np.cumsum(ref.rt_pmf, axis=0)])
    direct = 0.0
    for i, t in enumerate(trials.response_times[0]):
        b = np.searchsorted(edges, t, side="left") - 1
        mass = (cum[edges[1:], i] - cum[edges[:-1], i]) / (1 - ref.p_undecided)
        direct += np.log(mass[b]).sum()
    assert res.log_likelihood_at(dict(sigma2=2.0)) == pytest.approx(direct, rel=1e-10)


def test_response_times_identify_theta_and_sigma2(trials, rt_fit):
    assert rt_fit.converged
    for name in ("sigma2", "theta"):
        se = rt_fit.standard_errors[name]
        assert np.isfinite(se) and se > 0
        # 4 standard errors: the estimate's own sampling error on 400 trials
        assert abs(rt_fit.params[name] - TRUTH[name]) < 4 * se
    # From the choices alone the two trade off: the same fit is far less precise
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.FitConvergenceWarning)
        choice = mdft.fit(trials, M2, stopping=mdft.Threshold(4.0, MAX_STEPS),
                          params=["sigma2", "theta"], fixed=dict(w=TRUTH["w"], **KNOWN),
                          bounds=dict(sigma2=(0.2, 6.0), theta=(2.0, 20.0)), n_starts=2,
                          n_screen_per_start=4, tol=1e-7, rng=0, response_times=False)
    assert choice.likelihood == "choices"
    se_theta = choice.standard_errors["theta"]
    assert not np.isfinite(se_theta) or se_theta > 5 * rt_fit.standard_errors["theta"]


def test_simulated_binned_likelihood_for_three_options():
    M3 = np.array([[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]])
    m = mdft.MDFTModel(M3, [0.5, 0.5], sigma2=1.0, **KNOWN)
    sim = mdft.simulate(m, 300, stopping=mdft.Threshold(5.0, 300), rng=2)
    data = mdft.ChoiceData.from_trials([[0, 1, 2]] * 300, sim.choices,
                                       response_times=sim.decision_steps)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.FitConvergenceWarning)
        res = mdft.fit(data, M3, stopping=mdft.Threshold(5.0, 300), params=["sigma2"],
                       fixed=dict(w=[0.5, 0.5], **KNOWN), n_starts=1, n_samples=4000,
                       max_iter=20, rng=0)
    assert res.engine == "simulation" and res.likelihood == "choices and binned decision steps"
    assert res.rt_bins[0] == 0 and res.rt_bins[-1] == 300 and res.rt_bins.size <= 11
    # the truth (sigma2 = 1) is far more likely than a tenfold noise
    assert res.log_likelihood_at(dict(sigma2=1.0)) > res.log_likelihood_at(dict(sigma2=10.0))


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        (dict(response_times="yes"), ValueError, "response_times must be 'auto', True or False"),
        (dict(stopping=20, response_times=True), ValueError,
         "response_times=True needs data with response times .* got fixed-time stopping"),
        (dict(stopping=20, rt_bins=5), ValueError, "rt_bins is given but response times"),
        (dict(rt_bins=[1, 5, MAX_STEPS]), ValueError, "rt_bins edges must cover every"),
        (dict(rt_bins=[0, 5, 3, MAX_STEPS]), ValueError,
         "rt_bins must be an integer or increasing"),
        (dict(rt_bins=0), ValueError, "rt_bins must be an integer >= 1"),
        (dict(stopping=mdft.Threshold(6.0, 10)), ValueError, "beyond stopping.max_steps=10"),
        (dict(params=["theta"], stopping=20), ValueError, "theta can be fitted only with"),
        (dict(fixed=dict(theta=3.0, sigma2=1.0, **KNOWN)), ValueError,
         r"theta is given by stopping=mdft.Threshold\(theta\)"),
        (dict(params=["w", "theta"], bounds=dict(theta=(0, 10))), ValueError,
         r"bounds\['theta'\]\[0\] must be > 0"),
        (dict(threshold_options=5), TypeError, "threshold_options must be a dict of "
         "mdft.threshold_probabilities keyword arguments \\(got int\\)"),
        (dict(threshold_options=dict(n_cell=50)), ValueError,
         r"threshold_options has unknown name\(s\) \['n_cell'\]; allowed: \['atol'"),
        (dict(threshold_options=dict(theta=5.0)), ValueError, "unknown name"),
        (dict(stopping=20, threshold_options=dict(atol=1e-3)), ValueError,
         "threshold_options is given, but this fit uses the 'closed_form' engine"),
        (dict(method="simulation", threshold_options=dict(atol=1e-3)), ValueError,
         "uses the 'simulation' engine"),
    ],
)
def test_fit_response_time_bad_input(trials, kwargs, exc, match):
    args = dict(stopping=mdft.Threshold(6.0, MAX_STEPS), params=["w"],
                fixed=dict(sigma2=1.0, **KNOWN), n_starts=1, max_iter=1, rng=0)
    args.update(kwargs)
    with pytest.raises(exc, match=match):
        mdft.fit(trials, M2, **args)


def test_times_must_be_decision_steps():
    data = mdft.ChoiceData.from_trials([[0, 1]] * 3, [0, 1, 0], response_times=[0.4, 2, 3])
    with pytest.raises(ValueError, match=r"response_times\[0\]\[0\] must be decision steps"):
        mdft.fit(data, M2, stopping=mdft.Threshold(5.0, 100), fixed=dict(sigma2=1.0, **KNOWN),
                 n_starts=1, rng=0)
    no_rt = mdft.ChoiceData([[0, 1]], [[2, 1]])
    with pytest.raises(ValueError, match="got no response times"):
        mdft.fit(no_rt, M2, stopping=mdft.Threshold(5.0, 100), fixed=dict(sigma2=1.0, **KNOWN),
                 response_times=True, n_starts=1, rng=0)


@pytest.mark.parametrize(
    "rts, exc, match",
    [
        ("abc", TypeError, "response_times must be a sequence with one entry per subset"),
        ([[[1], [2]], [[3], [4]]], ValueError, "response_times must have one entry per subset"),
        ([[[1, 2]]], ValueError, r"response_times\[0\] must hold one array per option"),
        ([[[1, 2], [3]]], ValueError, r"response_times\[0\]\[0\] must hold one time per trial"),
        ([[[1], [-3]]], ValueError, r"response_times\[0\]\[1\] must be >= 0"),
        ([[[1], [np.nan]]], ValueError, "must contain only finite values"),
    ],
)
def test_choice_data_response_times_bad_input(rts, exc, match):
    with pytest.raises(exc, match=match):
        mdft.ChoiceData([[0, 1]], [[1, 1]], response_times=rts)


def test_choice_data_response_times_are_read_only_copies():
    times = [np.array([3.0, 4.0]), np.array([5.0])]
    d = mdft.ChoiceData([[0, 1]], [[2, 1]], response_times=[times])
    times[0][0] = 99.0
    assert d.response_times[0][0].tolist() == [3.0, 4.0] and d.has_response_times
    with pytest.raises(ValueError, match="read-only"):
        d.response_times[0][0][0] = 1.0


M3 = np.array([[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]])


def _triple_trials():
    """300 trials of a triple with their decision steps, and the model they came from."""
    m = mdft.MDFTModel(M3, [0.5, 0.5], sigma2=1.0, **KNOWN)
    sim = mdft.simulate(m, 300, stopping=mdft.Threshold(6.0, MAX_STEPS), rng=5)
    assert sim.n_undecided == 0
    return m, mdft.ChoiceData.from_trials([[0, 1, 2]] * 300, sim.choices,
                                          response_times=sim.decision_steps)


# one iteration from one start on purpose: the fit only has to carry the exact likelihood
@pytest.mark.filterwarnings("ignore::mdft.FitConvergenceWarning")
def test_exact_joint_likelihood_for_three_options():
    m, data = _triple_trials()
    res = mdft.fit(data, M3, stopping=mdft.Threshold(6.0, MAX_STEPS), params=["sigma2"],
                   fixed=dict(w=[0.5, 0.5], **KNOWN), method="threshold_exact", n_starts=1,
                   max_iter=1, rng=0)
    assert res.engine == "threshold_exact" and res.likelihood == "choices and decision steps"
    for s2 in (0.7, 1.6):
        ref = mdft.threshold_probabilities(m.replace(sigma2=s2), 6.0, max_steps=MAX_STEPS,
                                           fallback="raise")
        assert ref.engine == "plane"
        direct = _joint_log_likelihood(ref, data.response_times[0])
        assert res.log_likelihood_at(dict(sigma2=s2)) == pytest.approx(direct, rel=1e-10)


def test_exact_fit_of_a_triple_finds_its_optimum_and_standard_error():
    # the exact engine's likelihood on three options is smooth only to about 1e-6 of itself
    # (mdft.likelihood.PLANE_NOISE): with the Hessian's default step of 1e-4 this fit's
    # standard error came out at 0.0053, and without the bounds the fit took 914
    # evaluations and said it had not converged (docs/fitting.md, section 3)
    _, data = _triple_trials()
    res = mdft.fit(data, M3, stopping=mdft.Threshold(6.0, MAX_STEPS), params=["sigma2"],
                   fixed=dict(w=[0.5, 0.5], **KNOWN), bounds=dict(sigma2=(0.5, 2.0)),
                   method="threshold_exact", n_starts=2, n_screen_per_start=2, rng=0)
    assert res.converged, res.message
    x0, ll0 = res.params["sigma2"], res.log_likelihood
    around = {d: res.log_likelihood_at(dict(sigma2=x0 + d)) for d in (-0.05, -0.01, 0.01, 0.05)}
    band = 2.0 * PLANE_NOISE * abs(ll0)
    assert all(ll <= ll0 + band for ll in around.values()), (ll0, around)
    curvature = (around[-0.05] - 2.0 * ll0 + around[0.05]) / 0.05**2
    assert res.standard_errors["sigma2"] == pytest.approx(1.0 / np.sqrt(-curvature), rel=0.03)


# a triple of benchmarks/bench_fit_rt.py (model 3, seed 1003; M and w to four decimals):
# over a whole region of sigma2 and theta about its truth the moment closure's term sits at
# the default tolerances, and the exact engine refuses them (docs/fitting.md, "Where the
# exact engine cannot vouch")
M_AT_THE_DEFAULTS = np.array([[0.5633, 0.7701], [1.4840, 1.9824], [2.2563, 2.1693]])
W_AT_THE_DEFAULTS = np.array([0.4362, 0.5638])


def _trials_at_the_defaults():
    """200 trials of that triple at ``sigma2 = 1.8``, ``theta = 14.7``, and the model."""
    m = mdft.MDFTModel(M_AT_THE_DEFAULTS, W_AT_THE_DEFAULTS, sigma2=1.8, **KNOWN)
    sim = mdft.simulate(m, 200, stopping=mdft.Threshold(14.7, MAX_STEPS), rng=3)
    assert sim.n_undecided == 0
    return m, mdft.ChoiceData.from_trials([[0, 1, 2]] * 200, sim.choices,
                                          response_times=sim.decision_steps)


def test_where_the_exact_engine_cannot_meet_its_defaults_the_likelihood_asks_looser_ones():
    m, data = _trials_at_the_defaults()
    with pytest.raises(mdft.ThresholdToleranceError, match="atol=0.001"):
        mdft.threshold_probabilities(m, 14.7, max_steps=MAX_STEPS, fallback="raise")
    looser = mdft.threshold_probabilities(m, 14.7, max_steps=MAX_STEPS, fallback="raise",
                                          **LOOSER_TOLERANCES)
    assert looser.engine == "plane"
    stop = mdft.Threshold(14.7, MAX_STEPS)
    p = dict(M=M_AT_THE_DEFAULTS, w=W_AT_THE_DEFAULTS, sigma2=1.8, theta=14.7, **KNOWN)

    def likelihood(options):
        return Likelihood(data, stop, "threshold_exact", use_rt=True, rt_bins=None,
                          n_samples=0, seed=0, threshold_options=options)

    lik = likelihood(None)
    direct = _joint_log_likelihood(looser, data.response_times[0])
    assert lik.log_likelihood(p) == pytest.approx(direct, rel=1e-12)
    assert (lik.n_loosened, lik.last_loosened, lik.n_failed) == (1, True, 0)
    # tolerances the caller set are kept: no second try, an impossible point as before
    strict = likelihood(dict(atol=1e-3))
    assert strict.negative(p) == INFEASIBLE and strict.n_loosened == 0
    assert strict.first_failure.startswith("ThresholdToleranceError")


def test_a_fit_says_which_evaluations_were_answered_at_looser_tolerances(trials, monkeypatch):
    # the binary lattice made to refuse its defaults wherever sigma2 > 1.4 (the truth is 1.5):
    # the fit is carried there by the second tries, and its message says how many, the
    # optimum's included, and its log-likelihood is the looser one's
    real = mdft.threshold_probabilities

    def refusing(model, theta, **options):
        if model.sigma2 > 1.4 and "atol" not in options:
            raise mdft.ThresholdToleranceError("refused at the defaults (a test)")
        return real(model, theta, **options)

    monkeypatch.setattr(mdft.likelihood, "_threshold_exact_function", lambda: refusing)
    res = mdft.fit(trials, M2, stopping=mdft.Threshold(TRUTH["theta"], MAX_STEPS),
                   params=["sigma2"], fixed=dict(w=TRUTH["w"], **KNOWN), rng=0)
    assert res.converged and res.params["sigma2"] > 1.4, res.message
    found = re.search(r"vouched for (\d+) of (\d+) likelihood evaluations, the optimum's "
                      r"among them, only at atol=0.003, rt_rtol=0.01", res.message)
    assert found, res.message
    assert 0 < int(found[1]) < int(found[2]) and "failed" not in res.message
    ref = real(model(sigma2=res.params["sigma2"]), TRUTH["theta"], max_steps=MAX_STEPS,
               **LOOSER_TOLERANCES)
    assert res.log_likelihood == pytest.approx(
        _joint_log_likelihood(ref, trials.response_times[0]), rel=1e-12)


def test_the_likelihood_says_how_smooth_it_is():
    _, triple = _triple_trials()
    pairs = mdft.ChoiceData([[0, 1], [1, 2]], [[3, 2], [1, 4]])
    stop = mdft.Threshold(6.0, MAX_STEPS)

    def noise(data, engine):
        return Likelihood(data, stop, engine, use_rt=False, rt_bins=None, n_samples=100,
                          seed=0, threshold_options=None).noise

    assert noise(triple, "threshold_exact") == PLANE_NOISE > 0.0
    assert noise(pairs, "threshold_exact") == 0.0  # the binary lattice: smooth to rounding
    assert noise(triple, "simulation") == 0.0  # a step function, optimised by Nelder-Mead
