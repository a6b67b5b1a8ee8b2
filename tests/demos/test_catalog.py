"""What the study needs from the demos, without flying one: which demo flies which scenario, and its ports."""

from __future__ import annotations

import pytest

from demos import catalog, formation, localise, wall_hover
from demos.cli import DEMOS
from demos.stack import Ports
from secuav_common.scenario import load_scenario


def test_the_catalog_names_each_demo_and_the_scenario_it_flies() -> None:
    # closed-loop cells fly secuav-sim; height-hold needs an ArduPilot SITL binary, rangefinder-feed flies
    # ArduCopter SITL unless told --autopilot flightsim, vision flies PX4 SIH, so none is a study's demo;
    # command-tamper flies secuav-sim but holds nothing (it scores a takeoff and a mission): not a cell either
    hold_demos = {name for name, m in DEMOS.items() if m.AUTOPILOTS[0] == "flightsim"} - {"command-tamper"}
    assert set(catalog.SCENARIO_OF_DEMO) == hold_demos
    assert "height-hold" in DEMOS and "height-hold" not in catalog.SCENARIO_OF_DEMO
    assert "rangefinder-feed" in DEMOS and "rangefinder-feed" not in catalog.SCENARIO_OF_DEMO
    for module in (wall_hover, localise, formation):
        demo = next(name for name, m in DEMOS.items() if m is module)
        assert catalog.SCENARIO_OF_DEMO[demo] == module.SCENARIO
        assert catalog.demo_for(load_scenario(module.SCENARIO)) == demo
    # another scenario of a demo's shape is flown by that demo (a plugin's, a file's)
    assert catalog.demo_for(load_scenario("anchors8").model_copy(update={"name": "other", "duration_s": 1.0})) == (
        "localise")  # fmt: skip
    assert catalog.demo_for(load_scenario("anchors6_small")) == "localise"  # the example plugin's (installed)
    with pytest.raises(ValueError, match="closed-loop cells fly the demos, so the scenario must have a demo's shape"):
        catalog.demo_for(load_scenario("ardupilot_height"))  # its wall is the ground, below: no wall-hover
    two = load_scenario("formation")
    no_peer = two.model_copy(update={"vehicles": [two.vehicles[0], two.vehicles[1].model_copy(update={
        "target": two.vehicles[0].target})]})  # fmt: skip
    with pytest.raises(ValueError, match="'formation' has none of them"):
        catalog.demo_for(no_peer)


def test_secuav_demo_refuses_a_scenario_of_another_shape_in_one_line() -> None:
    from demos.cli import check_scenario

    assert check_scenario("localise", "anchors6_small") is None
    assert check_scenario("wall-hover", "anchors6_small") == (
        "--scenario anchors6_small: a localise scenario, not a wall-hover one")  # fmt: skip
    assert check_scenario("vision", "anchors8") == (
        "--scenario: only wall-hover, localise and formation fly another scenario, not vision")  # fmt: skip
    assert check_scenario("localise", "no_such_scenario").startswith("--scenario: scenario: ")


def test_a_port_block_is_what_base_port_documents() -> None:
    ports = Ports.block(20000)
    assert (ports.proxy_vehicle, ports.api, ports.gcs, ports.mqtt) == (20000, 20010, 20020, 20021)
    assert catalog.PORT_SPAN == 22 and ports.mqtt < 20000 + catalog.PORT_SPAN
    assert Ports() == Ports(14560, 14540, 14550, 1883)  # docs/interfaces.md's plan for vehicle 0
