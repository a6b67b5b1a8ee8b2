"""``l0``: the exact reference, an exhaustive search over every trusted subset over a window.

Paper: the l0 decoder of secure state estimation (Fawzi, Tabuada, Diggavi, IEEE
TAC 2014; Pajic et al., IEEE TCNS 2017, its "l0" problem): among all ways of
declaring at most ``s`` sensors attacked, pick the one whose remaining readings
fit the model best. It is combinatorial, which is why the other estimators
exist; here it is the answer they are checked against (small p only).

Model: any ``MeasurementModel``. Attacker: at most ``s`` sensors, the same ones
over the window of ``T`` steps, carrying arbitrary values; Gaussian noise.

Equations. For every subset S with |S| = p - s and every step t of the window,
``J_S,t = min_pos sum_{i in S} (z_i,t - h_i(pos))^2 / sigma_i^2``, solved to
convergence by Gauss-Newton from several starts (the previous answer, the
model's start, a grid over its box; the smallest minimum wins, so a local
minimum of the ranges cannot hide the global one). The window statistic
``E_S = sum_t J_S,t`` is chi-square with ``sum_t (|S|_t - d)`` degrees of
freedom when S is clean. The answer is ``S* = argmin_S E_S``: no gating, no
lazy evaluation, no evidence cleared. ``E_S* > chi2_{1-alpha}(dof)`` means no
subset of p - s sensors is consistent: more than s are attacked (or the model
is wrong), so the estimate is raised as an alarm (degraded, not to be trusted).
Output: S*'s fix at the current step and its covariance ``(H^T W H)^-1``;
attacked: sensors outside S* that fail the tests of ``attribution.py`` (family-wise alpha).
Defaults: T = 10, alpha = 0.01; refuses more than ``max_subsets`` subsets.

Asynchronous readings (``async_window_s``, estimators.aligned; the default on recorded ranges and in the secure
stage): the exhaustive search reads one vector per step, the window's readings brought to the step's time
(window alignment); its window of steps sums aligned steps.
"""

from __future__ import annotations

import itertools

import numpy as np

from estimators.bank import GnResult, gauss_newton, inv_small
from estimators.base import TUNED_ON_BUNDLED, Estimate, Estimator
from estimators.models import Known, MeasurementModel

GRID_PER_AXIS = 3  # starts per axis of the model's box (models of up to two dimensions)


class L0Exact(Estimator):
    name = "l0"
    tuned_on = TUNED_ON_BUNDLED
    secure = True

    def __init__(
        self, model: MeasurementModel, *, window: int = 10, max_subsets: int = 500, max_iter: int = 25, **params
    ) -> None:
        self.window = int(window)
        self.max_subsets = int(max_subsets)
        self.max_iter = int(max_iter)
        super().__init__(model, **params)

    @classmethod
    def applies_to(cls, model: MeasurementModel) -> bool:
        return model.subset_count(model.max_correctable) <= 500

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        model = self.model
        count = model.subset_count(self.s)  # counted first: building C(24, 11) masks to refuse them took seconds
        if count > self.max_subsets:
            raise ValueError(
                f"l0: {count} subsets of {model.p} sensors (tolerance {self.s}) exceed "
                f"max_subsets={self.max_subsets}; it is the exact reference for small p"
            )
        self.masks = model.honest_subsets(self.s)
        n_sub = self.masks.shape[0]
        self.cost_buf = np.zeros((self.window, n_sub))
        self.dof_buf = np.zeros((self.window, n_sub), dtype=int)
        self.k = 0
        self.pos = None if x0 is None else x0[: model.d].copy()
        self.starts = self._box_grid()

    def _box_grid(self) -> list[np.ndarray]:
        model = self.model
        starts = [model.initial_pos()]
        if model.bounds_m is not None and model.d <= 2:
            lo, hi = (np.asarray(b, dtype=float) for b in model.bounds_m)
            axes = [np.linspace(lo[k], hi[k], GRID_PER_AXIS + 2)[1:-1] for k in range(model.d)]
            starts += [np.array(point) for point in itertools.product(*axes)]
        return starts

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        model, d = self.model, self.model.d
        starts = [model.initial_guess(z, known), *self.starts] if self.pos is None else [self.pos, *self.starts]
        if d == 1:  # a scalar group: every reading is a start, so the global minimum is always among them
            starts = [*starts, *(np.array([v]) for v in z[~np.isnan(z)])]
        best = None
        for start in starts:
            fit = gauss_newton(model, z, self.masks, start, known, self.max_iter, tol_m=1e-7)
            if best is None:
                best = fit
                continue
            better = fit.cost < best.cost - 1e-12
            if better.any():
                best = _merge(best, fit, better)
        assert best is not None
        slot = self.k % self.window
        self.k += 1
        self.cost_buf[slot] = best.cost
        self.dof_buf[slot] = np.maximum(best.n_used - d, 0)
        valid = best.n_used >= model.min_sensors
        if not valid.any():
            return self._estimate(t_s, self.pos, alarm=True)
        total = np.where(valid, self.cost_buf.sum(axis=0), np.inf)
        dof = self.dof_buf.sum(axis=0)
        j = int(np.argmin(total))
        alarm = bool(total[j] > self.chi(int(dof[j])))
        self.pos = best.pos[j].copy()
        cov = inv_small(best.info[j])
        use = self.masks[j] & ~np.isnan(z)
        return self._estimate(t_s, self.pos, cov=cov, alarm=alarm, used=use)


def _merge(a: GnResult, b: GnResult, take_b: np.ndarray) -> GnResult:
    """Per subset, the fit of ``b`` where ``take_b``, else ``a``."""
    fields = {}
    for name in ("pos", "cost", "info", "n_used", "resid", "raw", "jac"):
        va, vb = np.asarray(getattr(a, name)), np.asarray(getattr(b, name))
        fields[name] = np.where(take_b.reshape(-1, *([1] * (va.ndim - 1))), vb, va)
    return GnResult(**fields)
