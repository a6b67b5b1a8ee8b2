"""The shared subset-bank engine: many estimators, one per sensor subset, in one numpy call.

A bank is a boolean mask array ``masks[j, i]`` (subset j uses sensor i). All
subsets share the full reading vector; a sensor outside a subset, or a
missing (NaN) reading, simply gets weight zero. So every subset has the same
array shapes and the whole bank runs as batched einsum/solve calls instead of
a Python loop (one engine for SecEKF, SecOPT, ReCaP's group search,
RARSE's hypotheses and the brute-force checks).

Two solvers live here:
- ``gauss_newton``: per subset, ``min_pos sum_{i in S} (z_i - h_i(pos))^2 / sigma_i^2``
  by damped Gauss-Newton, projected on the model's box after each step.
- ``EkfBank``: per subset, a constant-velocity EKF. The readings see only the
  position block, so the update needs only d x d algebra (push-through
  identity), never the p x p innovation covariance nor an n x n inverse: with
  ``W`` the masked inverse noise covariance, ``A = H^T W H``, ``b = H^T W nu``
  and ``C = (I + A P_pp)^-1``: ``x+ = x- + P[:, :d] C b``,
  ``P+ = P- - P[:, :d] C A P[:d, :]`` and
  ``NIS = nu^T (H P- H^T + R)^-1 nu = nu^T W nu - b^T P_pp C b``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.stats import chi2

from estimators.models import Known, MeasurementModel


@lru_cache(maxsize=64)
def _masks(p: int, k: int) -> np.ndarray:
    rows = list(itertools.combinations(range(p), k))
    out = np.zeros((len(rows), p), dtype=bool)
    for j, idx in enumerate(rows):
        out[j, list(idx)] = True
    out.setflags(write=False)
    return out


def subset_masks(p: int, k: int) -> np.ndarray:
    """All subsets of size k out of p, as a read-only ``(C(p, k), p)`` boolean array."""
    if not 0 <= k <= p:
        raise ValueError(f"subset size {k} outside 0..{p}")
    return _masks(p, k)


class Chi2Table:
    """Upper chi-square quantiles ``chi2.ppf(1 - alpha, dof)`` for dof 0..max_dof, looked up by array."""

    def __init__(self, alpha: float, max_dof: int) -> None:
        if not 0.0 < alpha < 1.0:
            raise ValueError(f"false-alarm level alpha={alpha} must lie in (0, 1)")
        self.alpha = alpha
        self._table = self._build(max_dof)

    def _build(self, max_dof: int) -> np.ndarray:
        dof = np.arange(max_dof + 1, dtype=float)
        table = chi2.ppf(1.0 - self.alpha, np.maximum(dof, 1.0))
        # dof 0: an exactly determined fit has no redundancy, so nothing can be tested.
        table[0] = np.inf
        return table

    def __call__(self, dof: np.ndarray | int) -> np.ndarray:
        if type(dof) is int and 0 <= dof < self._table.shape[0]:  # the per-step case: one plain lookup
            return self._table[dof]
        idx = np.asarray(dof, dtype=int)
        if idx.size and idx.max() >= self._table.shape[0]:
            self._table = self._build(2 * int(np.max(idx)))
        return self._table[idx]


@dataclass(frozen=True, eq=False)
class GnResult:
    pos: np.ndarray  # (J, d) fitted position per subset
    cost: np.ndarray  # (J,) weighted residual sum of squares
    info: np.ndarray  # (J, d, d) normal matrix H^T W H (inverse = covariance)
    n_used: np.ndarray  # (J,) readings actually used (subset AND not NaN)
    resid: np.ndarray  # (J, p) z - h(pos) (0 where unused)
    raw: np.ndarray  # (J, p) z - h(pos) for every reading (NaN where missing), for per-sensor tests
    jac: np.ndarray  # (J, p, d) Jacobian at pos


@lru_cache(maxsize=8)
def damping(d: int) -> np.ndarray:
    """``1e-9 I``: the tiny Levenberg damping every small normal-equation solve adds (read-only, cached)."""
    out = 1e-9 * np.eye(d)
    out.setflags(write=False)
    return out


def _inv_var(model: MeasurementModel) -> np.ndarray:
    """``1 / sigma^2`` per sensor, computed once per model (the model is frozen; the cache bypasses that)."""
    cached = model.__dict__.get("_inv_var_cache")
    if cached is None:
        cached = 1.0 / model.sigma_m**2
        object.__setattr__(model, "_inv_var_cache", cached)
    return cached


def gauss_newton(
    model: MeasurementModel,
    z: np.ndarray,
    masks: np.ndarray,
    start: np.ndarray,
    known: Known = None,
    n_iter: int = 6,
    tol_m: float = 1e-4,
    at_start: tuple[np.ndarray, np.ndarray] | None = None,
) -> GnResult:
    """Weighted least squares per subset, all subsets at once (see module docstring).

    The arrays are tiny (p ~ 8, d ~ 2), so numpy's per-call overhead, not
    arithmetic, is the cost: the loop keeps the number of calls low.
    """
    use = masks & ~np.isnan(z)
    w = use * _inv_var(model)
    n_sub, d = masks.shape[0], model.d
    pos = np.empty((n_sub, d))
    pos[...] = start
    # Tiny Levenberg damping keeps rank-deficient subsets (too few readings) finite.
    damp = damping(d)
    tol2 = tol_m * tol_m
    for it in range(n_iter + 1):
        # ``at_start``: h and its Jacobian at ``start``, when the caller already has them (broadcast over subsets).
        hx, jac = at_start if it == 0 and at_start is not None else model.h_jac(pos, known)
        raw = z - hx
        r = np.where(use, raw, 0.0)
        jtw = (jac * w[..., None]).mT
        info = jtw @ jac
        if it == n_iter:
            break
        step = solve_small(info + damp, (jtw @ r[..., None])[..., 0])
        pos = model.clip(pos + step)
        if float(np.vdot(step, step)) < tol2:
            # Converged: the cost and information at the last evaluation differ from
            # those after this sub-tolerance step only to second order; skip a re-evaluation.
            break
    if raw.ndim == 1:  # evaluated only at the caller's ``at_start``
        raw = np.broadcast_to(raw, (n_sub, model.p))
        jac = np.broadcast_to(jac, (n_sub, model.p, d))
    cost = np.einsum("jp,jp->j", w, r * r)
    return GnResult(pos=pos, cost=cost, info=info, n_used=use.sum(axis=1), resid=r, raw=raw, jac=jac)


_SIGNS2 = np.array([[1.0, -1.0], [-1.0, 1.0]])


def inv_small(a: np.ndarray) -> np.ndarray:
    """Batched inverse of symmetric positive semi-definite d x d matrices, damped so singular ones stay finite."""
    d = a.shape[-1]
    if d == 2 and a.ndim == 2:  # one 2 x 2: Python floats beat a dozen numpy calls
        (a00, a01), (a10, a11) = a.tolist()
        eps = 1e-9 * (a00 + a11 + 1e-9)
        d00, d11 = a00 + eps, a11 + eps
        det = d00 * d11 - a01 * a10
        return np.array([[d11 / det, -a01 / det], [-a10 / det, d00 / det]])
    if d == 2:  # a batch of 2 x 2: the damped adjugate over the determinant, element by element
        a00, a01, a10, a11 = a[..., 0, 0], a[..., 0, 1], a[..., 1, 0], a[..., 1, 1]
        eps = 1e-9 * (a00 + a11 + 1e-9)
        d00, d11 = a00 + eps, a11 + eps
        inv_det = 1.0 / (d00 * d11 - a01 * a10)
        out = np.empty(a.shape)
        out[..., 0, 0], out[..., 0, 1] = d11 * inv_det, -a01 * inv_det
        out[..., 1, 0], out[..., 1, 1] = -a10 * inv_det, d00 * inv_det
        return out
    damped = a + 1e-9 * (np.trace(a, axis1=-2, axis2=-1)[..., None, None] + 1e-9) * np.eye(d)
    if d == 1:
        return 1.0 / damped
    return np.linalg.inv(damped)


def solve_small(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched ``a[j] x[j] = b[j]`` for SYMMETRIC a; closed form for 1x1 and 2x2 (LAPACK's overhead dominates)."""
    d = a.shape[-1]
    if d == 1:
        return b / a[:, 0, :]
    if d == 2:
        if a.shape[0] == 1:  # one system: Python floats
            (a00, a01), (_, a11) = a[0].tolist()
            b0, b1 = b[0].tolist()
            det = a00 * a11 - a01 * a01
            return np.array([[(a11 * b0 - a01 * b1) / det, (a00 * b1 - a01 * b0) / det]])
        # Flipping both axes times the sign pattern is the adjugate only for symmetric a
        # (normal matrices, covariances: every caller); general 2x2 systems go to LAPACK.
        adj = a[:, ::-1, ::-1] * _SIGNS2
        det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
        return (adj @ b[..., None])[..., 0] / det[:, None]
    return np.linalg.solve(a, b[..., None])[..., 0]


def _inv_general_batch(m: np.ndarray) -> np.ndarray:
    """Inverses of J small general (non-symmetric) d x d matrices; closed form for d <= 2."""
    d = m.shape[-1]
    if d == 1:
        return 1.0 / m
    if d == 2:
        # adj([[a, b], [c, d]]) = [[d, -b], [-c, a]]: both axes flipped, transposed, signed.
        det = m[:, 0, 0] * m[:, 1, 1] - m[:, 0, 1] * m[:, 1, 0]
        return m[:, ::-1, ::-1].mT * _SIGNS2 / det[:, None, None]
    return np.linalg.inv(m)


def _solve_general(m: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``m x = rhs`` for one small general (non-symmetric) d x d matrix; rhs (d, k)."""
    d = m.shape[0]
    if d == 1:
        return rhs / m[0, 0]
    if d == 2:
        (m00, m01), (m10, m11) = m.tolist()
        det = m00 * m11 - m01 * m10
        return np.array([[m11 / det, -m01 / det], [-m10 / det, m00 / det]]) @ rhs
    return np.linalg.solve(m, rhs)


@lru_cache(maxsize=256)
def cv_matrices(d: int, dt_s: float, q_mps2: float | tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity model for state ``[pos(d), vel(d)]``: F and Q = G diag(q^2) G^T (white acceleration;
    ``q_mps2`` one value for every axis or one per axis).

    Cached: the step interval repeats (10 Hz streams), so the matrices are built once (hence a tuple).
    """
    eye = np.eye(d)
    f = np.block([[eye, dt_s * eye], [np.zeros((d, d)), eye]])
    g = np.vstack([0.5 * dt_s**2 * eye, dt_s * eye])
    q = (g * np.broadcast_to(np.asarray(q_mps2, dtype=float) ** 2, (d,))) @ g.T
    f.setflags(write=False)
    q.setflags(write=False)
    return f, q


class EkfBank:
    """J constant-velocity EKFs, filter j reading only the sensors of ``masks[j]``."""

    def __init__(self, model: MeasurementModel, masks: np.ndarray, q_mps2: float | tuple[float, ...]) -> None:
        self.model = model
        self.masks = np.asarray(masks, dtype=bool)
        self.q_mps2 = q_mps2
        self.d = model.d
        self.n = 2 * model.d
        n_sub = self.masks.shape[0]
        self.x = np.zeros((n_sub, self.n))
        self.P = np.tile(np.eye(self.n), (n_sub, 1, 1))

    def seed(self, x0: np.ndarray, P0: np.ndarray, which: np.ndarray | None = None) -> None:
        """Set filters (all, or those selected by the boolean/int index ``which``) to one state."""
        sel = slice(None) if which is None else which
        self.x[sel] = x0
        self.P[sel] = P0

    def predict(self, dt_s: float) -> None:
        if dt_s <= 0.0:
            return
        f, q = cv_matrices(self.d, dt_s, self.q_mps2)
        self.x = self.x @ f.T
        self.P = f @ self.P @ f.T + q

    def update_velocity(self, vel: np.ndarray, var: float) -> None:
        """Every filter reads the vehicle's own velocity (``H = [0 I]``, ``R = var I``): the motion input.

        Gain form: ``S = P_vv + R``, ``K = P[:, :, d:] S^-1``, ``x+ = x + K (v - x_v)``,
        ``P+ = P - K P[d:, :]`` (d x d solves, batched over filters)."""
        d = self.d
        s_mat = self.P[:, d:, d:] + var * np.eye(d)
        gain = np.linalg.solve(s_mat, self.P[:, d:, :]).mT  # S symmetric: (S^-1 P_v.)^T = P_.v S^-1
        self.x = self.x + (gain @ (vel - self.x[:, d:])[..., None])[..., 0]
        p_new = self.P - gain @ self.P[:, d:, :]
        self.P = 0.5 * (p_new + p_new.mT)

    def update(
        self, z: np.ndarray, known: Known = None, at_prior: tuple[np.ndarray, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Update every filter with its own sensors; returns (NIS, dof) per filter.

        ``at_prior``: h and its Jacobian at the (single) filter's predicted position, if already at hand.
        """
        if self.x.shape[0] == 1:
            return self._update_one(z, known, at_prior)
        # The push-through form of :meth:`_update_one`, batched over filters.
        model, d, P = self.model, self.d, self.P
        use = self.masks & ~np.isnan(z)
        w = use * _inv_var(model)
        hx, jac = model.h_jac(self.x[:, :d], known)
        nu = np.where(use, z - hx, 0.0)
        jtw = (jac * w[..., None]).mT  # (J, d, p)
        a_mat = jtw @ jac
        b = (jtw @ nu[..., None])[..., 0]
        p_pos = P[:, :d, :d]
        c_mat = _inv_general_batch(np.eye(d) + a_mat @ p_pos)
        g = (c_mat @ b[..., None])[..., 0]
        p_cols = P[:, :, :d]
        nis = np.einsum("jp,jp->j", w, nu * nu) - np.einsum("jd,jd->j", b, (p_pos @ g[..., None])[..., 0])
        self.x = self.x + (p_cols @ g[..., None])[..., 0]
        p_new = P - p_cols @ (c_mat @ a_mat) @ P[:, :d, :]
        self.P = 0.5 * (p_new + p_new.mT)
        return np.maximum(nis, 0.0), use.sum(axis=1)

    def _update_one(
        self, z: np.ndarray, known: Known, at_prior: tuple[np.ndarray, np.ndarray] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Single filter, with d x d algebra only (no m x m innovation covariance, no n x n inverse).

        The readings see only the position block, so with ``A = H^T W H``,
        ``b = H^T W nu`` (W the masked inverse noise variances) and
        ``C = (I + A P_pp)^-1`` (push-through identity):
        ``H^T S^-1 H = C A``, ``H^T S^-1 nu = C b``, hence
        ``x+ = x + P[:, :d] C b``, ``P+ = P - P[:, :d] C A P[:d, :]`` and
        ``NIS = nu^T W nu - b^T P_pp C b``; the same update as the gain form
        ``K = P H^T S^-1``, at d x d cost (d = 2 here, in closed form).
        """
        use = self.masks[0] & ~np.isnan(z)
        n_used = int(use.sum())
        if n_used == 0:
            return np.zeros(1), np.zeros(1, dtype=int)
        d, x, P = self.d, self.x[0], self.P[0]
        hx, jac = self.model.h_jac(x[:d], known) if at_prior is None else at_prior
        w = use * _inv_var(self.model)
        nu = np.where(use, z - hx, 0.0)
        jtw = (jac * w[:, None]).T  # (d, p)
        a_mat = jtw @ jac
        p_pos = P[:d, :d]
        # C [b | A] in one small solve: g = C b, ca = C A.
        b = jtw @ nu
        sol = _solve_general(np.eye(d) + a_mat @ p_pos, np.column_stack([b, a_mat]))
        g, ca = sol[:, 0], sol[:, 1:]
        p_cols = P[:, :d]
        nis = float(w @ (nu * nu) - b @ (p_pos @ g))
        self.x[0] = x + p_cols @ g
        p_new = P - p_cols @ ca @ P[:d, :]
        self.P[0] = 0.5 * (p_new + p_new.T)
        return np.array([nis]), np.array([n_used])
