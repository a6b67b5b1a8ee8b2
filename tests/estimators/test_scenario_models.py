"""Models built from the bundled scenarios carry the right geometry, noise and wire ids."""

from __future__ import annotations

import numpy as np

import estimators
from estimators.scenario_models import anchor_model, two_vehicle_model, wall_group_model
from secuav_common.scenario import load_scenario


def test_anchors8_model() -> None:
    # Default: the full position, the downward laser (id 0) one more reading beside the eight anchors.
    model = anchor_model(load_scenario("anchors8"))
    assert model.p == 9 and model.d == 3 and model.sensor_ids == (*range(10, 18), 0)
    assert np.allclose(model.sigma_m[:8], 0.1) and 0.02 < model.sigma_m[8] < 0.05  # laser noise + tilt allowance
    assert model.max_correctable == 2
    truth = np.array([2.5, 2.5, -2.5])
    assert model.h(truth)[8] == 2.5 and np.allclose(model.jac(truth)[8], [0.0, 0.0, -1.0])
    # The seed's split: (north, east), the height known.
    flat = anchor_model(load_scenario("anchors8"), dims=2)
    assert flat.p == 8 and flat.sensor_ids == tuple(range(10, 18))
    assert flat.vehicle_z_ned_m == -2.5 and np.allclose(flat.sigma_m, 0.1) and flat.max_correctable == 2


def test_wall_group_model_runs_every_estimator() -> None:
    model = wall_group_model(load_scenario("wall_hover"))
    assert model.sensor_ids == (0, 1, 2, 3, 4) and model.max_correctable == 2
    z = np.array([2.5, 2.5, 2.5, 9.0, 2.5])  # the infrared one lies
    assert "marzullo" in estimators.names(model)
    for name in [n for n in estimators.names(model) if n in estimators.registry.builtin_names()]:
        out = estimators.create(name, model).step(0.0, z)
        assert out.ok, name
        if name not in ("ls", "ekf"):
            assert out.attacked == {3} and abs(out.position_m[0] - 2.5) < 0.05, name


def test_formation_model() -> None:
    model = two_vehicle_model(load_scenario("formation"))
    assert model.p == 17 and model.sensor_ids[-1] == 52
    assert model.vehicle_z_ned_m == (-2.5, -2.5)


def test_a_stated_area_replaces_the_anchor_box() -> None:
    # A site where the vehicle ranges far outside its anchors (a recorded outdoor run) states the area the fixes
    # may lie in; without it they are clipped to the anchors' box plus 20 %.
    import pytest
    from pydantic import ValidationError

    base = load_scenario("anchors8")
    area = {"min_ne_m": (-10.0, -20.0), "max_ne_m": (40.0, 30.0)}
    wide = base.model_copy(update={"world": base.world.model_validate({**base.world.model_dump(), "area": area})})
    for dims in (2, 3):
        boxed, model = anchor_model(base, dims=dims), anchor_model(wide, dims=dims)
        assert np.allclose(model.bounds_m[0][:2], [-10.0, -20.0]) and np.allclose(model.bounds_m[1][:2], [40.0, 30.0])
        assert np.allclose(model.bounds_m[0][2:], boxed.bounds_m[0][2:])  # the height bounds stay
        assert np.allclose(model.clip(np.array([35.0, 25.0, -2.5][:dims])), [35.0, 25.0, -2.5][:dims])
        assert not np.allclose(boxed.clip(np.array([35.0, 25.0, -2.5][:dims])), [35.0, 25.0, -2.5][:dims])
    with pytest.raises(ValidationError, match="must lie below"):
        base.world.model_validate({**base.world.model_dump(), "area": {"min_ne_m": (5, 0), "max_ne_m": (5, 10)}})
