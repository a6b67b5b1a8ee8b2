"""Shared steps for flightsim tests: build a simulation, get a vehicle into the air."""

from __future__ import annotations

from flightsim.api import FlightMode, OffboardSetpoint
from flightsim.simulation import Simulation
from flightsim.vehicle import Vehicle
from secuav_common.scenario import load_scenario


def airborne(scenario: str = "anchors8", sysid: int = 1, seed: int | None = None) -> tuple[Simulation, Vehicle]:
    """A simulation whose vehicle has taken off to MIS_TAKEOFF_ALT and settled in Hold."""
    sim = Simulation(load_scenario(scenario), seed=seed)
    v = sim.vehicles[sysid]
    sim.run_for(0.2)
    assert v.arm().ok
    assert v.takeoff().ok
    sim.run_for(8.0)
    assert v.mode == FlightMode.HOLD
    return sim, v


def fly_offboard(sim: Simulation, v: Vehicle, sp: OffboardSetpoint, seconds: float) -> None:
    """Stream ``sp`` every physics step (well above PX4's 2 Hz minimum) for ``seconds``."""
    v.offboard_setpoint(sp)
    if v.mode != FlightMode.OFFBOARD:
        assert v.set_mode(FlightMode.OFFBOARD).ok
    sim.run_for(seconds, lambda _s: v.offboard_setpoint(sp))


def texts(v: Vehicle) -> list[str]:
    return [t for _, t in v.pop_status_texts()]
