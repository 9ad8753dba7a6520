"""Tests of the compiled pieces of the three-option chain's build (``mdft._plane``,
``mdft._plane_moment``) against the plain formulas they stand for.

The build computes the same numbers as those formulas, only fewer times (edge CDFs
shared between neighbouring cells, windows that stop where cells get less than the
cut, small inputs as tuples): each helper is checked for exact equality with the
formula on random inputs, and a built chain for conservation of every row's mass.
"""

import logging
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mdft
from mdft import MDFTModel, _lattice, _plane, _plane_moment
from mdft._lattice_chain import pair_parameters
from mdft._plane_chain import build_moment_chain


@settings(deadline=None, max_examples=200)
@given(o=st.floats(-20.0, 20.0), h=st.floats(0.05, 5.0), mu=st.floats(-30.0, 30.0),
       sd=st.one_of(st.just(0.0), st.floats(0.01, 10.0)), lo=st.integers(0, 30),
       n=st.integers(1, 30))
def test_margins_equal_interval_mass_cell_by_cell(o, h, mu, sd, lo, n):
    """``_margins`` writes exactly ``interval_mass`` of every cell and, for ``sd > 0``, the
    normal CDFs at the cell's edges (shared edges taken from the neighbour)."""
    hi = lo + n - 1
    marg = np.full((3, hi + 1), np.nan)
    top = _plane_moment._margins(lo, hi, o, h, mu, sd, marg)
    want = []
    for a in range(lo, hi + 1):
        c = o + a * h
        want.append(_plane.interval_mass(c - 0.5 * h, c + 0.5 * h, mu, sd))
        assert marg[0, a] == want[-1]
        if sd > 0.0:
            assert marg[1, a] == _plane.phi_cdf((c - 0.5 * h - mu) / sd)
            assert marg[2, a] == _plane.phi_cdf((c + 0.5 * h - mu) / sd)
    assert top == max(max(want), 0.0)
    assert np.isnan(marg[:, :lo]).all()  # nothing written outside the window


@settings(deadline=None, max_examples=300)
@given(o=st.floats(-20.0, 20.0), h=st.floats(0.02, 5.0), mu=st.floats(-30.0, 30.0),
       sd=st.floats(0.005, 10.0))
def test_cells_beyond_the_window_get_less_than_the_cut(o, h, mu, sd):
    """The window of a row stops ``_REACH`` standard deviations from the mean: the first
    cell beyond it on either side gets less than the cut, so leaving it out changes
    nothing (the cell would have been dropped)."""
    reach = _plane_moment._REACH
    lo = int(math.floor((mu - reach * sd - o) / h + 0.5))
    hi = int(math.floor((mu + reach * sd - o) / h + 0.5))
    for a in (lo - 1, hi + 1):
        c = o + a * h
        assert _plane.interval_mass(c - 0.5 * h, c + 0.5 * h, mu, sd) < _plane._CUT


def _absorb_formula(muP, theta, sd_opt, pair_sd, pair_rho):
    """``Pr(P_i >= theta) - sum_k Pr(P_i >= theta, P_k > P_i)``, with the same
    skipping of joint terms whose tails are negligible, on arrays."""
    tails = [_lattice.upper(muP[i], sd_opt[i], theta) for i in range(3)]
    out = np.zeros(3)
    for i in range(3):
        pi = tails[i]
        if pi <= 0.0:
            continue
        for k in range(3):
            if k == i or min(tails[i], tails[k]) < 1e-15:
                continue
            pi -= _lattice.joint_upper(muP[i], sd_opt[i], theta, muP[k] - muP[i],
                                       pair_sd[i, k], 0.0, pair_rho[i, k], _lattice._GL_X,
                                       _lattice._GL_W)
        out[i] = max(pi, 0.0)
    return out


@settings(deadline=None, max_examples=200)
@given(seed=st.integers(0, 2**32 - 1), theta=st.floats(1.0, 60.0),
       spread=st.floats(0.0, 3.0))
def test_absorb3_on_tuples_equals_the_formula_on_arrays(seed, theta, spread):
    """``absorb3`` (tuples in, probabilities out) equals the choice formula evaluated on
    arrays, bit for bit, for random means near and across the threshold and random noise
    covariances (the standard contrast's and arbitrary ones)."""
    rng = np.random.default_rng(seed)
    muP = theta + spread * rng.normal(size=3) * theta / 4
    L = rng.normal(size=(3, 3))
    cov = L @ L.T * rng.uniform(0.05, 4.0)
    sd_opt = np.sqrt(np.diag(cov))
    pair_sd, pair_rho = pair_parameters(cov, sd_opt)
    got = _plane.absorb3(muP[0], muP[1], muP[2], theta, tuple(sd_opt),
                         tuple(map(tuple, pair_sd)), tuple(map(tuple, pair_rho)))
    want = _absorb_formula(muP, theta, sd_opt, pair_sd, pair_rho)
    assert got[1:] == tuple(want)
    assert got[0] == want[0] + want[1] + want[2]


@settings(deadline=None, max_examples=100)
@given(mx=st.floats(-3.0, 3.0), my=st.floats(-3.0, 3.0), sx=st.floats(0.02, 2.0),
       sy=st.floats(0.2, 2.0), hx=st.floats(0.3, 1.5), hy=st.floats(0.3, 1.5),
       bound=st.floats(-1.0, 1.0), turn=st.floats(0.0, math.pi))
def test_cut_mass_with_tuples_and_given_edge_cdfs_equals_cut_mass(mx, my, sx, sy, hx, hy,
                                                                  bound, turn):
    """The build's form of the cut-cell integral (lines as tuples, the cell's edge CDFs
    passed in, a reused work array) gives exactly what ``cut_mass`` gives."""
    E = np.c_[np.array([2.0, -1.0, -1.0]) / math.sqrt(6.0),
              np.array([0.0, 1.0, -1.0]) / math.sqrt(2.0)]
    E = E @ np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
    ex, ey = np.ascontiguousarray(E[:, 0]), np.ascontiguousarray(E[:, 1])
    xlo, ylo = -hx / 2, -hy / 2
    want = _plane.cut_mass(xlo, xlo + hx, ylo, ylo + hy, mx, sx, my, sy, ex, ey, bound)
    work = np.full(11, np.nan)
    got = _plane.cut_mass_with(xlo, xlo + hx, ylo, ylo + hy, mx, sx, my, sy, tuple(ex),
                               tuple(ey), bound, _plane.phi_cdf((ylo - my) / sy),
                               _plane.phi_cdf((ylo + hy - my) / sy), work)
    assert got == want


@pytest.mark.parametrize("seed", [3, 4])
def test_built_rows_conserve_mass(seed):
    """Every row of a built chain (random three-option model, moving sum) splits its mass
    between staying and the choices: ``sum T0 + sum R0 = 1`` and ``sum T1 + sum R1 = 0``;
    the nonzeros and their 32-bit columns line up with the row pointers."""
    rng = np.random.default_rng(seed)
    M = rng.uniform(0.5, 4.0, size=(3, 2))
    model = MDFTModel(M, rng.dirichlet([4.0, 4.0]), phi1=0.03, phi2=0.06, beta=5.0,
                      sigma2=float(rng.uniform(0.5, 2.0)))
    theta = 12.0
    chain = build_moment_chain(model, theta, 1.0, np.array([0.0, 0.0, 0.0]), 0.5, 60_000)
    assert chain.cols.dtype == np.int32
    nnz = chain.row_ptr[-1]
    assert chain.cols.shape == chain.t0.shape == chain.t1.shape == (nnz,)
    assert chain.cols.min() >= 0 and chain.cols.max() < chain.n_states
    stay0 = np.add.reduceat(chain.t0, chain.row_ptr[:-1])
    stay1 = np.add.reduceat(chain.t1, chain.row_ptr[:-1])
    assert np.all(np.diff(chain.row_ptr) > 0)
    np.testing.assert_allclose(stay0 + chain.r0.sum(axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(stay1 + chain.r1.sum(axis=1), 0.0, atol=1e-5)
    first = chain.start_vals.sum() + chain.start_absorbed.sum()
    assert first == pytest.approx(1.0, abs=1e-6)


_CHAIN_FIELDS = ("row_ptr", "cols", "t0", "t1", "r0", "r1", "pos", "sref", "snext",
                 "start_cols", "start_vals", "start_absorbed")


def _random_chain_inputs(seed):
    rng = np.random.default_rng(seed)
    M = rng.uniform(0.5, 4.0, size=(3, 3))
    model = MDFTModel(M, rng.dirichlet([4.0, 4.0, 4.0]), phi1=0.03, phi2=0.06, beta=5.0,
                      sigma2=float(rng.uniform(0.2, 3.0)))
    return model, float(rng.uniform(8.0, 20.0))


@pytest.mark.parametrize("seed", [11, 12])
def test_build_is_the_same_in_any_number_of_parts(seed, monkeypatch):
    """The build evaluates its sources in parallel parts and adds them in order: one part,
    three parts, and slots too small for any source (every source evaluated again alone)
    give the same chain, array for array."""
    from mdft import _plane_chain

    model, theta = _random_chain_inputs(seed)
    ref = np.array([0.5, 0.01, -0.02])
    chains = []
    for parts, slot in [(1, 256), (3, 256), (2, 1)]:
        monkeypatch.setattr(_plane_chain, "_build_parts", lambda box, parts=parts: parts)
        monkeypatch.setattr(_plane_chain, "_FIRST_SLOT", slot)
        chains.append(build_moment_chain(model, theta, 1.0, ref, 0.4, 60_000))
    assert chains[0].n_states > 300  # several blocks of sources
    for other in chains[1:]:
        for field in _CHAIN_FIELDS:
            np.testing.assert_array_equal(getattr(other, field), getattr(chains[0], field))
        assert other.start_snext == chains[0].start_snext


@pytest.mark.parametrize("seed", [11, 13])
def test_propagation_in_parts_does_not_depend_on_the_threads(seed):
    """Propagated in parts, the chain gives the same answer, to the last bit, on one thread
    and on two; and the serial scatter's answer up to rounding (the parts' sums are added
    in another order)."""
    import numba

    from mdft._plane_chain import propagate_moments

    model, theta = _random_chain_inputs(seed)
    chain = build_moment_chain(model, theta, 1.0, np.array([0.5, 0.01, -0.02]), 0.4, 60_000)
    threads = numba.get_num_threads()
    runs = {}
    try:
        for name, n_threads, parts in [("one", 1, True), ("all", threads, True),
                                       ("serial", threads, False)]:
            numba.set_num_threads(n_threads)
            runs[name] = propagate_moments(chain, 400, 1e-12, (1e-3, 3e-3), second=True,
                                           in_parts=parts)
    finally:
        numba.set_num_threads(threads)
    for a, b, c in zip(runs["one"], runs["all"], runs["serial"]):
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
            np.testing.assert_allclose(a, c, rtol=1e-11, atol=1e-14)
        else:
            assert a == b
            assert a == pytest.approx(c, rel=1e-9, abs=1e-14)
    assert runs["one"][0].sum() > 0.5  # the run decides most of the mass


def _bench():
    """``benchmarks/bench_threshold_exact.py`` as a module."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_threshold_exact.py"
    spec = importlib.util.spec_from_file_location("bench_threshold_exact", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def test_benchmark_counts_the_calls_against_the_speed_targets():
    """The benchmark's summary counts the calls within the median target (0.2 s, included)
    and over the largest time allowed (2 s, excluded) and gives the median and maximum."""
    bench = _bench()
    line = bench.speed_summary([0.05, 0.2, 0.21, 2.0, 2.01, 7.5])
    assert line == "median 1.10 s, 2 of 6 calls at most 0.2 s, 2 over 2 s, max 7.50 s"


def test_benchmark_refuses_fewer_than_one_thread_and_unknown_ranges(capsys):
    """``bench_threshold_exact.py --threads`` and ``--ranges`` name the option and what
    they got; the wide and flat ranges draw within their documented bounds."""
    bench = _bench()
    with pytest.raises(SystemExit):
        bench.main(["--threads", "0", "--ternary", "0", "--binary", "0"])
    assert "--threads must be at least 1, got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        bench.main(["--ranges", "huge", "--ternary", "0", "--binary", "0"])
    assert "--ranges: invalid choice: 'huge'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        bench.main(["--trials", "-1", "--ternary", "0", "--binary", "0"])
    assert "--trials must be at least 0, got -1" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        bench.main(["--trials", "0", "--live", "--ternary", "0", "--binary", "0"])
    assert "--live screens the draws by simulation" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        bench.main(["--start", "1.5", "--ternary", "0", "--binary", "0"])
    assert "--start must be in [0, 1), got 1.5" in capsys.readouterr().err
    # --start: the two-option draws start away from 0 (and are answered, here on the lattice
    # whose thresholds move)
    bench.main(["--trials", "0", "--ternary", "0", "--binary", "2", "--seed", "3",
                "--start", "0.4", "--max-steps", "500"])
    assert "2 options: 2 models answered" in capsys.readouterr().out
    # --trials 0 times the calls alone: a line per model and the summary, no reference
    bench.main(["--trials", "0", "--ternary", "1", "--binary", "1", "--seed", "3",
                "--max-steps", "500"])
    out = capsys.readouterr().out
    assert "3 options, unscreened: " in out and "2 options: " in out and "time" in out
    rng = np.random.default_rng(0)
    for _ in range(50):
        model, theta = bench.draw_model(rng, 3, "wide")
        assert np.all((model.M >= 0.0) & (model.M <= 10.0))
        assert 0.0 <= model.phi1 <= 0.15 and 0.0 <= model.phi2 <= 0.15
        assert 0.5 <= model.beta <= 25.0 and 0.1 <= model.sigma2 <= 4.0 and 5.0 <= theta <= 60.0
    noise = []
    for _ in range(200):
        model, theta = bench.draw_model(rng, 3, "flat")
        assert np.all((model.M >= 1.0) & (model.M <= 5.0))
        assert 0.01 <= model.phi1 <= 0.1 and 0.01 <= model.phi2 <= 0.1
        assert 1.0 <= model.beta <= 15.0 and 0.1 <= model.sigma2 <= 4.0 and 5.0 <= theta <= 60.0
        noise.append(model.sigma2)
    # uniform, not log-uniform: about half the draws above 2 (about a fifth when log-uniform)
    assert 0.35 < np.mean(np.array(noise) > 2.0) < 0.65


def test_work_benchmark_measures_the_three_units(capsys):
    """``bench_threshold_work.py`` prints the propagated nonzero-step, the built nonzero and
    the simulated trial-step that the fallback's choice counts in, and the cost of the
    controlled trials of both kinds, and names bad options."""
    import importlib.util
    import re
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_threshold_work.py"
    spec = importlib.util.spec_from_file_location("bench_threshold_work", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    bench.main(["--models", "1", "--trials", "200", "--max-steps", "200",
                "--resolutions", "1.4"])
    out = capsys.readouterr().out
    step = re.search(r"propagated nonzero-step: median ([0-9.]+) ns", out)
    build = re.search(r"built nonzero: median ([0-9.]+) units", out)
    sim = re.search(r"simulated trial-step: median ([0-9.]+) ns = ([0-9.]+) units", out)
    monomials = re.search(r"trials with the monomials' controls: ([0-9.]+) times the plain "
                          r"trials' time", out)
    every = re.search(r"trials with every control: ([0-9.]+) times the plain trials' time", out)
    assert step and build and sim and monomials and every, out
    assert float(step.group(1)) > 0 and float(build.group(1)) > 0 and float(sim.group(2)) > 0
    assert float(monomials.group(1)) > 0 and float(every.group(1)) > 0
    with pytest.raises(SystemExit):
        bench.main(["--models", "0"])
    assert "--models must be at least 1, got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        bench.main(["--resolutions", "5"])
    assert "--resolutions must lie in [0.3, 2], got [5.0]" in capsys.readouterr().err


def _one_sided_model():
    """A model that mostly chooses its first option: the finer pass need not build rows
    for the cells behind the start, which the walks never reach."""
    model = MDFTModel([[4.0, 1.0], [1.0, 4.0], [1.0, 1.0]], [0.6, 0.4], phi1=0.03, phi2=0.06,
                      beta=5.0, sigma2=0.4)
    return model, 14.0


def test_rows_near_the_occupied_region_give_the_full_chains_answer():
    """Built with rows only near the states a coarser pass occupied, the chain has fewer
    nonzeros, loses no measurable mass to its frontier states, and gives the answer of the
    chain with every row."""
    from mdft._plane_chain import near_occupied, propagate_moments

    model, theta = _one_sided_model()
    ref = np.array([0.0, 0.0, 0.0])
    coarse = build_moment_chain(model, theta, 1.41, ref, 0.4, 60_000)
    occupied = propagate_moments(coarse, 400, 1e-10, (1e-3, 3e-3))[4]
    full = build_moment_chain(model, theta, 1.0, ref, 0.4, 60_000)
    near = build_moment_chain(model, theta, 1.0, ref, 0.4, 60_000,
                              near_occupied(coarse, occupied))
    assert not full.frontier.any()
    assert near.frontier.sum() > 20
    assert near.cols.shape[0] < 0.8 * full.cols.shape[0]
    a = propagate_moments(full, 400, 1e-10, (1e-3, 3e-3))
    b = propagate_moments(near, 400, 1e-10, (1e-3, 3e-3))
    assert a[6] == 0.0 and b[6] < 1e-15
    np.testing.assert_allclose(b[0], a[0], rtol=0.0, atol=1e-13)
    assert b[1] == pytest.approx(a[1], abs=1e-13)
    assert a[0].sum() > 0.99  # the run decides its mass


def test_mass_reaching_a_frontier_state_leaves_and_is_counted():
    """With rows only around the start, most of the mass reaches frontier states: it leaves
    the chain, and the choices, the undecided mass and the escaped mass still sum to one."""
    from mdft._plane_chain import propagate_moments

    model, theta = _one_sided_model()
    ref = np.array([0.0, 0.0, 0.0])
    full = build_moment_chain(model, theta, 1.0, ref, 0.4, 60_000)
    start = full.pos[:1]
    tight = build_moment_chain(model, theta, 1.0, ref, 0.4, 60_000, (start, full.h))
    assert tight.frontier.sum() > 0.5 * tight.n_states
    rt_pmf, undecided, _, _, _, _, escaped = propagate_moments(tight, 400, 1e-10)
    assert escaped > 0.1
    assert rt_pmf.sum() + undecided + escaped == pytest.approx(1.0, abs=1e-9)


def test_a_run_stops_at_the_step_where_the_escaped_mass_passes_its_limit():
    """With ``escape_max``, a run whose mass reaches frontier states stops at the step where
    the escaped mass first exceeds the limit (the pass is to be built again), and says so by
    the escaped mass it returns; without it, the run goes on to the end."""
    from mdft._plane_chain import propagate_moments

    model, theta = _one_sided_model()
    ref = np.array([0.0, 0.0, 0.0])
    full = build_moment_chain(model, theta, 1.0, ref, 0.4, 60_000)
    tight = build_moment_chain(model, theta, 1.0, ref, 0.4, 60_000, (full.pos[:1], full.h))
    whole = propagate_moments(tight, 400, 1e-10)
    limit = 1e-3 * whole[6]
    stopped = propagate_moments(tight, 400, 1e-10, escape_max=limit)
    assert stopped[6] > limit
    assert stopped[2] < whole[2]
    # the step before the last one run had let out no more than the limit
    assert propagate_moments(tight, stopped[2] - 1, 1e-10)[6] <= limit


def test_a_pass_whose_mass_escapes_its_rows_is_built_again_with_every_row(monkeypatch, caplog):
    """``threshold_probabilities`` rebuilds a pass with every row when more than
    ``ESCAPE_MAX`` of its mass reached states without one: forcing a region that holds only
    the start gives, bit for bit, the answer of a call that builds every row throughout."""
    import mdft
    from mdft import _plane_passes

    model, theta = _one_sided_model()
    answers = []
    for near in (lambda chain, occ: None,
                 lambda chain, occ: (chain.pos[:1], (0.1 * chain.h[0], 0.1 * chain.h[1]))):
        monkeypatch.setattr(_plane_passes, "near_occupied", near)
        caplog.clear()
        with caplog.at_level(logging.DEBUG, logger="mdft.threshold_exact"):
            answers.append(mdft.threshold_probabilities(model, theta, max_steps=1000,
                                                        fallback="raise"))
        answers.append("building every row" in caplog.text)
    full, full_rebuilt, rebuilt, rebuilt_rebuilt = answers
    assert not full_rebuilt and rebuilt_rebuilt
    np.testing.assert_array_equal(rebuilt.rt_pmf, full.rt_pmf)
    assert rebuilt.n_states == full.n_states
    assert rebuilt.error_probabilities == full.error_probabilities


def test_after_an_escape_from_rows_that_left_out_little_every_row_is_built_at_once(
        monkeypatch, caplog):
    """Once a pass's mass has left its rows and those rows held more than
    ``NEAR_SHARE_MAX`` of the nonzeros of the pass built again, the later passes build
    every row at once (one rebuild in the call, not one per pass); where they held less,
    each pass still tries the rows near the walks first. Every escape is forced here
    (``ESCAPE_MAX < 0``), so every answer comes from chains with every row: the same to
    the bit either way. The one-sided model's rows near the walks hold 0.66-0.76 of the
    nonzeros."""
    import mdft
    from mdft import _plane_passes

    model, theta = _one_sided_model()
    monkeypatch.setattr(_plane_passes, "ESCAPE_MAX", -1.0)
    answers, rebuilds = [], []
    for share_max in (0.5, _plane_passes.NEAR_SHARE_MAX):
        monkeypatch.setattr(_plane_passes, "NEAR_SHARE_MAX", share_max)
        caplog.clear()
        with caplog.at_level(logging.DEBUG, logger="mdft.threshold_exact"):
            answers.append(mdft.threshold_probabilities(model, theta, max_steps=1000,
                                                        fallback="raise"))
        rebuilds.append(caplog.text.count("building every row"))
    assert rebuilds[0] == 1
    assert rebuilds[1] >= 5
    np.testing.assert_array_equal(answers[0].rt_pmf, answers[1].rt_pmf)
    assert answers[0].resolution == answers[1].resolution
    assert answers[0].error_mean_rt == answers[1].error_mean_rt


def test_benchmark_canonical_sets_are_the_context_effects_at_the_canonical_parameters():
    """``bench_threshold_exact.py --canonical`` runs the option sets of ``mdft.effects``
    with ``w = (.5, .5)``, ``phi1 = .022``, ``phi2 = .05``, ``beta = 12`` and ``sigma2 = 1``
    unless a case changes it, each with a reference seed of its own."""
    bench = _bench()
    models, labels = bench.canonical_models(3)
    assert len(models) == len(labels) == len(bench.CANONICAL_CASES)
    for (model, theta, seed), (name, want_theta, changes), label in zip(
            models, bench.CANONICAL_CASES, labels):
        effect = mdft.effects.SCENARIOS[name]
        np.testing.assert_array_equal(model.M, np.asarray(effect.M))
        np.testing.assert_array_equal(model.w, [0.5, 0.5])
        assert theta == (17.5 if want_theta is None else want_theta) and name in label
        assert model.sigma2 == changes.get("sigma2", 1.0)
        assert (model.phi1, model.phi2, model.beta) == (0.022, 0.05, 12.0)
    assert len({seed for _, _, seed in models}) == len(models)  # a reference seed each
