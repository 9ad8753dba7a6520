"""The free parameters of a fit: names, bounds, starts and the map onto the unit cube.

The optimiser of :func:`mdft.fit` works on ``[0, 1]^k``: each bounded scalar is mapped
linearly, ``w`` by stick-breaking, ``M`` entry by entry with its first row held fixed.
"""

from __future__ import annotations

import numpy as np

from ._validation import as_attention, as_float_array, as_scalar

#: Parameters :func:`mdft.fit` can estimate, in the order of the free-parameter vector.
PARAMETERS = ("w", "phi1", "phi2", "beta", "sigma2", "theta", "M")
_SCALARS = ("phi1", "phi2", "beta", "sigma2", "theta")
_MODEL_SCALARS = ("phi1", "phi2", "beta", "sigma2")
#: Default search bounds of the scalar parameters.
DEFAULT_BOUNDS = {
    "phi1": (0.0, 1.0),
    "phi2": (0.0, 0.5),
    "beta": (0.0, 50.0),
    "sigma2": (1e-3, 25.0),
    "theta": (1.0, 100.0),
}
#: Default first start of the scalar parameters (the canonical values of the literature).
DEFAULT_START = {"phi1": 0.022, "phi2": 0.05, "beta": 12.0, "sigma2": 1.0}


class Layout:
    """Maps the unit cube of the optimiser to named parameter values and back."""

    def __init__(self, fitted, values, bounds, n_options, n_attributes):
        self.fitted = fitted
        self.values = values
        self.bounds = bounds
        self.n, self.J = n_options, n_attributes
        self.blocks = []  # (name, size)
        for name in PARAMETERS:
            if name not in fitted:
                continue
            if name == "w":
                self.blocks.append(("w", self.J - 1))
            elif name == "M":
                self.blocks.append(("M", (self.n - 1) * self.J))
            else:
                self.blocks.append((name, 1))
        self.size = sum(s for _, s in self.blocks)
        labels = []
        for name, _ in self.blocks:
            if name == "w":
                labels += [f"w[{j}]" for j in range(self.J)]
            elif name == "M":
                labels += [f"M[{i},{j}]" for i in range(1, self.n) for j in range(self.J)]
            else:
                labels.append(name)
        self.labels = tuple(labels)

    def unpack(self, u):
        p = dict(self.values)
        pos = 0
        for name, size in self.blocks:
            x = u[pos:pos + size]
            pos += size
            if name == "w":
                p["w"] = _stick_to_simplex(x)
            elif name == "M":
                lo, hi = self.bounds["M"]
                M = np.array(self.values["M"], dtype=np.float64)
                M[1:] = (lo[1:] + x.reshape(self.n - 1, self.J) * (hi[1:] - lo[1:]))
                p["M"] = M
            else:
                lo, hi = self.bounds[name]
                p[name] = float(lo + x[0] * (hi - lo))
        return p

    def pack(self, p):
        u = np.empty(self.size)
        pos = 0
        for name, size in self.blocks:
            if name == "w":
                u[pos:pos + size] = _simplex_to_stick(np.asarray(p["w"], dtype=np.float64))
            elif name == "M":
                lo, hi = self.bounds["M"]
                u[pos:pos + size] = ((np.asarray(p["M"])[1:] - lo[1:]) / (hi[1:] - lo[1:])).ravel()
            else:
                lo, hi = self.bounds[name]
                u[pos] = (p[name] - lo) / (hi - lo)
            pos += size
        return u

    def block_of(self, coordinate):
        """Name of the parameter block a free coordinate belongs to."""
        pos = 0
        for name, size in self.blocks:
            if coordinate < pos + size:
                return name
            pos += size
        raise IndexError(coordinate)

    def natural(self, u):
        """The labelled natural values (``w`` in full, ``M`` without its anchor row)."""
        p = self.unpack(u)
        out = []
        for name, _ in self.blocks:
            if name == "w":
                out += list(p["w"])
            elif name == "M":
                out += list(p["M"][1:].ravel())
            else:
                out.append(p[name])
        return np.array(out)


def _stick_to_simplex(v):
    """Stick-breaking map from [0, 1]^(J-1) onto the simplex of J weights."""
    w = np.empty(v.size + 1)
    rest = 1.0
    for j, vj in enumerate(v):
        w[j] = rest * vj
        rest -= w[j]
    w[-1] = max(rest, 0.0)
    return w


def _simplex_to_stick(w):
    v = np.empty(w.size - 1)
    rest = 1.0
    for j in range(w.size - 1):
        v[j] = w[j] / rest if rest > 1e-15 else 0.5
        rest -= w[j]
    return np.clip(v, 0.0, 1.0)


def check_names(name, names):
    if isinstance(names, str):
        names = [names]
    try:
        names = list(names)
    except TypeError as exc:
        raise TypeError(f"{name} must be a sequence of parameter names (got {names!r})") from exc
    bad = [x for x in names if x not in PARAMETERS]
    if bad:
        raise ValueError(f"{name} has unknown parameter name(s) {bad}; allowed: {list(PARAMETERS)}")
    if len(set(names)) != len(names):
        raise ValueError(f"{name} lists a parameter twice (got {names})")
    return names


def _pair(name, value):
    """``value`` as a (lower, upper) pair."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise ValueError(f"{name} must be a pair (lower, upper) (got {value!r})")
    return value[0], value[1]


def _broadcast(name, value, shape):
    """``value`` (a scalar or an array) as a float array of ``shape``."""
    arr = as_float_array(name, value)
    try:
        return np.broadcast_to(arr, shape).astype(np.float64)
    except ValueError:
        raise ValueError(f"{name} must be a number or an array of shape {shape} like M "
                         f"(got shape {arr.shape})") from None


def resolve(M, fitted, fixed, start, bounds, theta=None):
    """Check ``fixed``/``start``/``bounds``; return (values, bounds, first start).

    ``theta`` is the threshold of threshold stopping (None for fixed time): the
    value of ``"theta"`` when it is not fitted, its first start when it is.
    """
    n, J = M.shape
    fixed = dict(fixed or {})
    start = dict(start or {})
    bounds = dict(bounds or {})
    for label, d in (("fixed", fixed), ("start", start), ("bounds", bounds)):
        bad = [k for k in d if k not in PARAMETERS]
        if bad:
            raise ValueError(
                f"{label} has unknown parameter name(s) {bad}; allowed: {list(PARAMETERS)}"
            )
    clash = [k for k in fixed if k in fitted]
    if clash:
        raise ValueError(f"parameter(s) {clash} are both fitted and given in fixed; choose one")
    if "M" in fixed:
        raise ValueError("M is given as the positional argument, not in fixed")
    if "theta" in fixed:
        raise ValueError("theta is given by stopping=mdft.Threshold(theta), not in fixed")
    if "theta" in fitted and theta is None:
        raise ValueError(
            "params names 'theta' but stopping is fixed time; theta can be fitted only with "
            "stopping=mdft.Threshold(theta) (its start value)"
        )
    for label, d in (("start", start), ("bounds", bounds)):
        extra = [k for k in d if k not in fitted]
        if extra:
            raise ValueError(f"{label} names parameter(s) {extra} that are not being fitted")
    missing = [k for k in ("w", *_MODEL_SCALARS) if k not in fitted and k not in fixed]
    if missing:
        raise ValueError(
            f"fixed must give a value for every parameter that is not fitted; missing {missing}"
        )
    if "w" in fitted and J < 2:
        raise ValueError("w cannot be fitted with a single attribute (it is fixed at [1.0])")
    if "w" in bounds:
        raise ValueError("bounds cannot be given for w: it is fitted over the whole simplex")
    if "M" in fitted and n < 2:
        raise ValueError("M needs at least two options to be fitted")

    values = {"M": M}
    if "w" in fixed:
        values["w"] = as_attention(fixed["w"], J, name="fixed['w']")
    else:
        values["w"] = np.full(J, 1.0 / J)
    for k in _MODEL_SCALARS:
        if k in fixed:
            values[k] = as_scalar(f"fixed[{k!r}]", fixed[k], low=0.0)
        else:
            values[k] = DEFAULT_START[k]
    values["theta"] = theta

    res_bounds = {}
    for k in _SCALARS:
        if k not in fitted:
            continue
        lo, hi = _pair(f"bounds[{k!r}]", bounds.get(k, DEFAULT_BOUNDS[k]))
        # a threshold of 0 decides at once: theta's range is open at 0
        lo = as_scalar(f"bounds[{k!r}][0]", lo, low=0.0, low_inclusive=k != "theta")
        hi = as_scalar(f"bounds[{k!r}][1]", hi)
        if not hi > lo:
            raise ValueError(f"bounds[{k!r}] must satisfy lower < upper (got ({lo}, {hi}))")
        res_bounds[k] = (lo, hi)
    if "M" in fitted:
        if "M" in bounds:
            lo, hi = _pair("bounds['M']", bounds["M"])
            lo = _broadcast("bounds['M'][0]", lo, M.shape)
            hi = _broadcast("bounds['M'][1]", hi, M.shape)
        else:
            span = max(float(M.max() - M.min()), 1.0)
            lo = np.full(M.shape, M.min() - span)
            hi = np.full(M.shape, M.max() + span)
        if np.any(hi[1:] <= lo[1:]):
            raise ValueError("bounds['M'] must satisfy lower < upper for every entry")
        res_bounds["M"] = (lo, hi)

    first = dict(values)
    for k, v in start.items():
        if k == "w":
            first["w"] = as_attention(v, J, name="start['w']")
        elif k == "M":
            Mv = as_float_array("start['M']", v, shape=M.shape)
            lo, hi = res_bounds["M"]
            if np.any(Mv[1:] < lo[1:]) or np.any(Mv[1:] > hi[1:]):
                raise ValueError("start['M'] lies outside bounds['M']; widen the bounds or move the start")
            if not np.array_equal(Mv[0], M[0]):
                raise ValueError("start['M'] must keep the first row of M (the anchor row) unchanged")
            first["M"] = Mv
        else:
            x = as_scalar(f"start[{k!r}]", v)
            lo, hi = res_bounds[k]
            if not lo <= x <= hi:
                raise ValueError(
                    f"start[{k!r}] = {x} lies outside bounds [{lo}, {hi}]; widen the bounds or "
                    "move the start"
                )
            first[k] = x
    for k in _SCALARS:
        if k in fitted and k not in start:
            lo, hi = res_bounds[k]
            first[k] = float(min(max(first[k], lo), hi))
    if "M" in fitted and "M" not in start:
        lo, hi = res_bounds["M"]
        if np.any(M[1:] < lo[1:]) or np.any(M[1:] > hi[1:]):
            raise ValueError("M lies outside bounds['M']; the given M is the start of the fit")
    return values, res_bounds, first


def check_values(params, current):
    """``params`` (a dict of parameter values to evaluate at) checked as ``fixed`` values
    are, each against the shape of its value in ``current`` (the fitted parameters); the
    values as floats and arrays."""
    out = {}
    for k, v in params.items():
        label = f"params[{k!r}]"
        if k == "w":
            out[k] = as_attention(v, np.asarray(current["w"]).size, name=label)
        elif k == "M":
            out[k] = as_float_array(label, v, shape=np.asarray(current["M"]).shape)
        elif k == "theta":
            if current.get("theta") is None:
                raise ValueError(f"{label} is given, but the fit used fixed-time stopping")
            out[k] = as_scalar(label, v, low=0.0, low_inclusive=False)
        else:
            out[k] = as_scalar(label, v, low=0.0)
    return out
