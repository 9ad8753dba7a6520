"""The command line under hostile input: one line on stderr, exit code 2, never a traceback."""

import json
import string
import tomllib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from orchestration.cli import main

ROOT = Path(__file__).resolve().parents[1]


def exit_code_and_err(capsys, argv):
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    return code, capsys.readouterr().err


def assert_one_line_error(capsys, argv, message):
    code, err = exit_code_and_err(capsys, argv)
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("mdft"), err
    assert message in err
    assert "Traceback" not in err


def test_version(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    expected = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert out.startswith(f"mdft (pymdft) {expected}")


@pytest.mark.parametrize(
    "argv, message",
    [
        # preferences overflow over a long deliberation (rho(S) = 1.0089 > 1 for the compromise
        # set: about 1e386 after 100,000 steps; after 50,000, 1e193, which is still answered)
        (["simulate", "--options", "1,3;3,1;2,2", "--steps", "100000", "--samples", "10"],
         "preferences overflow over n_steps=100000"),
        (["simulate", "--options", "1,3;3,1", "--samples", "100000000000000"],
         "expected an integer <= 10,000,000"),
        (["simulate", "--options", "1,3;3,1", "--threshold", "5", "--max-steps", "10000000000"],
         "expected an integer <= 1,000,000"),
        (["simulate", "--options", "1,3;3,1", "--steps", "99999999999999999999"],
         "expected an integer <= 1,000,000"),
        (["effects", "--samples", "1"], "--trajectories (5) must not exceed --samples (1)"),
        (["effects", "--trajectories", "5000"], "must not exceed --samples (20000) nor 1000"),
        (["effects", "--samples", "100000000000000"], "expected an integer <= 10,000,000"),
        (["simulate", "--options", "1e300,3;3,1", "--samples", "10"], "invalid model"),
    ],
)
def test_found_by_fuzzing(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert_one_line_error(capsys, argv, message)


@pytest.mark.parametrize(
    "content, message",
    [
        (b'\xff\xfe{"M": [[1, 3], [3, 1]]}', "is not UTF-8 text (byte 0"),
        (b'{"M": [[1, 3], [3, 1]], "labels": 5}', "labels must be a list of names"),
        (b'{"M": [[1, 3], [3, 1]], "labels": [[1], {}]}', "labels must be a list of names"),
        (b'{"M": [[1e400, 3], [3, 1]]}', "M must contain only finite values"),
        (b'{"M": [[' + b"9" * 400 + b', 3], [3, 1]]}', "invalid model"),
        (b'{"M": [[' + b"9" * 5000 + b', 3], [3, 1]]}', "is not usable JSON"),
        (b'{"M": [[1e300, 3], [3, 1]]}', "invalid model"),
        (b'{"M": [[1, 3], [3, 1]], "phi1": "x"}', "invalid model"),
        (b'{"M": [[1, 3], [3, 1]], "w": {"a": 1}}', "invalid model"),
        (b'{"M": "abc"}', "M must be a rectangular"),
        (b"[" * 100_000 + b"]" * 100_000, "is not usable JSON"),
        (b"", "is not valid JSON"),
    ],
)
def test_bad_model_file_is_one_line(tmp_path, capsys, content, message):
    path = tmp_path / "m.json"
    path.write_bytes(content)
    assert_one_line_error(capsys, ["simulate", "--model", str(path), "--samples", "10"], message)


def test_an_error_is_one_line_even_for_multi_line_messages(capsys):
    # argparse would print the usage block first; here it is one line with a pointer to --help
    code, err = exit_code_and_err(capsys, ["simulate", "--nope"])
    assert code == 2 and err.count("\n") == 1
    assert "unrecognized arguments: --nope" in err and "see 'mdft --help'" in err
    code, err = exit_code_and_err(capsys, ["simulate", "--steps", "x"])
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("mdft simulate: error: argument --steps") and "mdft simulate --help" in err


# ----------------------------------------------------------------------------- fuzzing
_WORDS = ["simulate", "effects", "reproduce", "--help", "-h", "--version", "--json", "--quick",
          "--options", "--model", "--weights", "--labels", "--phi1", "--phi2", "--beta", "--sigma2",
          "--steps", "--threshold", "--max-steps", "--samples", "--seed", "--out",
          "--trajectories", "--criterion", "--workers", "--scheduler", "orchestrators", "all"]
_VALUES = ["0", "1", "2", "3", "-1", "0.5", "1e400", "-1e400", "nan", "inf", "", " ", "x",
           "1,3;3,1", "1,3;3,1;2,2", "1,3", "0.5,0.5", "A,B", "a.png", "m.json", "/", "=",
           "99999999999999999999", "1e-300", "1,x;3,1", "--", "-", "\x00", "é"]
_argv = st.lists(st.one_of(st.sampled_from(_WORDS), st.sampled_from(_VALUES),
                           st.text(string.printable, max_size=6)), max_size=7)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(argv=_argv)
def test_random_command_lines_exit_0_or_2_without_traceback(argv, tmp_path_factory, capsys,
                                                            monkeypatch):
    # only cheap runs: a real experiment or a large simulation is not what is fuzzed here
    if "reproduce" in argv[:1] or any(a in ("--samples", "--steps", "--max-steps") for a in argv):
        argv = [a for a in argv if a != "reproduce"] + ["--nonsense-flag"]
    work = tmp_path_factory.mktemp("fuzz")
    (work / "m.json").write_text(json.dumps({"M": [[1, 3], [3, 1]]}))
    monkeypatch.chdir(work)
    argv = argv + (["--samples", "50"] if argv[:1] in (["simulate"], ["effects"]) else [])
    code, err = exit_code_and_err(capsys, argv)
    assert code in (0, 2), (argv, err)
    assert "Traceback" not in err and "internal error" not in err, (argv, err)
    if code == 2:
        assert err.count("\n") == 1, (argv, err)
