"""The bundled thesis data sets and their loaders."""

import hashlib

import numpy as np
import pytest

import mdft
from mdft import datasets as ds


def test_every_bundled_set_loads_with_its_conventions():
    names = ds.thesis_sets()
    assert len(names) == 20 and set(ds.thesis_sets("time_based")) | set(
        ds.thesis_sets("pref_based")) == set(names)
    for name in names:
        problems = ds.load_thesis_set(name)
        assert len(problems) == 50
        n_options = int(name.split("nopts")[1].split("_")[0])
        n_subsets = int(name.split("ncomb")[1].split("_")[0])
        p = problems[0]
        assert p.M.shape == (n_options, 2) and p.data.n_subsets == n_subsets
        assert p.time_based == name.startswith("time_based")
        assert (p.n_steps is None) != (p.theta is None)
        assert p.sigma2 == pytest.approx(p.sig2**2)
        assert np.allclose(p.w.sum(), 1.0)


def test_name_path_and_suffix_give_the_same_set():
    name = "time_based/set_nopts3_ncomb1_nproblem50_no3"
    by_name = ds.load_thesis_set(name)
    by_suffix = ds.load_thesis_set(name + ".mat")
    by_path = ds.load_thesis_set(ds.THESIS_DATA / f"{name}.mat")
    for a, b, c in zip(by_name, by_suffix, by_path):
        np.testing.assert_array_equal(a.M, b.M)
        np.testing.assert_array_equal(a.M, c.M)
        np.testing.assert_array_equal(a.data.counts[0], c.data.counts[0])


def test_sushi_default_is_the_bundled_file():
    s = ds.load_sushi()
    assert s.M.shape == (10, 2) and s.test.n_subsets == 5
    t = ds.load_sushi(ds.THESIS_DATA / "pref_based" / "sushi.json")
    np.testing.assert_array_equal(s.M, t.M)


def test_bundled_files_have_licence_and_readme():
    assert "MIT License" in (ds.THESIS_DATA / "LICENSE").read_text()
    assert "Rahgooy/MDFT" in (ds.THESIS_DATA / "README.md").read_text()
    digest = hashlib.sha1(
        (ds.THESIS_DATA / "time_based" / "set_nopts3_ncomb1_nproblem50_no3.mat").read_bytes()
    ).hexdigest()
    assert digest.startswith("53afc2ddcb")  # the published file, unchanged


def test_bad_names_and_files(tmp_path):
    with pytest.raises(ValueError, match=r"kind must be one of \('time_based', 'pref_based'\)"):
        ds.thesis_sets("both")
    with pytest.raises(FileNotFoundError, match="path must be an existing .mat file"):
        ds.load_thesis_set("time_based/set_nopts4")
    with pytest.raises(TypeError, match="path must be a str or pathlib.Path \\(got int\\)"):
        ds.load_thesis_set(3)
    junk = tmp_path / "junk.mat"
    junk.write_bytes(b"\x00\x01 not matlab")
    with pytest.raises(ValueError, match="junk.mat' is not a readable .mat file"):
        ds.load_thesis_set(junk)
    with pytest.raises(ValueError, match="n_trials must be an integer >= 1 \\(got 0\\)"):
        ds.load_thesis_set("time_based/set_nopts3_ncomb1_nproblem50_no3", n_trials=0)
    for text, message in [
        (b"\xff\xfe", "not a readable JSON file"),
        (b"null", "must hold a JSON object \\(got NoneType\\)"),
        (b"[" * 100_000 + b"]" * 100_000, "not a readable JSON file"),
        (b'{"M": [[1, 2]]}', "lacks the field 'idx'"),
    ]:
        bad = tmp_path / "bad.json"
        bad.write_bytes(text)
        with pytest.raises(ValueError, match=message):
            ds.load_sushi(bad)
    text = (ds.THESIS_DATA / "pref_based" / "sushi.json").read_text().replace('"b":', '"b": "x", "_b":')
    bad = tmp_path / "bad.json"
    bad.write_text(text)
    with pytest.raises(ValueError, match="bad.json is not a valid SUSHI data set"):
        ds.load_sushi(bad)


def test_threshold_stopping_of_a_problem():
    p = ds.load_thesis_set("pref_based/set_nopts3_ncomb1_nproblem50_no3")[0]
    assert isinstance(p.stopping, mdft.Threshold) and p.stopping.theta == p.theta
