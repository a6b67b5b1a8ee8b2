"""Seed test case 1 geometry shared by the estimator tests."""

from __future__ import annotations

import numpy as np

ANCHORS8_NED_M = np.array(
    [
        [0.0, 0.0, -1.0],
        [2.5, 0.0, -1.0],
        [5.0, 0.0, -1.0],
        [5.0, 2.5, -1.0],
        [5.0, 5.0, -1.0],
        [2.5, 5.0, -1.0],
        [0.0, 5.0, -1.0],
        [0.0, 2.5, -1.0],
    ]
)
HOVER_XY_M = np.array([2.5, 2.5])
SIGMA_M = 0.1
