"""Saving and loading: MESC-IRL results (JSON), MDPs (NPZ), demonstrations (JSON) and the paper's data.

Nothing here uses pickle: JSON files hold lists and numbers, NPZ files hold
plain numeric and string arrays and are read with ``allow_pickle=False``.
The paper's small data files ship with the package (``irl/data``, MIT licence).
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import zipfile
import zlib
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from .demonstrations import Demonstrations
from .gridworld import GridWorld
from .mdp import MDP, TransitionFeatures
from ._typing import PathLike

if TYPE_CHECKING:
    from .mesc_result import MESCResult

__all__ = [
    "load_paper_worlds",
    "load_paper_demonstrations",
    "save_mesc_result",
    "load_mesc_result",
    "save_mdp",
    "load_mdp",
    "save_demonstrations",
    "load_demonstrations",
]

def _write_atomically(path, write) -> None:
    """Write a file through ``write(binary_file)`` so that it appears whole or not at all.

    The data go to a temporary file beside ``path`` that replaces ``path`` only once it is
    complete: an interrupted save never leaves a truncated file, nor destroys an older one.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


_PAPER_FILES = {"scobee_example": "scobee_example_data.json", "random_10": "random_data_10.json"}
_RESULT_FORMAT = "pymdft.mesc_result"


#: What a damaged or foreign file can raise while it is parsed; each becomes a ValueError
#: that names the file.
_PARSE_ERRORS = (KeyError, IndexError, AttributeError, TypeError, ValueError, EOFError,
                 OverflowError, RecursionError, zipfile.BadZipFile, zlib.error)


@contextlib.contextmanager
def _reading(path, what):
    """Turn any parsing failure inside the block into a ValueError naming the file."""
    try:
        yield
    except _PARSE_ERRORS as exc:
        if isinstance(exc, KeyError):
            reason = f"the field {exc.args[0]!r} is missing"
        elif isinstance(exc, RecursionError):
            reason = "its JSON is nested too deeply"
        else:
            reason = str(exc) or type(exc).__name__
        raise ValueError(f"file {str(path)!r} does not hold {what}: {reason}") from None


def _check_path(path) -> Path:
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path must be a str or os.PathLike (got {type(path).__name__})")
    return Path(path)


def _read_json(path, kind, what):
    path = _check_path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{kind} file not found: {path}")
    with _reading(path, what):
        return json.loads(path.read_bytes())


def _packaged(name):
    return resources.files("irl").joinpath("data", name)


def load_paper_worlds(name: str = "scobee_example", *, path: PathLike | None = None,
                      **world_kwargs: Any) -> list[GridWorld]:
    """The paper's gridworlds as :class:`~irl.GridWorld` objects.

    Parameters
    ----------
    name : {"scobee_example", "random_10"}
        The Figure 1 world (one world) or the 10 random worlds.
    path : str or Path, optional
        Read this JSON file (same format) instead of the packaged copy.
    **world_kwargs
        Fields for every world, e.g. ``p_slip=0.0``.

    Returns
    -------
    list of GridWorld

    Examples
    --------
    >>> world = load_paper_worlds()[0]
    >>> world.constrained_states, world.constrained_actions, world.constrained_colours
    ((31, 39, 41, 47, 51), (4, 5), (1, 2))
    >>> len(load_paper_worlds("random_10"))
    10
    """
    if path is None:
        if not isinstance(name, str) or name not in _PAPER_FILES:
            raise ValueError(f"name must be one of {sorted(_PAPER_FILES)} (got {name!r})")
        entries = json.loads(_packaged(_PAPER_FILES[name]).read_text())
    else:
        entries = _read_json(path, "world", "valid worlds")
    if isinstance(entries, dict):
        entries = [entries]
    if path is None:
        return [GridWorld.from_dict(e, **world_kwargs) for e in entries]
    if not isinstance(entries, list):
        raise ValueError(f"world file {str(path)!r} must hold a JSON object or a list of them "
                         f"(got {type(entries).__name__})")
    worlds = []
    for k, entry in enumerate(entries):
        if not isinstance(entry, dict):
            raise ValueError(f"world file {str(path)!r}: entry {k} must be a JSON object "
                             f"(got {type(entry).__name__})")
        with _reading(path, "valid worlds"):
            worlds.append(GridWorld.from_dict(entry, **world_kwargs))
    return worlds


def load_paper_demonstrations(*, path: PathLike | None = None) -> list[Demonstrations]:
    """The paper's demonstration sets in the Figure 1 world (10 sets of 100 trajectories).

    Parameters
    ----------
    path : str or Path, optional
        Read this JSON file instead of the packaged copy.

    Returns
    -------
    list of Demonstrations

    Examples
    --------
    >>> sets = load_paper_demonstrations()
    >>> len(sets), len(sets[0]), sets[0].trajectory(0)[0][:3]
    (10, 100, [0, 9, 18])
    """
    data = (
        json.loads(_packaged("scobee_example_trajectories.json").read_text())
        if path is None
        else _read_json(path, "demonstrations", "valid demonstrations")
    )
    out = []
    with _reading("packaged" if path is None else path, "valid demonstrations"):
        if not isinstance(data, list):
            raise TypeError(f"the file must hold a list of games (got {type(data).__name__})")
        for game in data:
            for t in game["trajs"]:
                out.append(Demonstrations.from_sequences(t["state_seq"], t["action_seq"]))
    return out


# ------------------------------------------------------------------ results
def save_mesc_result(result: MESCResult, path: PathLike) -> None:
    """Write a :class:`~irl.mesc_result.MESCResult` to JSON (penalties, names and diagnostics).

    The MDPs are not written; :func:`load_mesc_result` takes the nominal MDP.
    """
    from .mesc_result import MESCResult

    if not isinstance(result, MESCResult):
        raise TypeError(f"result must be a MESCResult (got {type(result).__name__})")
    doc = {
        "format": _RESULT_FORMAT,
        "version": 1,
        "feature_names": list(result.feature_names),
        "penalties": result.penalties.tolist(),
        "gradient": [None if not np.isfinite(g) else float(g) for g in result.gradient],
        "objective": None if not np.isfinite(result.objective) else float(result.objective),
        "horizon": result.horizon,
        "n_demonstrations": result.n_demonstrations,
        "n_iter": result.n_iter,
        "n_evaluations": result.n_evaluations,
        "converged": result.converged,
        "message": result.message,
        "selection": result.selection,
        "evidence": None if result.evidence is None else result.evidence.tolist(),
        "evidence_cost": result.evidence_cost,
    }
    _write_atomically(path, lambda fh: fh.write(json.dumps(doc, indent=1).encode()))


def load_mesc_result(path: PathLike, nominal: MDP) -> MESCResult:
    """Read a result written by :func:`save_mesc_result` and rebuild it on ``nominal``.

    Raises ValueError when the file's features do not match ``nominal.features``.

    Examples
    --------
    >>> import tempfile, os
    >>> from irl import GridWorld, MESCResult
    >>> world = GridWorld(4, 0, 15, constrained_states=[5])
    >>> res = MESCResult.from_penalties(world.nominal_mdp, world.true_penalties)
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     res.save(os.path.join(tmp, "r.json"))
    ...     back = load_mesc_result(os.path.join(tmp, "r.json"), world.nominal_mdp)
    >>> bool((back.penalties == res.penalties).all())
    True
    """
    from .mesc_result import MESCResult

    doc = _read_json(path, "result", "a valid MESC-IRL result")
    if not isinstance(doc, dict) or doc.get("format") != _RESULT_FORMAT:
        found = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise ValueError(f"{path} is not a MESC-IRL result file (format {found!r})")
    if not isinstance(nominal, MDP) or nominal.features is None:
        raise TypeError("nominal must be an irl.MDP with features")
    with _reading(path, "a valid MESC-IRL result"):
        return _result_from_doc(doc, path, nominal, MESCResult)


def _result_from_doc(doc, path, nominal, MESCResult):
    names = tuple(doc["feature_names"])
    if names != tuple(nominal.features.names):
        raise ValueError(
            f"the result in {path} was learned on {len(names)} features that do not match the "
            f"{nominal.n_features} features of nominal"
        )
    grad = np.array([np.nan if g is None else g for g in doc["gradient"]], dtype=float)
    return MESCResult.from_penalties(
        nominal, np.asarray(doc["penalties"], dtype=float),
        objective=float("nan") if doc["objective"] is None else doc["objective"], gradient=grad,
        horizon=int(doc["horizon"]), n_demonstrations=int(doc["n_demonstrations"]), n_iter=int(doc["n_iter"]),
        n_evaluations=int(doc["n_evaluations"]), converged=bool(doc["converged"]), message=str(doc["message"]),
        selection=str(doc.get("selection", "none")), evidence=doc.get("evidence"), evidence_cost=doc.get("evidence_cost"),
    )


# ---------------------------------------------------------------------- MDPs
def save_mdp(mdp: MDP, path: PathLike) -> None:
    """Write an MDP (arrays and features) to an NPZ file.

    Examples
    --------
    >>> import tempfile, os
    >>> from irl import GridWorld
    >>> mdp = GridWorld(3, 0, 8).constrained_mdp
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     save_mdp(mdp, os.path.join(tmp, "m.npz"))
    ...     back = load_mdp(os.path.join(tmp, "m.npz"))
    >>> bool((back.rewards == mdp.rewards).all()), back.features.names[0]
    (True, 'state 0')
    """
    if not isinstance(mdp, MDP):
        raise TypeError(f"mdp must be an irl.MDP (got {type(mdp).__name__})")
    arrays = dict(
        next_states=mdp.next_states, probs=mdp.probs, rewards=mdp.rewards, terminal=mdp.terminal,
        start=mdp.start, discount=np.array(mdp.discount),
    )
    f = mdp.features
    if f is not None:
        arrays["feature_names"] = np.array(f.names, dtype=str)
        arrays["feature_sizes"] = np.array([f.n_states, f.n_actions, f.n_features])
        for key in ("source", "action", "destination"):
            m = getattr(f, key)
            arrays[f"{key}_data"], arrays[f"{key}_indices"], arrays[f"{key}_indptr"] = m.data, m.indices, m.indptr
    _write_atomically(path, lambda fh: np.savez_compressed(fh, **arrays))


def load_mdp(path: PathLike) -> MDP:
    """Read an MDP written by :func:`save_mdp` (example there); no pickle is involved."""
    path = _check_path(path)
    if not path.is_file():
        raise FileNotFoundError(f"MDP file not found: {path}")
    with _reading(path, "a valid MDP"), np.load(path, allow_pickle=False) as z:
        feats = None
        if "feature_sizes" in z:
            n_s, n_a, n_f = (int(v) for v in z["feature_sizes"])
            rows = {"source": n_s, "action": n_a, "destination": n_s}
            blocks = {
                key: sp.csr_array((z[f"{key}_data"], z[f"{key}_indices"], z[f"{key}_indptr"]), shape=(rows[key], n_f))
                for key in rows
            }
            feats = TransitionFeatures(**blocks, names=[str(x) for x in z["feature_names"]], n_features=n_f)
        return MDP(
            z["next_states"], z["probs"], z["rewards"], terminal=z["terminal"], start=z["start"],
            discount=float(z["discount"]), features=feats,
        )


# ------------------------------------------------------------ demonstrations
def save_demonstrations(demonstrations: Demonstrations, path: PathLike) -> None:
    """Write demonstrations to JSON in the paper's format (``state_seq``, ``action_seq``).

    Examples
    --------
    >>> import tempfile, os
    >>> d = Demonstrations.from_sequences([[0, 1, 2]], [[1, 1]])
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     save_demonstrations(d, os.path.join(tmp, "d.json"))
    ...     load_demonstrations(os.path.join(tmp, "d.json")).trajectory(0)
    ([0, 1, 2], [1, 1])
    """
    if not isinstance(demonstrations, Demonstrations):
        raise TypeError(f"demonstrations must be an irl.Demonstrations (got {type(demonstrations).__name__})")
    doc = demonstrations.to_dict()
    if demonstrations.reached_terminal is not None:
        doc["reached_terminal"] = demonstrations.reached_terminal.tolist()
    _write_atomically(path, lambda fh: fh.write(json.dumps(doc).encode()))


def load_demonstrations(path: PathLike) -> Demonstrations:
    """Read demonstrations written by :func:`save_demonstrations` (example there)."""
    doc = _read_json(path, "demonstrations", "valid demonstrations")
    with _reading(path, "valid demonstrations"):
        if not isinstance(doc, dict):
            raise TypeError(f"it must hold a JSON object (got {type(doc).__name__})")
        d = Demonstrations.from_sequences(doc["state_seq"], doc["action_seq"])
        if "reached_terminal" in doc:
            d = Demonstrations(d.offsets, d.states, d.actions, d.next_states,
                               doc["reached_terminal"])
    return d
