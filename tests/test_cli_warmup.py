"""``mdft warmup``: both packages' kernels, their step tables, and the one-line error rule."""

import irl
import mdft
import pytest

from orchestration.cli import main


def test_warmup_prints_every_step_of_both_packages(capsys):
    assert main(["warmup", "--quiet"]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    expected = [*mdft.warmup().steps, *irl.warmup().steps]
    listed = [line.rsplit(None, 1)[0].strip() for line in out.splitlines()
              if line and not line.startswith(("mdft:", "irl:", "step", "total"))]
    assert listed == expected
    assert out.startswith("mdft: ") and "\nirl: " in out


def test_warmup_progress_lines_go_to_stderr(capsys):
    assert main(["warmup"]) == 0
    err = capsys.readouterr().err
    assert "[1/" in err and "done in" in err


def test_warmup_refuses_unknown_options(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["warmup", "--fast"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--fast" in err
