"""Standard errors of a maximum-likelihood fit from the numerical Hessian.

The Hessian of the negative log-likelihood is taken by central differences on the
optimiser's unit cube at the interior coordinates of the optimum, inverted, and mapped to
natural units by the delta method (``docs/fitting.md``). On a likelihood smooth only up to
a noise (``noise > 0``), each coordinate's step is about its own standard error instead of
``step`` (:func:`mdft._differences.rough_steps`), so that the noise is small beside what
the steps measure.
"""

from __future__ import annotations

import numpy as np

from ._differences import hessian, rough_steps
from ._fit_params import PARAMETERS


def standard_errors(negloglik, layout, u, smooth, step=1e-4, bound_tol=1e-3, noise=0.0):
    """Covariance and standard errors from the numerical Hessian (in natural units); with
    ``noise > 0`` the steps are those of :func:`mdft._differences.rough_steps`."""
    labels = layout.labels
    m = len(labels)
    cov = np.full((m, m), np.nan)
    ses, notes = {}, {}

    def fill(reason_by_block):
        pos = 0
        p = layout.unpack(u)
        for name, _ in layout.blocks:
            size = layout.J if name == "w" else (
                (layout.n - 1) * layout.J if name == "M" else 1)
            vals = np.sqrt(np.clip(np.diag(cov)[pos:pos + size], 0.0, None))
            vals = np.where(np.isfinite(np.diag(cov)[pos:pos + size]), vals, np.nan)
            if name == "w":
                ses["w"] = vals
            elif name == "M":
                full = np.full(p["M"].shape, np.nan)
                full[0] = 0.0
                full[1:] = vals.reshape(layout.n - 1, layout.J)
                ses["M"] = full
            else:
                ses[name] = float(vals[0])
            notes[name] = reason_by_block.get(name, "")
            pos += size

    if not smooth:
        fill({name: "undefined for a simulated likelihood (not smooth in the parameters)"
              for name, _ in layout.blocks})
        return cov, ses, notes

    interior = (u > bound_tol) & (u < 1.0 - bound_tol)
    reasons = {}
    # Which free coordinates each labelled natural value depends on.
    depends = []
    pos = 0
    for name, size in layout.blocks:
        if name == "w":
            depends += [np.arange(pos, pos + size)] * layout.J
        else:
            depends += [np.array([pos + i]) for i in range(size)]
        pos += size
    bad = ~interior
    idx = np.flatnonzero(interior)
    if idx.size:
        f0 = negloglik(u)  # once, for the steps and the Hessian
        steps = (rough_steps(negloglik, u, idx, f0) if noise > 0.0
                 else np.full(idx.size, step))
        H = hessian(negloglik, u, idx, steps, f0)
        # A coordinate that does not move the likelihood at all is not identified.
        d = np.diag(H)
        flat = d <= 1e-10 * max(float(np.max(np.abs(d))), 1e-300)
        for c in np.flatnonzero(flat):
            bad[idx[c]] = True
            reasons.setdefault(layout.block_of(idx[c]),
                               "Hessian not positive definite: parameter not identified here")
        keep = ~flat
        idx, H = idx[keep], H[np.ix_(keep, keep)]
    cov_u = None
    if idx.size:
        try:
            np.linalg.cholesky(H)
            cov_u = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            for c in idx:
                bad[c] = True
                reasons.setdefault(layout.block_of(c),
                                   "Hessian not positive definite: parameter not identified here")
    for c in np.flatnonzero(~interior):
        reasons.setdefault(layout.block_of(c), "estimate on (or next to) a bound of its range")
    if cov_u is not None:
        # Delta method: natural values as a function of the free interior coordinates.
        Jac = np.zeros((m, idx.size))
        for c, i in enumerate(idx):
            h = 1e-6
            up, dn = u.copy(), u.copy()
            up[i] += h
            dn[i] -= h
            Jac[:, c] = (layout.natural(up) - layout.natural(dn)) / (2 * h)
        full = Jac @ cov_u @ Jac.T
        ok = np.array([not np.any(bad[dep]) for dep in depends])
        cov[np.ix_(ok, ok)] = full[np.ix_(ok, ok)]
        # A block some of whose values are defined keeps a note only for the undefined ones.
        for name in list(reasons):
            if name == "M":
                pos_nat = sum(layout.J if b == "w" else sz for b, sz in layout.blocks
                              if PARAMETERS.index(b) < PARAMETERS.index("M"))
                n_undef = int(np.count_nonzero(~ok[pos_nat:]))
                reasons["M"] = f"{n_undef} entries undefined: " + reasons["M"]
    fill(reasons)
    return cov, ses, notes
