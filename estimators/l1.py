"""``l1``: robust l1 decoder in the spirit of Fawzi, Tabuada and Diggavi.

Paper: H. Fawzi, P. Tabuada, S. Diggavi, "Secure estimation and control for
cyber-physical systems under adversarial attacks", IEEE TAC 59(6), 2014. Their
decoder, for linear systems, is ``x = argmin_x sum_i ||Y_i - O_i x||_2``: the
sum over sensors of per-sensor residual norms, a convex relaxation of "fewest
sensors attacked" (exact recovery when the attacked set is small enough that
the honest sensors' residuals outweigh the attacked ones').

Model: any ``MeasurementModel``; nonlinear models are relinearised at each
iterate. Attacker: at most ``s`` of p sensors arbitrary (default
``model.max_correctable``); Gaussian noise of std sigma_i.

Equations (our snapshot reading, window T = 1, so each sensor's residual norm
is ``|z_i - h_i(x)|``): minimise ``L(x) = sum_i |z_i - h_i(x)|`` by
iteratively reweighted least squares: Gauss-Newton steps on
``sum_i w_i (z_i - h_i(x))^2`` with ``w_i = 1 / max(|r_i|, eps sigma_i)``,
which majorises L at the current iterate (``eps`` = 0.5 keeps noise-level
residuals from dominating). Every sensor counts once in L, not weighted by
1/sigma_i: L relaxes "number of attacked sensors", and weighting would let two
attacked precise sensors outvote three honest coarse ones (on a scalar group
L's minimiser is then the plain median). Noise weights enter the refit below.
Start at the previous estimate (cold start: the model's starting point, with
fifteen times the iterations). Then decode: the
(at most s) readings with the largest l1 residuals that fail
``chi2.ppf(1 - alpha, 1)`` are set aside, and the rest are refitted by weighted
least squares (debiasing: the l1 solution alone is noisier than least squares
on clean data). If fewer than s were set aside and a kept reading fails on its
deleted residual, it is set aside too and the rest refitted once more. The
kept readings must pass ``cost <= chi2.ppf(1 - alpha, kept - d)``, else alarm
(more than s attacked). Attacked: set-aside readings that fail the tests of
``attribution.py`` against the refit (family-wise alpha).

RECON: IRLS instead of an LP/SOCP solver (same minimiser; faster, no extra
dependency), the per-step snapshot window, the decode threshold and the
debiasing refit are ours. Defaults: n_irls = 2, eps = 0.5, alpha = 0.01.

Asynchronous readings (``async_window_s``, estimators.aligned; the default on recorded ranges and in the secure
stage): the decoder reads one vector per output time: the window's readings brought to that time (window alignment);
its window of steps then holds aligned vectors, consecutive ones sharing a slow link's reading.
"""

from __future__ import annotations

import numpy as np

from estimators.bank import damping, gauss_newton, inv_small, solve_small
from estimators.base import TUNED_ON_BUNDLED, Estimate, Estimator
from estimators.models import Known, MeasurementModel


class L1Decoder(Estimator):
    name = "l1"
    tuned_on = TUNED_ON_BUNDLED
    secure = True

    def __init__(self, model: MeasurementModel, *, n_irls: int = 2, eps: float = 0.5, **params) -> None:
        self.n_irls = int(n_irls)
        self.eps = eps
        super().__init__(model, **params)

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        d = self.model.d
        self.pos = None if x0 is None else x0[:d].copy()

    def _irls(self, z: np.ndarray, avail: np.ndarray, start: np.ndarray, known: Known, n_iter: int) -> np.ndarray:
        model = self.model
        zf = np.where(avail, z, 0.0)
        pos = start[None, :].copy()
        damp = damping(model.d)
        floor = self.eps * model.sigma_m
        for _ in range(n_iter):
            hx, jac = model.h_jac(pos, known)
            r = (zf - hx) * avail
            w = avail / np.maximum(np.abs(r), floor)
            jtw = (jac * w[..., None]).mT
            step = solve_small(jtw @ jac + damp, (jtw @ r[..., None])[..., 0])
            pos = model.clip(pos + step)
            if float(np.vdot(step, step)) < 1e-12:
                break
        return pos[0]

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        model = self.model
        avail = ~np.isnan(z)
        if avail.sum() < model.min_sensors:
            return self._estimate(t_s, self.pos, alarm=self.pos is None)
        start = model.initial_guess(z, known) if self.pos is None else self.pos
        # IRLS converges linearly: a cold start (far from the minimiser) gets fifteen times the budget.
        pos = self._irls(z, avail, start, known, self.n_irls if self.pos is not None else 15 * self.n_irls)
        at_pos = model.h_jac(pos, known)  # also the refit's first evaluation
        resid = z - at_pos[0]
        t = resid * resid / model.sigma_m**2
        t = np.where(np.isnan(t), -1.0, t)  # missing readings are never set aside
        # Decode: at most s readings, the largest l1 residuals that fail the gate, are
        # set aside; the rest must then be consistent as a whole, else alarm.
        worst = np.argsort(-t)[: self.s]
        use = avail.copy()
        use[worst[t[worst] > self.gate1]] = False
        fit = gauss_newton(model, z, use[None, :], pos, known, 2, at_start=at_pos)  # starts at the l1 solution
        cov = inv_small(fit.info[0])
        # Budget left (fewer than s set aside) and a kept reading fails on its deleted residual:
        # set it aside too (an attack near the gate can hide in the l1 fit).
        t = self._studentised(fit.raw[0], fit.jac[0], cov, use)
        worst = int(np.argmax(np.where(use, t, -np.inf)))
        if (avail & ~use).sum() < self.s and t[worst] > self.gate1 and use.sum() > model.min_sensors:
            use[worst] = False
            fit = gauss_newton(model, z, use[None, :], fit.pos[0], known, 2)
            cov = inv_small(fit.info[0])
        pos, cost = fit.pos[0], float(fit.cost[0])
        alarm = bool(use.sum() < model.min_sensors or cost > self.chi(int(use.sum()) - model.d))
        self.pos = pos
        return self._estimate(t_s, pos, cov=cov, alarm=alarm, used=use)
