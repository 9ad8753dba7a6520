"""The fixed-time closed form: moments, orthant probabilities, singular cases, bad input.

Reference values come from (a) a brute-force step-by-step recursion of the moments,
(b) scipy's multivariate normal CDF, (c) Monte Carlo simulation of MDFT, with a tolerance
of 3 standard errors of the Monte Carlo estimate, and (d) analytic limiting cases.
"""

import warnings

import numpy as np
import pytest
import scipy.stats as st
from hypothesis import given, settings
from hypothesis import strategies as hst

import mdft
from mdft import MDFTModel, choice_probabilities, preference_moments
from mdft.closed_form import _probabilities_from_moments

CANON = dict(phi1=0.022, phi2=0.05, beta=12.0)
A, B = [1.0, 3.0], [3.0, 1.0]
SETS = {
    "binary": [A, B],
    "similarity": [A, B, [0.9, 3.1]],
    "compromise": [A, B, [2.0, 2.0]],
    "attraction": [A, B, [0.5, 2.5]],
}


def model(M, w=(0.5, 0.5), **kw):
    params = {**CANON, "sigma2": 1.0, **kw}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return MDFTModel(M, list(w), **params)


def brute_moments(m, T):
    """Step-by-step recursion of the mean and covariance of P(t)."""
    S, mu, phi = np.asarray(m.S), m.valence_mean, m.valence_covariance
    xi, om = np.asarray(m.P0, float).copy(), np.zeros((m.n_options, m.n_options))
    for _ in range(T):
        xi = S @ xi + mu
        om = S @ om @ S.T + phi
    return xi, om


def monte_carlo(m, T, n_trials, seed):
    """Choice shares from ``mdft.simulate`` and the number of trials behind them."""
    res = mdft.simulate(m, n_trials, stopping=mdft.FixedTime(T), rng=seed)
    return np.asarray(res.probabilities), n_trials


def orthant_reference(mean, cov):
    """Choice probabilities from scipy's multivariate normal CDF."""
    n = mean.size
    out = []
    for i in range(n):
        L = -np.eye(n)[np.arange(n) != i]
        L[:, i] = 1.0
        if n == 2:
            out.append(st.norm.sf(0.0, loc=(L @ mean)[0], scale=np.sqrt((L @ cov @ L.T)[0, 0])))
        else:
            out.append(st.multivariate_normal.cdf(
                np.zeros(n - 1), mean=-(L @ mean), cov=L @ cov @ L.T, abseps=1e-6, releps=1e-6,
                rng=0))
    return np.array(out)


# ------------------------------------------------------------------ moments
@pytest.mark.parametrize("name", list(SETS))
@pytest.mark.parametrize("T", [1, 2, 3, 17, 100, 257])
def test_moments_match_brute_force(name, T):
    m = model(SETS[name])
    mean, cov = preference_moments(m, T)
    xi, om = brute_moments(m, T)
    np.testing.assert_allclose(mean, xi, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(cov, om, rtol=1e-10, atol=1e-10 * np.abs(om).max())


def test_moments_with_initial_preference_and_spectral_radius_one():
    # S = I exactly: xi = P0 + T mu and Omega = T Phi.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        m = MDFTModel.from_matrices([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5]], [0.3, 0.7],
                                    S=np.eye(3), P0=[1.0, -2.0, 0.5])
    for T in (1, 10, 1000):
        mean, cov = preference_moments(m, T)
        np.testing.assert_allclose(mean, m.P0 + T * m.valence_mean, atol=1e-9)
        np.testing.assert_allclose(cov, T * m.valence_covariance, rtol=1e-12, atol=1e-9)


def test_moments_are_symmetric_psd_and_inputs_untouched():
    m = model(SETS["compromise"])
    S_before = np.array(m.S)
    mean, cov = preference_moments(m, 100)
    np.testing.assert_array_equal(cov, cov.T)
    assert np.linalg.eigvalsh(cov).min() > -1e-9 * np.abs(cov).max()
    np.testing.assert_array_equal(m.S, S_before)


# ------------------------------------------------------------------ orthant probabilities
@pytest.mark.parametrize("n", [2, 3, 4, 5])
@pytest.mark.parametrize("seed", range(3))
def test_probabilities_match_scipy_mvn(n, seed):
    rng = np.random.default_rng(seed)
    mean = rng.normal(size=n)
    X = rng.normal(size=(n, n))
    cov = X @ X.T + 0.1 * np.eye(n)
    p = _probabilities_from_moments(mean, cov)
    ref = orthant_reference(mean, cov)
    tol = 1e-12 if n <= 3 else 5e-5  # Owen's T is exact; n >= 4 uses quasi-Monte Carlo
    np.testing.assert_allclose(p, ref, atol=tol)
    assert abs(p.sum() - 1.0) < 1e-12


def test_bivariate_special_points():
    # Zero means: Pr = 1/4 + asin(rho)/(2 pi) for each pair comparison.
    cov = np.array([[2.0, 0.3, 0.1], [0.3, 1.0, -0.2], [0.1, -0.2, 1.5]])
    p = _probabilities_from_moments(np.zeros(3), cov)
    np.testing.assert_allclose(p, orthant_reference(np.zeros(3), cov), atol=1e-12)
    for i in range(3):
        L = -np.eye(3)[np.arange(3) != i]
        L[:, i] = 1.0  # the two differences P_i - P_j
        D = L @ cov @ L.T
        rho = D[0, 1] / np.sqrt(D[0, 0] * D[1, 1])
        assert p[i] == pytest.approx(0.25 + np.arcsin(rho) / (2 * np.pi), abs=1e-12)
    # One comparison with mean exactly zero.
    mean = np.array([0.5, 0.5, -0.1])
    np.testing.assert_allclose(_probabilities_from_moments(mean, cov),
                               orthant_reference(mean, cov), atol=1e-12)


# ------------------------------------------------------------------ against Monte Carlo
@pytest.mark.parametrize("name", list(SETS))
def test_closed_form_agrees_with_monte_carlo_canonical_sets(name):
    """Within 3 standard errors sqrt(p (1 - p) / n_trials) per option, T = 100."""
    m = model(SETS[name])
    p = choice_probabilities(m, 100)
    q, n_trials = monte_carlo(m, 100, 200_000, seed=list(SETS).index(name))
    se = np.sqrt(np.maximum(q * (1 - q), 1e-4) / n_trials)
    assert np.all(np.abs(p - q) <= 3 * se), (p, q, se)


def test_canonical_effects_in_closed_form():
    """The effects with fixed deliberation time, as measured (docs/concepts.md, section 8).

    Compromise and attraction grow with T; the similarity effect (B's share among choices of A
    or B rises above its binary 0.5) shows for short deliberations and reverses for long ones.
    All three point the expected way at T = 32.
    """
    def effects(T):
        p_bin = choice_probabilities(model(SETS["binary"]), T)
        p_sim = choice_probabilities(model(SETS["similarity"]), T)
        p_com = choice_probabilities(model(SETS["compromise"]), T)
        p_att = choice_probabilities(model(SETS["attraction"]), T)
        similarity = p_sim[1] / (p_sim[0] + p_sim[1]) - p_bin[1]
        compromise = p_com[2] - max(p_com[0], p_com[1])
        attraction = p_att[0] / (p_att[0] + p_att[1]) - p_bin[0]
        return similarity, compromise, attraction

    sim10, com10, _ = effects(10)
    sim32, com32, att32 = effects(32)
    sim100, com100, att100 = effects(100)
    assert sim10 > 0.05 and com10 < 0
    assert sim32 > 0 and com32 > 0 and att32 > 0.05
    assert sim100 < -0.05 and com100 > 0.1 and att100 > 0.2


# ------------------------------------------------------------------ singular cases
def test_sigma2_zero_one_attribute_is_deterministic():
    m = MDFTModel([[1.0], [3.0], [2.0]], [1.0], **CANON, sigma2=0.0)
    np.testing.assert_array_equal(choice_probabilities(m, 50, method="normal"), [0.0, 1.0, 0.0])


def test_identical_options_split_ties_exactly():
    m = MDFTModel([[2.0], [2.0], [1.0]], [1.0], **CANON, sigma2=0.0)
    np.testing.assert_allclose(choice_probabilities(m, 10, method="normal"), [0.5, 0.5, 0.0])
    m = MDFTModel([[2.0], [2.0], [2.0]], [1.0], **CANON, sigma2=0.0)
    np.testing.assert_allclose(choice_probabilities(m, 10, method="normal"), [1 / 3] * 3)
    # Twins with attention switching only (sigma2 = 0): their preferences stay equal, and with
    # w = (1/2, 1/2) the valence is +-(-1, -1, 2) with equal chance, so P(t) is symmetric about
    # its zero mean: B wins half the time and the twins split the other half.
    m = MDFTModel([[1, 3], [1, 3], [3, 1]], [0.5, 0.5], **CANON, sigma2=0.0)
    for T in (1, 30):
        np.testing.assert_allclose(choice_probabilities(m, T, method="normal"), [0.25, 0.25, 0.5], atol=1e-12)


def test_sigma2_zero_rank_one_covariance_is_exact():
    # T = 1, sigma2 = 0, two attributes: P(1) = C M e_j, one of two points.
    M = np.array([[1.0, 3.0], [3.0, 1.0], [2.2, 2.2]])
    w = np.array([0.3, 0.7])
    m = MDFTModel(M, w, **CANON, sigma2=0.0)
    # The Gaussian with the same two moments: P = xi + a z along one direction.
    p = choice_probabilities(m, 1, method="normal")
    mean, cov = preference_moments(m, 1)
    vals, vecs = np.linalg.eigh(cov)
    a = vecs[:, -1] * np.sqrt(vals[-1])
    z = np.linspace(-9, 9, 400_001)
    choice = np.argmax(mean[None, :] + z[:, None] * a[None, :], axis=1)
    dens = st.norm.pdf(z) * (z[1] - z[0])
    ref = np.array([dens[choice == i].sum() for i in range(3)])
    np.testing.assert_allclose(p, ref, atol=1e-4)
    assert np.isclose(np.linalg.matrix_rank(cov), 1)


def test_sigma2_zero_many_options_rank_deficient():
    # Five options, two attributes, sigma2 = 0, T = 2: the covariance has rank <= 2.
    M = np.array([[1.0, 3.0], [3.0, 1.0], [2.0, 2.0], [0.5, 2.5], [2.5, 1.2]])
    m = MDFTModel(M, [0.4, 0.6], **CANON, sigma2=0.0)
    p = choice_probabilities(m, 2, method="normal")
    mean, cov = preference_moments(m, 2)
    # Reference: sample the degenerate Gaussian directly.
    rng = np.random.default_rng(3)
    vals, vecs = np.linalg.eigh(cov)
    keep = vals > 1e-12 * vals.max()
    Z = rng.standard_normal((400_000, keep.sum()))
    P = mean + Z @ (vecs[:, keep] * np.sqrt(vals[keep])).T
    q = np.bincount(P.argmax(axis=1), minlength=5) / len(P)
    se = np.sqrt(np.maximum(q * (1 - q), 1e-4) / len(P))
    assert np.all(np.abs(p - q) < 4 * se + 1e-4), (p, q)
    assert abs(p.sum() - 1) < 1e-9


def test_identity_feedback_matches_brute_force_probabilities():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        m = MDFTModel.from_matrices(SETS["compromise"], [0.5, 0.5], S=np.eye(3))
    mean, cov = preference_moments(m, 100)
    np.testing.assert_allclose(choice_probabilities(m, 100, method="normal"), orthant_reference(mean, cov),
                               atol=1e-12)


# ------------------------------------------------------------------ properties
@settings(deadline=None, max_examples=30)
@given(
    n=hst.integers(2, 5),
    seed=hst.integers(0, 10_000),
    T=hst.integers(1, 150),
    sigma2=hst.sampled_from([0.0, 0.3, 1.0]),
)
def test_property_sum_to_one_and_permutation(n, seed, T, sigma2):
    rng = np.random.default_rng(seed)
    M = rng.uniform(0, 4, size=(n, 2))
    w = rng.dirichlet([1, 1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        m = MDFTModel(M, w, phi1=0.05, phi2=0.04, beta=5.0, sigma2=sigma2)
        perm = rng.permutation(n)
        mp = MDFTModel(M[perm], w, phi1=0.05, phi2=0.04, beta=5.0, sigma2=sigma2)
    p = choice_probabilities(m, T, method="normal")
    assert np.all(p >= 0) and abs(p.sum() - 1) < 1e-9
    tol = 1e-9 if n <= 3 else 2e-4
    np.testing.assert_allclose(choice_probabilities(mp, T, method="normal"), p[perm], atol=tol)


def test_dominated_option_almost_never_chosen():
    m = model([[3.0, 3.0], [1.0, 1.0], [2.9, 3.1]])
    assert choice_probabilities(m, 100)[1] < 1e-6


# ------------------------------------------------------------------ bad input
def test_bad_n_steps():
    m = model(SETS["binary"])
    with pytest.raises(ValueError, match="n_steps must be an integer >= 1"):
        choice_probabilities(m, 0)
    with pytest.raises(TypeError, match="n_steps must be an integer"):
        choice_probabilities(m, 2.5)
    with pytest.raises(TypeError, match="n_steps must be an integer"):
        preference_moments(m, True)
    with pytest.raises(ValueError, match="n_steps must be an integer >= 1"):
        preference_moments(m, -3)


def test_bad_model():
    with pytest.raises(TypeError, match="model must be an mdft.MDFTModel"):
        choice_probabilities(np.eye(2), 10)
    with pytest.raises(TypeError, match="model must be an mdft.MDFTModel"):
        preference_moments("model", 10)


def test_non_finite_moments_warn():
    # A strongly expansive S over a very long horizon overflows: say so, do not hide it.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        m = MDFTModel.from_matrices(SETS["compromise"], [0.5, 0.5], S=2.0 * np.eye(3))
    with pytest.raises(ValueError, match="n_steps=5000 is too long for this model: the moments"):
        choice_probabilities(m, 5000)


# ------------------------------------------------------------------ exact mixture
def test_mixture_agrees_with_monte_carlo_and_bounds_gaussian_error():
    from mdft.closed_form import mixture_choice_probabilities

    m = model(SETS["similarity"])
    mix = mixture_choice_probabilities(m, 20, n_sequences=20_000, rng=0)
    assert abs(mix.probabilities.sum() - 1) < 1e-12
    q, n_trials = monte_carlo(m, 20, 400_000, seed=5)
    se = np.sqrt(q * (1 - q) / n_trials + mix.standard_errors**2)
    assert np.all(np.abs(mix.probabilities - q) <= 3 * se), (mix.probabilities, q, se)
    # The normal approximation is off by about 1e-3 on this set (docs/closed_form.md).
    gauss = choice_probabilities(m, 20)
    assert np.all(np.abs(gauss - mix.probabilities) < 3e-3)


def test_mixture_binary_symmetry_and_reproducibility():
    from mdft.closed_form import mixture_choice_probabilities

    m = model(SETS["binary"])
    a = mixture_choice_probabilities(m, 30, n_sequences=5000, rng=3)
    b = mixture_choice_probabilities(m, 30, n_sequences=5000, rng=3)
    np.testing.assert_array_equal(a.probabilities, b.probabilities)
    assert abs(a.probabilities[0] - 0.5) < 4 * a.standard_errors[0]


def test_mixture_bad_input():
    from mdft.closed_form import mixture_choice_probabilities

    m0 = model(SETS["compromise"], sigma2=0.0)
    with pytest.raises(ValueError, match="needs sigma2 > 0"):
        mixture_choice_probabilities(m0, 10)
    with pytest.raises(ValueError, match="n_sequences must be an integer >= 100"):
        mixture_choice_probabilities(model(SETS["binary"]), 10, n_sequences=10)
    with pytest.raises(ValueError, match="n_steps must be an integer >= 1"):
        mixture_choice_probabilities(model(SETS["binary"]), 0)


@pytest.mark.parametrize("q", [3, 4, 6])
def test_randomised_separation_of_variables_is_unbiased(q):
    # independent reference: SciPy's multivariate normal CDF (Pr(m + L z > 0) = Phi_q(m; LL^T))
    from scipy.stats import multivariate_normal

    from mdft._orthant import sov_orthants_many

    rng = np.random.default_rng(q)
    B = rng.normal(size=(q, q))
    cov = B @ B.T + 0.1 * np.eye(q)
    L = np.linalg.cholesky(cov)
    means = rng.normal(scale=1.5, size=(4, q))
    n_points = 40_000
    u = rng.random((means.shape[0], n_points, q - 1))
    est = sov_orthants_many(means, L, u)
    # standard error from the spread of 100 batch means (each an unbiased estimate itself)
    batches = np.stack([sov_orthants_many(means, L, u[:, k::100, :]) for k in range(100)])
    assert np.allclose(batches.mean(axis=0), est, rtol=1e-12, atol=1e-15)
    se = batches.std(axis=0, ddof=1) / np.sqrt(100)
    mvn = multivariate_normal(mean=np.zeros(q), cov=cov, abseps=1e-7, releps=1e-7)
    exact = np.array([mvn.cdf(m) for m in means])
    assert np.all(np.abs(est - exact) <= 4 * se + 2e-6), (est, exact, se)
