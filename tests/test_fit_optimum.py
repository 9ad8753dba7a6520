"""Fits that find the maximum of the likelihood or say they may not have; the result's
repr, summary and to_dict."""

import importlib.util
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import mdft
from mdft._differences import hessian, rough_steps
from mdft.likelihood import INFEASIBLE
from mdft.optimise import _local, multistart


def _load_benchmark():
    """The benchmark's generator of random problems, so that test and benchmark draw alike."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_fit_optimum.py"
    spec = importlib.util.spec_from_file_location("bench_fit_optimum", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


BENCH = _load_benchmark()
PARAMS = BENCH.PARAMS


def random_problem(seed):
    problem, truth = BENCH.random_problem(seed)
    return problem["data"], problem["M"], problem["stopping"], truth


def test_fit_reaches_the_likelihood_of_the_truth_or_does_not_claim_convergence():
    """The maximum is never below the likelihood at the true parameters: a fit that stops
    below it has missed the optimum and must say so (the benchmark
    bench_fit_optimum.py measures the share on 100 problems)."""
    reached, claimed_wrongly = 0, 0
    n = 3
    for seed in range(n):
        data, M, T, truth = random_problem(seed)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mdft.FitConvergenceWarning)
            res = mdft.fit(data, M, stopping=T, params=PARAMS, fixed=dict(beta=truth["beta"]),
                           n_starts=3, rng=seed)
        ok = res.log_likelihood >= res.log_likelihood_at({k: truth[k] for k in PARAMS}) - 0.01
        reached += ok
        claimed_wrongly += (not ok) and res.converged
    assert claimed_wrongly == 0
    assert reached >= n - 1


def test_optimum_on_a_bound_warns_and_is_not_converged():
    data, M, T, truth = random_problem(3)
    fixed = {k: truth[k] for k in ("w", "phi1", "beta", "sigma2")}
    with pytest.warns(mdft.FitConvergenceWarning, match=r"phi2 on a bound of its range"):
        res = mdft.fit(data, M, stopping=T, params=["phi2"], fixed=fixed,
                       bounds=dict(phi2=(0.3, 0.5)), n_starts=3, rng=0)
    assert res.on_bound == ("phi2",) and not res.converged
    assert "on a bound" in res.message and not np.isfinite(res.standard_errors["phi2"])


def test_starts_that_disagree_are_reported():
    # a narrow deep well at 0.9 that only the first start finds, a broad shallow one at 0.3
    def f(u):
        x = float(u[0])
        return -2.0 * np.exp(-((x - 0.9) / 0.01) ** 2) - np.exp(-((x - 0.3) / 0.2) ** 2)

    rng = np.random.default_rng(0)
    out = multistart(f, np.array([0.9]), n_starts=3, n_screen=8, rng=rng, smooth=True,
                     max_iter=200, tol=1e-12, fatol=1e-12, agree_tol=1e-3, n_confirm=2)
    assert out.best.x[0] == pytest.approx(0.9, abs=1e-3)
    assert out.n_agree == 1 and not out.converged and len(out.runs) == 5  # 3 + 2 confirmations
    assert any("the starts disagree" in p for p in out.problems)
    # the same search from a start in the broad well: every start agrees (on it)
    out2 = multistart(lambda u: -np.exp(-((float(u[0]) - 0.3) / 0.2) ** 2), np.array([0.5]),
                      n_starts=3, n_screen=8, rng=rng, smooth=True, max_iter=200, tol=1e-12,
                      fatol=1e-12, agree_tol=1e-3)
    assert out2.converged and out2.n_agree == 3 and out2.best.x[0] == pytest.approx(0.3, abs=1e-4)


def _lbfgsb_alone(f, u0):
    from scipy import optimize

    return optimize.minimize(f, u0, method="L-BFGS-B", jac="3-point", bounds=[(0, 1)] * u0.size,
                             options={"maxiter": 500, "ftol": 1e-10, "gtol": 1e-7})


def test_a_local_run_whose_first_step_lands_where_the_model_is_impossible_goes_on():
    # a bowl at c whose gradient at the start points into an impossible corner (the
    # likelihood's 1e300): L-BFGS-B's first step goes there, and it ends back at the start
    # claiming convergence; the local run goes on in boxes and reaches the minimum
    c = np.array([0.45, 0.2])

    def f(u):
        if (u[0] > 0.8 and u[1] < 0.3) or u[0] < 0.05:
            return INFEASIBLE
        return 2000.0 + 300.0 * float(np.sum((u - c) ** 2))

    u0 = np.array([0.6, 0.5])
    alone = _lbfgsb_alone(f, u0)
    assert alone.success and np.array_equal(alone.x, u0)  # the stall this guards against
    run = _local(f, u0, smooth=True, max_iter=500, tol=1e-10, fatol=1e-8)
    assert run.success and "boxes" in run.message
    np.testing.assert_allclose(run.x, c, atol=1e-4)
    assert run.fun == pytest.approx(2000.0, abs=1e-6)


@pytest.mark.parametrize("noise", [0.0, 3e-6])
def test_a_local_run_that_ends_on_a_slope_is_not_called_converged(noise):
    # the bowl's minimum lies beyond a wall of impossible values: the best point is at the
    # wall, where the slope is steep; it is found, but not called an optimum (also where the
    # objective is rough: the Newton step's differences cross the wall)
    def f(u):
        return INFEASIBLE if u[0] > 0.7 else 10.0 + 300.0 * float((u[0] - 0.9) ** 2)

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow in the Newton step
        run = _local(f, np.array([0.3]), smooth=True, max_iter=500, tol=1e-10, fatol=1e-8,
                     noise=noise)
    assert run.x[0] == pytest.approx(0.7, abs=5e-3) and not run.success
    assert "still changes along the cube" in run.message
    out = multistart(f, np.array([0.3]), n_starts=3, n_screen=8, rng=np.random.default_rng(0),
                     smooth=True, max_iter=500, tol=1e-10, fatol=1e-8, agree_tol=1e-3,
                     noise=noise)
    assert not out.converged and any("did not converge" in p for p in out.problems)


def test_the_best_screen_point_is_always_a_start():
    # a broad bowl and a narrow deep well 0.06 from the first start: the screen point in the
    # well is too close to the first start to count as spread out, but it is the best one,
    # so it is a start and no screened point beats the optimum returned
    def f(u):
        broad = 5.0 * float(np.sum((u - np.array([0.3, 0.7])) ** 2))
        well = -3.0 * math.exp(-float(np.sum((u - np.array([0.56, 0.45])) ** 2)) / 2.88e-4)
        return broad + well

    for seed in range(40):
        out = multistart(f, np.array([0.5, 0.5]), n_starts=5, n_screen=32,
                         rng=np.random.default_rng(seed), smooth=True, max_iter=500, tol=1e-10,
                         fatol=1e-8, agree_tol=0.01)
        assert out.best.fun <= out.screen_best + 1e-12, seed


def test_a_single_start_is_never_called_converged():
    # the narrow and the broad well of the test above: one start from the broad well ends
    # there, a local optimum; with nothing to check it against it must not claim convergence
    def f(u):
        x = float(u[0])
        return -2.0 * np.exp(-((x - 0.9) / 0.01) ** 2) - np.exp(-((x - 0.3) / 0.2) ** 2)

    out = multistart(f, np.array([0.5]), n_starts=1, n_screen=8, rng=np.random.default_rng(0),
                     smooth=True, max_iter=200, tol=1e-12, fatol=1e-12, agree_tol=1e-3)
    assert out.best.x[0] == pytest.approx(0.3, abs=1e-3) and out.best.success
    assert not out.converged and out.n_screen == 0 and len(out.runs) == 1
    assert any("a single start" in p for p in out.problems)
    data, M, T, truth = random_problem(1)
    fixed = {k: truth[k] for k in ("phi1", "phi2", "beta", "sigma2")}
    with pytest.warns(mdft.FitConvergenceWarning, match="a single start"):
        res = mdft.fit(data, M, stopping=T, params=["w"], fixed=fixed, n_starts=1, rng=0)
    assert not res.converged and "n_starts >= 2" in res.message


def test_fit_warns_when_only_one_start_reaches_the_best(monkeypatch):
    data, M, T, truth = random_problem(1)
    fixed = {k: truth[k] for k in ("phi1", "phi2", "beta", "sigma2")}
    with pytest.warns(mdft.FitConvergenceWarning, match="the starts disagree"):
        res = mdft.fit(data, M, stopping=T, params=["w"], fixed=fixed, n_starts=2,
                       n_confirm=0, agree_tol=0.0, max_iter=2, rng=0)
    assert not res.converged


def test_result_repr_summary_and_to_dict():
    data, M, T, truth = random_problem(2)
    fixed = {k: truth[k] for k in ("phi1", "phi2", "beta", "sigma2")}
    del fixed["phi2"]
    res = mdft.fit(data, M, stopping=T, params=["w", "phi2"], fixed=fixed, n_starts=2, rng=0)
    text = repr(res)
    assert text.startswith("FitResult(w=[") and "phi2=" in text and len(text) < 200
    lines = res.summary().splitlines()
    assert lines[0].startswith("MDFT fit: 2 parameters, ")
    assert lines[2].split()[0] == "w[0]" and lines[4].split()[0] == "phi2"
    assert float(lines[4].split()[1]) == pytest.approx(res.params["phi2"], rel=1e-3)
    d = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert d["params"]["w"] == pytest.approx(res.params["w"].tolist())
    assert d["log_likelihood"] == res.log_likelihood and d["stopping"] == {"n_steps": T}
    assert d["params"]["theta"] is None and d["converged"] == res.converged


def test_log_likelihood_at_bad_input():
    # a single start is never called converged, and says so: expected here
    with pytest.warns(mdft.FitConvergenceWarning, match="a single start"):
        res = mdft.fit(mdft.ChoiceData([[0, 1]], [[6, 4]]), [[1.0, 3.0], [3.0, 1.0]],
                       stopping=10, fixed=dict(phi1=0.02, phi2=0.05, beta=12.0, sigma2=1.0),
                       n_starts=1, rng=0)
    with pytest.raises(TypeError, match="params must be a dict"):
        res.log_likelihood_at([0.5, 0.5])
    with pytest.raises(ValueError, match=r"params has unknown parameter name\(s\) \['tau'\]"):
        res.log_likelihood_at({"tau": 1.0})
    # values are checked as fixed values are, each naming its parameter
    for bad, match in (({"w": [2.0, -1.0]}, r"params\['w'\] must be non-negative"),
                       ({"w": [0.3, 0.3]}, r"params\['w'\] must sum to 1"),
                       ({"w": [0.2, 0.3, 0.5]}, r"params\['w'\] must have one weight"),
                       ({"sigma2": -1.0}, r"params\['sigma2'\] must be >= 0"),
                       ({"phi2": float("nan")}, r"params\['phi2'\] must be finite"),
                       ({"M": [[1.0, 3.0]]}, r"params\['M'\] must have shape \(2, 2\)")):
        with pytest.raises(ValueError, match=match):
            res.log_likelihood_at(bad)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(n_confirm=-1), "n_confirm must be an integer >= 0"),
        (dict(agree_tol=-0.1), "agree_tol must be >= 0"),
    ],
)
def test_optimiser_settings_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        mdft.fit(mdft.ChoiceData([[0, 1]], [[6, 4]]), [[1.0, 3.0], [3.0, 1.0]], stopping=10,
                 fixed=dict(phi1=0.02, phi2=0.05, beta=12.0, sigma2=1.0), rng=0, **kwargs)


def test_failed_evaluations_are_reported():
    # phi2 up to 3 over 1000 steps: part of the box overflows and cannot be evaluated
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.FitConvergenceWarning)
        res = mdft.fit(mdft.ChoiceData([[0, 1]], [[60, 40]]), [[1.0, 3.0], [3.0, 1.0]],
                       stopping=1000, params=["w", "phi2"],
                       fixed=dict(phi1=0.0, beta=1.0, sigma2=1.0), bounds=dict(phi2=(0.0, 3.0)),
                       rng=0)
    assert "likelihood evaluations failed and counted as impossible" in res.message
    assert "preferences overflow" in res.message
    assert res.params["phi2"] < 2.0  # the optimum lies where the model can be evaluated


@pytest.mark.parametrize("response_times", [False, True])
def test_evaluations_where_no_trial_decides_are_reported_as_such(response_times):
    # thresholds up to 300 within 40 steps: part of the box decides in no trial
    model = mdft.MDFTModel([[1.0, 3.0], [3.0, 1.0]], [0.6, 0.4], phi1=0.02, phi2=0.05,
                           beta=12.0, sigma2=1.0)
    sim = mdft.simulate(model, 200, stopping=mdft.Threshold(6.0, max_steps=40), rng=3)
    ok = sim.choices >= 0
    data = mdft.ChoiceData.from_trials([[0, 1]] * int(ok.sum()), sim.choices[ok],
                                       response_times=sim.decision_steps[ok])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.FitConvergenceWarning)
        res = mdft.fit(data, model.M, stopping=mdft.Threshold(6.0, max_steps=40),
                       params=["theta"], fixed=dict(w=[0.6, 0.4], phi1=0.02, phi2=0.05,
                                                    beta=12.0, sigma2=1.0),
                       bounds=dict(theta=(2.0, 300.0)), response_times=response_times,
                       n_starts=3, rng=0)
    assert "likelihood evaluations failed and counted as impossible" in res.message
    assert "decides in no trial within max_steps" in res.message
    assert "overflow" not in res.message
    assert res.params["theta"] < 20.0  # the optimum lies where trials decide


@pytest.mark.parametrize("use_rt", [False, True])
def test_the_simulated_likelihood_skips_trials_at_a_threshold_out_of_reach(monkeypatch, use_rt):
    from mdft.likelihood import Likelihood

    M = np.array([[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]])
    model = mdft.MDFTModel(M, [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
    sim = mdft.simulate(model, 300, stopping=mdft.Threshold(8.0, max_steps=200), rng=1)
    ok = sim.choices >= 0
    data = mdft.ChoiceData.from_trials([[0, 1, 2]] * int(ok.sum()), sim.choices[ok],
                                       response_times=sim.decision_steps[ok])
    stopping = mdft.Threshold(8.0, max_steps=200)
    lik = Likelihood(data, stopping, "simulation", use_rt=use_rt, rt_bins=None,
                     n_samples=2000, seed=5, threshold_options=None)
    p = dict(M=M, w=np.array([0.5, 0.5]), phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
    calls = []
    real = mdft.simulate

    def counting(*args, **kwargs):
        calls.append(kwargs["stopping"].theta)
        return real(*args, **kwargs)

    monkeypatch.setattr(mdft, "simulate", counting)
    assert lik.negative(dict(p, theta=8.0)) < 1e299 and calls == [8.0]
    # 200 steps cannot bring a preference to 500: no trial is simulated, and the evaluation
    # fails for the reason the trials would have given
    assert lik.negative(dict(p, theta=500.0)) == 1e300 and calls == [8.0]
    assert lik.n_failed == 1 and "decides in no trial within max_steps" in lik.first_failure


def _rough_bowl(centre, A, level=1300.0, noise=3e-6, cell=1e-5):
    """``level + (u - c)^T A (u - c) / 2`` plus jumps: a deterministic value in
    ``+-noise * level`` on each cell of side ``cell`` (a likelihood smooth only to a
    tolerance, as the exact engine's on three options)."""
    def f(u):
        key = tuple(int(k) for k in np.floor(np.asarray(u) / cell))
        jump = np.random.default_rng(abs(hash(key)) % 2**32).uniform(-1.0, 1.0)
        d = np.asarray(u) - centre
        return level + 0.5 * float(d @ A @ d) + noise * level * jump
    return f


def test_a_rough_objective_is_optimised_with_steps_above_its_noise():
    # curvatures of 1e4 to 4e4: standard errors of 0.005-0.01 in unit-cube coordinates
    centre = np.array([0.42, 0.61])
    A = np.array([[1.0e4, 6.0e3], [6.0e3, 4.0e4]])
    f = _rough_bowl(centre, A)
    se = np.sqrt(np.diag(np.linalg.inv(A)))
    for start in (np.array([0.3, 0.3]), np.array([0.8, 0.7]), np.array([0.5, 0.45])):
        run = _local(f, start, smooth=True, max_iter=500, tol=1e-10, fatol=1e-8, noise=3e-6)
        assert run.success, run.message
        # within a tenth of a standard error of the minimum
        assert np.all(np.abs(run.x - centre) <= 0.1 * se), (run.x, se)
    out = multistart(f, np.array([0.3, 0.3]), n_starts=3, n_screen=8,
                     rng=np.random.default_rng(0), smooth=True, max_iter=500, tol=1e-10,
                     fatol=1e-8, agree_tol=0.01, noise=3e-6)
    assert out.converged, out.problems


def test_the_hessian_of_a_rough_likelihood_is_taken_over_a_standard_error():
    rng = np.random.default_rng(7)
    for _ in range(5):
        centre = rng.uniform(0.3, 0.7, size=3)
        B = rng.normal(size=(3, 3))
        A = 10.0 ** rng.uniform(3.0, 5.0) * (B @ B.T / 3.0 + np.eye(3))
        f = _rough_bowl(centre, A)
        idx = np.arange(3)
        steps = rough_steps(f, centre, idx)
        H = hessian(f, centre, idx, steps)
        se, se_true = np.sqrt(np.diag(np.linalg.inv(H))), np.sqrt(np.diag(np.linalg.inv(A)))
        np.testing.assert_allclose(se, se_true, rtol=0.02)
        # the default step differences the jumps instead
        H_default = hessian(f, centre, idx, np.full(3, 1e-4))
        assert np.max(np.abs(np.diag(H_default) / np.diag(A) - 1.0)) > 0.2
