"""Run an experiment's independent work units, save each as it finishes, resume after a stop.

An experiment is a list of :class:`Unit` s and one work function
``work(params, seed) -> dict``: a pure function of the unit's parameters and of
its seed, a :class:`numpy.random.SeedSequence` derived from the run's seed and
the unit's spawn key (:func:`unit_seed`). :func:`run_units` sends the units
that are not yet done to a :class:`concurrent.futures.Executor` (or runs them
in this process), writes each result to ``folder/units/<key>.json`` atomically
(a temporary file renamed over the target) as soon as it arrives, and returns
all results in unit order.

Because each unit depends only on its parameters and seed, and every result
is read back from its JSON file, the same seed gives the same results whatever
the executor, the number of workers, the completion order, or how often the
run was stopped and resumed.

A folder remembers the run it belongs to (``folder/run.json``: the identity,
that is the experiment and its settings, the seed and the unit keys); a run
with a different identity refuses to use it (:class:`RunMismatchError`).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import json
import logging
import multiprocessing
import os
import signal
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

__all__ = [
    "RunMismatchError",
    "RunResult",
    "Unit",
    "child_seed",
    "local_executor",
    "dask_executor",
    "run_units",
    "unit_seed",
    "write_atomically",
]

logger = logging.getLogger(__name__)

_FORMAT = 1
_MANIFEST = "run.json"
_UNITS = "units"


class RunMismatchError(ValueError):
    """The output folder holds units of a run with other settings or another seed."""


@dataclass(frozen=True)
class Unit:
    """One independent piece of work.

    Attributes
    ----------
    key : str
        Unique name within the experiment; also the file name of its result
        (letters, digits, ``-``, ``_`` and ``.`` only).
    params : dict
        JSON-serialisable parameters passed to the work function.
    spawn_key : tuple of int
        Where the unit's seed sits in the run's seed tree (:func:`unit_seed`).
        Units that share a spawn key get the same random stream (e.g. the
        same random world), which the work function can split with
        :func:`child_seed`.

    Examples
    --------
    >>> Unit("world-000", {"world": 0}, (0,)).key
    'world-000'
    """

    key: str
    params: dict
    spawn_key: tuple = ()

    def __post_init__(self):
        if not isinstance(self.key, str) or not self.key or not all(
            c.isalnum() or c in "-_." for c in self.key
        ) or self.key.startswith("."):
            raise ValueError(
                f"key must be a non-empty name of letters, digits, '-', '_' and '.' (got {self.key!r})"
            )
        keys = tuple(self.spawn_key)
        if not all(isinstance(k, (int, np.integer)) and not isinstance(k, bool) and k >= 0
                   for k in keys):
            raise ValueError(f"spawn_key must hold integers >= 0 (got {self.spawn_key!r})")
        object.__setattr__(self, "spawn_key", tuple(int(k) for k in keys))
        object.__setattr__(self, "params", _json_roundtrip(dict(self.params), f"params of {self.key}"))


@dataclass(frozen=True)
class RunResult:
    """Results of :func:`run_units`.

    Attributes
    ----------
    results : dict
        ``key -> result`` for every unit, in unit order, as read back from JSON.
    n_loaded : int
        Units found finished in the folder (done by an earlier run).
    n_computed : int
        Units computed by this run.
    folder : pathlib.Path
    """

    results: dict = field(repr=False)
    n_loaded: int
    n_computed: int
    folder: Path


def unit_seed(seed: int, spawn_key=()) -> np.random.SeedSequence:
    """The seed of a unit: ``SeedSequence(seed, spawn_key=spawn_key)``.

    Examples
    --------
    >>> a, b = unit_seed(0, (1,)), unit_seed(0, (2,))
    >>> bool(a.generate_state(1)[0] != b.generate_state(1)[0])
    True
    >>> unit_seed(0, (1,)).generate_state(2).tolist() == a.generate_state(2).tolist()
    True
    """
    return np.random.SeedSequence(int(seed), spawn_key=tuple(int(k) for k in spawn_key))


def child_seed(seed: np.random.SeedSequence, *keys: int) -> np.random.SeedSequence:
    """The child of ``seed`` at ``keys`` (its spawn key extended by ``keys``).

    Unlike :meth:`numpy.random.SeedSequence.spawn` it does not depend on how
    many children were spawned before, so a work function can name its
    streams: ``child_seed(seed, 0)`` for the world, ``child_seed(seed, 1, n)``
    for the demonstrations of size ``n``.

    Examples
    --------
    >>> s = unit_seed(0, (3,))
    >>> child_seed(s, 1).spawn_key
    (3, 1)
    """
    return np.random.SeedSequence(seed.entropy, spawn_key=tuple(seed.spawn_key) + tuple(int(k) for k in keys))


def _json_roundtrip(value, what):
    try:
        return json.loads(json.dumps(value))
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{what} must be JSON-serialisable ({exc})") from None


def write_atomically(path, text) -> None:
    """Write ``text`` (str or bytes) to ``path`` through a temporary file renamed over it.

    A reader never sees a half-written file, even if the process is killed.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "x.json"
    >>> write_atomically(p, "{}")
    >>> p.read_text()
    '{}'
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        data = text if isinstance(text, bytes) else text.encode("utf-8")
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _execute(work, params, seed, spawn_key):
    """Run one unit (in a worker): the work function on its parameters and seed."""
    return work(params, unit_seed(seed, spawn_key))


def _describe(identity: dict) -> str:
    return json.dumps(identity, sort_keys=True)


def _prepare(folder: Path, identity: dict, keys: list) -> None:
    manifest = {"format": _FORMAT, **identity, "units": keys}
    path = folder / _MANIFEST
    if path.exists():
        try:
            old = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise RunMismatchError(
                f"{str(folder)!r} has an unreadable {_MANIFEST} ({exc}); use another output folder"
            ) from None
        if old != manifest:
            diff = sorted(k for k in set(old) | set(manifest) if old.get(k) != manifest.get(k))
            shown = {k: old.get(k) for k in diff if k != "units"}
            raise RunMismatchError(
                f"{str(folder)!r} holds a run with other {', '.join(diff)} "
                f"({_describe(shown) if shown else 'other units'}); resume it with the same "
                "settings and seed, or use another output folder"
            )
    else:
        folder.mkdir(parents=True, exist_ok=True)
        write_atomically(path, json.dumps(manifest, indent=1))
    (folder / _UNITS).mkdir(exist_ok=True)
    for stale in (folder / _UNITS).glob(".*.tmp"):  # left by a killed run
        with contextlib.suppress(OSError):
            stale.unlink()


def _load(path: Path, unit: Unit):
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        logger.warning("ignoring unreadable unit file %s (%s); the unit is run again", path, exc)
        return None
    if data.get("key") != unit.key or data.get("params") != unit.params or \
            tuple(data.get("spawn_key", ())) != unit.spawn_key:
        raise RunMismatchError(f"{str(path)!r} holds another unit than {unit.key!r}; use another output folder")
    return data["result"]


def _save(folder: Path, unit: Unit, result) -> dict:
    record = {"key": unit.key, "params": unit.params, "spawn_key": list(unit.spawn_key),
              "result": result}
    text = json.dumps(record, separators=(",", ":"))
    write_atomically(folder / _UNITS / f"{unit.key}.json", text)
    return json.loads(text)["result"]


def run_units(work: Callable, units, folder, *, seed: int, identity: Mapping | None = None,
              executor: cf.Executor | None = None, progress: Callable | None = None) -> RunResult:
    """Run the units not yet done, saving each result as it arrives; return all results.

    Parameters
    ----------
    work : callable
        ``work(params: dict, seed: numpy.random.SeedSequence) -> dict``, a
        module-level function (it is pickled to the workers) returning
        JSON-serialisable results.
    units : sequence of Unit
        Keys must be unique.
    folder : str or path
        Output folder; created if needed. Finished units live in ``folder/units``.
    seed : int
        The run's seed (>= 0); unit ``u`` gets ``unit_seed(seed, u.spawn_key)``.
    identity : dict, optional
        JSON-serialisable description of the run (experiment name, settings).
        Together with the seed and the unit keys it must match the folder's
        earlier run, if any.
    executor : concurrent.futures.Executor, optional
        Where units run: e.g. :func:`local_executor` (processes) or
        :func:`dask_executor` (a Dask cluster). Default: in this process, one
        after the other.
    progress : callable, optional
        ``progress(n_done, n_total)``, called once at the start (with the
        units already done) and after each finished unit.

    Returns
    -------
    RunResult

    Raises
    ------
    RunMismatchError
        If the folder holds a run with another identity, seed or unit list.
    RuntimeError
        If a unit raised; the units finished before stay saved.

    Examples
    --------
    >>> import tempfile
    >>> from orchestration.experiments.runner import _demo_work
    >>> units = [Unit(f"u{i}", {"n": 3}, (i,)) for i in range(4)]
    >>> folder = tempfile.mkdtemp()
    >>> run = run_units(_demo_work, units, folder, seed=0)
    >>> run.n_computed, len(run.results["u0"]["draws"])
    (4, 3)
    >>> again = run_units(_demo_work, units, folder, seed=0)  # nothing left to do
    >>> again.n_loaded, again.results == run.results
    (4, True)
    """
    units = list(units)
    if not all(isinstance(u, Unit) for u in units):
        raise TypeError("units must be a sequence of Unit")
    keys = [u.key for u in units]
    if len(set(keys)) != len(keys):
        dup = sorted({k for k in keys if keys.count(k) > 1})
        raise ValueError(f"unit keys must be unique (got duplicates {dup[:5]})")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0 (got {seed!r})")
    seed = int(seed)
    ident = _json_roundtrip(dict(identity or {}), "identity")
    folder = Path(folder)
    _prepare(folder, {"identity": ident, "seed": seed}, keys)

    results = {}
    for u in units:
        path = folder / _UNITS / f"{u.key}.json"
        if path.exists():
            value = _load(path, u)
            if value is not None:
                results[u.key] = value
    n_loaded = len(results)
    pending = [u for u in units if u.key not in results]
    total = len(units)
    if progress is not None:
        progress(n_loaded, total)

    def finished(unit, value):
        results[unit.key] = _save(folder, unit, value)
        if progress is not None:
            progress(len(results), total)

    if executor is None:
        for u in pending:
            try:
                value = _execute(work, u.params, seed, u.spawn_key)
            except Exception as exc:
                raise RuntimeError(f"unit {u.key!r} failed: {type(exc).__name__}: {exc}") from exc
            finished(u, value)
    elif pending:
        futures = {executor.submit(_execute, work, u.params, seed, u.spawn_key): u for u in pending}
        try:
            for fut in cf.as_completed(futures):
                u = futures[fut]
                try:
                    value = fut.result()
                except Exception as exc:
                    raise RuntimeError(f"unit {u.key!r} failed: {type(exc).__name__}: {exc}") from exc
                finished(u, value)
        finally:
            for fut in futures:
                fut.cancel()
    ordered = {k: results[k] for k in keys}
    return RunResult(ordered, n_loaded, len(pending), folder)


# ----------------------------------------------------------------------------- executors
def _worker_init():
    """In each local worker: leave Ctrl-C to the parent, use one numba and one BLAS thread."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):  # pragma: no cover
        pass
    try:  # BLAS threads spinning on tiny matrices slow the optimisers down on a busy machine
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:  # pragma: no cover - threadpoolctl is optional
        pass


@contextlib.contextmanager
def local_executor(workers: int):
    """A pool of ``workers`` local processes, or None (run in this process) for one worker.

    Workers are started with the ``spawn`` method: a fresh interpreter each,
    which is safe with numba's and OpenMP's threads (``fork`` is not). Each
    worker uses one numba thread (and one BLAS thread where threadpoolctl is
    installed), so the workers do not oversubscribe the cores. On leaving the block (also on Ctrl-C) pending units are cancelled
    and the workers are stopped.

    Examples
    --------
    >>> with local_executor(1) as ex:
    ...     ex is None
    True
    """
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1 (got {workers!r})")
    if workers == 1:
        yield None
        return
    pool = cf.ProcessPoolExecutor(
        max_workers=int(workers), mp_context=multiprocessing.get_context("spawn"),
        initializer=_worker_init,
    )
    try:
        yield pool
    except BaseException:
        processes = list(getattr(pool, "_processes", {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for p in processes:  # do not wait for units in progress
            with contextlib.suppress(Exception):
                p.terminate()
        raise
    else:
        pool.shutdown(wait=True)


@contextlib.contextmanager
def dask_executor(address: str, *, timeout="10s"):
    """An executor on the Dask distributed cluster whose scheduler is at ``address``.

    Needs the optional extra ``dask`` (``pip install "pymdft[dask]"``) here and
    pymdft installed on the workers. ``address`` is e.g. ``tcp://host:8786``;
    ``timeout`` is how long to wait for the scheduler to answer.

    Raises
    ------
    ImportError
        If ``distributed`` is not installed.
    OSError
        If no scheduler answers at ``address``.
    """
    try:
        from distributed import Client
    except ImportError:
        raise ImportError(
            "running on a Dask cluster needs the optional extra: pip install 'pymdft[dask]'"
        ) from None
    try:
        client = Client(address, timeout=timeout)
    except (OSError, TimeoutError, ValueError) as exc:
        raise OSError(f"no Dask scheduler answered at {address!r} ({exc})") from None
    try:
        yield client.get_executor(pure=False)
    finally:
        client.close()


def _demo_work(params, seed):
    """A tiny work function for the examples: ``params['n']`` uniform draws."""
    rng = np.random.default_rng(seed)
    return {"draws": rng.random(int(params["n"])).tolist()}
