"""MDFTModel: the matrices against their definitions, properties, and every bad-input error."""

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import mdft
from mdft import MDFTModel, UnstableFeedbackWarning, contrast_matrix, distance_matrix

CANON = dict(phi1=0.022, phi2=0.05, beta=12.0)
A, B = (1.0, 3.0), (3.0, 1.0)


def hotaling_distance_2d(M, beta):
    """Hotaling's distance for two attributes, from the rotated coordinates (DESIGN.md)."""
    M = np.asarray(M, float)
    n = M.shape[0]
    D = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            d1, d2 = M[i] - M[j]
            dI = (d2 - d1) / np.sqrt(2)
            dD = (d1 + d2) / np.sqrt(2)
            D[i, j] = dI**2 + beta * dD**2
    return D


# ---------------------------------------------------------------- definitions
def test_contrast_matrix_definition():
    C = contrast_matrix(4)
    assert np.allclose(np.diag(C), 1.0)
    assert np.allclose(C[~np.eye(4, dtype=bool)], -1.0 / 3.0)


def test_distance_matches_two_attribute_rotation():
    M = [A, B, (2.0, 2.0), (0.5, 2.5)]
    assert np.allclose(distance_matrix(M, beta=12.0), hotaling_distance_2d(M, 12.0))
    assert np.allclose(distance_matrix(M, beta=3.5), hotaling_distance_2d(M, 3.5))


def test_beta_one_is_euclidean():
    rng = np.random.default_rng(0)
    M = rng.normal(size=(5, 3))
    euclid = ((M[:, None, :] - M[None, :, :]) ** 2).sum(axis=2)
    assert np.allclose(distance_matrix(M, beta=1.0), euclid)


def test_feedback_matrix_definition():
    model = MDFTModel([A, B], [0.5, 0.5], **CANON)
    expected = np.eye(2) - 0.05 * np.exp(-0.022 * hotaling_distance_2d([A, B], 12.0) ** 2)
    assert np.allclose(model.S, expected)
    assert model.spectral_radius == pytest.approx(np.max(np.abs(np.linalg.eigvals(expected))))


def test_valence_moments_match_sampling():
    """mu and Phi are the mean and covariance of V = C (M W + eps)."""
    rng = np.random.default_rng(1)
    model = MDFTModel([A, B, (2.0, 2.0)], [0.3, 0.7], sigma2=0.5, **CANON)
    n = 400_000
    j = rng.choice(2, size=n, p=model.w)
    V = (model.M[:, j].T + rng.normal(scale=np.sqrt(0.5), size=(n, 3))) @ model.C.T
    assert np.allclose(V.mean(axis=0), model.valence_mean, atol=0.01)
    assert np.allclose(np.cov(V.T), model.valence_covariance, atol=0.02)


def test_arrays_are_read_only_copies():
    M = np.array([A, B])
    model = MDFTModel(M, [0.5, 0.5], **CANON)
    M[0, 0] = 99.0
    assert model.M[0, 0] == 1.0
    with pytest.raises(ValueError, match="read-only"):
        model.S[0, 0] = 0.0


def test_unstable_feedback_warns_only_for_meaningful_growth():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        MDFTModel([A, B], [0.5, 0.5], **CANON)  # rho = 0.962
        MDFTModel([A, B, (2.0, 2.0)], [0.5, 0.5], **CANON)  # rho = 1.0089: 2.4-fold over 100
        twins = MDFTModel([A, A, B], [0.5, 0.5], phi1=0.022, phi2=0.0, beta=12.0)
        assert twins.spectral_radius >= 1.0  # 1 or a rounding above it
        MDFTModel.from_matrices([A, B], [0.5, 0.5], S=np.eye(2) * (1 + 2**-52))
        MDFTModel.from_matrices([A, B], [0.5, 0.5], S=np.eye(2) * 1.023)  # 1.023**100 = 9.7
    with pytest.warns(UnstableFeedbackWarning,
                      match=r"spectral radius 1.024: preferences can grow by a factor of up to "
                            r"10.7 over a deliberation of 100 steps \(the reference length\), "
                            r"more than 10; lower phi2"):
        MDFTModel.from_matrices([A, B], [0.5, 0.5], S=np.eye(2) * 1.024)
    with pytest.warns(UnstableFeedbackWarning, match="spectral radius"):
        MDFTModel([A, B, (2.0, 2.0)], [0.5, 0.5], phi1=0.022, phi2=0.2, beta=12.0)


@settings(max_examples=60, deadline=None)
@given(rho=st.floats(0.5, 1.2), n_steps=st.integers(1, 2000))
def test_growth_warning_follows_the_documented_rule(rho, n_steps):
    """Warn exactly where rho ** n_steps > GROWTH_LIMIT, for the model and for fixed time."""
    from mdft.model import GROWTH_LIMIT, REFERENCE_STEPS

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = MDFTModel.from_matrices([A, B], [0.5, 0.5], S=np.eye(2) * rho, sigma2=0.0)
    assert bool(caught) == (rho**REFERENCE_STEPS > GROWTH_LIMIT)
    if 2 * n_steps * np.log(max(rho, 1.0)) > 600:  # the covariance grows like rho^(2T)
        return
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mdft.preference_moments(m, n_steps)
    assert bool(caught) == (rho**n_steps > GROWTH_LIMIT)
    if caught:
        assert f"n_steps={n_steps} steps" in str(caught[0].message)


def test_from_matrices_and_subset():
    S = np.diag([0.9, 0.8, 0.7])
    model = MDFTModel.from_matrices([[1.0], [2.0], [3.0]], [1.0], S=S)
    assert np.allclose(model.C, contrast_matrix(3))
    sub = model.subset([2, 0])
    assert np.allclose(sub.S, np.diag([0.7, 0.9]))
    assert np.allclose(sub.M.ravel(), [3.0, 1.0])


def test_subset_rebuilds_parametric_matrices():
    full = MDFTModel([A, B, (2.0, 2.0)], [0.5, 0.5], **CANON)
    pair = full.subset([0, 1])
    direct = MDFTModel([A, B], [0.5, 0.5], **CANON)
    assert np.allclose(pair.S, direct.S)
    assert np.allclose(pair.C, direct.C)


def test_replace():
    model = MDFTModel([A, B], [0.5, 0.5], **CANON)
    other = model.replace(phi2=0.01, w=[0.2, 0.8])
    assert other.phi2 == 0.01 and np.allclose(other.w, [0.2, 0.8])
    assert model.phi2 == 0.05


# ------------------------------------------------------------------ properties
matrices = st.integers(2, 6).flatmap(
    lambda n: st.integers(1, 4).flatmap(
        lambda J: arrays(np.float64, (n, J), elements=st.floats(-5, 5, allow_nan=False))
    )
)


@settings(deadline=None, max_examples=60)
@given(M=matrices, beta=st.floats(0, 20), phi1=st.floats(0, 1), phi2=st.floats(0, 0.2))
def test_contrast_columns_sum_to_zero_and_S_symmetric(M, beta, phi1, phi2):
    J = M.shape[1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnstableFeedbackWarning)
        model = MDFTModel(M, np.full(J, 1.0 / J), phi1=phi1, phi2=phi2, beta=beta)
    assert np.allclose(model.C.sum(axis=0), 0.0)
    assert np.allclose(model.S, model.S.T)
    assert np.allclose(np.diag(model.S), 1.0 - phi2)
    assert np.all(model.D >= -1e-9)
    assert np.allclose(model.valence_mean.sum(), 0.0, atol=1e-9)


# ------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(M=[[1.0, 2.0]]), ValueError, r"M must have at least 2 options .*got shape \(1, 2\)"),
        (dict(M=[1.0, 2.0]), ValueError, r"M must be a 2-d array \(got 1-d"),
        (dict(M=[[1.0, np.nan], [2.0, 1.0]]), ValueError, "M must contain only finite values"),
        (dict(M=[[1.0, np.inf], [2.0, 1.0]]), ValueError, "M must contain only finite values"),
        (dict(M=[["a", "b"], ["c", "d"]]), TypeError, "M must be an array of real numbers"),
        (dict(w=[0.5, 0.3]), ValueError, r"w must sum to 1 \(got 0.8\)"),
        (dict(w=[1.5, -0.5]), ValueError, r"w must be non-negative \(got \[1.5, -0.5\]\)"),
        (dict(w=[1.0]), ValueError, r"w must have one weight per attribute, length 2 \(got length 1\)"),
        (dict(w=[np.nan, 0.5]), ValueError, "w must contain only finite values"),
        (dict(phi1=-0.1), ValueError, r"phi1 must be >= 0.0 \(got -0.1\)"),
        (dict(phi2=np.inf), ValueError, r"phi2 must be finite \(got inf\)"),
        (dict(beta=-1), ValueError, r"beta must be >= 0.0 \(got -1.0\)"),
        (dict(beta="12"), TypeError, "beta must be a real number"),
        (dict(sigma2=-1.0), ValueError, r"sigma2 must be >= 0.0 \(got -1.0\)"),
        (dict(P0=[0.0, 0.0, 0.0]), ValueError, r"P0 must have shape \(2\) \(got \(3,\)\)"),
        (dict(P0=[0.0, np.nan]), ValueError, "P0 must contain only finite values"),
    ],
)
def test_bad_input(kwargs, error, match):
    params = dict(M=[A, B], w=[0.5, 0.5], **CANON)
    params.update(kwargs)
    M, w = params.pop("M"), params.pop("w")
    with pytest.raises(error, match=match):
        MDFTModel(M, w, **params)


def test_bad_input_from_matrices_and_helpers():
    with pytest.raises(ValueError, match=r"S must have shape \(2, 2\) \(got \(3, 3\)\)"):
        MDFTModel.from_matrices([A, B], [0.5, 0.5], S=np.eye(3))
    with pytest.raises(ValueError, match=r"C must have shape \(2, 2\)"):
        MDFTModel.from_matrices([A, B], [0.5, 0.5], S=np.eye(2), C=np.eye(3))
    with pytest.raises(ValueError, match=r"n_options must be >= 2 \(got 1\)"):
        contrast_matrix(1)
    with pytest.raises(TypeError, match="n_options must be an integer"):
        contrast_matrix(2.0)
    model = MDFTModel([A, B], [0.5, 0.5], **CANON)
    with pytest.raises(ValueError, match=r"options must lie in \[0, 1\] \(got \[0, 2\]\)"):
        model.subset([0, 2])
    with pytest.raises(ValueError, match="at least two distinct indices"):
        model.subset([1, 1])
    with pytest.raises(TypeError, match="options must be a 1-d sequence of integers"):
        model.subset([0.0, 1.0])
    with pytest.raises(TypeError, match=r"unknown parameter\(s\) \['theta'\]"):
        model.replace(theta=1.0)
    custom = MDFTModel.from_matrices([A, B, A], [0.5, 0.5], S=np.eye(3), C=np.eye(3))
    with pytest.raises(ValueError, match="subset needs the standard contrast matrix"):
        custom.subset([0, 1])
    with pytest.raises(ValueError, match="replace needs a parametric model"):
        custom.replace(sigma2=2.0)


def test_public_names():
    assert mdft.MDFTModel is MDFTModel
