"""The estimator contract a plugin relies on (docs/plugins.md): ``make_estimate``, ``attribution``, the listing's
summary without its label."""

from __future__ import annotations

import numpy as np
import pytest

from estimators import AnchorRanges2D, create, registry
from estimators.base import Estimate, Estimator

ANCHORS = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0], [2.0, 0.0], [0.0, 2.0]])


def _model() -> AnchorRanges2D:
    return AnchorRanges2D.build(np.column_stack([ANCHORS, np.full(6, -1.0)]), 0.1, -2.0)


class Liar(Estimator):
    """ransac_ls: a stand-in that names reading 0 and says its answer is degraded."""

    name = "ransac_ls"
    secure = True

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        self.pos = np.array([2.0, 2.0])

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: object) -> Estimate:
        mask = np.zeros(self.model.p, dtype=bool)
        mask[0] = True
        return self.make_estimate(t_s, self.pos, covariance=0.01 * np.eye(2), used=~mask, attacked=mask,
                                  alarm=True, valid=False)  # fmt: skip


def test_make_estimate_carries_the_methods_own_claim_without_the_attribution() -> None:
    model = _model()
    z = model.h(np.array([2.0, 2.0]), model.default_known)
    own = Liar(model, attribution=False)
    out = own.step(0.0, z)
    assert out.attacked == frozenset({0}) and out.alarm and not out.valid and out.used == frozenset(range(1, 6))
    assert out.own_attacked == frozenset({0}) and out.own_alarm  # recorded as its own (secure: detects)
    judged = Liar(model).step(0.0, z)  # the class's default: secure, so the shared attribution runs
    assert judged.own_attacked == frozenset({0}) and judged.attacked == frozenset()  # the attribution's names
    assert Liar(model).attribution and not create("ekf", model).attribution


def test_make_estimate_refuses_readings_that_are_not_there() -> None:
    est = Liar(_model(), attribution=False)
    with pytest.raises(ValueError, match=r"0\.\.5"):
        est.make_estimate(0.0, np.zeros(2), attacked=[6])
    with pytest.raises(ValueError, match="6 entries"):
        est.make_estimate(0.0, np.zeros(2), used=np.ones(3, dtype=bool))
    assert not est.make_estimate(0.0, None).ok


@pytest.mark.parametrize("first", ["ransac_ls: RANSAC", "``ransac_ls``: RANSAC", "`ransac_ls` - RANSAC", "RANSAC"])
def test_the_listing_shows_the_summary_once_without_its_label(first: str) -> None:
    cls = type("R", (Liar,), {"__doc__": first + " then least squares.\n"})
    assert registry.summary(cls) == "RANSAC then least squares."
