"""Observed choices (and response times) on subsets of a common option set.

:class:`ChoiceData` is the data container of :func:`mdft.fit`: choice counts per offered
subset, optionally with the response time of every trial grouped by subset and chosen option.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import special

from ._validation import as_count, as_float_array

__all__ = ["ChoiceData"]

def _as_subset(name, value, n_options=None):
    arr = np.asarray(value)
    if arr.ndim != 1 or arr.size == 0 or arr.dtype.kind not in "iu":
        if arr.ndim == 1 and arr.dtype.kind == "f" and np.all(arr == np.round(arr)):
            arr = arr.astype(np.int64)
        else:
            raise TypeError(f"{name} must be a 1-d sequence of option indices (got {value!r})")
    arr = arr.astype(np.int64)
    if arr.size < 2:
        raise ValueError(f"{name} must hold at least two options (got {arr.tolist()})")
    if len(set(arr.tolist())) != arr.size:
        raise ValueError(f"{name} must hold distinct options (got {arr.tolist()})")
    if arr.min() < 0:
        raise ValueError(f"{name} must hold non-negative option indices (got {arr.tolist()})")
    if n_options is not None and arr.max() >= n_options:
        raise ValueError(
            f"{name} refers to option {arr.max()} but the option set has {n_options} options "
            f"(indices 0 to {n_options - 1})"
        )
    arr.flags.writeable = False
    return arr


#: Counts beyond this are not all whole numbers as floats (the likelihood's arithmetic).
MAX_COUNT = 2**53


def _as_counts(name, value, size):
    try:
        raw = np.asarray(value)
        arr = raw.astype(np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a sequence of counts (got {value!r})") from exc
    if raw.dtype == np.bool_:
        raise TypeError(f"{name} must hold counts (whole numbers), not booleans "
                        f"(got {raw.tolist()})")
    if arr.ndim != 1 or arr.size != size:
        raise ValueError(
            f"{name} must hold one count per option of its subset, length {size} "
            f"(got shape {arr.shape})"
        )
    if not np.all(np.isfinite(arr)) or np.any(arr < 0) or np.any(arr != np.round(arr)):
        raise ValueError(f"{name} must hold non-negative whole numbers (got {arr.tolist()})")
    if np.any(arr > MAX_COUNT) or sum(int(c) for c in arr) > MAX_COUNT:
        raise ValueError(f"{name} must hold counts that sum to at most 2**53 (got "
                         f"{arr.tolist()})")
    out = arr.astype(np.int64)
    if out.sum() == 0:
        raise ValueError(f"{name} sums to 0: every subset needs at least one observed choice")
    out.flags.writeable = False
    return out


@dataclass(frozen=True, init=False, eq=False)
class ChoiceData:
    """Observed choices on subsets of a common option set.

    Parameters
    ----------
    subsets : sequence of sequence of int
        ``subsets[k]`` lists the options (indices into the common option set, i.e. rows of
        ``M``) offered in choice set ``k``; at least two distinct options each.
    counts : sequence of sequence of int
        ``counts[k][i]`` is how often ``subsets[k][i]`` was chosen; same lengths as
        ``subsets``; non-negative, at least one choice per subset.
    n_options : int, optional
        Size of the common option set; by default one more than the largest index used.
    response_times : sequence, optional
        ``response_times[k][i]``: the response times of the ``counts[k][i]`` trials of
        subset ``k`` that chose ``subsets[k][i]`` (finite, >= 0). :func:`mdft.fit` with
        threshold stopping puts them in the likelihood; it reads them as decision steps
        (whole numbers >= 1) of the preference process.

    Attributes
    ----------
    subsets, counts : tuple of ndarray
        Read-only integer arrays.
    n_options : int
    response_times : tuple or None
        ``response_times[k][i]`` is the read-only array of response times of the trials of
        subset ``k`` that chose its ``i``-th option.

    Notes
    -----
    Two constructors: counts per subset (this constructor, or :meth:`from_shares` for
    proportions with a known number of trials) and one row per trial (:meth:`from_trials`).

    Examples
    --------
    >>> import mdft
    >>> data = mdft.ChoiceData([[0, 1], [0, 1, 2]], [[55, 45], [30, 28, 42]])
    >>> data.n_subsets, data.n_options, data.n_trials.tolist()
    (2, 3, [100, 100])
    >>> [s.round(2).tolist() for s in data.shares]
    [[0.55, 0.45], [0.3, 0.28, 0.42]]
    """

    subsets: tuple
    counts: tuple
    n_options: int
    response_times: tuple | None = field(default=None, repr=False)

    def __init__(self, subsets, counts, *, n_options=None, response_times=None):
        if isinstance(subsets, (str, bytes)) or not hasattr(subsets, "__len__"):
            raise TypeError(f"subsets must be a sequence of option subsets (got {subsets!r})")
        if len(subsets) == 0:
            raise ValueError("subsets is empty: ChoiceData needs at least one observed subset")
        if isinstance(counts, (str, bytes)) or not hasattr(counts, "__len__"):
            raise TypeError(f"counts must be a sequence of count vectors (got {counts!r})")
        if len(counts) != len(subsets):
            raise ValueError(
                f"counts must have one row per subset: got {len(counts)} rows of counts for "
                f"{len(subsets)} subsets"
            )
        if n_options is not None:
            n_options = as_count("n_options", n_options, low=2)
        subs = tuple(_as_subset(f"subsets[{k}]", s, n_options) for k, s in enumerate(subsets))
        cnts = tuple(_as_counts(f"counts[{k}]", c, s.size) for k, (s, c) in
                     enumerate(zip(subs, counts)))
        if n_options is None:
            n_options = int(max(s.max() for s in subs)) + 1
        object.__setattr__(self, "subsets", subs)
        object.__setattr__(self, "counts", cnts)
        object.__setattr__(self, "n_options", int(n_options))
        object.__setattr__(self, "response_times", _as_response_times(response_times, cnts))

    # ---------------------------------------------------------------- constructors
    @classmethod
    def from_counts(cls, subsets, counts, *, n_options=None) -> "ChoiceData":
        """Counts per subset; the same as the constructor.

        Examples
        --------
        >>> import mdft
        >>> mdft.ChoiceData.from_counts([[2, 0]], [[7, 3]]).n_options
        3
        """
        return cls(subsets, counts, n_options=n_options)

    @classmethod
    def from_shares(cls, subsets, shares, n_trials, *, n_options=None, atol=1e-6) -> "ChoiceData":
        """Choice proportions with a known number of trials per subset.

        Parameters
        ----------
        subsets : sequence of sequence of int
        shares : sequence of sequence of float
            Proportions per subset; each row sums to one.
        n_trials : int or sequence of int
            Trials per subset (one number for all, or one per subset). ``shares * n_trials``
            must be whole numbers (within ``atol * n_trials``).

        Examples
        --------
        >>> import mdft
        >>> d = mdft.ChoiceData.from_shares([[0, 1, 2]], [[0.25, 0.5, 0.25]], 1000)
        >>> d.counts[0].tolist()
        [250, 500, 250]
        """
        if isinstance(subsets, (str, bytes)) or not hasattr(subsets, "__len__"):
            raise TypeError(f"subsets must be a sequence of option subsets (got {subsets!r})")
        if hasattr(shares, "__len__") and len(shares) != len(subsets):
            raise ValueError(
                f"shares must have one row per subset: got {len(shares)} rows for "
                f"{len(subsets)} subsets"
            )
        n = np.atleast_1d(np.asarray(n_trials))
        if n.ndim != 1 or n.dtype.kind not in "iu" or np.any(n < 1):
            raise ValueError(f"n_trials must be a positive integer or one per subset (got {n_trials!r})")
        if n.size == 1:
            n = np.repeat(n, len(subsets))
        if n.size != len(subsets):
            raise ValueError(
                f"n_trials must be one number or one per subset ({len(subsets)}); got {n.size}"
            )
        counts = []
        for k, (row, nk) in enumerate(zip(shares, n)):
            r = as_float_array(f"shares[{k}]", row, ndim=1)
            if np.any(r < 0) or abs(r.sum() - 1.0) > 1e-6:
                raise ValueError(
                    f"shares[{k}] must be non-negative and sum to 1 (got sum {r.sum():.6g})"
                )
            c = r * nk
            if np.any(np.abs(c - np.round(c)) > atol * nk + 1e-9):
                raise ValueError(
                    f"shares[{k}] * n_trials is not a whole number of choices "
                    f"(got {c.tolist()}); check n_trials"
                )
            counts.append(np.round(c).astype(np.int64))
        return cls(subsets, counts, n_options=n_options)

    @classmethod
    def from_trials(cls, subsets, choices, response_times=None, *, n_options=None) -> "ChoiceData":
        """One row per trial: the subset offered, the option chosen, optionally the time.

        Trials are grouped by the set of options offered (order does not matter).

        Parameters
        ----------
        subsets : sequence of sequence of int
            ``subsets[t]``: options offered on trial ``t`` (indices into the option set).
        choices : sequence of int
            ``choices[t]``: the option chosen on trial ``t``, an index into the option set
            that must be one of ``subsets[t]``.
        response_times : sequence of float, optional
            ``response_times[t]``: the response time of trial ``t`` (finite, >= 0), kept in
            :attr:`response_times`. With threshold stopping :func:`mdft.fit` reads them as
            decision steps (whole numbers >= 1) and fits choices and times jointly.

        Examples
        --------
        >>> import mdft
        >>> d = mdft.ChoiceData.from_trials([[0, 1], [1, 0], [0, 1, 2]], [1, 1, 2],
        ...                                 response_times=[12, 30, 21])
        >>> [s.tolist() for s in d.subsets], [c.tolist() for c in d.counts]
        ([[0, 1], [0, 1, 2]], [[0, 2], [0, 0, 1]])
        >>> d.mean_response_times[0].tolist()
        [nan, 21.0]
        """
        if isinstance(subsets, (str, bytes)) or not hasattr(subsets, "__len__"):
            raise TypeError(f"subsets must be a sequence with one subset per trial (got {subsets!r})")
        choices_arr = np.asarray(choices)
        if choices_arr.ndim != 1 or (choices_arr.size and choices_arr.dtype.kind not in "iu"):
            raise TypeError(f"choices must be a 1-d sequence of option indices (got {choices!r})")
        if len(subsets) == 0:
            raise ValueError("no trials: subsets and choices are empty")
        if choices_arr.size != len(subsets):
            raise ValueError(
                f"choices must have one entry per trial: got {choices_arr.size} choices for "
                f"{len(subsets)} trials"
            )
        rts = None
        if response_times is not None:
            rts = as_float_array("response_times", response_times, ndim=1)
            if rts.size != len(subsets):
                raise ValueError(
                    f"response_times must have one entry per trial: got {rts.size} for "
                    f"{len(subsets)} trials"
                )
            if np.any(rts < 0):
                raise ValueError("response_times must be >= 0")
        groups: dict[tuple, list[int]] = {}
        for t, s in enumerate(subsets):
            sub = _as_subset(f"subsets[{t}]", s, n_options)
            c = int(choices_arr[t])
            if c not in sub.tolist():
                raise ValueError(
                    f"choices[{t}] = {c} is not one of the options offered on that trial "
                    f"({sub.tolist()})"
                )
            groups.setdefault(tuple(sorted(sub.tolist())), []).append(t)
        out_subsets, out_counts, out_rts = [], [], []
        for key, trials in groups.items():
            sub = list(key)
            ch = choices_arr[trials]
            out_subsets.append(sub)
            out_counts.append([int(np.sum(ch == o)) for o in sub])
            if rts is not None:
                times = rts[trials]
                per = []
                for o in sub:
                    a = times[ch == o].copy()
                    a.flags.writeable = False
                    per.append(a)
                out_rts.append(tuple(per))
        return cls(out_subsets, out_counts, n_options=n_options,
                   response_times=tuple(out_rts) if rts is not None else None)

    # ---------------------------------------------------------------- summaries
    @property
    def n_subsets(self) -> int:
        """Number of subsets."""
        return len(self.subsets)

    @property
    def n_trials(self) -> np.ndarray:
        """Trials per subset, shape (n_subsets,)."""
        return np.array([c.sum() for c in self.counts])

    @property
    def shares(self) -> tuple:
        """Observed choice proportions per subset."""
        return tuple(c / c.sum() for c in self.counts)

    @property
    def mean_response_times(self) -> tuple | None:
        """Mean response time per option of each subset (NaN where never chosen), or None."""
        if self.response_times is None:
            return None
        return tuple(
            np.array([a.mean() if a.size else np.nan for a in per]) for per in self.response_times
        )

    @property
    def has_response_times(self) -> bool:
        """Whether every trial carries a response time."""
        return self.response_times is not None

    def log_multinomial_coefficient(self) -> float:
        """``sum_k log(n_k! / prod_i c_ki!)``, the data-only term of the log-likelihood."""
        total = 0.0
        for c in self.counts:
            total += special.gammaln(c.sum() + 1.0) - special.gammaln(c + 1.0).sum()
        return float(total)




def _as_response_times(value, counts):
    """Validate ``response_times[k][i]`` against the counts; read-only float arrays."""
    if value is None:
        return None
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
        raise TypeError(
            f"response_times must be a sequence with one entry per subset (got {value!r})"
        )
    if len(value) != len(counts):
        raise ValueError(
            f"response_times must have one entry per subset: got {len(value)} for "
            f"{len(counts)} subsets"
        )
    out = []
    for k, (per, c) in enumerate(zip(value, counts)):
        if isinstance(per, (str, bytes)) or not hasattr(per, "__len__") or len(per) != c.size:
            raise ValueError(
                f"response_times[{k}] must hold one array per option of subset {k} "
                f"({c.size} options)"
            )
        row = []
        for i, times in enumerate(per):
            a = np.array(as_float_array(f"response_times[{k}][{i}]", times), dtype=np.float64)
            a = a.reshape(-1) if a.ndim == 0 else a
            if a.ndim != 1 or a.size != c[i]:
                raise ValueError(
                    f"response_times[{k}][{i}] must hold one time per trial that chose the "
                    f"option, {int(c[i])} (got shape {a.shape})"
                )
            if np.any(a < 0):
                raise ValueError(
                    f"response_times[{k}][{i}] must be >= 0 (got minimum {a.min():g})"
                )
            a.flags.writeable = False
            row.append(a)
        out.append(tuple(row))
    return tuple(out)
