"""Tests of the tails of mdft.threshold_probabilities' passes (``docs/threshold_exact.md``,
section 5): the geometric tail, the Krylov tail and when a pass stops, each against every
step propagated."""

import numpy as np
import pytest

from mdft import MDFTModel, _plane_passes, threshold_probabilities

from threshold_models import SETS, assert_matches_simulation, canonical, drawn, random_model


def test_geometric_tail_matches_full_propagation():
    model = canonical(SETS["similarity"])
    loose = dict(atol=0.01, rt_rtol=0.05)  # the point is the agreement of the two runs
    full = threshold_probabilities(model, 8.0, tail_tol=0.0, **loose)
    tail = threshold_probabilities(model, 8.0, **loose)
    assert tail.tail_start is not None and full.tail_start is None
    assert tail.n_iter < full.n_iter
    # the tail may change the answer by at most its share of the tolerances (which the
    # error estimate then includes)
    share = _plane_passes.TAIL_SHARE
    np.testing.assert_allclose(tail.probabilities, full.probabilities, atol=share * 0.01)
    np.testing.assert_allclose(tail.mean_response_times, full.mean_response_times,
                               rtol=share * 0.05)


@pytest.mark.parametrize("seed", [41, 42, 43, 44])
def test_extrapolated_tail_stays_within_its_own_estimate(seed):
    """On random three-option models (decided and undecided ones alike), filling the tail
    geometrically changes the answer by no more than the change it reports."""
    from mdft._plane_chain import build_moment_chain

    rng = np.random.default_rng(seed)
    model, theta = random_model(rng, 3, theta_range=(5.0, 30.0))
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    chain = build_moment_chain(model, theta, 1.4, ref, 0.5, 60_000)
    tail_against_full(chain, 1500, krylov=False)


def _coarse_chains(seed, n=4):
    """The moment chains (resolution 2, the pilots' first reference sum and spread) of the
    first ``n`` random three-option models of the test draws of ``seed``."""
    from mdft._plane_chain import build_moment_chain

    rng = np.random.default_rng(seed)
    for _ in range(n):
        model, theta = random_model(rng, 3)
        ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
        yield build_moment_chain(model, theta, 2.0, ref, 0.5, 60_000)


@pytest.mark.parametrize("seed", [2, 3, 5, 7])
def test_krylov_tail_stays_within_its_own_estimate(seed):
    """Random three-option models across the documented range (sigma2 0.1-4, theta 5-60)
    on a coarse grid, 6,000 steps: where the Krylov tail was filled, it changed the answer
    by no more than its estimate."""
    from mdft._plane_chain import _KRYLOV_FIRST, propagate_moments

    budget = (1e-5, 3e-5)
    used = 0
    for chain in _coarse_chains(seed):
        if propagate_moments(chain, 6000, 1e-14, budget)[3] < _KRYLOV_FIRST:
            continue  # decided, or a geometric tail (the test above)
        full, tail = tail_against_full(chain, 6000, budget=budget)
        used += tail[3] < 6000
    assert used >= 1  # each seed's four models include at least one long deliberation


def test_an_early_krylov_tail_stays_within_its_own_estimate():
    """The models of the test above with the schedule started early (``early``, given to
    the passes of a model whose pilots settle late): a tail filled from the less settled
    distribution after _KRYLOV_EARLY steps changed the answer by no more than its estimate,
    against every step propagated."""
    from mdft._plane_chain import _KRYLOV_EARLY

    budget = (1e-5, 3e-5)
    early = 0
    for seed in (2, 3, 5, 7):
        for chain in _coarse_chains(seed):
            _, tail = tail_against_full(chain, 6000, budget=budget, early=True)
            early += tail[3] == _KRYLOV_EARLY
    assert early >= 8  # most of the 16 (12 when written): the early try is what is tested


def test_krylov_tail_of_a_long_deliberation_saves_most_steps():
    """Seed 2026 model 5's slow next mode (section 5 of docs/threshold_exact.md): the Krylov
    tail starts at one of the first pauses and takes at most a hundred-odd steps of the
    chain, where the geometric tail alone needed thousands; both stay within their
    estimates."""
    from mdft._plane_chain import _KRYLOV_FIRST, build_moment_chain
    from mdft._plane_krylov import _DIMS

    model, theta = slow_mode_model()
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    chain = build_moment_chain(model, theta, 2.0, ref, 0.5, 60_000)
    _, krylov = tail_against_full(chain, 10_000, budget=(1e-5, 3e-5))
    _, geometric = tail_against_full(chain, 10_000, budget=(1e-5, 3e-5), krylov=False)
    assert krylov[3] in (_KRYLOV_FIRST, 2 * _KRYLOV_FIRST)
    assert krylov[2] - krylov[3] <= _DIMS[-1]
    assert geometric[2] > 6 * krylov[2]


def test_a_krylov_space_grows_past_its_cap_only_where_that_predicts_an_answer_cheaply():
    """Past a try's cap the space grows on only while the estimate falls, is predicted
    (geometrically, from the last two dimensions) to reach the budget within the largest
    dimension, and getting there costs less than the steps of the chain to the next try."""
    from mdft._plane_krylov import _DIMS, _worth_growing

    nonzeros, n_vec = 400_000, 12_000
    # falling tenfold per 20 dimensions from 100 times the budget: 40 more dimensions, which
    # cost 40 steps of the chain and Gram-Schmidt's products, against 250 steps
    assert _worth_growing((40, 1e3), (60, 1e2), 80, 250, nonzeros, n_vec)
    # the same fall, but the next try comes after 20 steps: cheaper to wait
    assert not _worth_growing((40, 1e3), (60, 1e2), 80, 20, nonzeros, n_vec)
    # no next try to compare with
    assert not _worth_growing((40, 1e3), (60, 1e2), 80, 0, nonzeros, n_vec)
    # not falling, or falling too slowly to reach the budget within the largest dimension
    assert not _worth_growing((40, 1e2), (60, 1e2), 80, 250, nonzeros, n_vec)
    assert not _worth_growing((40, 1.5e2), (60, 1e2), 80, 10_000, nonzeros, n_vec)
    assert _DIMS[-1] < 60 + 20 * np.log(1e2) / np.log(1.5)
    # a wide basis on a sparse chain: Gram-Schmidt's products dominate
    assert not _worth_growing((40, 1e3), (60, 1e2), 80, 250, 20_000, n_vec)


def test_krylov_start_follows_the_schedule_of_tries():
    """A finer pass's first Krylov try is where the coarser pass filled a Krylov tail (a
    point of the schedule: the first, doubled), the point after the try that failed
    before a geometric tail (filled between two points), and the schedule's first
    without a tail or with a geometric one before any try."""
    from mdft._plane_chain import _KRYLOV_FIRST, krylov_start

    first = _KRYLOV_FIRST
    assert krylov_start(None) == krylov_start(0) == krylov_start(first - 1) == first
    assert krylov_start(first) == first
    assert krylov_start(first + 1) == krylov_start(2 * first - 1) == 2 * first
    assert krylov_start(2 * first) == 2 * first
    assert krylov_start(8 * first) == 8 * first
    assert krylov_start(9 * first) == 16 * first
    # idempotent: a start passed on as krylov_from stays where it is
    for tail in (None, 0, first + 1, 9 * first):
        assert krylov_start(krylov_start(tail)) == krylov_start(tail)


def test_an_early_krylov_schedule_differs_only_before_the_usual_first_try():
    """With ``early`` the schedule starts at _KRYLOV_EARLY (half the usual first step):
    without a coarser tail, or after one filled before the usual first try, the first try
    comes earlier; after a tail filled later, where it would without ``early``. A try's
    cap depends only on its step."""
    from mdft._plane_chain import _KRYLOV_DIMS, _KRYLOV_EARLY, _KRYLOV_FIRST, krylov_start

    early = _KRYLOV_EARLY
    assert _KRYLOV_FIRST == 2 * early  # the usual schedule is the early one's second point on
    assert krylov_start(None, True) == krylov_start(0, True) == krylov_start(early - 1, True)
    assert krylov_start(None, True) == krylov_start(early, True) == early
    # a tail filled between the two first points was geometric after a failed early try
    assert krylov_start(early + 1, True) == krylov_start(_KRYLOV_FIRST, True) == _KRYLOV_FIRST
    for tail in (_KRYLOV_FIRST, _KRYLOV_FIRST + 1, 3 * _KRYLOV_FIRST, 9 * _KRYLOV_FIRST):
        assert krylov_start(tail, True) == krylov_start(tail)
        assert krylov_start(krylov_start(tail, True), True) == krylov_start(tail, True)
    assert len(_KRYLOV_DIMS) >= 3 and list(_KRYLOV_DIMS) == sorted(_KRYLOV_DIMS)


def _long_deliberation():
    """Seed 3 of the test draws, second model (theta 39.7)."""
    rng = np.random.default_rng(3)
    random_model(rng, 3)
    return random_model(rng, 3)


def test_a_krylov_space_grown_past_its_cap_fills_the_tail_at_the_first_try(monkeypatch):
    """The long deliberation of the test below on a coarse grid: at its first try the
    estimate falls from dimension 40 to 60 fast enough that growing the space on is worth
    it, and the tail is filled there, within its own estimate (against every step
    propagated) and with fewer steps of the chain than at the second try, where it is
    filled when every space stops at its cap."""
    from mdft import _plane_krylov
    from mdft._plane_chain import _KRYLOV_DIMS, _KRYLOV_FIRST, build_moment_chain

    model, theta = _long_deliberation()
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    chain = build_moment_chain(model, theta, 2.0, ref, 0.5, 60_000)
    budget = (1e-5, 3e-5)
    _, grown = tail_against_full(chain, 6000, budget=budget)
    assert grown[3] == _KRYLOV_FIRST
    assert grown[2] - grown[3] > _KRYLOV_DIMS[1]  # past the cap of the try at _KRYLOV_FIRST
    monkeypatch.setattr(_plane_krylov, "_worth_growing", lambda *args: False)
    _, capped = tail_against_full(chain, 6000, budget=budget)
    assert capped[3] == 2 * _KRYLOV_FIRST
    assert grown[2] < capped[2]


def test_a_finer_pass_leaves_out_the_krylov_tries_that_failed_on_the_coarser_grid(monkeypatch):
    """A random long deliberation (seed 3 of the test draws, theta 39.7) whose coarse pass
    fills its Krylov tail only at the second try when its spaces stop at their caps (the
    growth past a cap of the test above left out): the finer pass that starts there gives
    the very answer of the finer pass that tries from the first point on (its first try
    fails as well), without the failed try's work."""
    from mdft import _plane_chain, _plane_krylov
    from mdft._plane_chain import (_KRYLOV_FIRST, build_moment_chain, krylov_start,
                                   propagate_moments)

    tries = []
    tail = _plane_chain.krylov_tail
    monkeypatch.setattr(_plane_chain, "krylov_tail",
                        lambda *args: tries.append(args[3]) or tail(*args))
    monkeypatch.setattr(_plane_krylov, "_worth_growing", lambda *args: False)
    model, theta = _long_deliberation()
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    budget = (1e-5, 3e-5)
    coarse = propagate_moments(build_moment_chain(model, theta, 2.0, ref, 0.5, 60_000), 6000,
                               1e-14, budget)
    assert coarse[3] == 2 * _KRYLOV_FIRST
    fine = build_moment_chain(model, theta, 1.41, ref, 0.5, 60_000)
    tries.clear()
    every_try = propagate_moments(fine, 6000, 1e-14, budget)
    assert tries == [_KRYLOV_FIRST, 2 * _KRYLOV_FIRST]
    tries.clear()
    later = propagate_moments(fine, 6000, 1e-14, budget, krylov_from=krylov_start(coarse[3]))
    assert tries == [2 * _KRYLOV_FIRST]
    assert later[3] == every_try[3] == 2 * _KRYLOV_FIRST
    np.testing.assert_array_equal(later[0], every_try[0])
    assert later[1] == every_try[1]


@pytest.mark.parametrize("walks, switch", [(True, "EARLY_KRYLOV_WALK_STEPS"),
                                           (False, "EARLY_KRYLOV_PILOT_STEPS")])
def test_passes_try_the_krylov_tail_early_only_where_the_walks_settle_late(monkeypatch, walks,
                                                                          switch):
    """``threshold_probabilities`` starts its passes' Krylov schedule early where at least
    EARLY_KRYLOV_SHARE of the simulated walks are undecided after EARLY_KRYLOV_WALK_STEPS
    steps, or, where the pilots fit the reference sums, the last pilot ran at least
    EARLY_KRYLOV_PILOT_STEPS steps (a random model of seed 2 of the test draws, theta 58.1),
    and not where they settle sooner (the similarity set at a low threshold); the long
    one's answer is that of the usual schedule within the tails' budgets, which its
    estimate includes, and its last pass fills the tail at the early try."""
    from mdft._plane_chain import _KRYLOV_EARLY

    monkeypatch.setattr(_plane_passes, "WALK_FIT", walks)
    seen = []
    propagate = _plane_passes.propagate_moments
    monkeypatch.setattr(_plane_passes, "propagate_moments",
                        lambda *args, **kw: seen.append(kw.get("early")) or propagate(*args, **kw))
    steps = getattr(_plane_passes, switch)
    rng = np.random.default_rng(2)
    for _ in range(4):
        model, theta = random_model(rng, 3)
    early = threshold_probabilities(model, theta, fallback="raise")
    assert seen and all(seen)
    assert early.tail_start == _KRYLOV_EARLY
    seen.clear()
    monkeypatch.setattr(_plane_passes, switch, 10**9)
    usual = threshold_probabilities(model, theta, fallback="raise")
    assert seen and not any(seen)
    assert usual.resolution == early.resolution
    share = _plane_passes.TAIL_SHARE
    np.testing.assert_allclose(early.probabilities, usual.probabilities, atol=2 * share * 1e-3)
    # mean times weighed as in the error estimate (an option chosen with p = 1e-22 here
    # has no mean time to speak of)
    weight = np.minimum(1.0, usual.probabilities / 0.01)
    change = weight * np.abs(early.mean_response_times / usual.mean_response_times - 1.0)
    assert change.max() <= 2 * share * 3e-3
    monkeypatch.setattr(_plane_passes, switch, steps)
    seen.clear()
    threshold_probabilities(canonical(SETS["similarity"]), 8.0, fallback="raise")
    assert seen and not any(seen)


def test_a_run_stops_on_the_size_of_the_undecided_mass_not_its_signed_sum():
    """A random model (seed 777 of the benchmark's draws) whose moment closure lets the
    probabilities of some states turn negative: their signed sum fell below the stop
    tolerance while the walks still chose 1.3e-6 more of one option. Stopping on the sum of
    |x| gives every step's answer."""
    from mdft._plane_chain import build_moment_chain, propagate_moments, reference_sums

    model = drawn([[2.455354, 3.65308], [1.585164, 1.866527], [0.530718, 2.560094]],
                  [0.674101, 0.325899], phi1=0.08985654, phi2=0.03238458, beta=2.0401195,
                  sigma2=0.50501289)
    theta = 19.778292
    ref, delta = np.array([float(np.sum(model.P0)), 0.0, 0.0]), 0.5
    for _ in range(2):  # the reference sums as the library's pilots fit them
        pilot = build_moment_chain(model, theta, 2.0, ref, delta, 30_000)
        ref, delta, _ = reference_sums(pilot, propagate_moments(pilot, 1000, 1e-6,
                                                                second=True)[4])
    chain = build_moment_chain(model, theta, 1.41, ref, delta, 30_000)
    every = propagate_moments(chain, 10_000, -np.inf)
    stopped = propagate_moments(chain, 10_000, 1e-14)
    assert stopped[2] < 10_000
    np.testing.assert_allclose(stopped[0].sum(axis=0), every[0].sum(axis=0), rtol=0,
                               atol=1e-12)


def test_krylov_powers_match_matrix_powers():
    from mdft._plane_step import krylov_powers

    rng = np.random.default_rng(0)
    H = np.triu(rng.normal(size=(6, 6)) * 0.3, -1)
    out, n = krylov_powers(H, 2.0, 12, 0.0)
    assert n == 12
    for k in (0, 1, 5, 11):
        np.testing.assert_allclose(out[k], 2.0 * np.linalg.matrix_power(H, k)[:, 0],
                                   rtol=1e-12, atol=1e-15)
    # rows after the first below the negligible norm are zero
    out, n = krylov_powers(0.1 * np.eye(3), 1.0, 20, 1e-6)
    assert n == 8 and np.all(out[8:] == 0.0) and out[7, 0] == pytest.approx(1e-7)


def tail_against_full(chain, steps, budget=(5e-5, 1.5e-4), krylov=True, early=False):
    """Propagate ``chain`` for ``steps`` with and without the tail; assert that filling the
    tail changed the answer by no more than the change it reported (within ``budget``).
    The full run's own error (the mass of the states it left out as holding less than
    1e-15 of the undecided mass) counts on its side."""
    from mdft._plane_chain import propagate_moments

    # every step (no stop at a small undecided mass: where the moment closure lets x change
    # sign, the mass can pass below it while the walks still choose)
    full = propagate_moments(chain, steps, -np.inf)
    tail = propagate_moments(chain, steps, 1e-14, budget, krylov=krylov, early=early)
    times = np.arange(1, steps + 1)
    if full[5][2] > 1e-3:
        # an unstable moment closure (docs/threshold_exact.md, section 8): no distribution,
        # which threshold_probabilities refuses by its negative choices; so it must with the
        # tail
        assert tail[5][2] > 1e-3
        return full, tail
    err_p, err_rt, _ = tail[5]
    if tail[3] < steps:  # the tail was filled
        assert err_p <= budget[0] and err_rt <= budget[1]
    assert tail[2] <= full[2]
    p_full, p_tail = full[0].sum(axis=0), tail[0].sum(axis=0)
    assert np.abs(p_tail - p_full).max() <= err_p + full[5][0] + 1e-12
    assert abs(tail[1] - full[1]) <= err_p + full[5][0] + 1e-12
    for i in range(3):
        if p_full[i] > 1e-6:
            rt_full = times @ full[0][:, i] / p_full[i]
            rt_tail = times @ tail[0][:, i] / p_tail[i]
            weight = min(1.0, p_full[i] / 0.01)
            assert weight * abs(rt_tail / rt_full - 1.0) <= err_rt + 1e-9
    return full, tail


def test_hazard_drift_of_a_slow_mode_is_measured_over_longer_windows():
    """A hazard approaching its limit by a factor 0.998 per step shrinks by 0.951 per 25-step
    window, too slowly to count as geometric there; over doubled windows it does, and the
    distance estimated still to go covers the true one."""
    from mdft import _plane_tail

    t = np.arange(3000)
    hazard = 1e-3 - 1e-4 * 0.998**t
    hazard[0] = 0.0
    u = 1200
    w = _plane_tail.WINDOW
    assert _plane_tail.drift(hazard[u - 3 * w], hazard[u - 2 * w], hazard[u - w],
                             hazard[u]) == -1.0
    rest = 1e-4 * 0.998**u
    assert rest <= _plane_tail._hazard_drift(hazard, u) <= 2.5 * rest
    # a hazard still at 0 at the start of the longest window is not a geometric approach
    assert _plane_tail._hazard_drift(np.r_[np.zeros(200), hazard[200:]], 230) == -1.0


def test_a_negative_hazard_is_not_a_settled_one():
    """The moment closure's choices of mass far from the thresholds can be negative and of
    the size of rounding: a hazard settling geometrically at -1e-10 (as over the first
    hundred steps of seed 1208 model 10 of the benchmark, a thousand-step deliberation) is
    mass on its way, not the slowest mode, whose tail would decide nothing."""
    from mdft import _plane_tail

    t = np.arange(200)
    hazard = -1e-10 * (1.0 - 0.97**t)
    assert _plane_tail.drift(hazard[29], hazard[54], hazard[79], hazard[104]) >= 0.0
    assert _plane_tail._hazard_drift(hazard, 104) == -1.0
    # the same drift at a positive hazard counts
    assert _plane_tail._hazard_drift(-hazard + 1e-12, 104) >= 0.0


def slow_mode_model():
    """Seed 2026 model 5 of the benchmark: a long deliberation whose hazard settles by about
    0.998 per step."""
    model = MDFTModel([[3.257, 2.737, 2.809], [2.411, 3.710, 1.316], [2.598, 3.350, 0.972]],
                      [0.5958, 0.2729, 0.1313], phi1=0.03285, phi2=0.03892, beta=10.18,
                      sigma2=0.3481)
    return model, 41.77


def test_tail_of_a_slow_next_mode_is_filled_within_its_estimate():
    """A long deliberation whose hazard settles by about 0.998 per step (seed 2026, model 5
    of the benchmark, on a coarse grid): the tail is filled before the step limit, where a
    25-step window alone never sees a geometric drift, and within its own estimate."""
    from mdft._plane_chain import build_moment_chain

    model, theta = slow_mode_model()
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    chain = build_moment_chain(model, theta, 2.0, ref, 0.5, 60_000)
    steps = 10_000
    full, tail = tail_against_full(chain, steps, krylov=False)
    assert tail[3] < 0.7 * steps  # filled well before the limit
    # where it was filled, the drift over 25 steps is not (yet) geometric
    from mdft import _plane_tail

    chosen = full[0].sum(axis=1)
    hazard = chosen / np.r_[1.0, 1.0 - np.cumsum(chosen)[:-1]]
    u, w = tail[3] - 1, _plane_tail.WINDOW
    assert _plane_tail.drift(hazard[u - 3 * w], hazard[u - 2 * w], hazard[u - w],
                             hazard[u]) == -1.0


def test_slow_start_is_not_mistaken_for_the_geometric_tail():
    # A two-option walk that needs hundreds of steps to reach a distant threshold: while the
    # mass is on its way, the per-step choices are tiny and steady, which an earlier tail
    # detector took for the slowest mode, returning p_undecided = 1 with a zero error estimate.
    M = [[3.2911181, 2.62348387, 1.70785203], [3.81386927, 2.47182081, 2.01466959]]
    w = [0.23881413, 0.40882123, 0.35236464]
    model = MDFTModel(M, w, phi1=0.02, phi2=0.0533, beta=1.0, sigma2=0.2)
    res = threshold_probabilities(model, 30.0, max_steps=3000)
    assert res.p_undecided < 1e-3
    assert_matches_simulation(res, model, 30.0, 20_000, 8, max_steps=3000)
