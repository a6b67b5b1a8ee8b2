"""``EkfBank`` against a textbook EKF: the same predict and update, written as in FilterPy, on random models.

The bank's update is the push-through form (d x d algebra, batched over
subsets); the oracle below is the gain form a reader finds in any textbook:

    predict:  x = F x,               P = F P F^T + Q
    update:   y = z - h(x),          H = [dh/dpos, 0]
              S = H P H^T + R,       K = P H^T S^-1
              x = x + K y,           P = (I - K H) P (I - K H)^T + K R K^T   (Joseph form)
              NIS = y^T S^-1 y

restricted to the readings a filter uses (its mask, and not NaN). Both must
agree to rounding for every filter of a bank, with one filter (the bank's
single-filter path) and with many (the batched path).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimators.bank import EkfBank, cv_matrices
from estimators.models import AnchorRanges2D, AnchorRanges3D, MeasurementModel


class TextbookEkf:
    """One constant-velocity EKF on the readings of ``mask`` (state ``[pos(d), vel(d)]``)."""

    def __init__(self, model: MeasurementModel, mask: np.ndarray, x: np.ndarray, P: np.ndarray, q_mps2: float):
        self.model, self.mask, self.q = model, mask, q_mps2
        self.x, self.P = x.copy(), P.copy()

    def predict(self, dt_s: float) -> None:
        F, Q = cv_matrices(self.model.d, dt_s, self.q)
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + Q

    def update(self, z: np.ndarray) -> tuple[float, int]:
        d, n = self.model.d, self.x.shape[0]
        use = self.mask & ~np.isnan(z)
        if not use.any():
            return 0.0, 0
        hx, jac = self.model.h_jac(self.x[:d])
        H = np.hstack([jac[use], np.zeros((int(use.sum()), n - d))])
        R = np.diag(self.model.sigma_m[use] ** 2)
        y = z[use] - hx[use]
        S = H @ self.P @ H.T + R
        K = self.P @ H.T @ np.linalg.inv(S)
        self.x = self.x + K @ y
        IKH = np.eye(n) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T
        return float(y @ np.linalg.solve(S, y)), int(use.sum())


def _model(rng: np.random.Generator, dims: int, p: int) -> MeasurementModel:
    anchors = np.column_stack([rng.uniform(-10, 10, (p, 2)), rng.uniform(-3, 0, p)])
    sigma = rng.uniform(0.05, 0.5, p)
    return AnchorRanges2D.build(anchors, sigma) if dims == 2 else AnchorRanges3D.build(anchors, sigma)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), dims=st.sampled_from([2, 3]), n_filters=st.sampled_from([1, 4]))
def test_the_bank_is_a_textbook_ekf_per_filter(seed: int, dims: int, n_filters: int) -> None:
    rng = np.random.default_rng(seed)
    p = int(rng.integers(dims + 2, 9))
    model = _model(rng, dims, p)
    masks = rng.random((n_filters, p)) < 0.8
    masks[:, : dims + 1] = True  # every filter sees enough readings to be observable
    n = 2 * dims
    x0 = np.concatenate([rng.uniform(-5, 5, dims), rng.uniform(-1, 1, dims)])
    a = rng.normal(size=(n, n))
    P0 = a @ a.T * 0.1 + np.eye(n) * 0.05  # a random covariance, correlated position and velocity
    q = float(rng.uniform(0.1, 2.0))

    bank = EkfBank(model, masks, q)
    bank.seed(x0, P0)
    oracles = [TextbookEkf(model, masks[j], x0, P0, q) for j in range(n_filters)]
    truth = x0[:dims] + rng.normal(0, 0.3, dims)
    for _ in range(5):
        dt = float(rng.uniform(0.02, 0.3))
        z = model.h(truth) + rng.normal(0, model.sigma_m)
        z[rng.random(p) < 0.15] = np.nan  # missing readings
        bank.predict(dt)
        nis, dof = bank.update(z)
        for j, oracle in enumerate(oracles):
            oracle.predict(dt)
            want_nis, want_dof = oracle.update(z)
            assert dof[j] == want_dof
            assert nis[j] == pytest.approx(want_nis, rel=1e-7, abs=1e-9)
            np.testing.assert_allclose(bank.x[j], oracle.x, rtol=1e-8, atol=1e-9)
            np.testing.assert_allclose(bank.P[j], oracle.P, rtol=1e-7, atol=1e-10)
        truth = truth + rng.normal(0, 0.05, dims)
