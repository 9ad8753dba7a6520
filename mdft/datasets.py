"""Loaders for the MDFT data sets of Rahgooy's thesis on learning MDFT parameters.

The data sets ship with the package (``mdft/data/thesis``, MIT licence, see the ``README.md``
and ``LICENSE`` there): :func:`thesis_sets` lists them, and :func:`load_thesis_set` and
:func:`load_sushi` take a bundled set's name or the path of a file. The thesis's conventions
differ from pymdft's in one place, mapped here once:

* the thesis scales the valence noise by ``sig2`` as a *standard deviation*
  (``E = sig2 * C @ randn``), pymdft's ``sigma2`` is a *variance*: ``sigma2 = sig2**2``;
* ``b`` is Hotaling's ``beta``; ``S = I - phi2 exp(-phi1 D**2)`` as in pymdft;
* ``threshold`` is the number of time steps for the fixed-time (``time_based``) sets and
  the preference threshold for the ``pref_based`` sets (a trial stops when the largest
  preference reaches it);
* ``idx`` holds 1-based option indices in the ``.mat`` files and 0-based ones in
  ``sushi.json``; both become 0-based here;
* ``D`` holds choice proportions of 10,000 simulated trials per subset in the ``.mat`` files
  and of the 5,000 respondents of the SUSHI survey in ``sushi.json``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._validation import MAX_SAMPLES, as_count
from .choice_data import ChoiceData

__all__ = ["SushiData", "ThesisProblem", "load_sushi", "load_thesis_set", "thesis_sets"]

#: Folder of the bundled thesis data sets.
THESIS_DATA = Path(__file__).resolve().parent / "data" / "thesis"
_KINDS = ("time_based", "pref_based")


@dataclass(frozen=True, eq=False)
class ThesisProblem:
    """One problem of a thesis data set, with its true parameters and observed shares.

    Attributes
    ----------
    M : ndarray, shape (n_options, 2)
        Evaluations of the whole option set.
    w : ndarray, shape (2,)
        True attention weights.
    phi1, phi2, beta : float
        True feedback parameters (``beta`` is the thesis's ``b``).
    sigma2 : float
        True noise variance in pymdft's convention, ``sig2**2``.
    sig2 : float
        The thesis's noise parameter (a standard deviation).
    time_based : bool
        True for fixed deliberation time, False for threshold stopping.
    n_steps : int or None
        Deliberation time (``time_based``).
    theta : float or None
        Preference threshold (``pref_based``).
    data : ChoiceData
        Counts on the option subsets (0-based indices).
    index : int
        Position of the problem in its file.
    """

    M: np.ndarray
    w: np.ndarray
    phi1: float
    phi2: float
    beta: float
    sigma2: float
    sig2: float
    time_based: bool
    n_steps: int | None
    theta: float | None
    data: ChoiceData
    index: int

    @property
    def true_params(self) -> dict:
        """The true ``w``, ``phi1``, ``phi2``, ``beta``, ``sigma2`` as a dict."""
        return dict(w=self.w, phi1=self.phi1, phi2=self.phi2, beta=self.beta,
                    sigma2=self.sigma2)

    @property
    def stopping(self):
        """``mdft.FixedTime(n_steps)`` or ``mdft.Threshold(theta)`` (or ``n_steps`` if the
        stopping classes are not available)."""
        import mdft

        if self.time_based:
            return mdft.FixedTime(self.n_steps) if hasattr(mdft, "FixedTime") else self.n_steps
        return mdft.Threshold(self.theta)


@dataclass(frozen=True, eq=False)
class SushiData:
    """The SUSHI-derived set: ten sushi on two attributes, training and held-out triples.

    Attributes
    ----------
    M : ndarray, shape (10, 2)
    params : dict
        The parameters stored with the set (``w``, ``phi1``, ``phi2``, ``beta``,
        ``sigma2 = sig2**2``, ``theta``).
    train, test : ChoiceData
        Training triples and held-out triples.
    """

    M: np.ndarray
    params: dict
    train: ChoiceData
    test: ChoiceData


def _readonly(a):
    a = np.array(a, dtype=np.float64)
    a.flags.writeable = False
    return a


def thesis_sets(kind=None) -> tuple[str, ...]:
    """Names of the bundled thesis data sets, such as ``"time_based/set_nopts3_ncomb1_nproblem50_no3"``.

    Parameters
    ----------
    kind : {"time_based", "pref_based"}, optional
        Only the fixed-time sets or only the threshold sets; both by default.

    Returns
    -------
    tuple of str
        ``"<kind>/<file name without .mat>"``, sorted; each is accepted by
        :func:`load_thesis_set`.

    Examples
    --------
    >>> import mdft.datasets as ds
    >>> len(ds.thesis_sets()), len(ds.thesis_sets("time_based"))
    (20, 10)
    >>> ds.thesis_sets("time_based")[0]
    'time_based/set_nopts10_ncomb10_nproblem50_no3'
    """
    if kind is None:
        kinds: tuple[str, ...] = _KINDS
    elif isinstance(kind, str) and kind in _KINDS:
        kinds = (kind,)
    else:
        raise ValueError(f"kind must be one of {_KINDS} or None (got {kind!r})")
    return tuple(
        f"{k}/{f.stem}" for k in kinds for f in sorted((THESIS_DATA / k).glob("*.mat"))
    )


def _path(path, suffix):
    if not isinstance(path, (str, Path)):
        raise TypeError(f"path must be a str or pathlib.Path (got {type(path).__name__})")
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"path must be an existing {suffix} file (got {str(path)!r})")
    return p


def _bundled_or_path(name_or_path):
    """The bundled set called ``name_or_path`` (with or without ``.mat``), else the path."""
    if isinstance(name_or_path, str):
        name = name_or_path.removesuffix(".mat")
        if name in thesis_sets():
            return THESIS_DATA / f"{name}.mat"
    return _path(name_or_path, ".mat")


def load_thesis_set(path, *, n_trials=10_000) -> list[ThesisProblem]:
    """Load one ``.mat`` data set of the thesis (50 problems).

    Parameters
    ----------
    path : str or Path
        The name of a bundled set (:func:`thesis_sets`), such as
        ``"time_based/set_nopts3_ncomb1_nproblem50_no3"``, or the path of a file in the
        thesis's format.
    n_trials : int, default 10000
        Simulated trials per subset behind the stored proportions (10,000 in the thesis's
        generator); the proportions are turned into counts with it.

    Returns
    -------
    list of ThesisProblem

    Examples
    --------
    >>> import mdft.datasets as ds
    >>> problems = ds.load_thesis_set("time_based/set_nopts3_ncomb1_nproblem50_no3")
    >>> len(problems), problems[0].n_steps, problems[0].data.n_subsets
    (50, 25, 1)
    """
    from scipy.io import loadmat

    p = _bundled_or_path(path)
    n_trials = as_count("n_trials", n_trials, high=MAX_SAMPLES)
    try:
        raw = loadmat(p, squeeze_me=True, struct_as_record=False)
    except Exception as exc:  # scipy raises many types on a file that is not MATLAB data
        raise ValueError(f"path {str(p)!r} is not a readable .mat file ({exc})") from None
    if "dataset" not in raw:
        raise ValueError(f"{p.name} has no 'dataset' variable; not a thesis data set")
    try:
        return _thesis_problems(raw["dataset"], n_trials)
    except (TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{p.name} is not a valid thesis data set: {exc}") from None


def _thesis_problems(dataset, n_trials):
    problems = []
    for k, rec in enumerate(np.atleast_1d(dataset)):
        idx = np.atleast_2d(np.asarray(rec.idx, dtype=np.int64)) - 1
        shares = np.atleast_2d(np.asarray(rec.D, dtype=np.float64))
        time_based = not bool(rec.pref_based)
        M = _readonly(rec.M)
        data = ChoiceData.from_shares(idx, shares, n_trials, n_options=M.shape[0])
        problems.append(ThesisProblem(
            M=M,
            w=_readonly(np.ravel(rec.w)),
            phi1=float(rec.phi1),
            phi2=float(rec.phi2),
            beta=float(rec.b),
            sigma2=float(rec.sig2) ** 2,
            sig2=float(rec.sig2),
            time_based=time_based,
            n_steps=int(rec.threshold) if time_based else None,
            theta=None if time_based else float(rec.threshold),
            data=data,
            index=k,
        ))
    return problems


def load_sushi(path=None, *, n_trials=5000) -> SushiData:
    """Load ``sushi.json``: 10 sushi, training triples and held-out triples.

    Parameters
    ----------
    path : str or Path, optional
        A file in the format of ``sushi.json``; the bundled one by default.
    n_trials : int, default 5000
        Respondents per triple (the SUSHI survey's 5,000 people).

    Returns
    -------
    SushiData

    Examples
    --------
    >>> import mdft.datasets as ds
    >>> s = ds.load_sushi()
    >>> s.M.shape, s.train.n_subsets, s.test.n_subsets
    ((10, 2), 10, 5)
    """
    p = THESIS_DATA / "pref_based" / "sushi.json" if path is None else _path(path, ".json")
    n_trials = as_count("n_trials", n_trials, high=MAX_SAMPLES)
    try:
        raw = json.loads(p.read_bytes())
    except (ValueError, RecursionError) as exc:  # JSONDecodeError and UnicodeDecodeError
        raise ValueError(f"path {str(p)!r} is not a readable JSON file ({exc})") from None
    if isinstance(raw, list):
        if len(raw) != 1:
            raise ValueError(f"{p.name} must hold one data set (got {len(raw)})")
        raw = raw[0]
    if not isinstance(raw, dict):
        raise ValueError(f"{p.name} must hold a JSON object (got {type(raw).__name__})")
    for key in ("M", "idx", "D", "test_idx", "test_D", "w", "phi1", "phi2", "b", "sig2",
                "threshold"):
        if key not in raw:
            raise ValueError(f"{p.name} lacks the field {key!r}; not the SUSHI data set")
    try:
        return _sushi(raw, n_trials)
    except (TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{p.name} is not a valid SUSHI data set: {exc}") from None


def _sushi(raw, n_trials):
    M = _readonly(raw["M"])
    params = dict(
        w=_readonly(np.ravel(raw["w"])),
        phi1=float(raw["phi1"]),
        phi2=float(raw["phi2"]),
        beta=float(raw["b"]),
        sigma2=float(raw["sig2"]) ** 2,
        theta=float(raw["threshold"]),
    )
    train = ChoiceData.from_shares(raw["idx"], raw["D"], n_trials, n_options=M.shape[0])
    test = ChoiceData.from_shares(raw["test_idx"], raw["test_D"], n_trials,
                                  n_options=M.shape[0])
    return SushiData(M=M, params=params, train=train, test=test)
