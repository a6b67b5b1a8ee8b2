"""``poly``: the polyhedral reading of RARSE, set membership on circles turned into polygons.

Source: the seed thesis explains range localisation with its Fig. 2.3, a
circle discretised as a polygon with a FIXED matrix of face normals A, only
the offset vector b depending on the anchor and the reading, and cites ReSeT
(Alanwar, Snyder, Etzlinger, Chakraborty, Hespanha, Srivastava, "ReSeT:
Reformulating Secure State Estimation for Resilient Cyber-Physical Systems",
2018) by the same group as SecSens. RARSE is the one estimator of its Table 5.1
without an algorithm box, and no document or code named RARSE or ReSeT could be
found (estimators/README.md#what-the-sources-allow-us-to-check). This file is our reading of
that formulation; ``rarse.py`` keeps the earlier RANSAC reading so the two can
be compared. Everything below is RECON.

Model: ``AnchorRanges2D`` (horizontal position, height known: the seed's own
split). Attacker: at most ``s`` readings arbitrary. Noise: bounded by
``k_sigma`` standard deviations (set membership).

Equations. A reading ``r_i`` with tolerance ``eps_i = k sigma_i`` says the
vehicle lies within horizontal distance ``rho_i = sqrt((r_i + eps_i)^2 - dz_i^2)``
of anchor ``a_i``. The polygon circumscribing that disc, ``A x <= A a_i + rho_i 1``
(the N rows of A the unit normals at angles 2 pi k / N), contains the whole
disc, so an honest reading never excludes the truth. The estimate is the
centre of the largest disc inside the intersection of the kept readings'
polygons (its Chebyshev centre), with at most s readings dropped:

    min   lam * sum_i b_i - t
    s.t.  A x + t 1 - M b_i 1 <= A a_i + rho_i 1    (every reading i)
          sum_i b_i <= s,   b_i in {0, 1},   t >= 0,   x in the model's box

solved by ``scipy.optimize.milp`` (HiGHS). Infeasible (no s readings to drop
leave a common point): alarm, the previous estimate is kept. Attacked:
``b_i = 1``, then the tests of ``attribution.py``, against a covariance that
adds the set's own scale ``(k sigma)^2`` to the kept readings' least squares
(the centre of a set is no minimum-variance point). The set itself is a
guaranteed region under the noise bound, the point is only its centre.

Limits (measured in ``tests/estimators/test_poly.py``): only the outer
boundary of each annulus is convex, so a reading spoofed LONGER merely
loosens its own polygon and is never caught (a shortened one empties the
intersection and is dropped); the Chebyshev centre is a coarse point
estimate (the lens the outer polygons leave is ~2 eps wide), which is why the
seed's figures show RARSE noisier than the filters. Defaults: N = 16, k = 3,
lam = 10, M from the model's box (just large enough that a dropped reading's
rows never bind inside it).

Asynchronous readings (``async_window_s``, estimators.aligned; the default on recorded ranges and in the secure
stage): the polygons are drawn around one vector per step, the window's readings brought to the step's time
(window alignment).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, milp

from estimators.base import TUNED_ON_BUNDLED, Estimate, Estimator
from estimators.models import AnchorRanges2D, Known, MeasurementModel


class Polyhedral(Estimator):
    name = "poly"
    tuned_on = TUNED_ON_BUNDLED
    secure = True

    def __init__(
        self,
        model: MeasurementModel,
        *,
        faces: int = 16,
        k_sigma: float = 3.0,
        lam: float = 10.0,
        big_m: float | None = None,
        **params,
    ) -> None:
        if not self.applies_to(model):
            raise ValueError(f"poly works on 2-D anchor ranges (the seed's Fig. 2.3), not a {type(model).__name__}")
        angles = 2.0 * np.pi * np.arange(int(faces)) / int(faces)
        self.normals = np.column_stack([np.cos(angles), np.sin(angles)])  # A: fixed, only b follows the readings
        self.k_sigma, self.lam, self.big_m = k_sigma, lam, big_m
        super().__init__(model, **params)

    @classmethod
    def applies_to(cls, model: MeasurementModel) -> bool:
        return isinstance(model, AnchorRanges2D)

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        self.pos = None if x0 is None else x0[:2].copy()

    def offsets(self, z: np.ndarray, known: Known) -> np.ndarray:
        """b_i of every reading's circumscribed polygon, ``(p, N)`` (NaN rows for missing readings)."""
        model = self.model
        assert isinstance(model, AnchorRanges2D)
        anchors = model.anchors_ned_m[:, :2]
        height = model.vehicle_z_ned_m if known is None else float(np.ravel(known)[0])
        dz = height - model.anchors_ned_m[:, 2]
        reach = z + self.k_sigma * model.sigma_m
        rho = np.sqrt(np.maximum(reach * reach - dz * dz, 0.0))
        return anchors @ self.normals.T + rho[:, None]

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        model = self.model
        have = ~np.isnan(z)
        if int(have.sum()) < model.min_sensors:
            return self._estimate(t_s, self.pos, alarm=self.pos is not None, used=have)
        solved = self._solve(self.offsets(z, known), have)
        if solved is None:
            return self._estimate(t_s, self.pos, alarm=True, used=have)
        self.pos, dropped = solved
        use = have & ~dropped
        jac = model.jac(self.pos, known)[use]
        info = (jac / model.sigma_m[use, None] ** 2).T @ jac + 1e-9 * np.eye(2)
        # The centre of a set is no minimum-variance point: its spread is the set's, about k sigma.
        spread = (self.k_sigma * float(np.mean(model.sigma_m[use]))) ** 2
        return self._estimate(t_s, self.pos, cov=np.linalg.inv(info) + spread * np.eye(2), used=use)

    def _big_m(self, b: np.ndarray) -> float:
        """Large enough that a dropped reading's rows never bind anywhere in the box, small enough to keep the
        relaxation tight: the largest ``A x + t`` over the box's corners (t up to the box) less the smallest b."""
        lo, hi = self.model.bounds_m if self.model.bounds_m is not None else (np.full(2, -1e3), np.full(2, 1e3))
        corners = np.array([[x, y] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])
        reach = float(np.max(corners @ self.normals.T)) + float(np.max(hi - lo))
        return max(reach - float(np.min(b)), 1.0) + 1.0

    def _solve(self, b: np.ndarray, have: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Variables [x (2), t, b (p)]; None if infeasible."""
        p, faces = b.shape
        idx = np.flatnonzero(have)
        big_m = self.big_m if self.big_m is not None else self._big_m(b[idx])
        n = 3 + p
        rows = np.zeros((idx.size * faces, n))
        for j, i in enumerate(idx):
            block = slice(j * faces, (j + 1) * faces)
            rows[block, :2] = self.normals
            rows[block, 2] = 1.0
            rows[block, 3 + i] = -big_m
        budget = np.zeros((1, n))
        budget[0, 3:] = 1.0
        cost = np.concatenate([[0.0, 0.0, -1.0], np.full(p, self.lam)])
        lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
        if self.model.bounds_m is not None:
            lo[:2], hi[:2] = self.model.bounds_m
        lo[2], lo[3:], hi[3:] = 0.0, 0.0, 1.0
        hi[3:][~have] = 0.0  # a missing reading has no polygon to drop
        res = milp(
            cost,
            constraints=[LinearConstraint(rows, -np.inf, b[idx].reshape(-1)), LinearConstraint(budget, 0.0, self.s)],
            integrality=np.concatenate([np.zeros(3), np.ones(p)]),
            bounds=Bounds(lo, hi),
            options={"time_limit": 1.0},
        )
        if res.x is None:
            return None
        return res.x[:2].copy(), res.x[3:] > 0.5
