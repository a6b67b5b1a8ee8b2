"""A scenario says what it is (``Scenario.kind``), and the estimators build its model from that alone."""

from __future__ import annotations

import json

import pytest

from estimators.models import AnchorRanges2D, AnchorRangesHeight, ScalarGroup, TwoVehicleRanges
from estimators.scenario_models import model_for
from secuav_common.scenario import load_scenario, parse_scenario

WALL = """
name: one-wall
world:
  walls: [{name: north, point_ned_m: [6, 0, 0], normal_ned: [-1, 0, 0]}]
vehicles:
  - sysid: 1
    sensors:
      rangefinders:
        - {id: 0, orientation: forward, type: laser}
        - {id: 1, orientation: forward, type: radar}
        - {id: 2, orientation: forward, type: infrared}
    target: {kind: wall_distance, wall: north, sensor_ids: [0, 1, 2]}
"""


@pytest.mark.parametrize(("name", "kind", "model"), [
    ("anchors8", "anchors", AnchorRangesHeight),
    ("formation", "formation", TwoVehicleRanges),
    ("wall_hover", "wall", ScalarGroup),
    ("rangefinder_feed", "wall", ScalarGroup),  # the wall group fed by a companion
])  # fmt: skip
def test_bundled_scenarios_say_what_they_are_and_get_their_model(name: str, kind: str, model: type) -> None:
    scenario = load_scenario(name)
    assert scenario.kind == kind
    assert type(model_for(scenario)) is model


def test_a_wall_target_without_uwb_is_a_wall_and_its_group_is_the_model() -> None:
    scenario = parse_scenario(WALL, "one-wall.yaml")
    assert scenario.kind == "wall"
    group = model_for(scenario)
    assert isinstance(group, ScalarGroup) and group.ids() == (0, 1, 2)


def test_one_vehicle_of_a_pair_without_inter_vehicle_ranging_is_no_formation() -> None:
    """Two vehicles make a formation only when both range to anchors and to each other; else the first vehicle's
    anchor ranges are the model (``dims=2``: the plane model, the height known)."""
    doc = load_scenario("formation").model_dump(mode="json")
    doc["vehicles"][1]["sensors"]["inter_vehicle"] = None
    doc["vehicles"][1]["target"] = None
    scenario = parse_scenario(json.dumps(doc), "pair.yaml")
    assert scenario.kind == "anchors"
    assert isinstance(model_for(scenario, dims=2), AnchorRanges2D)
