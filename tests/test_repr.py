"""Models and results print as a short summary, not thousands of lines of arrays."""

import irl
import mdft


def test_large_dataclasses_have_short_reprs():
    world = irl.load_paper_worlds("scobee_example")[0]
    demos = irl.generate_demonstrations(world.constrained_mdp, 5, rng=0)
    model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
    sim = mdft.simulate(model, 2000, stopping=mdft.Threshold(17.5), rng=0)
    for obj in (world.nominal_mdp, demos, sim):
        text = repr(obj)
        assert len(text) < 1500, type(obj).__name__
        assert text.startswith(type(obj).__name__ + "(")
        assert "shape=" in text
    # small arrays and scalars are shown as they are
    assert "n_samples=2000" in repr(sim)
    assert "probabilities=[" in repr(sim)
