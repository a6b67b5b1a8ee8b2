"""A per-sensor window test for persistent small biases, shared by ``rarse`` and ``recap``.

RECON (our addition to both, not from any paper): a bias of a few sigma, or a
coordinated spoof that drifts slowly, hides inside any one step's chi-square
gate, so a per-step detector lets it pull the state along. Over a window of T
steps it cannot hide: each sensor's innovation against the filter's prediction,
normalised by its predicted std ``sqrt(sigma_i^2 + H_i P_pos H_i^T)``, is
~N(0, 1) for an honest sensor, so the window mean m over n readings is
~N(0, 1/n) and ``n m^2`` is chi-square with one degree of freedom. A sensor
fails when ``n m^2 > chi2.ppf(1 - alpha, 1)`` with at least 3 readings in the
window; the caller leaves failing sensors out of its estimate (only if at most
s fail: more means the prediction itself has drifted). This decides what the
estimate rests on, at each reading's own level alpha; who is *named* is decided
separately, at a family-wise level, by ``attribution.py``.
"""

from __future__ import annotations

import numpy as np


class InnovationWindow:
    """Ring buffer of signed normalised innovations (0 = missing) with running sums: O(p) per step."""

    def __init__(self, p: int, window: int, gate1: float) -> None:
        self.window = int(window)
        self.gate1 = gate1
        self.innov = np.zeros((self.window, p))
        self.seen = np.zeros((self.window, p), dtype=bool)
        self.innov_sum = np.zeros(p)
        self.seen_sum = np.zeros(p, dtype=int)
        self.k = 0
        self.vif = 1.0  # window-mean variance inflation for time-correlated errors (estimators.noise)

    def update(
        self, z: np.ndarray, hx: np.ndarray, jac: np.ndarray, cov_pos: np.ndarray, sigma_m: np.ndarray
    ) -> np.ndarray:
        """Add this step's innovations ``z - hx`` (Jacobian ``jac`` at the prediction); return the failing sensors."""
        var = sigma_m**2 + np.einsum("pd,de,pe->p", jac, cov_pos, jac)
        slot = self.k % self.window
        self.k += 1
        seen = ~np.isnan(z)
        value = np.where(seen, z - hx, 0.0) / np.sqrt(var)
        self.innov_sum += value - self.innov[slot]
        self.seen_sum += seen.astype(int) - self.seen[slot]
        self.innov[slot], self.seen[slot] = value, seen
        n = self.seen_sum
        # n m^2 with m = sum / n is sum^2 / n.
        return (n >= 3) & (self.innov_sum * self.innov_sum > self.gate1 * self.vif * n)
