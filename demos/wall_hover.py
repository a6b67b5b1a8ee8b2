"""The wall-hover demo: hold 2.5 m from a wall on five forward range sensors.

The controller (``demos/controllers/wall_hover.py``, also
``examples/wall_hover_controller.py``) takes off and holds; after ``settle_s``
the demo pushes the attack profile over MQTT (what ``secuav-attack apply``
does) and scores the rest of the hold from the simulator's ground truth, never
from what the controller believed.
"""

from __future__ import annotations

from typing import Any

from demos.catalog import SCENARIO_OF_DEMO
from demos.flight import Case, Controller, Options, fly
from demos.scoring import distance_metrics, held_summary
from secuav_common.scenario import load_scenario

SCENARIO = SCENARIO_OF_DEMO["wall-hover"]
CONTROLLER = "demos.controllers.wall_hover"
DEFAULT_ATTACK = "wall-spoof-two"
DEFAULT_SECURE = "secekf"
AUTOPILOTS = ("flightsim",)  # the vehicles it flies: secuav-sim's


async def run_case(case: Case, opts: Options) -> dict[str, Any]:
    name = opts.scenario or SCENARIO
    scenario = load_scenario(name)
    target = scenario.vehicles[0].target  # a wall_distance target (demos.catalog.demo_for checked the shape)
    hold = ("--target", str(target.distance_m), "--sensors", ",".join(str(i) for i in target.sensor_ids))  # type: ignore[union-attr]
    record = await fly(name, [Controller(1, CONTROLLER, hold)], case, opts, attack_sysids=[1])
    figures = distance_metrics(scenario, record.truth[1], record.steps[1], record.estimates[1], record.window)
    figures.update(case=case.slug, attack=case.attack, secure=case.secure, attack_ack=record.attack_ack.get(1))
    return figures


def summary(figures: dict[str, Any]) -> str:
    return held_summary(figures)
