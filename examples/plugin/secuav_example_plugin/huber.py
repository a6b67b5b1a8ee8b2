"""``huber``: a Huber M-estimator of position, snapshot by snapshot (an undefended robust baseline).

Paper: P. J. Huber, "Robust estimation of a location parameter", Ann. Math.
Statist. 35 (1964); solved by iteratively reweighted least squares (IRLS).
Model: any SecUAV ``MeasurementModel`` (anchor ranges, a scalar group).
Attacker: none assumed. Readings whose normalised residual ``|r_i| / sigma_i``
exceeds ``huber_k`` get the weight ``huber_k sigma_i / |r_i|`` instead of 1, so a
single large lie moves the fix by a bounded amount; several coordinated lies
still move it. Its own claim (``detects = True``): the readings whose final
normalised residual exceeds ``name_k`` are named attacked, an alarm is raised when
any is, and the answer is not valid when fewer than ``model.min_sensors`` readings
are left unnamed. It is not ``secure``: it claims no tolerance of attacked links,
so the bench does not run the shared attribution on it.

Each step, from the previous fix: ``n_irls`` times, ``r = z - h(pos)``,
``w_i = min(1, k / |r_i / sigma_i|) / sigma_i^2``, ``pos += (H^T W H)^-1 H^T W r``.
Covariance ``(H^T W H)^-1`` at the last iterate. Everything it calls is public
(docs/plugins.md, "The estimator contract"): ``model.h_jac``, ``model.clip``,
``model.initial_guess``, ``model.min_sensors``, ``model.sigma_m`` and
``self.make_estimate``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from estimators.base import Estimate, Estimator
from estimators.models import Known, MeasurementModel


class Huber(Estimator):
    name = "huber"
    detects = True  # its own attacked/alarm are scored (own_* columns); it is not secure: no attribution row
    tuned_on = "example defaults: Huber's 95 % efficiency constant, not tuned on the suite"
    # Shown by `secuav-plugins` beside the defaults read from __init__'s signature.
    param_ranges: ClassVar[dict[str, tuple[float, float]]] = {
        "huber_k": (0.5, 5.0), "n_irls": (1, 50), "name_k": (2.0, 20.0)}  # fmt: skip

    def __init__(self, model: MeasurementModel, *, huber_k: float = 1.345, n_irls: int = 8, name_k: float = 4.0,
                 **params: object) -> None:  # fmt: skip
        for key, value in (("huber_k", huber_k), ("name_k", name_k)):
            low, high = self.param_ranges[key]
            if not low <= value <= high:
                raise ValueError(f"{key}={value} must lie in [{low}, {high}]")
        self.huber_k = float(huber_k)
        self.n_irls = int(n_irls)
        self.name_k = float(name_k)
        # The base class's keywords (s, alpha, attribution, ...) go on to it: the bench passes some of them.
        super().__init__(model, **params)  # type: ignore[arg-type]

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        d = self.model.d
        self.pos = None if x0 is None else x0[:d].copy()
        self.cov = P0[:d, :d].copy()

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        avail = ~np.isnan(z)
        if avail.sum() < self.model.min_sensors:
            return self.make_estimate(t_s, self.pos, covariance=self.cov, used=avail, valid=False)
        pos = self.model.initial_guess(z, known) if self.pos is None else self.pos.copy()
        sigma = np.broadcast_to(np.asarray(self.model.sigma_m, dtype=float), z.shape)
        info = np.eye(self.model.d)
        for _ in range(self.n_irls):
            hx, jac = self.model.h_jac(pos, known)
            r = np.where(avail, z - hx, 0.0)
            u = np.abs(r) / sigma
            w = np.where(u <= self.huber_k, 1.0, self.huber_k / np.maximum(u, 1e-12)) * avail / sigma**2
            info = jac.T @ (w[:, None] * jac) + 1e-9 * np.eye(self.model.d)
            step = np.linalg.solve(info, jac.T @ (w * r))
            pos = self.model.clip(pos + step)
            if float(step @ step) < 1e-10:
                break
        self.pos, self.cov = pos, np.linalg.inv(info)
        u = np.abs(np.where(avail, z - self.model.h_jac(pos, known)[0], 0.0)) / sigma
        named = avail & (u > self.name_k)  # its own claim: these readings lie
        honest = int((avail & ~named).sum())
        return self.make_estimate(t_s, self.pos, covariance=self.cov, used=avail & ~named, attacked=named,
                                  alarm=bool(named.any()), valid=honest >= self.model.min_sensors)  # fmt: skip
