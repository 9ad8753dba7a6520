"""The direct L-BFGS-B driver (irl._lbfgsb) against scipy.optimize.minimize, and its fallback."""

import warnings

import numpy as np
import pytest
import scipy
from hypothesis import given, settings
from hypothesis import strategies as st

import irl._lbfgsb as lb
from irl import GridWorld, generate_demonstrations, mesc_irl


def problem(seed, n):
    """A smooth non-quadratic objective on n variables and a box with some finite, some zero bounds."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, n))
    h = a @ a.T / n + 0.05 * np.eye(n)
    b = rng.normal(size=n) * 2.0
    c = rng.uniform(0.0, 0.5, n)
    upper = np.where(rng.random(n) < 0.3, rng.uniform(0.0, 2.0, n), np.inf)
    upper[rng.random(n) < 0.15] = 0.0
    x0 = rng.uniform(0.0, 3.0, n)

    def fun(x):
        # log-sum-exp term: curvature that changes along the path, as in a likelihood
        z = np.logaddexp(0.0, x - 1.0)
        return float(0.5 * x @ h @ x - b @ x + c @ z), h @ x - b + c / (1.0 + np.exp(1.0 - x))

    return fun, x0, upper


def run(solver, fun, x0, upper, stop_at, **kw):
    seen, stopped = [], []

    def recording(x):
        seen.append(x.copy())
        return fun(x)

    def callback(x):
        stopped.append(x.copy())
        return len(stopped) == stop_at

    return solver(recording, x0, upper, callback=callback, **kw), seen, stopped


def assert_same_run(mine, ref):
    (r, seen, cb), (s, seen_ref, cb_ref) = mine, ref
    assert len(seen) == len(seen_ref) and len(cb) == len(cb_ref)
    for p, q in zip(seen + cb, seen_ref + cb_ref):
        assert p.tobytes() == q.tobytes()  # the same iterates, bit for bit
    assert r.x.tobytes() == s.x.tobytes()
    assert (r.nit, r.nfev, r.success, r.message) == (s.nit, s.nfev, s.success, s.message)


def test_the_driver_is_used_from_scipy_1_17_on():
    # written for and checked on scipy 1.17; a later release that changes the private routine
    # should fail here (the fits would still be right, through minimize, but slower)
    major, minor = (int(p) for p in scipy.__version__.split(".")[:2])
    assert lb.available() or (major, minor) < (1, 17)


@settings(deadline=None, max_examples=40)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 30), maxcor=st.sampled_from([3, 10, 40]),
       maxiter=st.sampled_from([2, 5, 1000]), stop_at=st.sampled_from([0, 1, 4]))
def test_same_iterates_and_result_as_scipy_minimize(seed, n, maxcor, maxiter, stop_at):
    fun, x0, upper = problem(seed, n)
    kw = dict(maxcor=maxcor, maxiter=maxiter, maxfun=20 * maxiter)
    assert_same_run(run(lb.minimize_box, fun, x0, upper, stop_at, **kw),
                    run(lb.minimize_box_scipy, fun, x0, upper, stop_at, **kw))


def test_edge_cases_match_scipy_minimize():
    fun, x0, upper = problem(3, 8)
    kw = dict(maxcor=5, maxiter=100, maxfun=2000)
    # every variable fixed at zero: one evaluation, scipy's message
    fixed = np.zeros(8)
    mine = run(lb.minimize_box, fun, x0, fixed, 0, **kw)
    assert_same_run(mine, run(lb.minimize_box_scipy, fun, x0, fixed, 0, **kw))
    assert mine[0].message == lb.FIXED_MESSAGE and mine[0].nit == 0 and not mine[0].x.any()
    # the evaluation limit: stops after the iteration in which it is passed
    tight = dict(kw, maxfun=3)
    mine = run(lb.minimize_box, fun, x0, upper, 0, **tight)
    assert_same_run(mine, run(lb.minimize_box_scipy, fun, x0, upper, 0, **tight))
    assert "EVALUATIONS" in mine[0].message and not mine[0].success
    # Rosenbrock's valley from (0.1, 5): the first line search needs more than a few steps
    def rosen(x):
        return float(100.0 * (x[1] - x[0] ** 2) ** 2 + (1.0 - x[0]) ** 2), np.array(
            [-400.0 * x[0] * (x[1] - x[0] ** 2) - 2.0 * (1.0 - x[0]), 200.0 * (x[1] - x[0] ** 2)])

    start, box = np.array([0.1, 5.0]), np.full(2, np.inf)
    mine = run(lb.minimize_box, rosen, start, box, 0, **kw)
    assert_same_run(mine, run(lb.minimize_box_scipy, rosen, start, box, 0, **kw))
    assert mine[0].success and np.allclose(mine[0].x, 1.0, atol=1e-3)
    # a start outside the box is clipped into it
    far = x0 + 10.0
    assert_same_run(run(lb.minimize_box, fun, far, upper, 0, **kw), run(lb.minimize_box_scipy, fun, far, upper, 0, **kw))


def fits(monkeypatch, direct, cases):
    monkeypatch.setattr(lb, "_STATE", {"ok": direct})
    out = []
    for nominal, demos, kw in cases:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            res = mesc_irl(nominal, demos, **kw)
        out.append((res.penalties, res.evidence, res.n_iter, res.n_evaluations, res.converged, res.message))
    return out


def test_mesc_fits_are_the_same_on_both_paths(monkeypatch):
    # the selection's whole sequence of fits, plain maximum likelihood, bounds, preconditioning and a
    # run stopped by max_iter, on random worlds with and without slip
    rng = np.random.default_rng(5)
    cases = []
    for i, slip in enumerate((0.0, 0.1, 0.2)):
        size = (6, 7, 8)[i]
        world = GridWorld.random(size, rng=int(rng.integers(1 << 30)), p_slip=slip, min_distance=0.6 * size)
        demos = generate_demonstrations(world.constrained_mdp, (40, 15, 60)[i], rng=i)
        nominal = world.nominal_mdp
        cases += [(nominal, demos, {}), (nominal, demos, {"selection": "l1"}),
                  (nominal, demos, {"selection": "none", "max_penalty": 1.5, "precondition": True})]
    cases.append((nominal, demos, {"selection": "none", "max_iter": 3}))
    direct = fits(monkeypatch, True, cases)
    reference = fits(monkeypatch, False, cases)
    for a, b in zip(direct, reference):
        assert a[0].tobytes() == b[0].tobytes()
        assert (a[1] is None and b[1] is None) or a[1].tobytes() == b[1].tobytes()
        assert a[2:] == b[2:]
    assert not direct[-1][4] and "ITERATIONS" in direct[-1][5]  # the max_iter case did stop early


class Broken:
    """A stand-in for a changed private routine."""

    def __init__(self, mode):
        self.mode = mode

    def setulb(self, *args):
        if self.mode == "signature":
            raise TypeError("setulb() takes 16 positional arguments")
        args[11][0] = 4  # "converged" at once: a different behaviour
        args[11][1] = 401


@pytest.mark.parametrize("mode", ["signature", "behaviour"])
def test_a_changed_routine_falls_back_to_scipy_minimize(monkeypatch, mode):
    world = GridWorld(5, 0, 24, constrained_states=[12], p_slip=0.1)
    demos = generate_demonstrations(world.constrained_mdp, 30, rng=0)
    ok = mesc_irl(world.nominal_mdp, demos)
    monkeypatch.setattr(lb, "_routine", Broken(mode))
    monkeypatch.setattr(lb, "_STATE", {})
    assert not lb.available()
    res = mesc_irl(world.nominal_mdp, demos)
    assert res.penalties.tobytes() == ok.penalties.tobytes() and res.evidence.tobytes() == ok.evidence.tobytes()
    assert res.n_evaluations == ok.n_evaluations and res.converged
