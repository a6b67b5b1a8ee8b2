"""Fixtures for the estimator tests: the seed's anchor layout and the wall group."""

from __future__ import annotations

import pytest

from estimators.models import AnchorRanges2D, ScalarGroup
from tests.support.est_helpers import ANCHORS8_NED_M, SIGMA_M


@pytest.fixture
def anchors8() -> AnchorRanges2D:
    return AnchorRanges2D.build(ANCHORS8_NED_M, SIGMA_M, vehicle_z_ned_m=-2.5)


@pytest.fixture
def wall_group() -> ScalarGroup:
    return ScalarGroup.build([0.02, 0.02, 0.05, 0.04, 0.08], sensor_ids=(0, 1, 2, 3, 4))
