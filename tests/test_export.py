"""Readable results: short reprs, summary tables, JSON-ready dicts and files, model round trips."""

import json
import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mdft

CANON = dict(phi1=0.022, phi2=0.05, beta=12.0)
M3 = [[1, 3], [3, 1], [2, 2]]


def _plain(obj):
    """True if ``obj`` is made of JSON builtins only, with no NaN or infinity."""
    if isinstance(obj, dict):
        return all(isinstance(k, str) and _plain(v) for k, v in obj.items())
    if isinstance(obj, list):
        return all(_plain(v) for v in obj)
    if isinstance(obj, float):
        return math.isfinite(obj)
    return obj is None or isinstance(obj, (str, int, bool))


def test_context_effects_repr_is_short_and_summary_carries_the_numbers(tmp_path):
    res = mdft.context_effects(n_samples=2000, rng=0, n_trajectories=2)
    assert len(repr(res)) < 400
    assert repr(res["compromise"]).startswith("EffectResult(name='compromise', effect_size=")
    lines = res.summary().splitlines()
    for r, line in zip(res, lines[1:]):
        cells = line.split()
        assert cells[0] == r.name and cells[1] == r.scenario.measure
        assert cells[4] == f"{r.effect_size:+.4f}" and cells[5] == f"{r.standard_error:.4f}"
        assert cells[7] == ("yes" if r.shown else "no")
    one = res["attraction"].summary().splitlines()
    assert one[3].split() == ["A", f"{res['attraction'].ternary[0]:.4f}",
                              f"{res['attraction'].ternary_se[0]:.4f}",
                              f"{res['attraction'].binary[0]:.4f}",
                              f"{res['attraction'].binary_se[0]:.4f}"]
    d = res.to_dict()
    assert _plain(d) and d["all_shown"] == res.all_shown
    for r, rd in zip(res, d["results"]):
        assert rd["ternary"] == r.ternary.tolist() and rd["effect_size"] == r.effect_size
        assert rd["scenario"]["labels"] == list(r.scenario.labels)
        assert "trajectories" not in rd
    assert res["compromise"].to_dict()["binary_measure"] is None  # NaN for a margin
    full = res.to_dict(trajectories=True)["results"][0]["trajectories"]
    assert np.asarray(full, dtype=float).shape[0] == 2
    path = tmp_path / "effects.json"
    text = res.to_json(path)
    assert json.loads(path.read_text()) == json.loads(text) == d


def test_simulation_result_summary_and_dict():
    model = mdft.MDFTModel([[1, 3], [3, 1], [-50, -50]], [0.5, 0.5], **CANON)
    res = mdft.simulate(model, 500, stopping=mdft.Threshold(5.0, max_steps=30), rng=1,
                        n_trajectories=3)
    assert res.counts[2] == 0  # never chosen: its mean response time is NaN
    d = res.to_dict()
    assert _plain(d)
    assert d["counts"] == res.counts.tolist() and d["n_undecided"] == res.n_undecided
    assert d["mean_response_times"][2] is None
    assert d["stopping"] == {"rule": "threshold", "theta": 5.0, "max_steps": 30}
    assert "choices" not in d
    trials = res.to_dict(trials=True)
    assert trials["choices"] == res.choices.tolist() and len(trials["trajectories"]) == 3
    lines = res.summary(labels=["A", "B", "X"]).splitlines()
    assert lines[0] == "500 trials, threshold 5 (at most 30 steps) (step-by-step)"
    assert lines[2].split() == ["A", f"{res.probabilities[0]:.4f}",
                                f"{res.standard_errors[0]:.4f}", str(res.counts[0]),
                                f"{res.mean_response_times[0]:.1f}"]
    assert lines[4].split()[-1] == "-"
    assert lines[5].split() == ["undecided", f"{res.p_undecided:.4f}", str(res.n_undecided)]
    assert json.loads(res.to_json()) == d
    with pytest.raises(ValueError, match=r"labels must hold one label per option, 3 \(got 2\)"):
        res.summary(labels=["A", "B"])
    with pytest.raises(TypeError, match="labels must be a sequence of 3 strings"):
        res.summary(labels=3)
    assert res.summary(labels="ABX") == res.summary(labels=["A", "B", "X"])


def test_mixture_result_export():
    model = mdft.MDFTModel(M3, [0.5, 0.5], **CANON)
    res = mdft.mixture_choice_probabilities(model, 10, n_sequences=200, rng=0)
    assert res.to_dict() == {"probabilities": res.probabilities.tolist(),
                             "standard_errors": res.standard_errors.tolist(),
                             "n_sequences": 200}
    assert res.summary().splitlines()[2].split()[1] == f"{res.probabilities[0]:.4f}"


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(2, 5), J=st.integers(1, 3), data=st.data(),
    explicit=st.booleans(),
)
def test_model_round_trip(n, J, data, explicit):
    real = st.floats(-5, 5, allow_nan=False)
    M = np.array(data.draw(st.lists(st.lists(real, min_size=J, max_size=J), min_size=n,
                                    max_size=n)))
    w = np.array(data.draw(st.lists(st.floats(0.01, 1), min_size=J, max_size=J)))
    w = w / w.sum()
    P0 = np.array(data.draw(st.lists(real, min_size=n, max_size=n)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        if explicit:
            S = np.array(data.draw(st.lists(st.lists(st.floats(-0.5, 0.5), min_size=n,
                                                     max_size=n), min_size=n, max_size=n)))
            model = mdft.MDFTModel.from_matrices(M, w, S=S, sigma2=0.7, P0=P0)
        else:
            model = mdft.MDFTModel(M, w, phi1=data.draw(st.floats(0, 1)),
                                   phi2=data.draw(st.floats(0, 0.2)),
                                   beta=data.draw(st.floats(0, 20)), sigma2=0.7, P0=P0)
        d = model.to_dict()
        back = mdft.MDFTModel.from_dict(json.loads(json.dumps(d)))
    assert _plain(d) and back.to_dict() == d
    for name in ("M", "w", "S", "C", "P0"):
        np.testing.assert_array_equal(getattr(back, name), getattr(model, name))
    assert back.is_parametric == model.is_parametric and back.sigma2 == model.sigma2
    assert model.summary().splitlines()[0] == f"MDFT model: {n} options, {J} attributes"


def test_model_from_dict_and_to_json_bad_input(tmp_path):
    with pytest.raises(TypeError, match=r"data must be a dict \(got list\)"):
        mdft.MDFTModel.from_dict([1, 2])
    good = {"M": M3, "w": [0.5, 0.5], **CANON}
    with pytest.raises(ValueError, match=r"data has unknown key\(s\) \['labels'\]; allowed"):
        mdft.MDFTModel.from_dict({**good, "labels": ["A", "B", "C"]})
    with pytest.raises(ValueError, match=r"data lacks the key\(s\) \['beta'\]; required"):
        mdft.MDFTModel.from_dict({k: v for k, v in good.items() if k != "beta"})
    with pytest.raises(ValueError, match=r"data has unknown key\(s\) \['beta', 'phi1', 'phi2'\]"):
        mdft.MDFTModel.from_dict({**good, "S": np.eye(3).tolist()})
    model = mdft.MDFTModel.from_dict(good)
    with pytest.raises(ValueError, match="folder .* does not exist"):
        model.to_json(tmp_path / "missing" / "model.json")
    with pytest.raises(TypeError, match=r"path must be a str or os.PathLike \(got int\)"):
        model.to_json(3)
    model.to_json(tmp_path / "model.json")
    again = mdft.MDFTModel.from_dict(json.loads((tmp_path / "model.json").read_text()))
    np.testing.assert_array_equal(again.S, model.S)
