"""The MDFT model: evaluations, attention, contrast and feedback matrices.

Conventions (Roe, Busemeyer & Townsend 2001; Hotaling, Busemeyer & Li 2010),
stated once here and in ``docs/concepts.md``:

* ``M[option, attribute]``: option ``i``'s evaluation on attribute ``j``.
* ``w[attribute]``: attention weights; at each step exactly one attribute is
  attended, attribute ``j`` with probability ``w[j]``.
* ``C``: contrast, ``c_ii = 1``, ``c_ij = -1/(n-1)``.
* Valence ``V(t) = C (M W(t) + eps(t))`` with ``eps(t) ~ N(0, sigma2 I)``.
* Preference ``P(t+1) = S P(t) + V(t+1)``, ``P(0) = P0``.
* Hotaling distance ``D_ij = |d|^2 + (beta - 1) (u.d)^2`` with ``d = M_i - M_j``
  and ``u`` the unit vector along the dominance direction (all ones / sqrt(J)).
* Feedback ``S = I - phi2 * exp(-phi1 * D**2)``.
"""

from __future__ import annotations

import math
import os
import warnings
from typing import Any, Mapping, Sequence

import numpy as np

from ._typing import ArrayLike
from ._export import builtin, fmt, labels_for, table, to_json
from ._validation import MAX_OPTIONS, as_attention, as_count, as_float_array, as_scalar

__all__ = [
    "GROWTH_LIMIT",
    "REFERENCE_STEPS",
    "MDFTModel",
    "UnstableFeedbackWarning",
    "contrast_matrix",
    "distance_matrix",
    "feedback_matrix",
]


#: Growth of preferences, ``rho(S) ** n_steps``, past which an
#: :class:`UnstableFeedbackWarning` is issued (``docs/concepts.md``, section 4).
GROWTH_LIMIT = 10.0

#: Deliberation length assumed where no horizon is known (when a model is built):
#: the fixed time of the paper's orchestrator and the order of the canonical
#: threshold's response times. A model warns when ``rho(S) ** 100 > 10``, i.e.
#: ``rho(S) > 1.0233``.
REFERENCE_STEPS = 100


class UnstableFeedbackWarning(RuntimeWarning):
    """Preferences can grow by a meaningful factor over the deliberation.

    Issued when ``rho(S) ** n_steps > GROWTH_LIMIT`` (10): by
    :class:`MDFTModel` for the reference horizon of ``REFERENCE_STEPS`` (100)
    steps, and by the fixed-time computations (:func:`mdft.simulate` with
    :class:`mdft.FixedTime`, :func:`mdft.choice_probabilities`) for their own
    ``n_steps``. A spectral radius at or barely above 1 (rounding, or the
    canonical compromise set's 1.009) is not flagged.
    """


def growth_factor(spectral_radius: float, n_steps: int) -> float:
    """``rho(S) ** n_steps``: how much preferences can grow over ``n_steps`` steps (inf on overflow)."""
    if spectral_radius <= 1.0:
        return spectral_radius**n_steps
    exponent = n_steps * math.log(spectral_radius)
    return math.exp(exponent) if exponent < 700.0 else math.inf


def warn_if_growing(spectral_radius: float, n_steps: int | None = None, *, stacklevel=3) -> None:
    """Issue :class:`UnstableFeedbackWarning` where ``rho(S) ** n_steps > GROWTH_LIMIT``.

    ``n_steps=None`` means no horizon is known: :data:`REFERENCE_STEPS` is used.
    """
    horizon = REFERENCE_STEPS if n_steps is None else n_steps
    growth = growth_factor(spectral_radius, horizon)
    if growth <= GROWTH_LIMIT:
        return
    where = (f"a deliberation of {horizon} steps (the reference length)" if n_steps is None
             else f"n_steps={horizon} steps")
    warnings.warn(
        f"the feedback matrix S has spectral radius {spectral_radius:.6g}: preferences can grow "
        f"by a factor of up to {growth:.3g} over {where}, more than {GROWTH_LIMIT:g}; lower phi2 "
        "or raise phi1 for a stable model",
        UnstableFeedbackWarning,
        stacklevel=stacklevel + 1,
    )


def contrast_matrix(n_options: int) -> np.ndarray:
    """Return the MDFT contrast matrix ``C`` for ``n_options`` options.

    Parameters
    ----------
    n_options : int
        Number of options, at least 2 and at most 1,000 (``MAX_OPTIONS``).

    Returns
    -------
    C : ndarray, shape (n_options, n_options)
        ``C[i, i] = 1`` and ``C[i, j] = -1 / (n_options - 1)``: each option is
        compared with the mean of its rivals. Every column sums to zero.

    Examples
    --------
    >>> contrast_matrix(3)
    array([[ 1. , -0.5, -0.5],
           [-0.5,  1. , -0.5],
           [-0.5, -0.5,  1. ]])
    """
    if isinstance(n_options, bool) or not isinstance(n_options, (int, np.integer)):
        raise TypeError(f"n_options must be an integer (got {n_options!r})")
    if n_options < 2:
        raise ValueError(f"n_options must be >= 2 (got {n_options}); MDFT compares options")
    n_options = as_count("n_options", n_options, low=2, high=MAX_OPTIONS)
    C = np.full((n_options, n_options), -1.0 / (n_options - 1))
    np.fill_diagonal(C, 1.0)
    return C


def distance_matrix(M: ArrayLike, *, beta: float) -> np.ndarray:
    """Return Hotaling's squared distance between every pair of options.

    Parameters
    ----------
    M : array_like, shape (n_options, n_attributes)
        Evaluations.
    beta : float
        Weight of the dominance dimension, ``beta >= 0``.

    Returns
    -------
    D : ndarray, shape (n_options, n_options)
        ``D[i, j] = |d|^2 + (beta - 1) (u.d)^2`` with ``d = M[i] - M[j]`` and
        ``u = (1, ..., 1) / sqrt(n_attributes)``. For two attributes this is
        ``dI**2 + beta * dD**2`` with the indifference and dominance
        coordinates ``dI = (d2 - d1)/sqrt(2)`` and ``dD = (d1 + d2)/sqrt(2)``.

    Examples
    --------
    >>> distance_matrix([[1.0, 3.0], [3.0, 1.0]], beta=12.0)
    array([[0., 8.],
           [8., 0.]])
    """
    M = as_float_array("M", M, ndim=2)
    beta = as_scalar("beta", beta, low=0.0)
    if M.shape[1] < 1:
        raise ValueError(f"M must have at least 1 attribute (column) (got shape {M.shape})")
    if M.shape[0] > MAX_OPTIONS:
        raise ValueError(f"M must have at most {MAX_OPTIONS:,} options (rows) (got {M.shape[0]:,})")
    with np.errstate(over="ignore", invalid="ignore"):
        diff = M[:, None, :] - M[None, :, :]
        along = diff.sum(axis=2) ** 2 / M.shape[1]
        D = (diff**2).sum(axis=2) + (beta - 1.0) * along
    if not np.all(np.isfinite(D)):
        raise ValueError(
            f"M and beta={beta:g} give distances between options too large for floating point "
            f"(largest |M| = {np.abs(M).max():.3g}); rescale M or lower beta"
        )
    return D


def feedback_matrix(D: ArrayLike, *, phi1: float, phi2: float) -> np.ndarray:
    """Return the feedback matrix ``S = I - phi2 * exp(-phi1 * D**2)``.

    Parameters
    ----------
    D : array_like, shape (n_options, n_options)
        Squared distances (:func:`distance_matrix`).
    phi1 : float
        Sensitivity of lateral inhibition to distance, ``phi1 >= 0``.
    phi2 : float
        Strength of lateral inhibition and of decay, ``phi2 >= 0``; the diagonal
        of ``S`` is ``1 - phi2``.

    Returns
    -------
    S : ndarray, shape (n_options, n_options)
        Symmetric feedback matrix.

    Notes
    -----
    ``D`` already holds squared distances, so the exponent is quartic in the
    attribute differences, as in Hotaling's and Busemeyer's code.

    Examples
    --------
    >>> D = distance_matrix([[1.0, 3.0], [3.0, 1.0]], beta=12.0)
    >>> feedback_matrix(D, phi1=0.022, phi2=0.05).round(4)
    array([[ 0.95  , -0.0122],
           [-0.0122,  0.95  ]])
    """
    D = as_float_array("D", D, ndim=2)
    if D.shape[0] != D.shape[1]:
        raise ValueError(f"D must be a square matrix (got shape {D.shape})")
    phi1 = as_scalar("phi1", phi1, low=0.0)
    phi2 = as_scalar("phi2", phi2, low=0.0)
    if phi1 == 0.0:  # exp(-0 * D**2) = 1, also where D**2 overflows
        return np.eye(D.shape[0]) - phi2
    with np.errstate(over="ignore", under="ignore"):
        inhibition = np.exp(-phi1 * D**2)  # D**2 = inf gives exp(-inf) = 0, as it should
    return np.eye(D.shape[0]) - phi2 * inhibition


class MDFTModel:
    """A Multi-alternative Decision Field Theory model.

    Parameters
    ----------
    M : array_like, shape (n_options, n_attributes)
        Evaluations ``M[option, attribute]``; at least 2 options and 1 attribute.
    w : array_like, shape (n_attributes,)
        Attention weights: non-negative, summing to one.
    phi1 : float
        Sensitivity of lateral inhibition to distance (``S`` equation), >= 0.
    phi2 : float
        Strength of lateral inhibition (``S`` equation), >= 0.
    beta : float
        Weight of the dominance dimension in Hotaling's distance, >= 0.
    sigma2 : float, default 1.0
        Variance of the valence noise ``eps(t) ~ N(0, sigma2 I)``, >= 0.
    P0 : array_like, shape (n_options,), optional
        Initial preference ``P(0)``; zero by default.

    Attributes
    ----------
    M, w, C, D, S, P0 : ndarray
        Read-only arrays. ``D`` is ``None`` for a model built with
        :meth:`from_matrices`.
    sigma2, phi1, phi2, beta : float
        Parameters (``phi1``, ``phi2``, ``beta`` are ``None`` for a model built
        from matrices).
    spectral_radius : float
        ``max |eig(S)|``. Preferences stay bounded in expectation only if it is
        below 1. An :class:`UnstableFeedbackWarning` is issued where it lets them
        grow more than tenfold over a deliberation of 100 steps
        (``rho(S) > 1.0233``); the fixed-time computations check their own
        number of steps.

    Notes
    -----
    The dynamics is ``P(t+1) = S P(t) + C (M W(t+1) + eps(t+1))``, where
    ``W(t)`` is the unit vector of the attribute attended at step ``t``.

    Examples
    --------
    The binary choice between A = (1, 3) and B = (3, 1) with the canonical
    parameters:

    >>> model = MDFTModel([[1, 3], [3, 1]], [0.5, 0.5],
    ...                   phi1=0.022, phi2=0.05, beta=12.0)
    >>> model.n_options, model.n_attributes
    (2, 2)
    >>> round(model.spectral_radius, 4)
    0.9622
    >>> model.C.sum(axis=0)
    array([0., 0.])

    Adding the compromise C = (2, 2) makes ``S`` slightly expansive (its
    spectral radius is about 1.009): lateral inhibition between close options
    is what produces the compromise effect. Preferences can then grow by a
    factor of ``1.009 ** 100 = 2.4`` over 100 steps, too little to warn about.
    """

    __slots__ = (
        "_M",
        "_w",
        "_C",
        "_D",
        "_S",
        "_P0",
        "_sigma2",
        "_phi1",
        "_phi2",
        "_beta",
        "_standard_contrast",
        "_spectral_radius",
    )

    def __init__(self, M: ArrayLike, w: ArrayLike, *, phi1: float, phi2: float, beta: float,
                 sigma2: float = 1.0, P0: ArrayLike | None = None) -> None:
        M = as_float_array("M", M, ndim=2)
        _check_option_count(M)
        phi1 = as_scalar("phi1", phi1, low=0.0)
        phi2 = as_scalar("phi2", phi2, low=0.0)
        beta = as_scalar("beta", beta, low=0.0)
        D = distance_matrix(M, beta=beta)
        S = feedback_matrix(D, phi1=phi1, phi2=phi2)
        self._init(M, w, contrast_matrix(M.shape[0]), S, sigma2, P0, standard_contrast=True)
        self._D = _readonly(D)
        self._phi1, self._phi2, self._beta = phi1, phi2, beta

    @classmethod
    def from_matrices(cls, M: ArrayLike, w: ArrayLike, *, S: ArrayLike, C: ArrayLike | None = None,
                      sigma2: float = 1.0, P0: ArrayLike | None = None) -> "MDFTModel":
        """Build a model from an explicit feedback matrix ``S`` (and contrast ``C``).

        Parameters
        ----------
        M : array_like, shape (n_options, n_attributes)
        w : array_like, shape (n_attributes,)
        S : array_like, shape (n_options, n_options)
            Feedback matrix. Need not be symmetric.
        C : array_like, shape (n_options, n_options), optional
            Contrast matrix; the standard one (:func:`contrast_matrix`) by default.
        sigma2 : float, default 1.0
        P0 : array_like, shape (n_options,), optional

        Examples
        --------
        >>> m = MDFTModel.from_matrices([[1.0], [0.0]], [1.0], S=[[1, 0], [0, 1]])
        >>> m.spectral_radius
        1.0
        """
        M = as_float_array("M", M, ndim=2)
        _check_option_count(M)
        n = M.shape[0]
        S = as_float_array("S", S, shape=(n, n))
        standard = C is None
        C = contrast_matrix(n) if standard else as_float_array("C", C, shape=(n, n))
        self = cls.__new__(cls)
        self._init(M, w, C, S, sigma2, P0, standard_contrast=standard)
        self._D = None  # type: ignore[assignment]
        self._phi1 = self._phi2 = self._beta = None  # type: ignore[assignment]
        return self

    def _init(self, M, w, C, S, sigma2, P0, *, standard_contrast):
        n, J = M.shape
        self._M = _readonly(M)
        self._w = _readonly(as_attention(w, J))
        self._C = _readonly(C)
        self._S = _readonly(S)
        self._sigma2 = as_scalar("sigma2", sigma2, low=0.0)
        P0 = np.zeros(n) if P0 is None else as_float_array("P0", P0, shape=(n,))
        self._P0 = _readonly(P0)
        self._standard_contrast = standard_contrast
        self._check_magnitudes()
        self._spectral_radius = _spectral_radius(S)
        warn_if_growing(self._spectral_radius, stacklevel=3)

    def _check_magnitudes(self) -> None:
        """Refuse values whose valence moments overflow: every engine would return NaN."""
        with np.errstate(over="ignore", invalid="ignore"):
            finite = (np.all(np.isfinite(self.valence_mean))
                      and np.all(np.isfinite(self.valence_covariance)))
        if not finite:
            raise ValueError(
                "M, C and sigma2 are too large for floating point: the mean or covariance of "
                f"the valence overflows (largest |M| = {np.abs(self._M).max():.3g}, largest "
                f"|C| = {np.abs(self._C).max():.3g}, sigma2 = {self._sigma2:.3g}); rescale them"
            )

    # ------------------------------------------------------------------ accessors
    M = property(lambda self: self._M, doc="Evaluations, shape (n_options, n_attributes).")
    w = property(lambda self: self._w, doc="Attention weights, shape (n_attributes,).")
    C = property(lambda self: self._C, doc="Contrast matrix, shape (n_options, n_options).")
    D = property(
        lambda self: self._D,
        doc="Hotaling squared distances, shape (n_options, n_options); None if built from S.",
    )
    S = property(lambda self: self._S, doc="Feedback matrix, shape (n_options, n_options).")
    P0 = property(lambda self: self._P0, doc="Initial preference, shape (n_options,).")
    sigma2 = property(lambda self: self._sigma2, doc="Variance of the valence noise.")
    phi1 = property(lambda self: self._phi1, doc="Distance sensitivity of inhibition.")
    phi2 = property(lambda self: self._phi2, doc="Strength of inhibition.")
    beta = property(lambda self: self._beta, doc="Weight of the dominance dimension.")
    spectral_radius = property(
        lambda self: self._spectral_radius, doc="Spectral radius of S, ``max |eig(S)|``."
    )

    @property
    def n_options(self) -> int:
        return self._M.shape[0]

    @property
    def n_attributes(self) -> int:
        return self._M.shape[1]

    @property
    def distance(self) -> np.ndarray | None:
        """Alias of :attr:`D`, Hotaling's squared distance matrix."""
        return self._D

    @property
    def is_parametric(self) -> bool:
        """True if ``S`` was built from ``phi1``, ``phi2`` and ``beta``."""
        return self._phi1 is not None

    # ------------------------------------------------------- moments of valence
    @property
    def valence_mean(self) -> np.ndarray:
        """``mu = C M w``, the mean valence per step, shape (n_options,)."""
        return self._C @ (self._M @ self._w)

    @property
    def valence_covariance(self) -> np.ndarray:
        """``Phi = C M Psi M^T C^T + sigma2 C C^T`` with ``Psi = diag(w) - w w^T``.

        The covariance of the valence of one step, shape (n_options, n_options).
        """
        w = self._w
        psi = np.diag(w) - np.outer(w, w)
        CM = self._C @ self._M
        return CM @ psi @ CM.T + self._sigma2 * (self._C @ self._C.T)

    # ---------------------------------------------------------------- variants
    def subset(self, options: ArrayLike) -> "MDFTModel":
        """Return the model restricted to some options, in the given order.

        For a parametric model ``C`` and ``S`` are rebuilt for the subset (the
        contrast depends on the number of options); for a model built from
        matrices, ``S`` is restricted and ``C`` rebuilt if it was the standard one.

        Parameters
        ----------
        options : sequence of int
            Distinct option indices, at least two.

        Examples
        --------
        >>> model = MDFTModel([[1, 3], [3, 1], [2, 2]], [0.5, 0.5],
        ...                   phi1=0.022, phi2=0.05, beta=12.0)
        >>> model.subset([0, 1]).M
        array([[1., 3.],
               [3., 1.]])
        """
        idx = np.asarray(options)
        if idx.ndim != 1 or idx.dtype.kind not in "iu":
            raise TypeError(f"options must be a 1-d sequence of integers (got {options!r})")
        if idx.size < 2 or len(set(idx.tolist())) != idx.size:
            raise ValueError(f"options must hold at least two distinct indices (got {idx.tolist()})")
        if idx.min() < 0 or idx.max() >= self.n_options:
            raise ValueError(
                f"options must lie in [0, {self.n_options - 1}] (got {idx.tolist()})"
            )
        if self.is_parametric:
            return MDFTModel(
                self._M[idx], self._w, phi1=self._phi1, phi2=self._phi2, beta=self._beta,
                sigma2=self._sigma2, P0=self._P0[idx],
            )
        if not self._standard_contrast:
            raise ValueError(
                "subset needs the standard contrast matrix; this model was built with a custom C"
            )
        return MDFTModel.from_matrices(
            self._M[idx], self._w, S=self._S[np.ix_(idx, idx)], sigma2=self._sigma2,
            P0=self._P0[idx],
        )

    def replace(self, **changes: Any) -> "MDFTModel":
        """Return a copy with some of ``M``, ``w``, ``phi1``, ``phi2``, ``beta``,
        ``sigma2``, ``P0`` replaced (parametric models only).

        Examples
        --------
        >>> model = MDFTModel([[1, 3], [3, 1]], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
        >>> model.replace(w=[0.7, 0.3]).w
        array([0.7, 0.3])
        """
        allowed = {"M", "w", "phi1", "phi2", "beta", "sigma2", "P0"}
        unknown = set(changes) - allowed
        if unknown:
            raise TypeError(
                f"replace got unknown parameter(s) {sorted(unknown)}; allowed: {sorted(allowed)}"
            )
        if not self.is_parametric:
            raise ValueError("replace needs a parametric model (built with phi1, phi2, beta)")
        params = dict(
            M=self._M, w=self._w, phi1=self._phi1, phi2=self._phi2, beta=self._beta,
            sigma2=self._sigma2, P0=self._P0,
        )
        if "M" in changes and "P0" not in changes:
            params["P0"] = None
        params.update(changes)
        M = params.pop("M")
        w = params.pop("w")
        return MDFTModel(M, w, **params)

    # ----------------------------------------------------------------- export
    def to_dict(self) -> dict:
        """The model as JSON-ready builtins; :meth:`from_dict` rebuilds it.

        A parametric model gives ``M``, ``w``, ``phi1``, ``phi2``, ``beta``, ``sigma2``
        and ``P0``; a model built from matrices gives ``M``, ``w``, ``S``, ``C``,
        ``sigma2`` and ``P0``.

        Examples
        --------
        >>> m = MDFTModel([[1, 3], [3, 1]], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
        >>> m.to_dict()
        {'M': [[1.0, 3.0], [3.0, 1.0]], 'w': [0.5, 0.5], 'sigma2': 1.0, 'P0': [0.0, 0.0], \
'phi1': 0.022, 'phi2': 0.05, 'beta': 12.0}
        >>> MDFTModel.from_dict(m.to_dict()).S.round(4).tolist()
        [[0.95, -0.0122], [-0.0122, 0.95]]
        """
        out = {"M": self._M, "w": self._w, "sigma2": self._sigma2, "P0": self._P0}
        if self.is_parametric:
            out.update(phi1=self._phi1, phi2=self._phi2, beta=self._beta)
        else:
            out.update(S=self._S, C=self._C)
        return builtin(out)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "MDFTModel":
        """Rebuild a model from :meth:`to_dict`'s output (or a dict of the same keys).

        Parameters
        ----------
        data : dict
            ``M``, ``w`` and either ``phi1``, ``phi2``, ``beta`` or ``S`` (and
            optionally ``C``); optionally ``sigma2`` and ``P0``.

        Examples
        --------
        >>> MDFTModel.from_dict({"M": [[1, 3], [3, 1]], "w": [0.5, 0.5], "phi1": 0.022,
        ...                      "phi2": 0.05, "beta": 12.0}).n_options
        2
        """
        if not isinstance(data, dict):
            raise TypeError(f"data must be a dict (got {type(data).__name__})")
        parametric = {"M", "w", "phi1", "phi2", "beta", "sigma2", "P0"}
        explicit = {"M", "w", "S", "C", "sigma2", "P0"}
        allowed = explicit if "S" in data else parametric
        required = {"M", "w", "S"} if "S" in data else {"M", "w", "phi1", "phi2", "beta"}
        unknown = sorted(set(map(str, data)) - allowed)
        if unknown:
            raise ValueError(f"data has unknown key(s) {unknown}; allowed: {sorted(allowed)}")
        missing = sorted(required - set(data))
        if missing:
            raise ValueError(f"data lacks the key(s) {missing}; required: {sorted(required)}")
        kwargs = {k: v for k, v in data.items() if k not in ("M", "w")}
        if "S" in data:
            return cls.from_matrices(data["M"], data["w"], **kwargs)
        return cls(data["M"], data["w"], **kwargs)

    def to_json(self, path: str | os.PathLike | None = None) -> str:
        """:meth:`to_dict` as JSON text, also written to ``path`` if given.

        Read it back with ``MDFTModel.from_dict(json.loads(text))``.
        """
        return to_json(self.to_dict(), path)

    def summary(self, labels: Sequence[str] | None = None) -> str:
        """A text table of the options' evaluations and the model's parameters.

        Examples
        --------
        >>> m = MDFTModel([[1, 3], [3, 1]], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
        >>> print(m.summary(labels=["A", "B"]))
        MDFT model: 2 options, 2 attributes
        option  attr 0  attr 1
        A       1.0000  3.0000
        B       3.0000  1.0000
        w       0.5000  0.5000
        phi1=0.022, phi2=0.05, beta=12, sigma2=1, spectral radius of S 0.9622
        """
        names = labels_for(labels, self.n_options)
        header = ["option"] + [f"attr {j}" for j in range(self.n_attributes)]
        rows = [[name] + [fmt(x) for x in row] for name, row in zip(names, self._M)]
        rows.append(["w"] + [fmt(x) for x in self._w])
        params = (f"phi1={self._phi1:g}, phi2={self._phi2:g}, beta={self._beta:g}, "
                  if self.is_parametric else "explicit S, ")
        if np.any(self._P0 != 0):
            params += f"P0={np.round(self._P0, 4).tolist()}, "
        return "\n".join([
            f"MDFT model: {self.n_options} options, {self.n_attributes} attributes",
            table(header, rows),
            f"{params}sigma2={self._sigma2:g}, spectral radius of S {self._spectral_radius:.4f}",
        ])

    def __repr__(self) -> str:
        if self.is_parametric:
            params = f"phi1={self._phi1:g}, phi2={self._phi2:g}, beta={self._beta:g}, "
        else:
            params = "S=<explicit>, "
        return (
            f"MDFTModel(n_options={self.n_options}, n_attributes={self.n_attributes}, "
            f"{params}sigma2={self._sigma2:g}, spectral_radius={self._spectral_radius:.4g})"
        )


def _spectral_radius(S: np.ndarray) -> float:
    """``max |eig(S)|``; a ValueError, not a LinAlgError, where the eigenvalues do not converge."""
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            eigenvalues = np.linalg.eigvals(S)
    except np.linalg.LinAlgError:
        eigenvalues = np.array([np.nan])
    radius = float(np.max(np.abs(eigenvalues)))
    if not np.isfinite(radius):
        raise ValueError(
            f"S has entries too large for its eigenvalues to be computed (largest |S| = "
            f"{np.abs(S).max():.3g}); the feedback matrix must be of moderate size"
        )
    return radius


def _check_option_count(M: np.ndarray) -> None:
    if M.shape[0] > MAX_OPTIONS:
        raise ValueError(
            f"M must have at most {MAX_OPTIONS:,} options (rows) (got {M.shape[0]:,})"
        )
    if M.shape[0] < 2:
        raise ValueError(
            f"M must have at least 2 options (rows) (got shape {M.shape}); MDFT compares options"
        )
    if M.shape[1] < 1:
        raise ValueError(f"M must have at least 1 attribute (column) (got shape {M.shape})")


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a
