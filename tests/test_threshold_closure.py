"""Tests of the three-option moment closure of mdft.threshold_probabilities
(``docs/threshold_exact.md``, sections 2 and 8): the moment step, the pilots whose closure
runs away, negative choices, and closures that are refused."""

import numpy as np
import pytest

from mdft import MDFTModel, _plane_passes, threshold_probabilities

from threshold_models import SETS, assert_within_stated_error, drawn


def runaway_pilot_model():
    """Seed 9191 model 14 of the benchmark's draws (a long deliberation, mean times 540-590
    steps): with the pilot's first guess of the reference sums, its moment closure runs away
    after about 200 steps."""
    model = drawn([[2.0356108074080255, 2.253562468264767],
                   [0.9061297268088968, 2.1682379023887544],
                   [0.623301638882569, 2.0033458201561873]],
                  [0.4138242065397861, 0.586175793460214], phi1=0.008507515982439344,
                  phi2=0.06767721501851882, beta=10.305919742706031, sigma2=0.22853328717998567)
    return model, 50.78103007752905


def pilot_occupation(chain, max_steps, tol, budget):
    """A pilot pass's ``(occupation, steps, cut)``."""
    from mdft._plane_chain import pilot_pass

    out, cut = pilot_pass(chain, max_steps, tol, budget)
    return out[4], out[2], cut


def test_a_pilot_whose_closure_runs_away_keeps_the_steps_before(monkeypatch):
    from mdft import _plane_chain
    from mdft._plane_chain import build_moment_chain, propagate_moments

    model, theta = runaway_pilot_model()
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    chain = build_moment_chain(model, theta, 2.0, ref, 0.5, 30_000)
    occ, steps, cut = pilot_occupation(chain, 1000, 1e-6, (1e-5, 3e-5))
    assert cut and 100 <= steps < 1000 and steps % _plane_chain._PILOT_CHUNK == 0
    # the occupation kept is that of a pass of that many steps
    alone = propagate_moments(chain, steps, 1e-6, (1e-5, 3e-5), second=True)
    np.testing.assert_allclose(occ, alone[4], rtol=1e-12, atol=1e-300)
    # unguarded, the pass goes on to the step limit and its answer is no distribution: its
    # negative choices (clipped, and counted) outweigh the whole
    monkeypatch.setattr(_plane_chain, "PILOT_RUNAWAY", np.inf)
    occ_all, steps_all, cut_all = pilot_occupation(chain, 1000, 1e-6, (1e-5, 3e-5))
    assert not cut_all and steps_all == 1000
    wild = propagate_moments(chain, 1000, 1e-6, (1e-5, 3e-5), second=True)
    assert wild[5][2] > 1.0


def test_negative_choices_are_clipped_scaled_and_counted():
    from mdft._plane_chain import _clip_negative

    rt_pmf = np.array([[0.5, -0.1, 0.0], [0.45, 0.2, -0.05]])
    mass, clipped = _clip_negative(rt_pmf, 0.0)
    assert clipped == pytest.approx(0.15) and mass == 0.0
    assert rt_pmf.min() == 0.0 and rt_pmf.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(rt_pmf, np.array([[0.5, 0, 0], [0.45, 0.2, 0]]) / 1.15)
    untouched = np.array([[0.25, 0.25, 0.0]])
    assert _clip_negative(untouched, 0.5) == (0.5, 0.0)
    assert untouched.sum() == 0.5


def test_a_closure_whose_choices_turn_negative_answers_a_distribution_and_says_so():
    # seed 8282 model 14 of the benchmark's draws: option 1 is chosen in every one of 10**6
    # simulated trials (mean time 46.28 steps), but the linearised choices of the other two
    # turn negative by 0.0008 in all. Clipped and left out, they made p_1 = 1.0008 with an
    # estimate of 5e-5; clipped, scaled back and counted, p_1 = 1 and the estimate covers them.
    # A pass's closure turns negative by 0.0012 (0.0015 on the pilots' plane of reference
    # sums), beyond the default atol: refused as unstable there. At atol = 2e-3 it is
    # answered, with the clipped size in its estimate (0.00087 in all); its mean time is 0.21 %
    # long against an estimate of 0.29 % (on the pilots' plane 0.14 % long, the closure's term
    # 0.04 %: the spread among the walks about to decide, 1.23, was larger than the pilots',
    # 0.45, and its probe moved the answer less)
    model = drawn([[1.66396564, 1.14790297, 0.64966856], [3.98162207, 2.97665791, 2.54034374],
                   [1.72459506, 0.66875495, 1.71616334]], [0.2046643, 0.50472451, 0.29061119],
                  phi1=0.010131737724362024, phi2=0.03996832951331772, beta=11.772343811026468,
                  sigma2=0.17304052523857907)
    with pytest.raises(ValueError, match=r"closure of the summed preference is unstable.*"
                                         r"turn negative by 0\.001[0-9]"):
        threshold_probabilities(model, 40.354331093471934, fallback="raise")
    res = threshold_probabilities(model, 40.354331093471934, fallback="raise", atol=2e-3)
    assert res.probabilities.min() >= 0.0
    assert res.probabilities.sum() + res.p_undecided == pytest.approx(1.0, abs=1e-12)
    assert abs(res.probabilities[1] - 1.0) <= 1e-4
    assert 4e-4 <= res.error_probabilities <= 1e-3
    assert res.mean_response_times[1] == pytest.approx(46.28, rel=3e-3)


def test_a_healthy_pilot_is_not_cut(monkeypatch):
    # the canonical compromise set: the pilot's closure stays sound, and running it in
    # chunks gives the occupation of one run
    from mdft import _plane_chain
    from mdft._plane_chain import build_moment_chain

    model = MDFTModel(SETS["compromise"], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0,
                      sigma2=1.0)
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    chain = build_moment_chain(model, 17.5, 2.0, ref, 0.5, 30_000)
    occ, steps, cut = pilot_occupation(chain, 1000, 1e-6, (1e-5, 3e-5))
    assert not cut and steps > 2 * _plane_chain._PILOT_CHUNK
    monkeypatch.setattr(_plane_chain, "_PILOT_CHUNK", 10_000)
    occ_one, steps_one, _ = pilot_occupation(chain, 1000, 1e-6, (1e-5, 3e-5))
    assert steps_one == steps
    np.testing.assert_allclose(occ, occ_one, rtol=1e-12, atol=1e-300)


def test_a_model_whose_first_pilot_runs_away_is_answered():
    """Before the guard, the reference sums fitted from the runaway pilot made every pass's
    closure unstable, and the call simulated (40 s). Reference: 10**6 simulated trials
    (benchmarks/bench_threshold_exact.py, seed 9191, max_steps 10,000): p = 2.1e-5,
    0.50616, 0.493819 (standard errors 0.0005) and mean times 582 (21 trials), 538.78,
    587.04 steps."""
    model, theta = runaway_pilot_model()
    res = threshold_probabilities(model, theta, fallback="raise")
    assert res.engine == "plane"
    np.testing.assert_allclose(res.probabilities, [2.1e-5, 0.50616, 0.493819], atol=0.002)
    np.testing.assert_allclose(res.mean_response_times[1:], [538.78, 587.04], rtol=0.005)


def test_reference_sums_refitted_after_a_cut_pilot_are_checked():
    """Seed 5150 model 3 of the benchmark's draws: its pilot's closure runs away within 50
    steps, and the pilot cut at 150 steps fits reference sums that leave the chain stable but
    biased (0.0067 and 0.9933, mean time 226 steps for the second option). Refitted to the
    walks of the first pass that counts, the answer is within the tolerances of
    5 * 10**6 simulated trials (1 and 4 million with seeds 1 and 7 of mdft.simulate, pooled:
    p = 0.00826, 0.99174, mean times 143.6 and 217.2 steps)."""
    model = drawn([[1.8138094066077708, 3.9686312912630735],
                   [2.579267199608471, 2.9609474427885942],
                   [0.9511985461332478, 1.3554338688020402]],
                  [0.5606021609462761, 0.4393978390537239], phi1=0.0076642266530194715,
                  phi2=0.03956108946247433, beta=2.745171083240042, sigma2=0.18106185763880178)
    res = threshold_probabilities(model, 31.51853929122604, fallback="raise")
    np.testing.assert_allclose(res.probabilities, [0.00826, 0.99174, 0.0], atol=0.001)
    np.testing.assert_allclose(res.mean_response_times[:2], [143.6, 217.2], rtol=0.005)


def test_refits_after_a_cut_pilot_fill_their_tails_like_any_pass(monkeypatch):
    """Seed 7171 model 21 of the benchmark's draws: a deliberation of 2,600-2,700 steps on
    average whose pilot is cut at step 800. The passes that refit its reference sums used
    to be pilot passes, without the Krylov tail, and ran 8,000 steps each (2.9 s of a
    call of 8.6 s); they only need the occupation of x and m, and now fill their tails as
    every counted pass does. No pass runs past 1,000 steps, and the answer stays within
    the tolerances of 10**6 simulated trials (p = 0.05148 and 0.93969, se 0.00024; mean
    times 2639.1 and 2706.0 steps)."""
    from mdft import _plane_passes

    steps = []
    for name in ("pilot_pass", "propagate_moments"):
        def record(*args, _f=getattr(_plane_passes, name), **kwargs):
            out = _f(*args, **kwargs)
            steps.append((out[0] if isinstance(out[1], bool) else out)[2])
            return out
        monkeypatch.setattr(_plane_passes, name, record)
    model = drawn([[3.1537035226359675, 0.8808545856311994],
                   [2.7730410568133492, 1.2444840756777709],
                   [1.5987715902904598, 0.7755564342573016]],
                  [0.5054147206128466, 0.4945852793871533], phi1=0.010331027841670047,
                  phi2=0.049353808973166956, beta=8.95287011945652, sigma2=0.31547276941694447)
    res = threshold_probabilities(model, 50.717586548304915, fallback="raise")
    assert steps and max(steps) <= 1000
    np.testing.assert_allclose(res.probabilities, [0.051478, 0.939687, 0.0],
                               atol=res.error_probabilities + 4 * 0.00024)
    np.testing.assert_allclose(res.mean_response_times[:2], [2639.13, 2705.96],
                               rtol=res.error_mean_rt + 0.002)


@pytest.mark.parametrize("in_parts", [False, True])
def test_moment_step_carries_the_covariance_of_the_sum_and_the_transition(in_parts):
    # One step of the moment chain from a state whose sum is spread around its reference
    # s_ref with variance delta**2 (no mean deviation): the staying probability is linear
    # in the sum, T(s) = t0 + t1 (s - s_ref), and the next sum is s' = s_next + b (s - s_ref),
    # so the first moment reaching the next state is E[s' T(s)] = s_next t0 + b t1 delta**2.
    # The same, serially and in parallel parts.
    from mdft import _plane_step
    from mdft._plane_chain import tail_track

    t0, t1, s_ref, s_next, b, delta = 0.6, 0.05, 10.0, 9.0, 0.9, 1.5
    x = np.array([1.0, 0.0])
    m = np.array([s_ref, 0.0])
    q = np.zeros(2)
    rt_pmf = np.zeros((2, 3))
    _plane_step.propagate(
        np.array([0, 1, 1]), np.array([1], dtype=np.int32), np.array([t0]), np.array([t1]),
        np.zeros((2, 3)), np.zeros((2, 3)), np.array([s_ref, s_ref]), np.array([s_next, s_next]),
        b, delta**2, x, m, q, rt_pmf, np.zeros((2, 3)), 0.0, False, 0.0, 0.0, 0.01, np.zeros(3),
        in_parts, np.zeros(2, dtype=bool), 2, 1, *tail_track(2, 2), np.inf)
    assert x[1] == pytest.approx(t0)
    assert m[1] == pytest.approx(s_next * t0 + b * t1 * delta**2)


def test_an_unstable_moment_closure_is_refused_with_its_reason(monkeypatch):
    """Two near-identical options, almost no leakage and a long deliberation: the first-order
    closure in the summed preference grows without bound on this model (a pass's
    probabilities summed to 1e34) about the pilots' plane of reference sums. The call
    refuses and says why, instead of reporting an error estimate of that size. About the
    walks' plane the closure holds, and its term (0.0028 in a probability, 2.4 % in a mean
    time) refuses the call on the coarsest grid."""
    model = MDFTModel([[4.72, 9.53], [0.32, 0.41], [4.31, 9.96]], [0.462, 0.538],
                      phi1=0.0584, phi2=0.0694, beta=21.85, sigma2=0.3006)
    with pytest.raises(ValueError, match=r"alone may change the probabilities by 0\.00[1-9]"
                                         r".*whatever the resolution"):
        threshold_probabilities(model, 41.98, max_steps=3000, fallback="raise")
    monkeypatch.setattr(_plane_passes, "WALK_FIT", False)
    with pytest.raises(ValueError, match="moment closure of the summed preference is "
                                         "unstable for this model"):
        threshold_probabilities(model, 41.98, max_steps=3000, fallback="raise")


# a starting preference that sums to -10.9 (the sum then settles towards 0 over a
# deliberation of about 15 steps): the second pilot's variance of the sum within the states
# came out negative in every state, so delta was 0 and the chain followed no slope in the
# sum; its mean times were 10-12 % long while it estimated 0.17 %
FAR_START = dict(M=[[3.0479509925572756, 3.7574602279408804, 0.5293200946537767],
                    [3.9534130089023796, 2.1933438682917794, 1.6957587746545797],
                    [2.057188375016216, 1.3167817477039536, 2.7690832567078076]],
                 w=[0.09201724330555719, 0.4146007378183366, 0.4933820188761062],
                 phi1=0.06537419532956461, phi2=0.020263047737633898, beta=2.5277918821075884,
                 sigma2=1.9748398971177674,
                 P0=[-4.678987126613378, -4.773385598558563, -1.4459075977183329])
FAR_START_THETA = 6.1725443131374655


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_a_spread_of_the_sum_the_pilots_cannot_measure_is_refused(scale, monkeypatch):
    # the pilots run where the walks cannot fit the reference sums (mdft._plane_spread)
    monkeypatch.setattr(_plane_passes, "WALK_FIT", False)
    params = dict(FAR_START, P0=[scale * p for p in FAR_START["P0"]])
    model = drawn(**params)
    with pytest.raises(ValueError, match="could not measure the spread of the summed "
                                         "preference"):
        threshold_probabilities(model, FAR_START_THETA, fallback="raise")
    res = threshold_probabilities(model, FAR_START_THETA)
    assert res.engine == "simulation"
    assert_within_stated_error(res, model, FAR_START_THETA, 200_000, 21)


@pytest.mark.parametrize("scale, engine", [(1.0, "simulation"), (0.5, "plane")])
def test_the_walks_fit_the_sum_of_a_far_start(scale, engine):
    # the walks' own plane and spread: half that start is answered by the chain (against
    # 2 x 10^6 simulated trials: within 0.00025 in a probability and 0.13 % in a mean time,
    # its estimate 0.16 %); the whole start leaves the closure's term over rt_rtol, and the
    # default fallback simulates
    model = drawn(**dict(FAR_START, P0=[scale * p for p in FAR_START["P0"]]))
    res = threshold_probabilities(model, FAR_START_THETA)
    assert res.engine == engine
    assert_within_stated_error(res, model, FAR_START_THETA, 200_000, 23)


def test_a_start_whose_sum_the_pilots_can_follow_is_answered_by_the_chain():
    # a quarter of that start: the pilots measure a spread, and the chain answers within its
    # stated error
    model = drawn(**dict(FAR_START, P0=[0.25 * p for p in FAR_START["P0"]]))
    res = threshold_probabilities(model, FAR_START_THETA, fallback="raise")
    assert res.engine == "plane"
    assert_within_stated_error(res, model, FAR_START_THETA, 200_000, 22)


def pair_and_dominated(phi2, sigma2):
    """Two identical options and a dominated third under strong inhibition, deciding in
    about 10 steps: the pocket of docs/threshold_exact.md, section 8."""
    return drawn([[2.0, 5.0], [1.0, 1.0], [2.0, 5.0]], [0.580461, 0.419539],
                 phi1=0.01400131208025551, phi2=phi2, beta=0.8131529373390731, sigma2=sigma2)


def test_a_short_deliberation_probes_a_larger_spread_of_the_sum():
    """The probe with a smaller spread alone vouched for mean times 0.69 % long (10.5879
    steps, estimate 0.25 %; 10**7 simulated trials: 10.5150 and 10.5131, se 0.0026): in a
    short deliberation the larger spread's probe (0.51 %) refuses it, saying that more
    states cannot help, and the default fallback simulates to the tolerances."""
    model, theta = pair_and_dominated(0.15, 0.10959392210553112), 5.256539845366378
    with pytest.raises(ValueError, match=r"may change .* the mean response times by 0\.00[5-9]"
                                         r".*whatever the resolution\. Raise atol or rt_rtol,"):
        threshold_probabilities(model, theta, fallback="raise")
    res = threshold_probabilities(model, theta)
    assert res.engine == "simulation"
    reference = np.array([10.5150, 10.5131])
    se = 0.0026
    off = np.abs(res.mean_response_times[[0, 2]] - reference)
    assert np.all(off <= res.error_mean_rt * reference + 4 * se)
    # a longer deliberation of the same kind (about 52 steps) is not probed that way and is
    # answered by the chain: 51.85 steps with an estimate of 0.20 %, where 2 x 10**6
    # simulated trials give 51.97 and 52.02 (0.24-0.32 % short, within the 0.5 % target)
    long = threshold_probabilities(pair_and_dominated(0.15, 1.0), 12.0, fallback="raise")
    assert long.engine == "plane"
