"""The worst-case error an exact (l0) secure estimator can be driven to, linear in the noise bound.

Pajic et al. (ICCPS 2014 "Robustness of attack-resilient state estimators";
TCNS 2017 "Attack-resilient state estimation for noisy dynamical systems")
show that with bounded noise the l0 estimator (the MILP) has a worst-case
error linear in the noise bound, whatever the attacker does. Their exact
constant could not be read (abstracts only); the bound here is the standard
argument behind such results, written out for our linearised range models:

Readings ``z = H x + e + v`` with ``|v_i| <= delta_i`` (a box) and ``e`` non-zero
on at most s readings. The l0 estimate ``x'`` explains ``z`` with at most s
readings set aside, each remaining reading within its box. Readings set aside
by neither the truth nor the estimate number at least p - 2s; call them G. On G
both explanations hold, so ``|H_G (x' - x)| <= 2 delta_G`` element-wise, and if
every such ``H_G`` has full column rank (2s-sparse observability)::

    ||x' - x|| <= 2 max_{|G| = p - 2s}  max_{|u_i| <= delta_i}  ||H_G^+ u||

The inner maximum of a convex function over a box is at a vertex, so it is an
enumeration of the 2^|G| sign patterns (32 for the 8 anchors and the laser,
s = 2). ``position_rows`` restricts the norm to part of the state (the
horizontal error of a 3-D model). Beyond the linearisation the bound is local:
it holds for errors small against the ranges. Gaussian noise is not bounded,
so with ``delta = 3 sigma`` it holds on the steps where every honest reading is
inside three sigma (97.6 % of steps for the nine readings of test case 1). It
bounds the l0 decoder of the bounded-noise setting (the MILP), not estimators
that decide by chi-square tests or filters.
"""

from __future__ import annotations

import itertools

import numpy as np

from estimators.models import Known, MeasurementModel


def l0_error_bound(
    model: MeasurementModel,
    pos: np.ndarray,
    s: int,
    delta_m: np.ndarray | float,
    known: Known = None,
    position_rows: slice | None = None,
) -> float:
    """The worst-case error of the l0 estimator at ``pos`` (module docstring); inf if not 2s-sparse observable."""
    jac = np.asarray(model.jac(np.asarray(pos, dtype=float), known), dtype=float)
    p = jac.shape[0]
    delta = np.broadcast_to(np.asarray(delta_m, dtype=float), (p,))
    keep = p - 2 * s
    if keep < jac.shape[1]:
        return float("inf")
    rows = slice(None) if position_rows is None else position_rows
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=keep)))
    worst = 0.0
    for group in itertools.combinations(range(p), keep):
        sub = jac[list(group)]
        if np.linalg.matrix_rank(sub) < jac.shape[1]:
            return float("inf")
        pinv = np.linalg.pinv(sub)[rows]
        corners = (signs * delta[list(group)]) @ pinv.T
        worst = max(worst, float(np.sqrt(np.max(np.einsum("kd,kd->k", corners, corners)))))
    return 2.0 * worst
