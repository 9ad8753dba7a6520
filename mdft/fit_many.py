"""Many fits at once: participants or problems fitted through an executor, resumably.

:func:`fit_many` runs :func:`mdft.fit` on every problem through a
:class:`concurrent.futures.Executor` (local processes by default, a Dask cluster when given),
shows progress, and saves each finished fit atomically in a checkpoint folder, so that a
re-run resumes without redoing finished fits. Each problem gets its own random seed, spawned
from one :class:`numpy.random.SeedSequence`, so the results do not depend on the executor,
the number of workers or the order in which fits finish.
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import inspect
import logging
import multiprocessing
import numbers
import os
import pickle
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._fit_params import PARAMETERS, check_names
from ._validation import as_count, as_generator
from .likelihood import stopping_kind
from .fit_result import FitResult, to_builtin

__all__ = ["FitManyResult", "fit_many"]

logger = logging.getLogger(__name__)

#: 2: fingerprints of the settings in one spelling (version 1 took them as written).
_CHECKPOINT_VERSION = 2
#: Where a checkpoint folder keeps the root entropy of a run with ``rng=None``.
_ENTROPY_FILE = "root-entropy.txt"


@dataclass(frozen=True, eq=False)
class FitManyResult:
    """Outcome of :func:`fit_many`.

    Attributes
    ----------
    keys : tuple
        The problems' keys (indices for a sequence, the mapping's keys for a dict).
    results : tuple of FitResult or None
        One per key; None where the fit raised (with ``on_error="store"``).
    errors : dict
        ``key -> "ExceptionType: message"`` of the fits that raised.
    seeds : tuple of int
        The random seed each problem's fit used.
    n_resumed : int
        Fits read back from the checkpoint instead of being run.

    Examples
    --------
    >>> import mdft
    >>> fixed = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
    >>> problems = [dict(data=mdft.ChoiceData([[0, 1]], [[c, 100 - c]]), M=[[1, 3], [3, 1]])
    ...             for c in (40, 60)]
    >>> many = mdft.fit_many(problems, stopping=20, params=["w"], fixed=fixed, rng=0,
    ...                      executor="serial")
    >>> [round(float(r.params["w"][0]), 2) for r in many.results]
    [0.54, 0.46]
    >>> many.n_converged, len(many)
    (2, 2)
    """

    keys: tuple
    results: tuple
    errors: dict
    seeds: tuple
    n_resumed: int = 0
    checkpoint: str | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.keys)

    def __getitem__(self, key):
        try:
            return self.results[self.keys.index(key)]
        except ValueError:
            raise KeyError(f"no problem with key {key!r}") from None

    @property
    def n_converged(self) -> int:
        """Fits that report ``converged=True``."""
        return sum(1 for r in self.results if r is not None and r.converged)

    def __repr__(self) -> str:
        return (f"FitManyResult(n_problems={len(self)}, n_converged={self.n_converged}, "
                f"n_errors={len(self.errors)}, n_resumed={self.n_resumed})")

    def summary(self) -> str:
        """A small text table: one row per problem (log-likelihood, converged, estimates).

        Examples
        --------
        >>> import mdft
        >>> fixed = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
        >>> problems = {"anna": dict(data=mdft.ChoiceData([[0, 1]], [[40, 60]]),
        ...                          M=[[1, 3], [3, 1]])}
        >>> print(mdft.fit_many(problems, stopping=20, params=["w"], fixed=fixed, rng=0,
        ...                     executor="serial").summary())
        key     log-lik  converged  estimates
        anna     -2.511       True  w=[0.5355, 0.4645]
        1 problems, 1 converged, 0 errors, 0 resumed
        """
        lines = [f"{'key':<6s} {'log-lik':>8s} {'converged':>10s}  estimates"]
        for key, res in zip(self.keys, self.results):
            if res is None:
                lines.append(f"{str(key):<6s} {'':>8s} {'error':>10s}  {self.errors[key]}")
                continue
            est = ", ".join(
                f"{k}={np.array2string(np.asarray(res.params[k]), precision=4, separator=', ')}"
                if k in ("w", "M") else f"{k}={res.params[k]:.4g}" for k in res.fitted)
            lines.append(f"{str(key):<6s} {res.log_likelihood:8.4g} {str(res.converged):>10s}"
                         f"  {est}")
        lines.append(f"{len(self)} problems, {self.n_converged} converged, "
                     f"{len(self.errors)} errors, {self.n_resumed} resumed")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-serialisable builtins: keys, seeds, errors and every result's ``to_dict()``.

        Examples
        --------
        >>> import json, mdft
        >>> fixed = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
        >>> many = mdft.fit_many([dict(data=mdft.ChoiceData([[0, 1]], [[40, 60]]),
        ...                            M=[[1, 3], [3, 1]])], stopping=20, params=["w"],
        ...                      fixed=fixed, rng=0, executor="serial")
        >>> sorted(json.loads(json.dumps(many.to_dict())))
        ['errors', 'keys', 'n_resumed', 'results', 'seeds']
        """
        return {
            "keys": to_builtin(list(self.keys)),
            "seeds": [int(s) for s in self.seeds],
            "errors": {str(k): v for k, v in self.errors.items()},
            "n_resumed": int(self.n_resumed),
            "results": [None if r is None else r.to_dict() for r in self.results],
        }


# ---------------------------------------------------------------- workers
def _fit_one(kwargs, seed):
    """Run one fit (in a worker); its convergence verdict is in the result, not warned."""
    from .fit import fit, quiet

    quiet.on = True  # per thread: a thread executor's other fits and the caller still warn
    try:
        return fit(**kwargs, rng=seed)
    finally:
        quiet.on = False


def _init_worker(n_threads):
    """Worker initialiser: limit numba's threads so that workers do not oversubscribe cores."""
    try:
        import numba

        numba.set_num_threads(max(1, min(n_threads, numba.config.NUMBA_NUM_THREADS)))
    except (ImportError, ValueError):  # pragma: no cover - numba is a dependency
        pass


class _Serial(cf.Executor):
    """Runs each submitted call at once in the calling process (an interrupt propagates)."""

    def submit(self, fn, /, *args, **kwargs):
        future = cf.Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except Exception as exc:  # noqa: BLE001 - handed to the caller via the future
            future.set_exception(exc)
        return future


# ---------------------------------------------------------------- checkpoint
def _canonical(value):
    """``value`` in one spelling: mappings sorted by key, numbers and arrays of numbers as
    float64 arrays, other sequences as tuples (so that ``[0.5, 1]`` and ``(0.5, 1.0)``, or
    two orders of the same ``fixed``, give the same fingerprint)."""
    if isinstance(value, dict):
        return ("dict", tuple(sorted((str(k), _canonical(v)) for k, v in value.items())))
    if isinstance(value, (str, bytes, bool)) or value is None:
        return value
    if isinstance(value, (numbers.Number, list, tuple, np.ndarray)):
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            return ("seq", tuple(_canonical(v) for v in value))
        return ("array", arr.shape, arr.tobytes())
    return value


def _fit_arguments(kwargs):
    """The arguments of :func:`mdft.fit` that ``kwargs`` give, defaults filled in, in one
    spelling; raises ``TypeError`` for a name that is not one of fit's arguments."""
    from .fit import fit

    args = inspect.signature(fit).bind(**kwargs)
    args.apply_defaults()
    out = dict(args.arguments)
    try:
        out["stopping"] = stopping_kind(out["stopping"])
        out["params"] = tuple(k for k in PARAMETERS if k in check_names("params", out["params"]))
    except (KeyError, TypeError, ValueError):
        pass  # invalid: fit will say so
    return out


def _fingerprint(args, seed):
    """What a checkpoint file must have been made from: the problem, the settings
    (``_fit_arguments``) and the seed, the same for settings spelt differently that give
    the same fit."""
    settings = {k: v for k, v in args.items() if k != "data"}
    blob = pickle.dumps((_canonical(settings), args.get("data"), int(seed)), protocol=4)
    return hashlib.sha256(blob).hexdigest()


def _write_atomic(path, mode, write):
    """Call ``write(fh)`` on a temporary file beside ``path``, then rename it over ``path``."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=path.suffix)
    try:
        with os.fdopen(fd, mode) as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _save(path, payload):
    """Write ``payload`` to ``path`` atomically (a temporary file renamed over it)."""
    _write_atomic(path, "wb",
                  lambda fh: pickle.dump(payload, fh, protocol=pickle.HIGHEST_PROTOCOL))


def _load(path, fingerprint):
    """The stored result of ``path`` if it was made from the same problem, else raise."""
    try:
        with open(path, "rb") as fh:
            payload = pickle.load(fh)
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, IndexError,
            TypeError, ValueError) as exc:
        raise ValueError(f"checkpoint file {path} cannot be read ({type(exc).__name__}: "
                         f"{exc}); delete it to fit that problem again") from exc
    if not isinstance(payload, dict) or "version" not in payload:
        raise ValueError(f"checkpoint file {path} is not a fit_many checkpoint; use a new "
                         "checkpoint folder or delete it")
    if payload["version"] != _CHECKPOINT_VERSION:
        raise ValueError(
            f"checkpoint file {path} was written by another version of fit_many (format "
            f"{payload['version']}, this one reads {_CHECKPOINT_VERSION}); use a new checkpoint "
            "folder or delete it"
        )
    if payload["fingerprint"] != fingerprint:
        raise ValueError(
            f"checkpoint file {path} holds the fit of a different problem or settings; "
            "use a new checkpoint folder or delete the stale one"
        )
    return payload["result"]


def _root_entropy(folder):
    """The root entropy of ``rng=None`` runs in ``folder``: read back, or drawn and saved."""
    path = folder / _ENTROPY_FILE
    if path.exists():
        text = path.read_text().strip()
        if not text.isdigit():
            raise ValueError(f"checkpoint file {path} does not hold a root entropy (got "
                             f"{text[:40]!r}); delete it or use a new checkpoint folder")
        return int(text)
    entropy = int(np.random.SeedSequence().entropy)
    _write_atomic(path, "w", lambda fh: fh.write(f"{entropy}\n"))
    return entropy


# ---------------------------------------------------------------- fit_many
def _problem_list(problems):
    if isinstance(problems, dict):
        items = list(problems.items())
    elif isinstance(problems, (list, tuple)):
        items = list(enumerate(problems))
    else:
        raise TypeError(
            "problems must be a list of dicts (or a dict of dicts keyed by participant) with "
            f"the arguments of mdft.fit, e.g. dict(data=..., M=...) (got {type(problems).__name__})"
        )
    if not items:
        raise ValueError("problems is empty: give at least one problem to fit")
    for key, prob in items:
        if not isinstance(prob, dict):
            raise TypeError(
                f"problems[{key!r}] must be a dict of mdft.fit arguments with 'data' and 'M' "
                f"(got {type(prob).__name__})"
            )
        missing = [k for k in ("data", "M") if k not in prob]
        if missing:
            raise ValueError(f"problems[{key!r}] lacks {missing}; each problem needs data and M")
        if "rng" in prob:
            raise ValueError(
                f"problems[{key!r}] gives rng; fit_many spawns one seed per problem from its "
                "own rng= argument"
            )
    return items


def _usable_cores():
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
        os.cpu_count() or 1)


def _is_dask_client(executor):
    return hasattr(executor, "get_executor") and hasattr(executor, "nthreads")


def _check_executor(executor):
    """Raise unless ``executor`` is None, "serial", an Executor or a Dask Client."""
    if executor is None or (isinstance(executor, str) and executor == "serial"):
        return
    if isinstance(executor, str):
        raise ValueError(
            f"executor must be None, 'serial', a concurrent.futures.Executor or a "
            f"dask.distributed Client (got {executor!r})"
        )
    if not (_is_dask_client(executor) or isinstance(executor, cf.Executor)):
        raise TypeError(
            "executor must be None, 'serial', a concurrent.futures.Executor or a "
            f"dask.distributed Client (got {type(executor).__name__})"
        )


def _resolve_executor(executor, n_workers):
    """``(executor, owned, slots)``: the executor to submit to, whether fit_many must shut it
    down, and how many fits to keep submitted at a time (one per worker where that is
    known), so that every fit submitted is running and none waits in a queue. ``executor``
    has passed :func:`_check_executor`."""
    if executor is None:
        n = n_workers or max(1, min(_usable_cores(), 8))
        ctx = multiprocessing.get_context(
            "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn")
        pool = cf.ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=_init_worker,
                                      initargs=(1,))
        return pool, True, n
    if isinstance(executor, str):
        return _Serial(), True, 1
    if _is_dask_client(executor):
        threads = sum(executor.nthreads().values())
        return executor.get_executor(), False, threads if threads > 0 else _usable_cores()
    workers = getattr(executor, "_max_workers", None)  # the standard library's pools
    slots = workers if isinstance(workers, int) and workers > 0 else _usable_cores()
    return executor, False, slots


def fit_many(problems, *, executor=None, n_workers=None, progress=False, checkpoint=None,
             rng=None, on_error="raise", **common) -> FitManyResult:
    """Fit many problems (participants, data sets) with :func:`mdft.fit`, concurrently.

    Parameters
    ----------
    problems : list of dict or dict of dict
        Each problem holds the arguments of :func:`mdft.fit` that are its own: at least
        ``data`` and ``M``, and any keyword (``stopping``, ``params``, ``fixed``, ...)
        that overrides ``common``. A dict keys the problems (e.g. by participant).
    executor : None, "serial", concurrent.futures.Executor or dask.distributed.Client
        Where the fits run. None: a local process pool (``n_workers`` processes started
        with ``"forkserver"`` where available, else ``"spawn"``, never ``"fork"``, which is
        unsafe with numba's and OpenMP's threads; numba uses one thread per worker).
        ``"serial"``: in this process, one after the other. An executor or a Dask
        ``Client`` (its ``get_executor()``) is used as given and not shut down. One fit
        per worker is submitted at a time, so an interrupt leaves none queued. A script
        that uses the default pool must call ``fit_many`` under
        ``if __name__ == "__main__":`` (its workers import the script).
    n_workers : int, optional
        Processes of the default pool (default: the usable cores, at most 8).
    progress : bool or callable, default False
        True shows a ``tqdm`` progress bar; a callable is called as
        ``progress(n_done, n_total, key, result)`` after each fit (``result`` is None for a
        fit that raised).
    checkpoint : str or path-like, optional
        A folder: each finished fit is saved there atomically as it completes, and a later
        call with the same folder reads finished fits back instead of running them
        (settings spelt differently, e.g. ``fixed`` in another order, still resume). A
        file made from a different problem, settings or seed, or that cannot be read,
        raises ``ValueError``.
    rng : None, int or numpy.random.SeedSequence
        Root of the per-problem seeds (problem ``i`` uses the ``i``-th spawned child); the
        same ``rng`` gives the same fits whatever the executor. None draws fresh entropy;
        with ``checkpoint`` it is kept in the folder (``root-entropy.txt``), so that a
        re-run with ``rng=None`` resumes.
    on_error : {"raise", "store"}, default "raise"
        What to do when a fit raises: re-raise it (after saving the fits that finished), or
        record it in :attr:`FitManyResult.errors` and go on.
    **common
        Keyword arguments of :func:`mdft.fit` shared by every problem.

    Returns
    -------
    FitManyResult

    Examples
    --------
    >>> import mdft
    >>> fixed = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
    >>> problems = [dict(data=mdft.ChoiceData([[0, 1]], [[c, 100 - c]]), M=[[1, 3], [3, 1]])
    ...             for c in (30, 50, 70)]
    >>> done = []
    >>> many = mdft.fit_many(problems, stopping=20, params=["w"], fixed=fixed, rng=0,
    ...                      executor="serial", progress=lambda i, n, key, res: done.append(key))
    >>> sorted(done), many.n_converged
    ([0, 1, 2], 3)
    """
    items = _problem_list(problems)
    if on_error not in ("raise", "store"):
        raise ValueError(f"on_error must be 'raise' or 'store' (got {on_error!r})")
    if "rng" in common:  # pragma: no cover - rng is a named argument
        raise ValueError("rng is fit_many's own argument")
    if n_workers is not None:
        n_workers = as_count("n_workers", n_workers)
    _check_executor(executor)  # also where every fit is resumed and none runs
    if not (isinstance(progress, bool) or callable(progress)):
        raise TypeError(f"progress must be True, False or a callable (got {progress!r})")
    folder = None
    if checkpoint is not None:
        folder = Path(checkpoint)
        if folder.exists() and not folder.is_dir():
            raise ValueError(f"checkpoint must be a folder (got the file {folder})")
        folder.mkdir(parents=True, exist_ok=True)
    if isinstance(rng, np.random.SeedSequence):
        root = rng
    elif rng is None:
        # fresh entropy, kept in the checkpoint folder so that a re-run resumes
        root = np.random.SeedSequence(None if folder is None else _root_entropy(folder))
    else:
        root = np.random.SeedSequence(int(as_generator("rng", rng).integers(2**63)))
    seeds = tuple(int(c.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))
                  for c in root.spawn(len(items)))

    n = len(items)
    results = [None] * n
    errors = {}
    kwargs_list = [{**common, **prob} for _, prob in items]
    prints = []
    for (key, _), kw, seed in zip(items, kwargs_list, seeds):
        try:
            args = _fit_arguments(kw)
        except TypeError as exc:
            raise TypeError(
                f"problems[{key!r}] with the common keywords: {exc}; fit_many's own "
                "arguments are executor, n_workers, progress, checkpoint, rng and on_error, "
                "and every other keyword must be an argument of mdft.fit"
            ) from None
        prints.append(_fingerprint(args, seed))
    todo = []
    n_resumed = 0
    for i in range(n):
        path = folder / f"fit-{i:06d}.pkl" if folder is not None else None
        if path is not None and path.exists():
            results[i] = _load(path, prints[i])
            n_resumed += 1
        else:
            todo.append(i)

    bar = None
    if progress is True:
        try:
            from tqdm.auto import tqdm
        except ImportError as exc:  # pragma: no cover - tqdm is a dependency
            raise ImportError("progress=True needs tqdm (pip install tqdm)") from exc
        bar = tqdm(total=n, initial=n_resumed, desc="fits", unit="fit")
    n_done = n_resumed

    def save(i, res):
        _save(folder / f"fit-{i:06d}.pkl", {"version": _CHECKPOINT_VERSION,
                                            "fingerprint": prints[i], "key": items[i][0],
                                            "result": res})

    pool, owned, slots = (_resolve_executor(executor, n_workers) if todo
                          else (_Serial(), True, 1))
    waiting = iter(todo)
    running = {}  # at most `slots` fits submitted at a time: none waits in a queue

    def submit_more():
        for i in waiting:
            running[pool.submit(_fit_one, kwargs_list[i], seeds[i])] = i
            if len(running) >= slots:
                return

    try:
        submit_more()
        while running:
            done, _ = cf.wait(list(running), return_when=cf.FIRST_COMPLETED)
            for fut in done:
                i = running.pop(fut)
                key = items[i][0]
                try:
                    res = fut.result()
                except Exception as exc:
                    if on_error == "raise":
                        raise  # the fits still running are saved below
                    errors[key] = f"{type(exc).__name__}: {exc}"
                    res = None
                else:
                    results[i] = res
                    if folder is not None:
                        save(i, res)
                n_done += 1
                if bar is not None:
                    bar.update(1)
                elif callable(progress):
                    progress(n_done, n, key, res)
                logger.debug("fit %s done (%d of %d)", key, n_done, n)
            submit_more()
    finally:
        if bar is not None:
            bar.close()
        # stopped early (an interrupt or an error): no further fit is submitted, and those
        # already running (at most one per worker) finish and are saved, not thrown away
        if folder is not None and running:
            cf.wait(list(running))
            for fut, i in running.items():
                if results[i] is None and not fut.cancelled() and fut.exception() is None:
                    save(i, fut.result())
        if owned:
            pool.shutdown(wait=True, cancel_futures=True)
    for r in results:
        if r is not None and not isinstance(r, FitResult):  # pragma: no cover - defensive
            raise TypeError(f"a fit returned {type(r).__name__}, not a FitResult")
    return FitManyResult(keys=tuple(k for k, _ in items), results=tuple(results),
                         errors=errors, seeds=seeds, n_resumed=n_resumed,
                         checkpoint=None if folder is None else str(folder))
