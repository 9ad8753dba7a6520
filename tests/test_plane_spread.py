"""The spread of the summed preference among the walks about to decide
(``mdft._plane_spread``), which the three-option moment chain evaluates its steps with."""

import math
import warnings

import numba
import numpy as np
import pytest

import mdft
from mdft import _plane_passes, _plane_spread
from mdft._plane_chain import plane_geometry
from mdft.simulate import _fallback_trials, _reduced_args


def _random_model(rng):
    """A three-option model of the documented range whose walks decide within a few
    hundred steps (so that the independent simulation below stays quick)."""
    n_attributes = int(rng.integers(2, 4))
    model = mdft.MDFTModel(rng.uniform(0.5, 4.0, (3, n_attributes)),
                           rng.dirichlet(np.full(n_attributes, 4.0)),
                           phi1=float(np.exp(rng.uniform(np.log(0.005), np.log(0.1)))),
                           phi2=float(rng.uniform(0.01, 0.1)),
                           beta=float(rng.uniform(1.0, 15.0)),
                           sigma2=float(np.exp(rng.uniform(np.log(0.5), np.log(4.0)))))
    return model, float(rng.uniform(5.0, 25.0))


def _spread(model, theta, max_steps, E, ref):
    """The spread about the plane ``ref`` of the walks the chain simulates."""
    return _plane_spread.spread_about(_plane_spread.simulate_walks(model, theta, max_steps), E,
                                      ref)


def _numpy_last_sums(model, theta, max_steps, n, seed):
    """Sums and plane coordinates' source (the preferences) of ``n`` walks the step before
    they decide, after the first step: plain numpy, three normals a step through ``C``."""
    rng = np.random.default_rng(seed)
    S, C, CM = model.S, model.C, model.C @ model.M
    P = np.tile(np.asarray(model.P0, dtype=float), (n, 1))
    alive = np.ones(n, dtype=bool)
    last = []
    for t in range(1, max_steps + 1):
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            break
        before = P[idx]
        attended = rng.choice(model.n_attributes, size=idx.size, p=model.w)
        noise = rng.normal(0.0, math.sqrt(model.sigma2), (idx.size, 3)) @ C.T
        P[idx] = before @ S.T + CM[:, attended].T + noise
        decided = (P[idx] >= theta).any(axis=1)
        alive[idx[decided]] = False
        if t >= 2:
            last.append(before[decided])
    return np.concatenate(last)


def _numpy_positions(model, theta, max_steps, n, seed):
    """The preferences of ``n`` walks at every step after which they stand undecided: plain
    numpy, three normals a step through ``C``."""
    rng = np.random.default_rng(seed)
    S, C, CM = model.S, model.C, model.C @ model.M
    P = np.tile(np.asarray(model.P0, dtype=float), (n, 1))
    alive = np.ones(n, dtype=bool)
    seen = []
    for _ in range(max_steps):
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            break
        attended = rng.choice(model.n_attributes, size=idx.size, p=model.w)
        noise = rng.normal(0.0, math.sqrt(model.sigma2), (idx.size, 3)) @ C.T
        P[idx] = P[idx] @ S.T + CM[:, attended].T + noise
        alive[idx[(P[idx] >= theta).any(axis=1)]] = False
        seen.append(P[alive])
    return np.concatenate(seen)


@pytest.mark.parametrize("seed", range(3))
def test_the_plane_matches_an_independent_simulation(seed):
    # the least-squares plane of the sum over the plane coordinates at every undecided step
    # of the walks, against the same fit to 8,000 walks simulated in numpy: the two planes'
    # sums, where those walks went, differ by far less than the sums' spread about them
    rng = np.random.default_rng(4420 + seed)
    model, theta = _random_model(rng)
    E = plane_geometry(model, theta, 1.0)["E"]
    got = _plane_spread.walk_plane(_plane_spread.simulate_walks(model, theta, 3000), E)
    P = _numpy_positions(model, theta, 3000, 8_000, seed)
    X = np.c_[np.ones(P.shape[0]), P @ E]
    want = np.linalg.lstsq(X, P.sum(axis=1), rcond=None)[0]
    spread = float(np.std(P.sum(axis=1) - X @ want))
    # each fit rests on thousands of independent walks: a plane's sums stray from the true
    # one's by a few hundredths of the spread
    assert got is not None
    assert float(np.sqrt(np.mean((X @ (got - want)) ** 2))) < 0.15 * spread
    # the slopes matter here: the flat plane at the mean sum is far off
    flat = np.array([float(np.mean(P.sum(axis=1))), 0.0, 0.0])
    assert float(np.sqrt(np.mean((X @ (flat - want)) ** 2))) > 0.5 * spread


def test_the_plane_needs_walks_that_decide():
    model, _ = _random_model(np.random.default_rng(4413))
    E = plane_geometry(model, 60.0, 1.0)["E"]
    walks = _plane_spread.simulate_walks(model, 60.0, 5)
    assert walks.moments[0, 0] > 0.0  # undecided steps were counted
    assert _plane_spread.walk_plane(walks, E) is None
    assert _plane_spread.spread_about(walks, E, np.zeros(3)) is None


def test_walks_whose_sums_overflowed_fit_nothing():
    # no plane, no spread, and no warning from arithmetic on infinities: the pilots take over
    E = plane_geometry(*_random_model(np.random.default_rng(4414)), 1.0)["E"]
    steps = np.full(300, 5)
    good = _plane_spread.Walks(steps, np.ones((300, 3)), np.eye(4))
    for walks in (good.__class__(steps, good.last, np.full((4, 4), np.inf)),
                  good.__class__(steps, np.full((300, 3), -np.inf), np.full((4, 4), np.nan))):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert _plane_spread.walk_plane(walks, E) is None
            if not np.isfinite(walks.last).all():
                assert _plane_spread.spread_about(walks, E, np.zeros(3)) is None


@pytest.mark.parametrize("seed", range(4))
def test_the_spread_matches_an_independent_simulation(seed):
    rng = np.random.default_rng(4400 + seed)
    model, theta = _random_model(rng)
    E = plane_geometry(model, theta, 1.0)["E"]
    ref = np.array([rng.normal(0.0, 3.0), rng.normal(0.0, 0.3), rng.normal(0.0, 0.3)])
    got = _spread(model, theta, 3000, E, ref)
    P = _numpy_last_sums(model, theta, 3000, 20_000, seed)
    assert (P < theta).all()
    deviation = P.sum(axis=1) - (ref[0] + (P @ E) @ ref[1:])
    want = float(np.std(deviation, ddof=1))
    # these walks decide within a few hundred steps, so the function simulates MAX_TRIALS
    # (at least half of them decided after the first step): the relative standard error of
    # a standard deviation is about 1 / sqrt(2 n) for each side
    n_got = _plane_spread.MAX_TRIALS // 2
    tol = 4.0 * math.sqrt(1.0 / (2 * n_got) + 1.0 / (2 * P.shape[0]))
    assert got is not None
    assert abs(got / want - 1.0) < tol, (got, want, tol)


def test_its_walks_are_the_fallbacks_trials():
    # the same streams and draws as the simulation fallback's kernel: the same decision
    # steps, trial by trial, from the same generator
    model, theta = _random_model(np.random.default_rng(4411))
    args = _reduced_args(model, theta, 2000)
    steps, last, _ = _plane_spread._trials(args, 3000, np.random.default_rng(7))
    _, want = _fallback_trials(model, 3000, theta, 2000, np.random.default_rng(7))
    np.testing.assert_array_equal(steps, want)
    assert (last[steps > 0] < theta).all()


def test_the_spread_and_the_plane_do_not_depend_on_the_threads():
    model, theta = _random_model(np.random.default_rng(4412))
    E = plane_geometry(model, theta, 1.0)["E"]
    ref = np.array([1.0, 0.1, -0.2])
    walks = _plane_spread.simulate_walks(model, theta, 3000)
    first, plane = _plane_spread.spread_about(walks, E, ref), _plane_spread.walk_plane(walks, E)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        walks = _plane_spread.simulate_walks(model, theta, 3000)
        one = _plane_spread.spread_about(walks, E, ref)
        plane_one = _plane_spread.walk_plane(walks, E)
    finally:
        numba.set_num_threads(threads)
    assert first == one
    np.testing.assert_array_equal(plane, plane_one)


def test_too_few_walks_decide_to_measure_a_spread():
    model, _ = _random_model(np.random.default_rng(4413))
    E = plane_geometry(model, 60.0, 1.0)["E"]
    # a threshold that no walk reaches within five steps
    assert _spread(model, 60.0, 5, E, np.zeros(3)) is None


def _recorded_call(monkeypatch):
    """The compromise set's default call, recording the planes and spreads the walks give
    and each chain built: ``(planes, spreads, builds)``, a build ``(kappa, ref, delta)``."""
    planes, spreads, built = [], [], []
    real_plane, real_spread = _plane_passes.walk_plane, _plane_passes.spread_about
    real_build = _plane_passes.build_moment_chain

    def plane(*args):
        planes.append(real_plane(*args))
        return planes[-1]

    def spread(*args):
        spreads.append(real_spread(*args))
        return spreads[-1]

    def build(model, theta, kappa, ref, delta, *args, **kwargs):
        built.append((kappa, np.array(ref, dtype=float), delta))
        return real_build(model, theta, kappa, ref, delta, *args, **kwargs)

    monkeypatch.setattr(_plane_passes, "walk_plane", plane)
    monkeypatch.setattr(_plane_passes, "spread_about", spread)
    monkeypatch.setattr(_plane_passes, "build_moment_chain", build)
    # the compromise set: the parametric feedback's unequal column sums move the sum
    model = mdft.MDFTModel([[1, 3], [3, 1], [2, 2]], [0.5, 0.5], phi1=0.022, phi2=0.05,
                           beta=12.0)
    mdft.threshold_probabilities(model, 12.0)
    return planes, spreads, built


def test_the_passes_use_the_walks_plane_and_spread(monkeypatch):
    planes, spreads, built = _recorded_call(monkeypatch)
    assert len(planes) == 1 and len(spreads) == 1 and spreads[0] > 0.0
    # no pilot: the first chain is the first pass that counts, on the walks' plane with their
    # spread, and the closure's spread probe runs with that spread over sqrt(2)
    first = _plane_passes.KAPPA * _plane_passes.REFINE
    assert built[0][0] == pytest.approx(first)
    assert all(kappa <= first + 1e-12 for kappa, _, _ in built)
    np.testing.assert_array_equal(built[0][1], planes[0])
    assert built[0][2] == spreads[0]
    deltas = {delta for _, _, delta in built}
    assert deltas <= {spreads[0], spreads[0] / _plane_passes.REFINE}
    assert spreads[0] / _plane_passes.REFINE in deltas


def test_without_the_walks_fit_the_pilots_fit_the_plane_and_the_walks_the_spread(
        monkeypatch):
    monkeypatch.setattr(_plane_passes, "WALK_FIT", False)
    planes, spreads, built = _recorded_call(monkeypatch)
    assert planes == [] and len(spreads) == 1 and spreads[0] is not None
    # two pilots (from the assumed spread, then from the first's fit), then the passes that
    # count with the spread measured about the pilots' plane
    assert [kappa for kappa, _, _ in built[:2]] == pytest.approx([2.0, 2.0])
    assert built[0][2] == _plane_passes.PILOT_DELTA
    assert built[2][2] == spreads[0]
    assert {delta for _, _, delta in built[2:]} <= {spreads[0],
                                                   spreads[0] / _plane_passes.REFINE}


def test_a_long_deliberation_whose_sum_moves_decides():
    # seed 1208 model 10 of the benchmark's draws: the first option is chosen after about
    # 1,070 steps. With the spread among the walks about to decide (0.48, against 1.84 in
    # the pilots), the closure's choices of the mass still far from the thresholds came out
    # negative at the level of rounding over the first hundred steps, and the geometric tail
    # took that for the slowest mode: p_undecided = 1 with an error estimate of 4e-7
    # (mdft._plane_tail; tests/test_threshold_tail.py). Now 0.02 % from 10^6 simulated trials
    # (the pilots' spread had left it 0.37 % short).
    model = mdft.MDFTModel([[0.9728, 1.4914], [0.7383, 1.8025], [2.0054, 3.337]],
                           [0.6573, 0.3427], phi1=0.04479, phi2=0.06347, beta=12.2963,
                           sigma2=0.1675)
    theta = 31.489
    res = mdft.threshold_probabilities(model, theta, fallback="raise")
    assert res.engine == "plane"
    assert res.p_undecided < 1e-3 and res.probabilities[0] > 0.999
    sim = mdft.simulate(model, 100_000, stopping=mdft.Threshold(theta, max_steps=10_000),
                        rng=5)
    steps = sim.decision_steps[sim.choices == 0]
    se = steps.std() / math.sqrt(steps.size) / steps.mean()
    assert abs(res.mean_response_times[0] / steps.mean() - 1.0) <= res.error_mean_rt + 4 * se
