"""The process noise of the constant-velocity model, fitted on a window of readings instead of guessed.

Every filter here (and the window alignment, estimators.aligned) moves the state with a constant-velocity model
whose white acceleration has std ``q_mps2`` (``bank.cv_matrices``: ``Q = G diag(q^2) G^T``). Where the vehicle
reports its own motion (``velocity_std_mps``: LOCAL_POSITION_NED's velocity from IMU, flow or GPS) that input drives
the prior and ``q`` matters little. Otherwise ``q`` decides how far the prior may move between readings, and a
value guessed for one vehicle is wrong for the next (the bench's default 0.5 m/s^2 is a hovering multirotor's).

:func:`fit_process_noise` fits it on an attack-free window (the calibration window, estimators.noise) by maximum
likelihood of the innovations (R. K. Mehra, "On the identification of variances and adaptive Kalman filtering",
IEEE TAC 15(2), 1970; here a grid search over q): per step a least-squares fix from the (offset-corrected)
readings and its covariance ``(H^T W H)^-1``; a constant-velocity Kalman filter on those fixes for each q of a
geometric grid; the q whose innovations ``nu ~ N(0, S)`` are most likely. RECON: the fixes as the filter's
measurements (a two-stage fit), the grid and its bounds are ours. The fit sees what the window holds: errors
correlated over seconds (real UWB, docs/datasets.md) look like motion to it and raise q; a window in which the
vehicle stands still fits the grid's floor (said in ``at_bound``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.bank import cv_matrices
from estimators.models import Known, MeasurementModel

GRID_MPS2 = np.geomspace(0.02, 20.0, 41)  # 0.02 (a parked vehicle's jitter) .. 20 m/s^2 (2 g), 41 points
MIN_FIXES = 10


@dataclass(frozen=True)
class ProcessNoiseFit:
    q_mps2: float  # the most likely white-acceleration std
    fixes: int  # steps of the window with a fix (the filter's measurements)
    at_bound: str | None  # "low" or "high" when the optimum is the grid's end (the true value may lie beyond)
    loglik: np.ndarray  # (len(GRID_MPS2),) the innovations' log-likelihood per grid value

    def report(self) -> dict[str, object]:
        return {"q_mps2": round(self.q_mps2, 4), "source": "fitted", "fixes": self.fixes, "at_bound": self.at_bound}


def _fixes(
    model: MeasurementModel, z: np.ndarray, known: list[Known], n_iter: int = 8
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per step with min_sensors readings: a weighted LS position and its covariance; (index, pos, cov)."""
    w_all = 1.0 / model.sigma_m**2
    rows, poss, covs = [], [], []
    start = model.initial_pos()
    for k in range(z.shape[0]):
        use = np.isfinite(z[k])
        if use.sum() < model.min_sensors:
            continue
        guess = model.initial_guess(np.where(use, z[k], np.nan), known[k])
        pos = (guess if np.isfinite(guess).all() else start).astype(float).copy()
        w = w_all[use]
        for _ in range(n_iter):
            hx, jac = model.h_jac(pos, known[k])
            j = jac[use] * np.sqrt(w)[:, None]
            step = np.linalg.lstsq(j, (z[k][use] - hx[use]) * np.sqrt(w), rcond=None)[0]
            pos = model.clip(pos + step)
            if float(step @ step) < 1e-10:
                break
        _, jac = model.h_jac(pos, known[k])
        info = (jac[use] * w[:, None]).T @ jac[use]
        try:
            cov = np.linalg.inv(info + 1e-9 * np.eye(model.d))
        except np.linalg.LinAlgError:
            continue
        rows.append(k)
        poss.append(pos)
        covs.append(cov)
        start = pos
    if not rows:
        return np.zeros(0, dtype=int), np.zeros((0, model.d)), np.zeros((0, model.d, model.d))
    return np.array(rows), np.array(poss), np.array(covs)


def loglik(model: MeasurementModel, t_s: np.ndarray, pos: np.ndarray, cov: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Innovation log-likelihood of a CV Kalman filter on position fixes, for every q of ``grid`` at once."""
    d, g = model.d, grid.size
    x = np.zeros((g, 2 * d))
    x[:, :d] = pos[0]
    big = np.zeros((2 * d, 2 * d))
    big[:d, :d] = cov[0]
    big[d:, d:] = np.eye(d)  # 1 m/s: the vehicle's speed is not known at the window's start
    P = np.broadcast_to(big, (g, 2 * d, 2 * d)).copy()
    total = np.zeros(g)
    axes = [model.axis_noise(float(q)) for q in grid]
    for k in range(1, pos.shape[0]):
        dt = float(t_s[k] - t_s[k - 1])
        if dt > 0:
            fq = [cv_matrices(d, dt, a) for a in axes]
            f = fq[0][0]
            q = np.array([m[1] for m in fq])
            x = x @ f.T
            P = np.einsum("ij,gjk,lk->gil", f, P, f) + q
        s_mat = P[:, :d, :d] + cov[k]
        nu = pos[k] - x[:, :d]
        s_inv = np.linalg.inv(s_mat)
        sol = np.einsum("gij,gj->gi", s_inv, nu)
        _, logdet = np.linalg.slogdet(s_mat)
        total += -0.5 * (logdet + np.einsum("gi,gi->g", nu, sol) + d * np.log(2 * np.pi))
        gain = np.einsum("gij,gjk->gik", P[:, :, :d], s_inv)
        x = x + np.einsum("gij,gj->gi", gain, nu)
        P = P - np.einsum("gij,gjk->gik", gain, P[:, :d, :])
        P = 0.5 * (P + np.transpose(P, (0, 2, 1)))
    return total


def fit_process_noise(
    model: MeasurementModel, t_s: np.ndarray, z: np.ndarray, known: list[Known], grid: np.ndarray = GRID_MPS2
) -> ProcessNoiseFit | None:
    """The most likely ``q_mps2`` on the window (``z`` (T, p) corrected readings, NaN missing); None with fewer than
    ``MIN_FIXES`` fixes."""
    rows, pos, cov = _fixes(model, np.asarray(z, dtype=float), known)
    if rows.size < MIN_FIXES:
        return None
    ll = loglik(model, np.asarray(t_s, dtype=float)[rows], pos, cov, np.asarray(grid, dtype=float))
    best = int(np.argmax(ll))
    bound = "low" if best == 0 else "high" if best == grid.size - 1 else None
    return ProcessNoiseFit(float(grid[best]), int(rows.size), bound, ll)
