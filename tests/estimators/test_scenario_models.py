"""Models built from the bundled scenarios carry the right geometry, noise and wire ids."""

from __future__ import annotations

import numpy as np

import estimators
from estimators.scenario_models import anchor_model, two_vehicle_model, wall_group_model
from secuav_common.scenario import load_scenario


def test_anchors8_model() -> None:
    model = anchor_model(load_scenario("anchors8"))
    assert model.p == 8 and model.sensor_ids == tuple(range(10, 18))
    assert model.vehicle_z_ned_m == -2.5 and np.allclose(model.sigma_m, 0.1)
    assert model.max_correctable == 2
    assert anchor_model(load_scenario("anchors8"), dims=3).d == 3


def test_wall_group_model_runs_every_estimator() -> None:
    model = wall_group_model(load_scenario("wall_hover"))
    assert model.sensor_ids == (0, 1, 2, 3, 4) and model.max_correctable == 2
    z = np.array([2.5, 2.5, 2.5, 9.0, 2.5])  # the infrared one lies
    assert "marzullo" in estimators.names(model)
    for name in estimators.names(model):
        out = estimators.create(name, model).step(0.0, z)
        assert out.ok, name
        if name not in ("ls", "ekf"):
            assert out.attacked == {3} and abs(out.position_m[0] - 2.5) < 0.05, name


def test_formation_model() -> None:
    model = two_vehicle_model(load_scenario("formation"))
    assert model.p == 17 and model.sensor_ids[-1] == 52
    assert model.vehicle_z_ned_m == (-2.5, -2.5)
