"""The three-option passes of :func:`mdft.threshold_probabilities`: the grids of the
schedule, the pilots that fit the reference sums, the passes that count and the probes of
the moment closure (``docs/threshold_exact.md``, sections 2 and 4).
"""

from __future__ import annotations

import logging
import math
from functools import partial
from types import SimpleNamespace

import numpy as np

from ._plane_chain import (PILOT_RUNAWAY, TooManyStates, build_moment_chain, mean_sums,
                           narrow_axes, near_occupied, pilot_pass, plane_geometry,
                           propagate_moments, reference_sums, solve_moments)
from ._plane_spread import simulate_walks, spread_about, walk_plane
from ._threshold_fallback import RT_WEIGHT_FLOOR, steps_per_walk
from ._threshold_solve import error_estimate, krylov, mean_rt
from .threshold_result import ThresholdProbabilities

# the passes report to the log of threshold_probabilities, whose steps they are
logger = logging.getLogger("mdft.threshold_exact")

# First resolution (cell size in per-step standard deviations) and refinements.
KAPPA = 1.0
REFINE = math.sqrt(2.0)
MAX_REFINEMENTS = 4
# After the first resolution, a half step (the cells 2**(1/4) smaller, about twice the
# nonzeros instead of four times) between each refinement and the next; when a half step
# is run, and how its answer is compared, is decided in mdft.threshold_exact.
HALF_STEP = 2.0**0.25
# Spread of the summed preference within a state assumed by the pilot pass, and the
# pilot's step limit (its occupation only fits the reference sums).
PILOT_DELTA = 0.5
PILOT_STEPS = 1_000
PILOT_PASSES = 2
# After a pilot cut short (its closure ran away), the reference sums are fitted
# again to the walks of a pass at the first resolution that counts, at most REFITS times,
# until the answer changes by at most REFIT_SHARE of the tolerances; the last change is
# added to the closure's error.
REFITS = 4
REFIT_SHARE = 0.1
# A closure error above this share of a tolerance on the coarsest grid is measured again on
# the next (and refuses at once there only beyond the first comparison's factor times the
# tolerance, mdft.threshold_exact).
RECHECK_SHARE = 0.5
# The geometric tail is filled once the change it may make is within this
# share of atol and rt_rtol (that change is added to the error estimate).
TAIL_SHARE = 0.01
# "propagate": a pass whose mass reaching states without rows (left out as
# never occupied by the coarser pass) exceeds this is built again with every row.
ESCAPE_MAX = 1e-10
# Where such a pass's rows held more than this share of the nonzeros of the pass built again,
# leaving rows out saves too little to risk another escape: the later passes of the call
# build every row at once.
NEAR_SHARE_MAX = 0.9
# A deliberation of at most this many steps on average (the first pass that counts): the
# walks decide before their sums settle, so the one spread the pilots fit over the whole
# occupation is least sure, and the closure's spread is probed larger too.
SHORT_DELIBERATION = 30.0
# The passes that count try the Krylov tail early (mdft._plane_chain.propagate_moments's
# ``early``) where the last pilot ran at least this many steps before its geometric tail
# could be filled: their walks settle late, and a try at the usual first step would find
# more than it needs.
EARLY_KRYLOV_PILOT_STEPS = 250
# Where the simulated walks fit the reference sums instead of the pilots, the passes try it
# early where at least EARLY_KRYLOV_SHARE of the walks are still undecided after
# EARLY_KRYLOV_WALK_STEPS steps (on the 46 models of two random draws whose pilots ran,
# those whose last pilot ran at least EARLY_KRYLOV_PILOT_STEPS steps all had that share
# undecided, as had five more).
EARLY_KRYLOV_WALK_STEPS = 125
EARLY_KRYLOV_SHARE = 0.01
# Whether the simulated walks fit the reference sums and their spread (where they can:
# mdft._plane_spread), so that no pilot pass runs. A switch for the tests of the pilots.
WALK_FIT = True


def narrow_everywhere(model, theta, kappa):
    """Why no three-option pass can be trusted, or "" when the finest one may be.

    A pass is not trusted where the noise is narrower than its cells over ``sqrt(3)``
    (``MomentChain.narrow``). The cells shrink in proportion to the resolution and the
    noise does not, so a grid that is narrow at the finest resolution of the schedule is
    narrow at every one: the chain could only build ever larger chains and refuse.
    """
    finest = kappa / REFINE**MAX_REFINEMENTS
    g = plane_geometry(model, theta, finest)
    narrow = narrow_axes(g)
    if narrow.size == 0:
        return ""
    k = int(narrow[0])
    cells = (g["h1"], g["h2"])
    return (f"the noise (per-step sd {float(g['sd_exact'][k]):.3g} along a grid axis) is "
            f"narrower than the cells over sqrt(3) even at the finest resolution {finest:.3g} "
            f"(spacing {float(cells[k]):.3g} along that axis), where the chain's answers are "
            "not trusted")


def plane_runs(model, theta, kappa, max_states, solve, closure, tolerances, cheaper=None,
               edge=False):
    """Computations of increasing resolution for three options (the moment chain).

    Before the first, a short simulation of the walks (:mod:`mdft._plane_spread`) fits the
    reference sums (the plane of the sum over the plane coordinates along the walks) and
    their spread (among the walks about to decide); every pass uses that fit, so
    ``"propagate"`` and ``"solve"`` solve the same chains. Where the walks cannot fit them
    (too few decide; or ``WALK_FIT`` is off), two pilot passes at the coarsest resolution
    do (the first from a constant reference sum and spread ``PILOT_DELTA``, the second from
    the first's fit), from their occupation, with the spread measured among the walks about
    to decide where it can be, the pilots' where not. A pilot whose closure runs away is
    cut (:func:`mdft._plane_chain.pilot_pass`), and its fit is then refitted to the walks
    of passes at the first resolution that counts, the last change joining the closure's
    error as ``closure["reference"]``. ``tolerances``: ``(atol, rt_rtol)``.

    ``cheaper(answer, nonzeros, steps)``, when given, is asked once before the closure's
    probes of the first pass that counts, with its answer and the nonzeros that its probes
    and the next pass are expected to build (each refinement by ``REFINE`` four times the
    nonzeros of the grid before) and its steps, and with ``probed=None`` (no probe of the
    control variates); or, where pilots run, after the first pilot, with its answer
    (``probabilities``, ``p_undecided``, ``rt_pmf``; None where the pilot was cut), the
    nonzeros that the first pass that counts, its probes and the next pass (and after a cut
    pilot, two refits) are expected to build, and the pilot's steps. What it returns other
    than None (a simulated answer) is the first run's result. ``edge``: every chain's rows
    carry the edge terms (:mod:`mdft._plane_boundary`).
    """
    # the coarsest, the first, then refinements by sqrt(2) with a half step before each (the
    # odd powers of HALF_STEP)
    kappas = [kappa * REFINE] + [kappa / HALF_STEP**j for j in range(2 * MAX_REFINEMENTS + 1)]
    halves = [False] + [j % 2 == 1 for j in range(2 * MAX_REFINEMENTS + 1)]
    state = dict(ref=np.array([float(np.sum(model.P0)), 0.0, 0.0]), delta=PILOT_DELTA,
                 near=None, krylov_from=None, early=False, every_row=False)
    # the occupied region of each pass limits the rows of the next, finer one ("propagate":
    # the solver of the long run has no step limit, so every reachable state may matter)
    limit = solve["method"] == "propagate"

    # the change the extrapolated tail may make: a share of the tolerances (0: no tail)
    budget = (0.0, 0.0) if solve["tail_tol"] == 0.0 else tuple(TAIL_SHARE * t for t in tolerances)

    def fitting_pass(k, steps, tol):
        # a pass carrying the occupation of the sum's moments, with every row, at the current
        # reference sums: (chain, answer, cut)
        chain = build_moment_chain(model, theta, k, state["ref"], state["delta"], max_states,
                                   edge=edge)
        out, cut = pilot_pass(chain, steps, tol, budget, floor=RT_WEIGHT_FLOOR)
        return chain, out, cut

    def pilot(k):
        g = plane_geometry(model, theta, k)
        E = g["E"]
        # where the sum stays put, there is nothing to fit (the pilots are short then)
        walks = simulate_walks(model, theta, solve["max_steps"]) if g["n_levels"] > 1 else None
        if WALK_FIT and walks is not None and fitted_by_walks(walks, E):
            return
        unmeasured = False
        for i in range(PILOT_PASSES):
            chain, out, cut = fitting_pass(k, PILOT_STEPS, 1e-6)
            occ, steps = out[4], out[2]
            if cut:
                # the pilot's closure ran away (its reference sums were too far from the
                # walks' sums): only its steps before are fitted, and the fit is checked
                # against the walks of the first pass that counts (refit)
                logger.debug("resolution %.3g: the pilot pass was cut after %d steps", k, steps)
                state["cut"] = True
            if steps == 0:
                break  # nothing to fit: the reference sums and spread stay as they were
            state["ref"], state["delta"], measured = reference_sums(chain, occ)
            # judged on the last pilot, which starts from the first one's fit
            unmeasured = not measured and not cut
            if i == 0 and cheaper is not None:
                # the first pilot's answer tells what simulating would cost (a cut pilot's
                # does not: the first trials do)
                state["simulated"] = ask_cheaper(chain, out, cut)
                if state["simulated"] is not None:
                    return
        if unmeasured:
            raise TooManyStates(
                "the pilots could not measure the spread of the summed preference within the "
                "states (its variance came out negative: the walks' sums stray far from the "
                "sums the chain is linearised about, as where the starting preference P0 sums "
                "far from where the walks' sums settle)")
        if state["delta"] > 0.0:
            # the spread that matters: among the walks about to decide (simulated), not the
            # pilots' spread over the whole occupation
            spread = None if walks is None else spread_about(walks, E, state["ref"])
            if spread is not None:
                logger.debug("spread of the sum: %.3g in the pilots, %.3g among the walks "
                             "about to decide", state["delta"], spread)
                state["delta"] = spread
        if limit:
            # a cut pilot's occupation stops short of where the walks go: every row
            state["near"] = None if cut else near_occupied(chain, occ)
        # walks that settle late on the pilots' grid settle late on finer ones
        state["early"] = not cut and steps >= EARLY_KRYLOV_PILOT_STEPS

    def fitted_by_walks(walks, E):
        # the reference sums and their spread from the walks (of a sum that moves), where
        # enough of them decide: the pilots are not needed, and the first pass that counts
        # builds every row and answers the question the first pilot would have (make)
        ref = walk_plane(walks, E)
        spread = None if ref is None else spread_about(walks, E, ref)
        if spread is None or not spread > 0.0:
            return False
        state["ref"], state["delta"] = ref, spread
        steps = walks.lengths(solve["max_steps"])
        state["early"] = bool(np.mean(steps > EARLY_KRYLOV_WALK_STEPS) >= EARLY_KRYLOV_SHARE)
        state["ask_first"] = cheaper is not None  # (given only to "propagate": an rt_pmf)
        logger.debug("the walks' reference sums %s and spread %.3g (%d walks)",
                     np.array2string(ref, precision=4), spread, walks.steps.shape[0])
        return True

    def ask_cheaper(chain, out, cut):
        # the passes ahead at the least: the first that counts with its two probes (where the
        # sum moves; three in a short deliberation), on a grid REFINE finer than the
        # pilots', and the next; after a cut pilot, two refits before them
        passes = (3 if state["delta"] > 0.0 else 1) + (2 if cut else 0)
        nonzeros = chain.cols.shape[0] * (passes * REFINE**4 + REFINE**8)
        answer = None  # a cut pilot's answer predicts nothing
        if not cut:
            # (negative choices of the pilot's closure, its error, do not count)
            rt_pmf = np.maximum(out[0], 0.0)
            answer = SimpleNamespace(probabilities=rt_pmf.sum(axis=0),
                                     p_undecided=max(out[1], 0.0), rt_pmf=rt_pmf)
        return cheaper(answer, nonzeros, out[2])

    def run(k, delta, ref_map=None):
        if solve["method"] == "propagate":
            steps = solve["max_steps"]
            near_nonzeros = None
            for near in (None if state["every_row"] else state["near"], None):
                chain = build_moment_chain(model, theta, k, state["ref"], delta, max_states,
                                           near, ref_map, edge)
                out = propagate_moments(chain, steps, solve["tol"], budget,
                                        floor=RT_WEIGHT_FLOOR,
                                        krylov_from=state["krylov_from"],
                                        escape_max=math.inf if near is None else ESCAPE_MAX,
                                        early=state["early"])
                if near is None or out[6] <= ESCAPE_MAX:
                    break
                # the coarser pass did not foresee where the mass goes: every row after all
                logger.debug("resolution %.3g: %.2g of the mass left the rows built; "
                             "building every row", k, out[6])
                near_nonzeros = chain.cols.shape[0]
            if near_nonzeros is not None:
                share = near_nonzeros / max(chain.cols.shape[0], 1)
                state["every_row"] = share > NEAR_SHARE_MAX
                logger.debug("resolution %.3g: the rows built held %.3g of the nonzeros%s", k,
                             share, "; every row from now on" if state["every_row"] else "")
            rt_pmf, mass, n_iter, tail_start, occ, tail_err, escaped = out
            state["walks"] = (chain, occ)
            state["near"] = near_occupied(chain, occ)
            # the next pass leaves out the Krylov tries that failed on this one
            state["krylov_from"] = tail_start if tail_start < steps else None
        else:
            chain = build_moment_chain(model, theta, k, state["ref"], delta, max_states,
                                       ref_map=ref_map, edge=edge)
        closure["narrow"] = chain.narrow
        closure["nonzeros"] = chain.cols.shape[0]
        common = dict(theta=theta, n_cells=int(math.ceil(theta / min(chain.h))),
                      spacing=float(min(chain.h)), n_levels=1, n_states=chain.n_states,
                      engine="plane", resolution=float(k))
        if solve["method"] == "propagate":
            probs = rt_pmf.sum(axis=0)
            closure["clipped"] = tail_err[2]
            if not tail_err[2] <= tolerances[0]:
                # the first-order closure in the sum can grow without bound where the slopes
                # T1 are large and the deliberation long; its answer is then no distribution
                raise TooManyStates(
                    f"at resolution {k:.3g} the moment closure of the summed preference is "
                    f"unstable for this model: its choices and undecided mass turn negative "
                    f"by {tail_err[2]:.2g} in all (atol={tolerances[0]:g})")
            times = np.arange(1, steps + 1, dtype=np.float64)
            return ThresholdProbabilities(
                probabilities=probs, p_undecided=mass, rt_pmf=rt_pmf,
                mean_response_times=mean_rt(times @ rt_pmf, probs), max_steps=steps,
                method="propagate", n_iter=n_iter, converged=True,
                tail_start=tail_start if tail_start < steps else None,
                error_probabilities=tail_err[0] + escaped, error_mean_rt=tail_err[1],
                **common)
        probs, weighted, n_iter, ok, clipped, occ = solve_moments(chain, solve["tol"],
                                                                  solve["max_iter"], krylov)
        state["walks"] = (chain, occ)
        closure["clipped"] = clipped
        if not ok:
            raise ValueError(
                f"the iterative solver did not reach tol={solve['tol']:g} within "
                f"max_iter={solve['max_iter']} on {2 * chain.n_states} unknowns; raise "
                "max_iter or tol, or use method='propagate'")
        return ThresholdProbabilities(
            probabilities=probs, p_undecided=0.0, rt_pmf=None,
            mean_response_times=mean_rt(weighted, probs), max_steps=None, method="solve",
            n_iter=n_iter, converged=True, tail_start=None, **common)

    def refit(k):
        # a pass at resolution k, the reference sums fitted again to its own walks' mean sums,
        # until the answer changes by less than REFIT_SHARE of the tolerances; the last
        # change is the closure's reference term
        previous = None
        change = (math.inf, math.inf)
        times = np.arange(1, solve["max_steps"] + 1, dtype=np.float64)
        for _ in range(REFITS):
            # a pass that counts, with every row (the Krylov tail too: a refit needs the
            # occupation of x and m only, not the second moment that pilots carry)
            chain = build_moment_chain(model, theta, k, state["ref"], state["delta"],
                                       max_states, edge=edge)
            out = propagate_moments(chain, solve["max_steps"], solve["tol"], budget,
                                    floor=RT_WEIGHT_FLOOR, early=state["early"])
            # a closure that runs away: the choices and undecided mass turned negative by
            # as much as a pilot is cut for (their sizes summing to 1 + PILOT_RUNAWAY)
            if not out[5][2] <= 0.5 * PILOT_RUNAWAY:
                raise TooManyStates(
                    f"at resolution {k:.3g} the moment closure of the summed preference is "
                    "unstable for this model: it runs away even with the reference sums fitted "
                    "to the walks' own mean sums")
            probs = out[0].sum(axis=0)
            answer = SimpleNamespace(probabilities=probs, p_undecided=out[1],
                                     mean_response_times=mean_rt(times @ out[0], probs))
            if previous is not None:
                change = error_estimate(answer, previous)
                logger.debug("resolution %.3g: refitting the reference sums changed the "
                             "answer by %.2g and %.2g", k, *change)
                if (change[0] <= REFIT_SHARE * tolerances[0]
                        and change[1] <= REFIT_SHARE * tolerances[1]):
                    break
            previous = answer
            state["ref"] = reference_sums(chain, out[4])[0]
        closure["reference"] = change

    def make(k, first):
        def compute():
            if first:
                # the pilots fit the reference sums on a grid one step coarser (a quarter of the
                # nonzeros): the fit is a plane and a spread, which need no finer grid
                pilot(k * REFINE)
                if state.get("simulated") is not None:
                    return state["simulated"]
                if state.get("cut"):
                    refit(k)
            result = run(k, state["delta"])
            if first and state.get("ask_first"):
                # the first pass's answer tells what simulating plain trials would cost,
                # against the passes ahead at the least: its two probes and the next pass (the
                # probe of control variates, once per call, is left to the hand-over after a
                # comparison, whose budget is the next pass's: this one's is too small for
                # most controlled simulations of a chain this large)
                simulated = cheaper(result, closure["nonzeros"] * (2 + REFINE**4),
                                    result.n_iter, probed=None)
                if simulated is not None:
                    return simulated
            clipped = closure["clipped"]
            if state["delta"] > 0.0 and (first or not closure["settled"]):
                # the closure's error, measured on the coarsest grid, and again on the next
                # while it exceeds half a tolerance there (a cut cell's place moves with the
                # sum, more unevenly the coarser the cells): from the plane of reference
                # sums, the change when every cell's reference sum is instead the mean sum of
                # this pass's walks in it (the grid's own passes go on from this pass's rows
                # and tails) ...
                walks = mean_sums(*state["walks"])
                plane = (0.0, 0.0)
                if walks is not None:
                    kept = (state["near"], state["krylov_from"])
                    plane = error_estimate(result, run(k, state["delta"], walks))
                    state["near"], state["krylov_from"] = kept
                # ... and from the spread: the change that a spread of the sum within the
                # states smaller by a factor sqrt(2) makes; in a short deliberation, the
                # larger of that and the change a spread larger by sqrt(2) makes (there the
                # answer can move with a larger spread only: the smaller one alone had
                # vouched for mean times 0.7 % long)
                spread = error_estimate(result, run(k, state["delta"] / REFINE))
                if result.rt_pmf is not None and steps_per_walk(
                        result.rt_pmf, result.p_undecided,
                        result.max_steps) <= SHORT_DELIBERATION:
                    kept = (state["walks"], state["near"], state["krylov_from"])
                    larger = error_estimate(result, run(k, state["delta"] * REFINE))
                    state["walks"], state["near"], state["krylov_from"] = kept
                    spread = (max(spread[0], larger[0]), max(spread[1], larger[1]))
                # the larger of the spread's and the plane's: both measure the one
                # linearisation around the reference sums (their sum counted it twice)
                err = (max(spread[0], plane[0]), max(spread[1], plane[1]))
                logger.debug("resolution %.3g: the closure's probes changed the answer by "
                             "%.2g and %.2g (plane), %.2g and %.2g (spread)", k, *plane,
                             *spread)
                closure.update(error=err, settled=not first or (
                    err[0] <= RECHECK_SHARE * tolerances[0]
                    and err[1] <= RECHECK_SHARE * tolerances[1]))
            closure["clipped"] = clipped  # this pass's, not the smaller spread's
            return result
        return compute

    def narrow(k):
        # a half step whose noise is narrower than its cells could never answer (and is
        # nobody's partner): left out (asked only of a half step about to run)
        return narrow_axes(plane_geometry(model, theta, k)).size > 0

    runs = [make(k, i == 0) for i, k in enumerate(kappas)]
    for compute, k, half in zip(runs, kappas, halves):
        compute.half = half
        compute.kappa = k
        compute.narrow = partial(narrow, k)
    return runs

