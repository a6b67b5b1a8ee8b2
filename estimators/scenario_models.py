"""Measurement models built from a scenario file (anchors, rangefinder groups, peers).

The wire ids of docs/interfaces.md ride along as ``sensor_ids``, so a caller can map
``Estimate.attacked`` (indices into z) back to DISTANCE_SENSOR ids. Imports only
the shared scenario schema, never a service.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from estimators.models import (
    AnchorRanges2D,
    AnchorRanges3D,
    AnchorRangesHeight,
    MeasurementModel,
    ScalarGroup,
    TwoVehicleRanges,
)
from secuav_common.scenario import Rangefinder, Scenario, Vehicle, WallDistanceTarget
from secuav_common.sensor_ids import anchor_sensor_id, peer_sensor_id


def _uwb_anchor_ids(scenario: Scenario, vehicle: Vehicle) -> list[int]:
    uwb = vehicle.sensors.uwb
    if uwb is None:
        raise ValueError(f"vehicle {vehicle.sysid} of scenario {scenario.name!r} has no UWB ranging")
    return sorted(scenario.anchor_positions(uwb.anchors))


# The downward laser measures along the body axis; a tilt of t lengthens it by 1/cos(t) - 1 (0.4 % at 5 deg,
# 1.5 % at 10 deg), a bias with the tilt. The model treats 1 % of the hold height as extra noise on top of the
# laser's own.
LASER_TILT_FRACTION = 0.01
HOVER_BAND_M = 0.5  # the flight region's half height around the hold height (the model's flight_region)


def model_for(scenario: Scenario, dims: int = 3) -> MeasurementModel:
    """The measurement model the estimators run on for this scenario, by what it is (``Scenario.kind``): the wall
    group, both vehicles' ranges, or the first vehicle's anchor ranges (``dims`` as in :func:`anchor_model`)."""
    first = scenario.vehicles[0]
    if scenario.kind == "wall":
        return wall_group_model(scenario, first.sysid)
    if scenario.kind == "formation":
        return two_vehicle_model(scenario, first.sysid, scenario.vehicles[1].sysid)
    return anchor_model(scenario, first.sysid, dims)


def anchor_model(
    scenario: Scenario, sysid: int = 1, dims: int = 3
) -> AnchorRanges2D | AnchorRanges3D | AnchorRangesHeight:
    """The vehicle's UWB anchor ranges.

    ``dims=3`` (default): the full NED position, and the downward laser, if the
    vehicle has one, is one more reading (its DISTANCE_SENSOR id last in
    ``sensor_ids``), so a spoofed laser is outvoted like a spoofed range.
    ``dims=2``: (north, east) with the height a known input (the seed's split;
    the hold altitude is its default), which leaves the laser outside every test.
    """
    model = _anchor_model(scenario, sysid, dims)
    area = scenario.world.area
    if area is None or model.bounds_m is None:
        return model
    # The scenario's area replaces the anchors' box horizontally (north, east); the height bounds stay.
    lo, hi = (np.array(b, dtype=float) for b in model.bounds_m)
    lo[:2], hi[:2] = area.min_ne_m, area.max_ne_m
    return dataclasses.replace(model, bounds_m=(lo, hi))


def _anchor_model(
    scenario: Scenario, sysid: int, dims: int
) -> AnchorRanges2D | AnchorRanges3D | AnchorRangesHeight:
    vehicle = scenario.vehicle(sysid)
    ids = _uwb_anchor_ids(scenario, vehicle)
    table = scenario.anchor_positions(ids)
    anchors = np.array([table[k] for k in ids])
    sigma = vehicle.sensors.uwb.noise_std_m if vehicle.sensors.uwb else 0.1
    wire = tuple(anchor_sensor_id(k) for k in ids)
    z = _hold_z(vehicle)
    if dims == 3:
        # The flight region the layout check (estimators/observability.py) covers: over the anchors, within
        # HOVER_BAND_M of the hold height. Take-off and landing are outside it, and so are its claims.
        region = (
            np.array([*anchors[:, :2].min(axis=0), z - HOVER_BAND_M]),
            np.array([*anchors[:, :2].max(axis=0), z + HOVER_BAND_M]),
        )
        laser = down_rangefinder(vehicle)
        if laser is None:
            return AnchorRanges3D.build(anchors, sigma, sensor_ids=wire, region_m=region)
        laser_sigma = float(np.hypot(max(laser.noise_std_m, 1e-3), LASER_TILT_FRACTION * abs(z)))
        return AnchorRangesHeight.build_with_laser(
            anchors, sigma, laser_sigma, sensor_ids=(*wire, laser.id), region_m=region
        )
    return AnchorRanges2D.build(anchors, sigma, vehicle_z_ned_m=z, sensor_ids=wire)


def down_rangefinder(vehicle: Vehicle) -> Rangefinder | None:
    """The vehicle's first downward-looking rangefinder (its height), if any."""
    return next((r for r in vehicle.sensors.rangefinders if r.orientation == "down"), None)


def _hold_z(vehicle: Vehicle) -> float:
    """NED down of the vehicle's hold target (-2.5 m without one)."""
    target = vehicle.target
    if target is None:
        return -2.5
    return target.pos_ned_m[2] if hasattr(target, "pos_ned_m") else -target.altitude_m


def wall_group_model(scenario: Scenario, sysid: int = 1) -> ScalarGroup:
    """The redundant rangefinder group of a wall-distance target (ReCaP's setting)."""
    vehicle = scenario.vehicle(sysid)
    target = vehicle.target
    if not isinstance(target, WallDistanceTarget):
        raise ValueError(f"vehicle {sysid} of scenario {scenario.name!r} has no wall_distance target")
    by_id = {r.id: r for r in vehicle.all_rangefinders}  # its own, or a companion's fed to it (external)
    return ScalarGroup.build(
        [max(by_id[i].noise_std_m, 1e-3) for i in target.sensor_ids],
        sensor_ids=tuple(target.sensor_ids),
        normal_ned=tuple(scenario.wall(target.wall).normal_ned),
    )


def two_vehicle_model(scenario: Scenario, first: int = 1, second: int = 2) -> TwoVehicleRanges:
    """Both vehicles' anchor ranges plus the range ``first`` measures to ``second`` (seed test case 2)."""
    v1, v2 = scenario.vehicle(first), scenario.vehicle(second)
    ids = _uwb_anchor_ids(scenario, v1)
    if _uwb_anchor_ids(scenario, v2) != ids:
        raise ValueError("both vehicles must range to the same anchors")
    table = scenario.anchor_positions(ids)
    anchors = np.array([table[k] for k in ids])
    sig_uwb = v1.sensors.uwb.noise_std_m if v1.sensors.uwb else 0.1
    sig_peer = v1.sensors.inter_vehicle.noise_std_m if v1.sensors.inter_vehicle else 0.1
    sigma = np.array([sig_uwb] * (2 * len(ids)) + [sig_peer])
    wire = tuple(anchor_sensor_id(k) for k in ids) * 2 + (peer_sensor_id(second),)

    return TwoVehicleRanges.build(anchors, sigma, (_hold_z(v1), _hold_z(v2)), sensor_ids=wire)
