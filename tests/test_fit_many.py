"""mdft.fit_many: the same fits whatever the executor, progress, resumable checkpoints."""

import pickle
import sys
import warnings

import numpy as np
import pytest

import mdft

FIXED = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
M3 = [[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]]


def make_problems(n=4, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        w = rng.uniform(0.3, 0.7)
        model = mdft.MDFTModel(M3, [w, 1 - w], **FIXED)
        counts = rng.multinomial(300, mdft.choice_probabilities(model, 30))
        out.append(dict(data=mdft.ChoiceData([[0, 1, 2]], [counts]), M=M3))
    return out


COMMON = dict(stopping=30, params=["w"], fixed=FIXED, n_starts=2)


def estimates(many):
    return [r.params["w"][0] for r in many.results]


@pytest.fixture(scope="module")
def serial():
    return mdft.fit_many(make_problems(), rng=7, executor="serial", **COMMON)


def test_serial_equals_individual_fits_with_the_spawned_seeds(serial):
    for prob, res, seed in zip(make_problems(), serial.results, serial.seeds):
        alone = mdft.fit(prob["data"], prob["M"], rng=seed, **COMMON)
        assert alone.log_likelihood == res.log_likelihood
    assert len(set(serial.seeds)) == len(serial.seeds) == 4
    assert serial.n_converged == 4 and serial.errors == {} and serial.keys == (0, 1, 2, 3)


def test_process_pool_and_thread_executor_give_the_same_fits(serial):
    from concurrent.futures import ThreadPoolExecutor

    pool = mdft.fit_many(make_problems(), rng=7, n_workers=2, **COMMON)
    assert estimates(pool) == estimates(serial)
    with ThreadPoolExecutor(2) as ex:
        threads = mdft.fit_many(make_problems(), rng=7, executor=ex, **COMMON)
    assert estimates(threads) == estimates(serial)


def test_dask_local_cluster_gives_the_same_fits(serial):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        many = mdft.fit_many(make_problems(), rng=7, executor=client, **COMMON)
    assert estimates(many) == estimates(serial)


def test_checkpoint_resumes_without_refitting(tmp_path, serial):
    folder = tmp_path / "fits"
    calls = []
    first = mdft.fit_many(make_problems(), rng=7, executor="serial", checkpoint=folder,
                          progress=lambda *a: calls.append(a[2]), **COMMON)
    assert sorted(calls) == [0, 1, 2, 3] and first.n_resumed == 0
    files = sorted(p.name for p in folder.iterdir())
    assert files == [f"fit-{i:06d}.pkl" for i in range(4)]  # no temporary files left
    calls.clear()
    again = mdft.fit_many(make_problems(), rng=7, executor="serial", checkpoint=folder,
                          progress=lambda *a: calls.append(a[2]), **COMMON)
    assert calls == [] and again.n_resumed == 4
    assert estimates(again) == estimates(serial)
    (folder / "fit-000002.pkl").unlink()
    third = mdft.fit_many(make_problems(), rng=7, executor="serial", checkpoint=folder,
                          progress=lambda *a: calls.append(a[2]), **COMMON)
    assert calls == [2] and third.n_resumed == 3 and estimates(third) == estimates(serial)
    # a checkpoint of other problems or seeds is refused, not silently reused
    with pytest.raises(ValueError, match="holds the fit of a different problem"):
        mdft.fit_many(make_problems(seed=1), rng=7, executor="serial", checkpoint=folder,
                      **COMMON)
    with pytest.raises(ValueError, match="holds the fit of a different problem"):
        mdft.fit_many(make_problems(), rng=8, executor="serial", checkpoint=folder, **COMMON)
    (folder / "fit-000000.pkl").write_bytes(pickle.dumps({"x": 1}))
    with pytest.raises(ValueError, match="is not a fit_many checkpoint"):
        mdft.fit_many(make_problems(), rng=7, executor="serial", checkpoint=folder, **COMMON)


def interrupt(*args):
    raise KeyboardInterrupt


def test_an_interrupted_run_keeps_the_fits_that_were_running(tmp_path, serial):
    # two workers: one fit per worker is submitted at a time, so when the first fit ends the
    # other is running and none waits in a queue; an interrupt then submits no more, and the
    # running one finishes and is saved, not thrown away
    from concurrent.futures import ThreadPoolExecutor

    folder = tmp_path / "fits"
    with ThreadPoolExecutor(max_workers=2) as pool, pytest.raises(KeyboardInterrupt):
        mdft.fit_many(make_problems(), rng=7, executor=pool, checkpoint=folder,
                      progress=interrupt, **COMMON)
    saved = sorted(p.name for p in folder.glob("fit-*.pkl"))
    assert len(saved) == 2, saved
    again = mdft.fit_many(make_problems(), rng=7, executor="serial", checkpoint=folder,
                          **COMMON)
    assert again.n_resumed == 2 and estimates(again) == estimates(serial)


def test_an_interrupted_dask_run_keeps_the_fits_that_were_running(tmp_path, serial):
    # cancelling a Dask future stops its task even while it runs: the running fits must be
    # waited for, not cancelled
    distributed = pytest.importorskip("dask.distributed")
    folder = tmp_path / "fits"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client, pytest.raises(KeyboardInterrupt):
        mdft.fit_many(make_problems(), rng=7, executor=client, checkpoint=folder,
                      progress=interrupt, **COMMON)
    assert len(list(folder.glob("fit-*.pkl"))) == 2
    again = mdft.fit_many(make_problems(), rng=7, executor="serial", checkpoint=folder,
                          **COMMON)
    assert again.n_resumed == 2 and estimates(again) == estimates(serial)


def test_serial_runs_save_each_fit_as_it_ends_and_stop_on_an_interrupt(tmp_path, monkeypatch):
    # "serial" used to run every fit before the first was saved or reported, and an
    # interrupt inside a fit was kept in its future while the other fits ran on
    module = sys.modules["mdft.fit_many"]  # the module (mdft.fit_many is the function)
    folder = tmp_path / "fits"
    seen = []

    def check(n_done, n_total, key, res):
        seen.append(sorted(p.name for p in folder.glob("fit-*.pkl")))

    mdft.fit_many(make_problems(3), rng=7, executor="serial", checkpoint=folder,
                  progress=check, **COMMON)
    assert [len(files) for files in seen] == [1, 2, 3]
    calls = []
    real = module._fit_one

    def second_interrupted(kwargs, seed):
        calls.append(seed)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(kwargs, seed)

    monkeypatch.setattr(module, "_fit_one", second_interrupted)
    other = tmp_path / "other"
    with pytest.raises(KeyboardInterrupt):
        mdft.fit_many(make_problems(3), rng=7, executor="serial", checkpoint=other, **COMMON)
    assert len(calls) == 2 and len(list(other.glob("fit-*.pkl"))) == 1


def test_thread_workers_keep_the_verdict_in_the_result_without_warning():
    # one start is never confirmed: every fit is not converged, and says so in its result
    from concurrent.futures import ThreadPoolExecutor

    one_start = {**COMMON, "n_starts": 1}
    with warnings.catch_warnings(record=True) as caught, ThreadPoolExecutor(2) as pool:
        warnings.simplefilter("always")
        many = mdft.fit_many(make_problems(), rng=7, executor=pool, **one_start)
    assert many.n_converged == 0
    assert all("a single start" in r.message for r in many.results)
    assert not [w for w in caught if issubclass(w.category, mdft.FitConvergenceWarning)]
    prob = make_problems(1)[0]
    with pytest.warns(mdft.FitConvergenceWarning, match="a single start"):
        mdft.fit(prob["data"], prob["M"], rng=0, **one_start)


def test_checkpoint_resumes_settings_written_differently(tmp_path, serial):
    # the same settings in another spelling give the same fits, so they resume
    folder = tmp_path / "fits"
    mdft.fit_many(make_problems(), rng=7, executor="serial", checkpoint=folder, **COMMON)
    respelt = dict(stopping=mdft.FixedTime(30), params=("w",), n_starts=2, max_iter=500,
                   fixed=dict(sigma2=1, beta=12, phi2=0.05, phi1=0.022))
    again = mdft.fit_many(make_problems(), rng=7, executor="serial", checkpoint=folder,
                          **respelt)
    assert again.n_resumed == 4 and estimates(again) == estimates(serial)
    with pytest.raises(ValueError, match="holds the fit of a different problem"):
        mdft.fit_many(make_problems(), rng=7, executor="serial", checkpoint=folder,
                      **{**respelt, "n_starts": 3})
    with pytest.raises(TypeError, match="executor must be None, 'serial'"):
        # every fit is resumed, and the executor is still checked
        mdft.fit_many(make_problems(), rng=7, executor=NotAnExecutor(), checkpoint=folder,
                      **COMMON)
    (folder / "fit-000001.pkl").write_bytes(b"\x80\x04garbage")
    with pytest.raises(ValueError, match=r"fit-000001.pkl cannot be read .*delete it"):
        mdft.fit_many(make_problems(), rng=7, executor="serial", checkpoint=folder, **COMMON)
    (folder / "fit-000001.pkl").write_bytes(pickle.dumps({"version": 1, "result": None}))
    with pytest.raises(ValueError, match="written by another version of fit_many"):
        mdft.fit_many(make_problems(), rng=7, executor="serial", checkpoint=folder, **COMMON)


def test_checkpoint_resumes_with_the_default_rng(tmp_path):
    # rng=None drew fresh seeds on every call, so the fingerprints of a re-run never matched
    # and an interrupted run with the default rng could not resume (ValueError)
    folder = tmp_path / "fits"
    problems = make_problems(2)
    first = mdft.fit_many(problems, executor="serial", checkpoint=folder, **COMMON)
    (folder / "fit-000001.pkl").unlink()  # as if interrupted before the second fit ended
    again = mdft.fit_many(problems, executor="serial", checkpoint=folder, **COMMON)
    assert again.n_resumed == 1 and again.seeds == first.seeds
    assert estimates(again) == estimates(first)
    (folder / "root-entropy.txt").write_text("oops")
    with pytest.raises(ValueError, match="does not hold a root entropy"):
        mdft.fit_many(problems, executor="serial", checkpoint=folder, **COMMON)


def test_keyed_problems_errors_and_summary(tmp_path):
    probs = dict(zip(["ann", "bob"], make_problems(2)))
    probs["bad"] = dict(data=mdft.ChoiceData([[0, 5]], [[1, 1]]), M=M3)
    with pytest.raises(ValueError, match="data refers to 6 options but M has only 3 rows"):
        mdft.fit_many(probs, rng=0, executor="serial", **COMMON)
    many = mdft.fit_many(probs, rng=0, executor="serial", on_error="store", **COMMON)
    assert many["bad"] is None and "data refers to 6 options" in many.errors["bad"]
    assert many["ann"].converged
    with pytest.raises(KeyError, match="no problem with key 'eve'"):
        many["eve"]
    text = many.summary()
    assert text.splitlines()[1].startswith("ann") and "error" in text.splitlines()[3]
    assert "3 problems, 2 converged, 1 errors" in text
    d = many.to_dict()
    assert d["keys"] == ["ann", "bob", "bad"] and d["results"][2] is None
    assert repr(many) == "FitManyResult(n_problems=3, n_converged=2, n_errors=1, n_resumed=0)"


def test_progress_bar(capsys):
    mdft.fit_many(make_problems(2), rng=0, executor="serial", progress=True, **COMMON)
    assert "2/2" in capsys.readouterr().err


class NotAnExecutor:
    """Has ``submit`` but returns no future."""

    def submit(self, fn, *args, **kwargs):
        return fn(*args, **kwargs)


@pytest.mark.parametrize(
    "problems, kwargs, exc, match",
    [
        ("abc", {}, TypeError, "problems must be a list of dicts"),
        ([], {}, ValueError, "problems is empty"),
        ([dict(data=None)], {}, ValueError, r"problems\[0\] lacks \['M'\]"),
        ([[1, 2]], {}, TypeError, r"problems\[0\] must be a dict of mdft.fit arguments"),
        ([dict(data=None, M=None, rng=1)], {}, ValueError, r"problems\[0\] gives rng"),
        (None, dict(executor="cloud"), ValueError, "executor must be None, 'serial'"),
        (None, dict(executor=3), TypeError, "executor must be None, 'serial'"),
        (None, dict(on_error="ignore"), ValueError, "on_error must be 'raise' or 'store'"),
        (None, dict(progress="yes"), TypeError, "progress must be True, False or a callable"),
        (None, dict(n_workers=0), ValueError, "n_workers must be an integer >= 1"),
        (None, dict(executor=NotAnExecutor()), TypeError, "executor must be None, 'serial'"),
        (None, dict(progres=True), TypeError,
         r"problems\[0\] with the common keywords: got an unexpected keyword argument "
         "'progres'; fit_many's own arguments are"),
        ([dict(data=None, M=None, n_start=3)], {}, TypeError, "'n_start'"),
    ],
)
def test_fit_many_bad_input(problems, kwargs, exc, match, tmp_path):
    problems = make_problems(1) if problems is None else problems
    with pytest.raises(exc, match=match):
        mdft.fit_many(problems, **{**COMMON, "rng": 0, **kwargs})


def test_checkpoint_must_be_a_folder(tmp_path):
    f = tmp_path / "file.txt"
    f.write_text("x")
    with pytest.raises(ValueError, match="checkpoint must be a folder"):
        mdft.fit_many(make_problems(1), rng=0, checkpoint=f, executor="serial", **COMMON)
