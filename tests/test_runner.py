"""The experiment runner: same seed, same results under every executor; atomic saving; resuming."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from orchestration.experiments import (
    RunMismatchError,
    Unit,
    child_seed,
    dask_executor,
    local_executor,
    reproduce,
    run_units,
    unit_seed,
)
from tests._runner_work import fails_on_three, noisy_sum, slow_noisy_sum

ROOT = Path(__file__).resolve().parents[1]
UNITS = [Unit(f"u{k:02d}", {"n": 4, "k": k}, (k,)) for k in range(8)]


def reference(units, seed):
    """The obviously-correct serial loop: each unit's work on its own SeedSequence."""
    return {u.key: noisy_sum(u.params, np.random.SeedSequence(seed, spawn_key=u.spawn_key))
            for u in units}


def test_in_process_run_matches_the_serial_reference_and_saves_every_unit(tmp_path):
    run = run_units(noisy_sum, UNITS, tmp_path, seed=7)
    assert run.results == reference(UNITS, 7)
    assert list(run.results) == [u.key for u in UNITS]
    assert (run.n_loaded, run.n_computed) == (0, 8)
    saved = sorted(p.name for p in (tmp_path / "units").iterdir())
    assert saved == [f"{u.key}.json" for u in UNITS]
    record = json.loads((tmp_path / "units" / "u03.json").read_text())
    assert record["params"] == {"n": 4, "k": 3} and record["spawn_key"] == [3]
    assert record["result"] == run.results["u03"]


def test_seeds_differ_between_units_and_runs(tmp_path):
    a = run_units(noisy_sum, UNITS, tmp_path / "a", seed=1).results
    b = run_units(noisy_sum, UNITS, tmp_path / "b", seed=2).results
    sums = [r["sum"] for r in a.values()]
    assert len(set(sums)) == len(sums)
    assert all(a[k]["sum"] != b[k]["sum"] for k in a)


def test_child_seeds_are_named_streams():
    s = unit_seed(5, (2,))
    assert child_seed(s, 1, 3).spawn_key == (2, 1, 3)
    draws = lambda seq: np.random.default_rng(seq).random(3).tolist()  # noqa: E731
    assert draws(child_seed(s, 0)) == draws(np.random.SeedSequence(5, spawn_key=(2, 0)))
    assert draws(child_seed(s, 0)) != draws(child_seed(s, 1))


def test_same_results_with_two_local_processes(tmp_path):
    with local_executor(2) as ex:
        run = run_units(noisy_sum, UNITS, tmp_path, seed=7, executor=ex)
    assert run.results == reference(UNITS, 7)


def test_same_results_on_a_dask_cluster(tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(processes=False, n_workers=2, threads_per_worker=1,
                                  dashboard_address=None) as cluster:
        with dask_executor(cluster.scheduler_address) as ex:
            run = run_units(noisy_sum, UNITS, tmp_path, seed=7, executor=ex)
    assert run.results == reference(UNITS, 7)


def test_dask_executor_without_a_scheduler_is_a_clear_error():
    pytest.importorskip("distributed")
    with pytest.raises(OSError, match="no Dask scheduler answered at 'tcp://127.0.0.1:9'"):
        with dask_executor("tcp://127.0.0.1:9", timeout="1s"):
            pass


def test_an_interrupted_run_resumes_to_the_uninterrupted_result(tmp_path):
    def interrupt_after_three(done, total):
        if done == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_units(noisy_sum, UNITS, tmp_path / "a", seed=3, progress=interrupt_after_three)
    assert len(list((tmp_path / "a" / "units").glob("*.json"))) == 3
    seen = []
    resumed = run_units(noisy_sum, UNITS, tmp_path / "a", seed=3,
                        progress=lambda d, t: seen.append((d, t)))
    assert (resumed.n_loaded, resumed.n_computed) == (3, 5)
    assert seen[0] == (3, 8) and seen[-1] == (8, 8)
    assert resumed.results == run_units(noisy_sum, UNITS, tmp_path / "b", seed=3).results


def test_a_killed_run_loses_no_finished_unit_and_resumes(tmp_path):
    units = [Unit(f"u{k:02d}", {"n": 3, "k": k, "sleep": 0.4}, (k,)) for k in range(16)]
    script = (
        "import sys; sys.path.insert(0, %r)\n"
        "from orchestration.experiments import Unit, run_units\n"
        "from tests._runner_work import slow_noisy_sum\n"
        "units = [Unit(f'u{k:02d}', {'n': 3, 'k': k, 'sleep': 0.4}, (k,)) for k in range(16)]\n"
        "run_units(slow_noisy_sum, units, %r, seed=11)\n" % (str(ROOT), str(tmp_path / "a"))
    )
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT)
    deadline = time.monotonic() + 120
    unit_dir = tmp_path / "a" / "units"
    while time.monotonic() < deadline and proc.poll() is None:
        if unit_dir.is_dir() and len(list(unit_dir.glob("u*.json"))) >= 3:
            break
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done = sorted(unit_dir.glob("u*.json"))
    assert 3 <= len(done) < 16
    for path in done:  # every saved unit is complete JSON
        json.loads(path.read_text())
    resumed = run_units(slow_noisy_sum, units, tmp_path / "a", seed=11)
    assert resumed.n_loaded == len(done)
    fresh = reference([Unit(u.key, {"n": 3, "k": u.params["k"]}, u.spawn_key) for u in units], 11)
    assert {k: r["sum"] for k, r in resumed.results.items()} == {k: r["sum"] for k, r in fresh.items()}


def test_a_folder_refuses_another_seed_or_other_settings(tmp_path):
    run_units(noisy_sum, UNITS[:2], tmp_path, seed=1, identity={"size": 3})
    with pytest.raises(RunMismatchError, match=r"holds a run with other seed \(\{\"seed\": 1\}\)"):
        run_units(noisy_sum, UNITS[:2], tmp_path, seed=2, identity={"size": 3})
    with pytest.raises(RunMismatchError, match=r"other identity \(\{\"identity\": \{\"size\": 3\}\}\)"):
        run_units(noisy_sum, UNITS[:2], tmp_path, seed=1, identity={"size": 4})
    with pytest.raises(RunMismatchError, match="other units"):
        run_units(noisy_sum, UNITS[:3], tmp_path, seed=1, identity={"size": 3})
    # the same run is accepted and has nothing left to do
    assert run_units(noisy_sum, UNITS[:2], tmp_path, seed=1, identity={"size": 3}).n_computed == 0


def test_a_failing_unit_names_itself_and_keeps_the_others(tmp_path):
    with pytest.raises(RuntimeError, match="unit 'u03' failed: ArithmeticError: unit three"):
        run_units(fails_on_three, UNITS, tmp_path, seed=0)
    assert sorted(p.stem for p in (tmp_path / "units").glob("*.json")) == ["u00", "u01", "u02"]


@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        (dict(units=[Unit("a", {}), Unit("a", {})]), ValueError, r"unique \(got duplicates \['a'\]\)"),
        (dict(seed=-1), ValueError, "seed must be an integer >= 0 .got -1."),
        (dict(seed=1.5), ValueError, "seed must be an integer >= 0 .got 1.5."),
        (dict(units=[("a", {})]), TypeError, "units must be a sequence of Unit"),
        (dict(identity={"f": object()}), TypeError, "identity must be JSON-serialisable"),
    ],
)
def test_bad_arguments(tmp_path, kwargs, error, message):
    args = dict(units=UNITS[:1], seed=0) | kwargs
    with pytest.raises(error, match=message):
        run_units(noisy_sum, args.pop("units"), tmp_path, **args)


@pytest.mark.parametrize(
    "args, message",
    [
        (("../x", {}), "key must be a non-empty name"),
        (("", {}), "key must be a non-empty name"),
        (("a", {}, (-1,)), r"spawn_key must hold integers >= 0 \(got \(-1,\)\)"),
        (("a", {"x": {1, 2}}), "params of a must be JSON-serialisable"),
    ],
)
def test_bad_units(args, message):
    with pytest.raises((ValueError, TypeError), match=message):
        Unit(*args)


def test_local_executor_rejects_zero_workers():
    with pytest.raises(ValueError, match=r"workers must be an integer >= 1 \(got 0\)"):
        with local_executor(0):
            pass


# ----------------------------------------------------------------------------- a real experiment
TINY = dict(n_demonstrations=[3], n_repeats=2, zeta_levels=[0.6], n_model_trajectories=20)


def test_an_experiment_gives_the_same_results_in_process_and_on_a_dask_cluster(tmp_path):
    distributed = pytest.importorskip("distributed")
    a = reproduce("hard-constraints", tmp_path / "a", settings=TINY, seed=4)
    with distributed.LocalCluster(processes=False, n_workers=1, threads_per_worker=2,
                                  dashboard_address=None) as cluster:
        with dask_executor(cluster.scheduler_address) as ex:
            b = reproduce("hard-constraints", tmp_path / "b", settings=TINY, seed=4, executor=ex)
    ra = json.loads((tmp_path / "a" / "results.json").read_text())
    rb = json.loads((tmp_path / "b" / "results.json").read_text())
    assert ra == rb and a.rows == b.rows
    assert {p.name for p in a.files} == {"results.json", "summary.txt", "hard_constraints.png"}


def test_unknown_settings_are_refused(tmp_path):
    with pytest.raises(ValueError, match=r"settings of 'transfer' are .* \(got unknown \['colour'\]\)"):
        reproduce("transfer", tmp_path, settings={"colour": 1})
    with pytest.raises(ValueError, match="experiment must be one of"):
        reproduce("figure-9", tmp_path)


def test_the_runner_page_examples_run(tmp_path, monkeypatch):
    """The ```python blocks of docs/experiments/runner.md run as a user would paste them."""
    import re

    pytest.importorskip("distributed")
    text = (ROOT / "docs" / "experiments" / "runner.md").read_text()
    blocks = re.findall(r"^```python\n(.*?)^```", text, re.S | re.M)
    assert len(blocks) == 2
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for i, block in enumerate(blocks):
        exec(compile(block, f"runner.md[block {i}]", "exec"), namespace)
        assert namespace["report"].files
