"""Orchestration results print a short repr and a text summary that carry their numbers."""

import numpy as np

from orchestration import Episode, mdft_vs_wa, mdft_vs_wa_instance


def test_episode_summary_and_repr():
    ep = Episode(np.arange(30), np.zeros(29, dtype=int), -np.ones(29), -29.0, False, True)
    head, path = ep.summary().splitlines()
    assert head == "29 steps, total reward -29, truncated"
    assert path.startswith("states: 0 -> 1 -> ") and path.endswith("-> 20 -> ... (9 more)")
    assert repr(ep) == "Episode(n_steps=29, total_reward=-29, terminated=False, truncated=True)"


def test_mdft_vs_wa_summaries_carry_the_fields():
    inst = mdft_vs_wa_instance(5, n_actions=4, n_choices=40, n_steps=10)
    lines = inst.summary().splitlines()
    table = [line.split() for line in lines[2:-1]]
    assert len(table) == 4
    np.testing.assert_allclose([float(r[1]) for r in table], inst.wa_probabilities, atol=5e-5)
    assert [int(r[2]) for r in table] == inst.counts.tolist()
    np.testing.assert_allclose([float(r[3]) for r in table], inst.mdft_probabilities, atol=5e-5)
    assert f"{inst.js_divergence:.4f} fitted" in lines[-1]
    assert len(repr(inst)) < 200

    res = mdft_vs_wa(2, rng=1, n_actions=3, n_choices=30, n_steps=10)
    text = res.summary()
    assert f"{res.mean_js:.4f} +- {res.se_js:.4f}" in text
    assert f"{res.mean_exact_js:.4f} +- {res.se_exact_js:.4f}" in text
    assert "n_instances=2" in repr(res) and len(repr(res)) < 200
