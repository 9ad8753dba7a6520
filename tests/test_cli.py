"""The ``mdft`` command line: both commands, JSON output, model files and bad input."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import mdft
from orchestration.cli import main

ROOT = Path(__file__).resolve().parents[1]
INLINE = ["simulate", "--options", "1,3;3,1;2,2", "--samples", "1000", "--seed", "0"]


def run_json(capsys, argv):
    assert main(argv + ["--json"]) == 0
    return json.loads(capsys.readouterr().out)


# ----------------------------------------------------------------------------- simulate
def test_simulate_prints_a_table(capsys):
    assert main(INLINE) == 0
    out = capsys.readouterr()
    assert "fixed time, 100 steps" in out.out
    assert "P(choose)" in out.out and "undecided" in out.out
    # each option's row carries the numbers of the JSON output for the same seed
    rows = {line.split()[0]: line.split() for line in out.out.splitlines() if line.strip()}
    data = run_json(capsys, INLINE)
    for o in data["options"]:
        row = rows[o["label"]]
        assert row[-3:] == [f"{o['probability']:.4f}", f"{o['standard_error']:.4f}",
                            str(o["count"])]
    # the compromise set has rho(S) ~ 1.009, too little growth over 100 steps for a note
    assert "spectral radius" not in out.err


def test_simulate_json_is_complete_and_sums_to_one(capsys):
    data = run_json(capsys, INLINE)
    probs = [o["probability"] for o in data["options"]]
    assert [o["label"] for o in data["options"]] == ["A", "B", "C"]
    assert sum(probs) + data["p_undecided"] == pytest.approx(1.0)
    assert sum(o["count"] for o in data["options"]) + data["n_undecided"] == 1000
    assert data["stopping"] == {"rule": "fixed_time", "n_steps": 100}
    assert data["parameters"] == {"phi1": 0.022, "phi2": 0.05, "beta": 12.0, "sigma2": 1.0}
    assert data["seed"] == 0 and data["w"] == [0.5, 0.5]
    assert data["spectral_radius"] == pytest.approx(1.00893, abs=1e-5)
    # the numbers are those of the library run with the same model and seed
    model = mdft.MDFTModel([[1, 3], [3, 1], [2, 2]], [0.5, 0.5], phi1=0.022, phi2=0.05,
                           beta=12.0, sigma2=1.0)
    res = mdft.simulate(model, 1000, stopping=mdft.FixedTime(100), rng=0)
    assert [o["count"] for o in data["options"]] == res.counts.tolist()
    np.testing.assert_allclose(probs, res.probabilities, rtol=0, atol=0)
    np.testing.assert_allclose([o["standard_error"] for o in data["options"]],
                               res.standard_errors, rtol=1e-15)


def test_simulate_same_seed_same_output(capsys):
    assert run_json(capsys, INLINE) == run_json(capsys, INLINE)


def test_simulate_threshold_reports_response_times(capsys):
    data = run_json(
        capsys,
        ["simulate", "--options", "1,3;3,1", "--threshold", "5", "--max-steps", "500",
         "--samples", "500", "--seed", "1"],
    )
    assert data["stopping"] == {"rule": "threshold", "theta": 5.0, "max_steps": 500}
    model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
    res = mdft.simulate(model, 500, stopping=mdft.Threshold(5.0, max_steps=500), rng=1)
    assert [o["count"] for o in data["options"]] == res.counts.tolist()
    np.testing.assert_allclose([o["mean_response_time"] for o in data["options"]],
                               res.mean_response_times, rtol=1e-15)
    assert all(o["mean_response_time"] >= 1 for o in data["options"])
    assert main(["simulate", "--options", "1,3;3,1", "--threshold", "5", "--samples", "200"]) == 0
    assert "mean RT" in capsys.readouterr().out


def test_simulate_parameters_weights_and_labels_inline(capsys):
    data = run_json(
        capsys,
        INLINE + ["--weights", "0.8,0.2", "--labels", "x,y,z", "--phi1", "0.01", "--phi2", "0.01",
                  "--beta", "2", "--sigma2", "0.5", "--steps", "20"],
    )
    assert [o["label"] for o in data["options"]] == ["x", "y", "z"]
    assert data["w"] == [0.8, 0.2]
    assert data["parameters"] == {"phi1": 0.01, "phi2": 0.01, "beta": 2.0, "sigma2": 0.5}
    assert data["stopping"]["n_steps"] == 20
    # attending mostly attribute 1 favours B = (3, 1)
    probs = {o["label"]: o["probability"] for o in data["options"]}
    assert probs["y"] > probs["x"]


def test_simulate_model_from_a_json_file(tmp_path, capsys):
    spec = {"M": [[1, 3], [3, 1], [0.5, 2.5]], "w": [0.5, 0.5], "phi1": 0.022, "phi2": 0.05,
            "beta": 12, "sigma2": 1, "labels": ["A", "B", "D"]}
    path = tmp_path / "model.json"
    path.write_text(json.dumps(spec))
    data = run_json(capsys, ["simulate", "--model", str(path), "--samples", "500", "--seed", "2"])
    assert [o["label"] for o in data["options"]] == ["A", "B", "D"]
    assert data["options"][2]["M"] == [0.5, 2.5]
    # a flag overrides the file
    data = run_json(capsys, ["simulate", "--model", str(path), "--phi2", "0.01",
                             "--samples", "100", "--seed", "2"])
    assert data["parameters"]["phi2"] == 0.01


def test_simulate_minimal_json_file_uses_defaults(tmp_path, capsys):
    path = tmp_path / "m.json"
    path.write_text('{"M": [[1, 0, 0], [0, 1, 0]]}')
    data = run_json(capsys, ["simulate", "--model", str(path), "--samples", "100"])
    assert data["w"] == pytest.approx([1 / 3] * 3)
    assert isinstance(data["seed"], int)
    # the seed drawn and reported reproduces the run
    again = run_json(capsys, ["simulate", "--model", str(path), "--samples", "100",
                              "--seed", str(data["seed"])])
    assert again == data


# ----------------------------------------------------------------------------- effects
def test_effects_table_and_figure(tmp_path, capsys):
    out = tmp_path / "fx.png"
    assert main(["effects", "--samples", "2000", "--seed", "0", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "threshold 17.5" in text
    for name in ("similarity", "attraction", "compromise"):
        assert name in text
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_effects_json(tmp_path, capsys):
    out = tmp_path / "fx.png"
    data = run_json(capsys, ["effects", "--samples", "1000", "--seed", "3", "--out", str(out),
                             "--steps", "30", "--trajectories", "0"])
    assert data["stopping"] == {"rule": "fixed_time", "n_steps": 30}
    assert [e["name"] for e in data["effects"]] == ["similarity", "attraction", "compromise"]
    expected = mdft.context_effects(stopping=mdft.FixedTime(30), n_samples=1000, rng=3)
    for e, r in zip(data["effects"], expected):
        assert sum(e["ternary"]) + e["p_undecided"][0] == pytest.approx(1.0)
        assert isinstance(e["shown"], bool)
        # the same numbers as the library with the same seed
        np.testing.assert_allclose(e["ternary"], r.ternary, rtol=0, atol=0)
        np.testing.assert_allclose(e["binary"], r.binary, rtol=0, atol=0)
        assert e["effect_size"] == pytest.approx(r.effect_size, rel=1e-15)
        assert e["shown"] == r.shown
    assert out.exists()


def test_python_m_orchestration_runs_effects(tmp_path):
    out = tmp_path / "effects.png"
    env = dict(os.environ, MPLBACKEND="Agg")
    proc = subprocess.run(
        [sys.executable, "-m", "orchestration", "effects", "--samples", "2000", "--seed", "0",
         "--out", str(out)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "compromise" in proc.stdout and out.exists()


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "argv, message",
    [
        ([], "the following arguments are required: COMMAND"),
        (["fit"], "invalid choice: 'fit'"),
        (["simulate"], "give the options either inline with --options or in a file with --model"),
        (["simulate", "--options", "1,3;3,1", "--model", "m.json"], "either inline with --options"),
        (["simulate", "--options", "1,3"], "--options needs at least two options"),
        (["simulate", "--options", "1,3;3"], "every option needs the same number of attributes"),
        (["simulate", "--options", "1,x;3,1"], "option 1 ('1,x') must be numbers"),
        (["simulate", "--options", "1,nan;3,1"], "--options must contain finite numbers only"),
        (["simulate", "--options", "1,3;3,1", "--weights", "0.3,0.3"], "w must sum to 1"),
        (["simulate", "--options", "1,3;3,1", "--weights", "1"], "w must have one weight"),
        (["simulate", "--options", "1,3;3,1", "--weights", "a,b"], "--weights must be values"),
        (["simulate", "--options", "1,3;3,1", "--labels", "A"], "labels: need one per option, 2"),
        (["simulate", "--options", "1,3;3,1", "--phi2", "-1"], "phi2 must be >= 0"),
        (["simulate", "--options", "1,3;3,1", "--beta", "inf"], "expected a finite number"),
        (["simulate", "--options", "1,3;3,1", "--steps", "0"], "expected a positive integer, got 0"),
        (["simulate", "--options", "1,3;3,1", "--steps", "1.5"], "expected a positive integer"),
        (["simulate", "--options", "1,3;3,1", "--threshold", "-2"], "expected a finite positive"),
        (["simulate", "--options", "1,3;3,1", "--steps", "5", "--threshold", "2"],
         "either --steps (fixed time) or --threshold, not both"),
        (["simulate", "--options", "1,3;3,1", "--max-steps", "5"],
         "--max-steps applies to threshold stopping only"),
        (["simulate", "--options", "1,3;3,1", "--samples", "0"], "expected a positive integer"),
        (["simulate", "--options", "1,3;3,1", "--seed", "-1"], "expected an integer >= 0"),
        (["simulate", "--model", "/nonexistent/m.json"], "--model: cannot read"),
        (["effects", "--out", "fig.pdf"], "--out must name a .png file"),
        (["effects", "--out", "/nonexistent/dir/fig.png"], "does not exist"),
        (["effects", "--steps", "10", "--threshold", "5"], "not both"),
        (["effects", "--criterion", "0"], "expected a finite positive number"),
    ],
)
def test_bad_input_exits_2_with_a_clear_message(argv, message, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert message in err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "content, message",
    [
        ("{not json", "is not valid JSON"),
        ("[1, 2]", "must hold a JSON object"),
        ('{"w": [1]}', "has no 'M'"),
        ('{"M": [[1], [2]], "colour": 3}', "unknown key(s) ['colour']"),
        ('{"M": [[1, 2], [3]]}', "M must be a rectangular"),
        ('{"M": [[1, 2]]}', "M must have at least 2 options"),
        ('{"M": [[1], [2]], "P0": [0, 0, 0]}', "P0 must have shape (2)"),
    ],
)
def test_bad_model_file_exits_2(tmp_path, capsys, content, message):
    path = tmp_path / "m.json"
    path.write_text(content)
    with pytest.raises(SystemExit) as info:
        main(["simulate", "--model", str(path)])
    assert info.value.code == 2
    assert message in capsys.readouterr().err


def test_negative_first_value_with_equals_form(capsys):
    data = run_json(capsys, ["simulate", "--options=-1,3;3,-1", "--samples", "200", "--seed", "0"])
    assert data["options"][0]["M"] == [-1.0, 3.0]


def test_help_lists_both_commands(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "simulate" in out and "effects" in out
