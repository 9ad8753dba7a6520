"""Fuzzing the public API of ``mdft``: bad and edge inputs get a ValueError or TypeError that
names the parameter, never another exception (no OverflowError, LinAlgError, IndexError, ...).

Each test replaces one argument of a cheap, valid call by a drawn value and checks what
escapes. Valid draws simply run; the sizes are kept small so that the suite takes seconds.
"""

import json
import warnings

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import mdft  # noqa: E402
from fuzzing import FUZZ, odd, run, scalars  # noqa: E402
from mdft import datasets, plot  # noqa: E402

M3 = [[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]]
W = [0.5, 0.5]
CANON = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
counts = st.one_of(odd, st.integers(-5, 60), st.integers(10**8 + 1, 2**80))
reals = st.floats(allow_nan=True, allow_infinity=True, width=64)
matrices = st.one_of(
    odd,
    st.lists(st.lists(reals, min_size=0, max_size=3), min_size=0, max_size=4),
    st.lists(st.lists(st.integers(-(10**400), 10**400), min_size=2, max_size=2), min_size=2,
             max_size=3),
    st.sampled_from([np.zeros((2, 0)), np.zeros((0, 2)), np.ones((2, 2, 2)), np.ones(3),
                     [[1e300, 1e300], [-1e300, 1e300]], [[1e200, 0.0], [0.0, 1e200]],
                     [["a", "b"], [1, 2]]]),
)


def model(**changes):
    params = dict(M=M3, w=W, **CANON)
    params.update(changes)
    M, w = params.pop("M"), params.pop("w")
    return mdft.MDFTModel(M, w, **params)


def use(m):
    """Exercise a model through the cheap engines."""
    mdft.simulate(m, 50, stopping=mdft.FixedTime(20), rng=0)
    mdft.simulate(m, 50, stopping=mdft.Threshold(3.0, max_steps=50), rng=0)
    mdft.choice_probabilities(m, 20)


@FUZZ
@given(name=st.sampled_from(["phi1", "phi2", "beta", "sigma2"]), value=scalars)
def test_model_parameters(name, value):
    run(lambda: use(model(**{name: value})), name, "M and", "n_steps", "S has")


@FUZZ
@given(M=matrices)
def test_model_evaluations(M):
    run(lambda: use(model(M=M)), "M", "w must have one weight per attribute")
    run(lambda: mdft.distance_matrix(M, beta=12.0), "M")
    run(lambda: mdft.decide(M, W, n_steps=5, rng=0, **CANON), "M", "w must have shape")


@FUZZ
@given(w=matrices, P0=matrices)
def test_attention_and_start(w, P0):
    run(lambda: use(model(w=w)), "w")
    run(lambda: use(model(P0=P0)), "P0", "model.P0")
    run(lambda: mdft.decide(M3, w, n_steps=5, rng=0, **CANON), "w")


@FUZZ
@given(S=matrices, C=matrices)
def test_explicit_matrices(S, C):
    run(lambda: use(mdft.MDFTModel.from_matrices(M3[:2], W, S=S)), "S", "n_steps", "M and")
    run(lambda: mdft.MDFTModel.from_matrices(M3[:2], W, S=np.eye(2), C=C), "C")
    run(lambda: mdft.feedback_matrix(S, phi1=0.1, phi2=0.1), "D")


@FUZZ
@given(value=counts)
def test_counts(value):
    m = model()
    run(lambda: mdft.simulate(m, value, stopping=mdft.FixedTime(5), rng=0), "n_samples")
    run(lambda: mdft.FixedTime(value), "n_steps")
    run(lambda: mdft.Threshold(3.0, max_steps=value), "max_steps")
    run(lambda: mdft.simulate(m, 50, stopping=mdft.FixedTime(5), n_trajectories=value),
        "n_trajectories")
    run(lambda: mdft.choice_probabilities(m, value), "n_steps")
    run(lambda: mdft.preference_moments(m, value), "n_steps")
    run(lambda: mdft.mixture_choice_probabilities(m, 5, n_sequences=value, rng=0),
        "n_sequences")
    run(lambda: mdft.decide(M3, W, n_steps=value, rng=0, **CANON), "n_steps")
    run(lambda: mdft.contrast_matrix(value), "n_options")
    run(lambda: mdft.context_effects("attraction", stopping=mdft.FixedTime(5),
                                     n_samples=value, rng=0), "n_samples")


@FUZZ
@given(value=scalars)
def test_stopping_and_criteria(value):
    m = model()
    run(lambda: mdft.simulate(m, 50, stopping=mdft.Threshold(value, max_steps=30), rng=0),
        "theta")
    run(lambda: mdft.simulate(m, 50, stopping=value, rng=0), "stopping")
    run(lambda: mdft.context_effects("similarity", stopping=mdft.FixedTime(5), n_samples=100,
                                     criterion=value, rng=0), "criterion")
    run(lambda: mdft.context_effects(value, stopping=mdft.FixedTime(5), n_samples=100, rng=0),
        "scenarios")
    run(lambda: mdft.context_effects("similarity", method=value, n_samples=100), "method")
    run(lambda: mdft.simulate(m, 50, stopping=mdft.FixedTime(5), rng=0).summary(labels=value),
        "labels")
    run(lambda: m.subset(value), "options")
    run(lambda: mdft.MDFTModel.from_dict(value), "data")


@FUZZ
@given(value=st.one_of(odd, scalars, st.just(np.random.SeedSequence(1)),
                       st.just(np.random.default_rng(1))))
def test_rng(value):
    # every entry point that draws resolves rng alike and names it when it cannot
    m = model()
    run(lambda: mdft.simulate(m, 20, stopping=mdft.FixedTime(5), rng=value), "rng")
    run(lambda: mdft.decide(M3, W, n_steps=5, rng=value, **CANON), "rng")
    run(lambda: mdft.mixture_choice_probabilities(m, 5, n_sequences=100, rng=value), "rng")
    run(lambda: mdft.context_effects("similarity", stopping=mdft.FixedTime(5), n_samples=100,
                                     rng=value), "rng")
    run(lambda: mdft.threshold_probabilities(m.subset([0, 1]), 3.0, rng=value), "rng")


@FUZZ
@given(data=st.dictionaries(st.sampled_from(["M", "w", "phi1", "phi2", "beta", "S", "C",
                                             "sigma2", "P0", "labels"]),
                            st.one_of(scalars, matrices), max_size=6))
def test_model_from_dict(data):
    base = {"M": M3, "w": W, "phi1": 0.022, "phi2": 0.05, "beta": 12.0}
    run(lambda: use(mdft.MDFTModel.from_dict({**base, **data})), "data", *data, "M and",
        "n_steps", "S has")


@FUZZ
@given(value=st.one_of(odd, st.text(max_size=30)), n_trials=counts)
def test_datasets(value, n_trials, tmp_path_factory):
    run(lambda: datasets.thesis_sets(value), "kind")
    # A path to nothing is a FileNotFoundError, as for open() and numpy.load.
    run(lambda: datasets.load_thesis_set(value), "path",
        errors=(ValueError, TypeError, FileNotFoundError))
    name = "time_based/set_nopts3_ncomb1_nproblem50_no3"
    run(lambda: datasets.load_thesis_set(name, n_trials=n_trials), "n_trials", "n_trials")


@FUZZ
@given(content=st.one_of(st.binary(max_size=200),
                         st.recursive(st.one_of(st.none(), st.booleans(), st.floats(),
                                                st.text(max_size=4)),
                                      lambda x: st.lists(x, max_size=3)
                                      | st.dictionaries(st.text(max_size=3), x, max_size=3),
                                      max_leaves=8).map(lambda v: json.dumps(v).encode())))
def test_dataset_files(content, tmp_path_factory):
    folder = tmp_path_factory.mktemp("files")
    for name, load in (("x.mat", datasets.load_thesis_set), ("x.json", datasets.load_sushi)):
        path = folder / name
        path.write_bytes(content)
        try:
            load(path)
        except ValueError as exc:
            assert name in str(exc)


@FUZZ
@given(value=st.one_of(odd, matrices))
def test_plots(value):
    res = mdft.context_effects("compromise", stopping=mdft.FixedTime(5), n_samples=100, rng=0)
    fig, ax = plt.subplots()
    try:
        run(lambda: plot.plot_choice_shares(ax, value), "result")
        run(lambda: plot.plot_choice_shares(ax, res["compromise"], n_se=value), "n_se")
        run(lambda: plot.plot_trajectories(ax, value), "trajectories")
        run(lambda: plot.plot_trajectories(value, np.zeros((1, 3, 2))), "ax")
        run(lambda: plot.plot_context_effects(value), "results")
    finally:
        plt.close("all")


def test_known_cases():
    """The inputs reported as crashing, each answered by its parameter's name."""
    cases = [
        (lambda: mdft.Threshold(10**400), ValueError, "theta must be finite"),
        (lambda: mdft.simulate(model(), 2**63, stopping=mdft.FixedTime(5)), ValueError,
         "n_samples must be an integer <= 100,000,000"),
        (lambda: model(beta=1e300, phi1=0.0, M=[[1e200, 0.0], [0.0, 1e200]]), ValueError,
         "M and beta=1e[+]300 give distances"),
        (lambda: mdft.contrast_matrix(43562), ValueError,
         r"n_options must be an integer <= 1,000 \(got 43,562\)"),
        (lambda: mdft.distance_matrix(np.zeros((3, 0)), beta=1.0), ValueError,
         "M must have at least 1 attribute"),
        (lambda: mdft.context_effects(n_samples=1, rng=0), ValueError,
         "n_samples must be an integer >= 100"),
        # (at 50,000 steps the preferences are finite, about 1e193, and are simulated)
        (lambda: mdft.simulate(model(), 10, stopping=mdft.FixedTime(100_000)), ValueError,
         "preferences overflow over n_steps=100000 steps"),
    ]
    for call, error, match in cases:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with pytest.raises(error, match=match):
                call()


@FUZZ
@given(name=st.sampled_from(["name", "labels", "M", "target", "rivals", "measure", "expected",
                             "baseline", "direction", "w", "phi1", "phi2", "beta", "sigma2"]),
       value=st.one_of(scalars, matrices))
def test_context_effect_scenarios(name, value):
    run(lambda: mdft.ATTRACTION.with_parameters(**{name: value}), name, "M and", "M, C",
        "w must")
