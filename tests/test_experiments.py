"""The experiments of ``mdft reproduce`` at tiny sizes: metrics against independent references."""

import json
from collections import deque

import numpy as np
import pytest

import irl
import orchestration
from orchestration.experiments import reproduce
from orchestration.experiments import orchestrators as orch_exp
from orchestration.experiments import transfer as transfer_exp
from orchestration.experiments.base import units_of

TINY = {
    "orchestrators": dict(n_worlds=2, n_demonstrations=20, n_trajectories=20, n_weights=3),
    "mdft-vs-wa": dict(n_instances=2, n_actions=3, n_choices=30, n_steps=10),
    "soft-constraints": dict(n_demonstrations=[3, 6], n_repeats=1, chi_levels=[0.1, 0.3],
                             n_model_trajectories=20),
    "transfer": dict(n_repeats=1, n_source=20, n_demonstrations=[3], n_model_trajectories=20),
}


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    out = {}
    for name, settings in TINY.items():
        folder = tmp_path_factory.mktemp(name)
        report = reproduce(name, folder, settings=settings, seed=1)
        out[name] = (report, json.loads((folder / "results.json").read_text()), folder)
    return out


@pytest.mark.parametrize("name", list(TINY))
def test_each_experiment_writes_its_files_and_a_table(reports, name):
    report, data, folder = reports[name]
    names = {p.name for p in report.files}
    assert {"results.json", "summary.txt"} <= names
    pngs = [p for p in report.files if p.suffix == ".png"]
    assert pngs and all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)
    assert (folder / "summary.txt").read_text().strip() == report.text()
    assert report.rows and all(len(r) == len(report.header) for r in report.rows)
    assert data["experiment"] == name and data["seed"] == 1


# ----------------------------------------------------------------------------- orchestrators
def brute_force_violations(world, traj):
    """Each transition: the constrained features among its active ones, each once."""
    mask = world.constraint_mask
    out = []
    for i in range(len(traj)):
        states, actions = traj.trajectory(i)
        out.append(sum(int(np.count_nonzero(world.features.phi(s, a, s2)[mask]))
                       for s, a, s2 in zip(states[:-1], actions, states[1:])))
    return np.array(out)


def bfs_shortest(world):
    dist = {world.start: 0}
    queue = deque([world.start])
    while queue:
        s = queue.popleft()
        for a in range(world.n_actions):
            t = world.move(s, a)
            if t not in dist:
                dist[t] = dist[s] + 1
                queue.append(t)
    return dist[world.goal]


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_violations_penalties_and_shortest_paths_against_brute_force(seed):
    world = irl.GridWorld.random(rng=seed, p_slip=0.3)
    traj = irl.generate_demonstrations(world.nominal_mdp, 30, rng=seed)  # many violations
    expected = brute_force_violations(world, traj)
    assert expected.sum() > 0
    np.testing.assert_array_equal(orch_exp.violations_per_trajectory(world, traj), expected)
    penalties = np.random.default_rng(seed).random(world.n_features)
    ref = [sum(world.features.phi(s, a, s2) @ penalties
               for s, a, s2 in zip(st[:-1], ac, st[1:])) for st, ac in map(traj.trajectory, range(len(traj)))]
    np.testing.assert_allclose(orch_exp.penalty_per_trajectory(world.nominal_mdp, penalties, traj), ref)
    assert orch_exp.shortest_path_length(world) == bfs_shortest(world)


def test_orchestrators_results(reports):
    report, data, _ = reports["orchestrators"]
    assert data["weights_w_c"] == [0.0, 0.5, 1.0]
    methods = data["methods"]
    assert set(methods) == {"nominal", "constrained", "greedy", "wa-0", "mdft-0", "wa-1", "mdft-1",
                            "wa-2", "mdft-2"}
    # the Constrained policy's penalty is the unit of the penalty ratio
    assert methods["constrained"]["penalty"][0] == pytest.approx(1.0)
    for m in methods.values():
        assert m["length"][0] >= 1.0 and 0.0 <= m["js"][0] <= np.log(2)
        assert m["violations"][0] >= 0.0 and m["reached"][0] == pytest.approx(1.0)
    assert len(data["ks"]) == 3 and all(0 <= k["pooled_length_p"] <= 1 for k in data["ks"])
    assert [r[0] for r in report.rows[:3]] == ["Nominal", "Constrained", "Greedy"]


def test_orchestrators_unit_uses_the_real_orchestrators(tmp_path):
    """One world recomputed by hand: learned constraints, WA at w_c = 1 is the Constrained policy."""
    units = units_of("orchestrators", settings=TINY["orchestrators"])
    unit = units[0]
    from orchestration.experiments.runner import child_seed, unit_seed

    seed = unit_seed(5, unit.spawn_key)
    result = orch_exp.work(unit.params, seed)
    world = irl.GridWorld.random(rng=np.random.default_rng(child_seed(seed, 0)), p_slip=0.1)
    assert result["shortest"] == bfs_shortest(world)
    # WA at (0, 1) and Constrained are the same orchestrator run on different streams;
    # their per-world means agree within Monte Carlo error only, so compare policies instead
    demos = irl.generate_demonstrations(world.constrained_mdp, 20, rng=child_seed(seed, 1))
    learned = irl.mesc_irl(world.nominal_mdp, demos)
    prefs = orchestration.action_preferences(world.nominal_mdp, learned.constrained)
    wa = orchestration.WeightedAverageOrchestrator.from_preferences(prefs, (0.0, 1.0))
    np.testing.assert_allclose(wa.action_probabilities(world.start), prefs.sq_constrained[world.start])
    traj = orchestration.rollout(
        orchestration.GreedyOrchestrator.from_preferences(prefs), 20,
        rng=np.random.default_rng(child_seed(seed, 3, 2)), max_length=500)
    assert result["methods"]["greedy"]["length"] == pytest.approx(traj.lengths.mean() / result["shortest"])
    assert result["methods"]["greedy"]["violations"] == pytest.approx(
        brute_force_violations(world, traj).mean())


# ----------------------------------------------------------------------------- mdft-vs-wa
def test_mdft_vs_wa_units_are_the_library_instances(reports):
    report, data, _ = reports["mdft-vs-wa"]
    for inst in data["instances"]:
        ref = orchestration.mdft_vs_wa_instance(inst["seed"], n_actions=3, n_choices=30, n_steps=10)
        assert inst["js"] == ref.js_divergence and inst["exact_fit_js"] == ref.exact_fit_js_divergence
        assert inst["exact_fit_js"] <= inst["js"] + 1e-9
    assert data["js"][0] == pytest.approx(np.mean([i["js"] for i in data["instances"]]))
    assert data["paper_js"] == [0.024, 0.0013]


# ----------------------------------------------------------------------------- soft constraints
def test_soft_constraint_errors_shrink_with_tolerance(reports):
    _, data, _ = reports["soft-constraints"]
    for slip, c in data["curves"].items():
        for key in ("fn", "fp"):
            loose, strict = np.array(c[key]["0.3"])[:, 0], np.array(c[key]["0.1"])[:, 0]
            assert np.all(loose <= strict + 1e-12)
        js = np.array(c["js"])[:, 0]
        assert np.all((js >= 0) & (js <= np.log(2)))


# ----------------------------------------------------------------------------- transfer
def test_transfer_nominal_misses_exactly_the_true_transferable_constraints(reports):
    _, data, _ = reports["transfer"]
    # zero penalties give zeta = sigmoid(-1) = 0.27 < zeta_true - 0.2 on every true constraint;
    # the 11 transferable features hold 2 constrained actions and 2 constrained colours
    assert data["curves"]["nominal"]["fn_transferable"][0][0] == pytest.approx(4 / 11)
    assert data["curves"]["nominal"]["fp_transferable"][0][0] == 0.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_transfer_target_keeps_actions_and_colours_and_moves_the_cells(seed):
    from orchestration.experiments.runner import unit_seed

    source = irl.GridWorld.random(rng=seed, p_slip=0.1)
    target = transfer_exp.target_world(source, unit_seed(seed))
    assert target.constrained_actions == source.constrained_actions
    assert target.constrained_colours == source.constrained_colours
    assert target.constrained_states != source.constrained_states
    assert target.constraint_free_path_exists()
