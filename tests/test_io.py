"""Saving is all-or-nothing: an interrupted save leaves the earlier file intact."""

import json

import numpy as np
import pytest

import irl
from irl import io


def test_interrupted_save_keeps_the_old_file(tmp_path, monkeypatch):
    world = irl.load_paper_worlds("scobee_example")[0]
    demos = irl.generate_demonstrations(world.constrained_mdp, 3, rng=0)
    path = tmp_path / "demos.json"
    irl.save_demonstrations(demos, path)
    before = path.read_bytes()

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt("interrupted while writing")

    monkeypatch.setattr(io.json, "dumps", interrupted)
    with pytest.raises(KeyboardInterrupt, match="interrupted while writing"):
        irl.save_demonstrations(irl.generate_demonstrations(world.constrained_mdp, 5, rng=1), path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["demos.json"]  # no partial file is left
    monkeypatch.undo()
    assert json.loads(path.read_text())  # still parses
    assert irl.load_demonstrations(path).to_dict() == demos.to_dict()


def test_mdp_round_trip_writes_exactly_the_given_path(tmp_path):
    world = irl.load_paper_worlds("scobee_example")[0]
    path = tmp_path / "world.npz"
    irl.save_mdp(world.nominal_mdp, path)
    back = irl.load_mdp(path)
    for name in ("next_states", "probs", "rewards", "start", "terminal"):
        np.testing.assert_array_equal(getattr(back, name), getattr(world.nominal_mdp, name), err_msg=name)
    assert back.discount == world.nominal_mdp.discount
    assert back.features.names == world.nominal_mdp.features.names
    assert sorted(p.name for p in tmp_path.iterdir()) == ["world.npz"]
