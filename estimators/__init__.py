"""Secure state estimators for range-based UAV localisation (pure numpy/scipy library).

``create(name, model, **params)`` builds one; ``names()`` lists them; every
estimator has ``reset(x0=None, t_s=0.0, P0=None)`` and
``step(t_s, z, known=None) -> Estimate``. Models live in ``estimators.models``.
"""

from estimators.base import Estimate, Estimator
from estimators.ekf import ExtendedKalman
from estimators.l0 import L0Exact
from estimators.l1 import L1Decoder
from estimators.ls import LeastSquares
from estimators.marzullo import Marzullo
from estimators.milp import Milp
from estimators.models import (
    AnchorRanges2D,
    AnchorRanges3D,
    LinearModel,
    MeasurementModel,
    ScalarGroup,
    TwoVehicleRanges,
)
from estimators.poly import Polyhedral
from estimators.rarse import Rarse
from estimators.recap import Recap
from estimators.registry import create, known, names, register
from estimators.secekf import SecEkf
from estimators.secopt import SecOpt

_ALL = (LeastSquares, ExtendedKalman, L1Decoder, SecEkf, SecOpt, Recap, Rarse, Polyhedral, L0Exact, Milp, Marzullo)
for _cls in _ALL:
    register(_cls)

__all__ = [
    "AnchorRanges2D",
    "AnchorRanges3D",
    "Estimate",
    "Estimator",
    "LinearModel",
    "MeasurementModel",
    "ScalarGroup",
    "TwoVehicleRanges",
    "create",
    "known",
    "names",
]
