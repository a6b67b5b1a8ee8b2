"""What others need to know about the demos without starting one: which demo flies which scenario (its own, or
one of the same shape: a plugin's or a file, ``secuav-demo --scenario``), and the block of loopback ports a run
takes (``secuav-study`` runs demos side by side and needs both).

``secuav-demo --base-port B`` puts vehicle i's proxy port at B+i, its MAVSDK port at B+10+i, the GCS at
B+20 and the MQTT broker at B+21: a run takes :data:`PORT_SPAN` ports from B.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from secuav_common.scenario import Scenario

# the closed-loop demos that fly secuav-sim; height-hold, rangefinder-feed (ArduCopter SITL by default, a binary
# built outside the package), vision (PX4 SIH) and command-tamper (it scores a takeoff and a mission, not a hold)
# are not here
SCENARIO_OF_DEMO = {"wall-hover": "wall_hover", "localise": "anchors8", "formation": "formation"}
PROXY_OFFSET, API_OFFSET, GCS_OFFSET, MQTT_OFFSET = 0, 10, 20, 21
PORT_SPAN = MQTT_OFFSET + 1


def demo_for(scenario: Scenario) -> str:
    """The demo that flies this scenario: a demo's own, or any scenario of its shape (a plugin's, a file);
    ``ValueError`` naming the shapes when it has none of them.

    The shapes are what each demo's controllers and scoring read from the scenario: wall-hover, one vehicle
    (sysid 1) with a ``wall_distance`` target measured by forward rangefinders; localise, one vehicle (sysid 1)
    with a ``hold`` target and UWB anchors; formation, vehicle 1 with a ``hold`` target and vehicle 2 with a
    ``keep_range`` target on vehicle 1, both with UWB and vehicle 2 with the inter-vehicle range.
    """
    from secuav_common.scenario import load_scenario

    for demo, bundled in SCENARIO_OF_DEMO.items():
        if load_scenario(bundled) == scenario:
            return demo
    shape = _shape(scenario)
    if shape is not None:
        return shape
    raise ValueError("closed-loop cells fly the demos, so the scenario must have a demo's shape: one vehicle "
                     "(sysid 1) holding a wall distance on forward rangefinders (wall-hover) or a position on UWB "
                     "anchors (localise), or vehicle 1 holding on UWB and vehicle 2 keeping a range to it "
                     f"(formation); {scenario.name!r} has none of them")  # fmt: skip


def _shape(scenario: Scenario) -> str | None:
    by_sysid = {v.sysid: v for v in scenario.vehicles}
    kinds = {s: getattr(v.target, "kind", None) for s, v in by_sysid.items()}
    if kinds == {1: "wall_distance"}:
        group = set(by_sysid[1].target.sensor_ids)  # type: ignore[union-attr]
        ahead = {r.id for r in by_sysid[1].sensors.rangefinders if r.orientation == "forward"}
        return "wall-hover" if group <= ahead else None  # its controller flies towards a wall ahead
    if kinds == {1: "hold"} and by_sysid[1].sensors.uwb is not None:
        return "localise"
    if kinds == {1: "hold", 2: "keep_range"} and getattr(by_sysid[2].target, "peer", None) == 1:
        lead, follow = by_sysid[1].sensors, by_sysid[2].sensors
        if lead.uwb is not None and follow.uwb is not None and follow.inter_vehicle is not None:
            return "formation"
    return None
