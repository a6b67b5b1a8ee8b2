"""The vehicle flies on real JSBSim: arm, takeoff, hold, land, auto-disarm."""

from __future__ import annotations

import statistics

from flightsim.api import FlightMode, LandedState
from flightsim.simulation import Simulation
from secuav_common.scenario import load_scenario


def test_takeoff_hold_land_disarm() -> None:
    sim = Simulation(load_scenario("anchors8"))
    v = sim.vehicles[1]
    sim.run_for(0.2)
    assert v.arm().ok
    assert v.takeoff().ok
    assert v.landed_state == LandedState.ON_GROUND
    sim.run_for(8.0)
    assert v.mode == FlightMode.HOLD
    assert v.landed_state == LandedState.IN_AIR
    assert abs(-v.truth.pos_ned_m[2] - 2.5) < 0.2
    xs: list[float] = []
    sim.run_for(10.0, lambda s: xs.append(v.truth.pos_ned_m[0]))
    assert statistics.pstdev(xs) < 0.1
    assert v.land().ok
    sim.run_for(10.0)
    assert v.landed_state == LandedState.ON_GROUND
    assert not v.armed
    texts = [t for _, t in v.pop_status_texts()]
    assert "Landing detected" in texts
    assert "Disarmed by landing" in texts


def test_vehicle_offers_everything_the_api_protocol_declares() -> None:
    import inspect

    from flightsim.api import VehicleModel
    from flightsim.vehicle import Vehicle

    sim = Simulation(load_scenario("formation"))
    v = sim.vehicles[2]
    members = set(VehicleModel.__annotations__) | {
        n for n, _ in inspect.getmembers(VehicleModel) if not n.startswith("_")
    }
    assert {"truth", "estimate", "arm", "pop_readings", "config", "sysid", "home"} <= members
    for name in members:
        assert hasattr(v, name), name
        proto = inspect.getattr_static(VehicleModel, name, None)
        if inspect.isfunction(proto):
            ours = inspect.signature(getattr(Vehicle, name))
            assert list(ours.parameters) == list(inspect.signature(proto).parameters), name
    assert v.sysid == 2 and v.config.sysid == 2 and v.home == sim.scenario.world.home
