"""``mdft reproduce``: output folder, resuming, refusals, progress bar, all experiments."""

import dataclasses
import json
import sys

import pytest

import orchestration.experiments as experiments
from orchestration.cli import main
from orchestration.experiments import hard_constraints, transfer

TINY_HARD = dict(world="scobee_example", n_demonstrations=[3], n_repeats=2, zeta_levels=[0.6],
                 best_zeta=0.6, n_model_trajectories=20)
TINY_TRANSFER = dict(n_repeats=1, n_source=20, n_demonstrations=[3], p_slip=0.1, chi=0.2,
                     transfer_features=["action", "colour"], n_model_trajectories=20)


@pytest.fixture
def tiny(monkeypatch):
    """The CLI's experiments at tiny sizes (the same code, smaller settings)."""
    for module, s in ((hard_constraints, TINY_HARD), (transfer, TINY_TRANSFER)):
        monkeypatch.setattr(module, "EXPERIMENT",
                            dataclasses.replace(module.EXPERIMENT, settings=lambda quick, s=s: dict(s)))


def run(capsys, argv):
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def test_reproduce_writes_prints_and_resumes(tiny, tmp_path, capsys):
    out = tmp_path / "hc"
    code, text, err = run(capsys, ["reproduce", "hard-constraints", "--out", str(out),
                                   "--workers", "1", "--quiet"])
    assert code == 0, err
    assert "Scobee & Sastry" in text and "MESC-IRL zeta >= 0.6" in text
    assert err == ""  # no progress bar when quiet
    assert (out / "summary.txt").read_text().strip() in text
    first = json.loads((out / "results.json").read_text())
    assert first["settings"] == TINY_HARD and first["seed"] == 0
    stamp = {p.name: p.stat().st_mtime_ns for p in (out / "units").iterdir()}
    code, again, _ = run(capsys, ["reproduce", "hard-constraints", "--out", str(out),
                                  "--workers", "1", "--quiet"])
    assert code == 0 and again == text
    assert {p.name: p.stat().st_mtime_ns for p in (out / "units").iterdir()} == stamp


def test_reproduce_refuses_to_mix_runs(tiny, tmp_path, capsys):
    out = tmp_path / "hc"
    assert run(capsys, ["reproduce", "hard-constraints", "--out", str(out), "--workers", "1",
                        "--quiet"])[0] == 0
    code, _, err = run(capsys, ["reproduce", "hard-constraints", "--out", str(out), "--seed", "5",
                                "--workers", "1", "--quiet"])
    assert code == 2 and err.count("\n") == 1
    assert "holds a run with other seed" in err and "Traceback" not in err


def test_reproduce_all_makes_one_folder_per_experiment(tiny, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(experiments, "EXPERIMENTS",
                        {"hard-constraints": "hard_constraints", "transfer": "transfer"})
    code, text, err = run(capsys, ["reproduce", "all", "--out", str(tmp_path), "--workers", "1",
                                   "--quiet"])
    assert code == 0, err
    assert (tmp_path / "hard-constraints" / "hard_constraints.png").exists()
    assert (tmp_path / "transfer" / "transfer.png").exists()
    assert "Hard constraints" in text and "Transfer" in text


def test_progress_bar_on_a_terminal(tiny, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    code, _, err = run(capsys, ["reproduce", "transfer", "--out", str(tmp_path), "--workers", "1"])
    assert code == 0
    assert "transfer" in err and "1/1" in err and "100%" in err


@pytest.mark.parametrize(
    "argv, message",
    [
        (["reproduce"], "the following arguments are required: EXPERIMENT"),
        (["reproduce", "figure-9"], "EXPERIMENT must be one of orchestrators, mdft-vs-wa"),
        (["reproduce", "transfer", "--workers", "0"], "expected a positive integer, got 0"),
        (["reproduce", "transfer", "--workers", "2", "--scheduler", "tcp://x:1"],
         "either --workers (local processes) or --scheduler"),
        (["reproduce", "transfer", "--seed", "-3"], "expected an integer >= 0"),
    ],
)
def test_reproduce_bad_input(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, argv)
    assert code == 2 and message in err and err.count("\n") == 1


def test_out_that_is_a_file_is_refused(tmp_path, capsys):
    (tmp_path / "f").write_text("x")
    code, _, err = run(capsys, ["reproduce", "transfer", "--out", str(tmp_path / "f")])
    assert code == 2 and "exists and is not a folder" in err
