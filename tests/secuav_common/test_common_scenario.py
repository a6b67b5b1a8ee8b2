"""The scenario schema: bundled files load, bad files fail with one clear line."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from secuav_common.geo import geodetic_to_ned, ned_to_geodetic
from secuav_common.loading import InputError
from secuav_common.scenario import Home, load_scenario, parse_scenario
from secuav_common.sensor_ids import SensorKind, anchor_sensor_id, classify, peer_sensor_id
from secuav_common.urls import parse_endpoint


@pytest.mark.parametrize("name", ["wall_hover", "anchors8", "formation"])
def test_bundled_scenarios_load(name: str) -> None:
    scenario = load_scenario(name)
    assert scenario.vehicles


def test_anchor_layout_is_the_seed_test_case_1() -> None:
    scenario = load_scenario("anchors8")
    xy = sorted((a.pos_ned_m[0], a.pos_ned_m[1]) for a in scenario.world.anchors)
    assert xy == sorted([(0, 0), (2.5, 0), (5, 0), (5, 2.5), (5, 5), (2.5, 5), (0, 5), (0, 2.5)])
    assert scenario.vehicles[0].target.pos_ned_m[:2] == (2.5, 2.5)


def test_wall_hover_has_five_forward_sensors_of_four_kinds() -> None:
    vehicle = load_scenario("wall_hover").vehicles[0]
    group = [r for r in vehicle.sensors.rangefinders if r.id in vehicle.target.sensor_ids]
    assert len(group) == 5
    assert {r.orientation for r in group} == {"forward"}
    assert sorted(r.type for r in group) == ["infrared", "laser", "laser", "radar", "ultrasound"]


@pytest.mark.parametrize(
    ("text", "field", "value"),
    [
        ("name: x\nvehicles: [{sysid: 0}]", "vehicles[0].sysid", "0"),
        ("name: x\nvehicles: [{sysid: 1, sensors: {rangefinders: [{id: 0, type: lidar}]}}]",
         "vehicles[0].sensors.rangefinders[0].type", "'lidar'"),
        ("name: x\nvehicles: [{sysid: 1, sensors: {uwb: {anchors: [3]}}}]",
         "vehicles[0].sensors.uwb.anchors[0]", "3"),
        ("name: x\nvehicles: [{sysid: 1}, {sysid: 1}]", "vehicles[1].sysid", "1"),
        ("name: x\nvehicles: [{sysid: 1, sensors: {rangefinders: [{id: 0, min_m: 5, max_m: 1}]}}]",
         "vehicles[0].sensors.rangefinders[0]", "1"),
        ("name: x\nvehicles: [{sysid: 1, external: {rangefinders: [{id: 0, orientation: forward}]}}]",
         "vehicles[0].external.rangefinders[0]", "'forward'"),
        ("name: x\nvehicles: [{sysid: 1, external: {rangefinders: [{id: 0, orientation: forward, surface: w}]}}]",
         "vehicles[0].external.rangefinders[0].surface", "'w'"),
        ("name: x\nvehicles: [{sysid: 1, sensors: {rangefinders: [{id: 2}]},\n"
         "  external: {rangefinders: [{id: 2, orientation: down}]}}]",
         "vehicles[0].external.rangefinders[0].id", "2"),
        ("name: x\nvehicles: [{sysid: 1, external: {uwb: {}}}]", "vehicles[0].external.uwb", "world.anchors"),
        ("name: x\nvehicles: [{sysid: 1, external: {source_compids: [0]}}]",
         "vehicles[0].external.source_compids", "0"),
    ],
)
def test_bad_scenario_names_file_field_and_value(text: str, field: str, value: str) -> None:
    with pytest.raises(InputError) as info:
        parse_scenario(text, "bad.yaml")
    message = str(info.value)
    assert message.startswith("bad.yaml: ")
    assert field in message
    assert value in message
    assert "\n" not in message


def test_the_external_block_is_optional_and_vision_may_be_a_flag() -> None:
    for name in ("wall_hover", "anchors8", "formation"):
        assert all(v.external is None for v in load_scenario(name).vehicles)
    sc = parse_scenario("name: x\nvehicles: [{sysid: 1, external: {vision: true}}]")
    ext = sc.vehicles[0].external
    assert ext is not None and ext.vision is not None and ext.vision.message == "vision_position_estimate"
    assert ext.source_sysid is None and 158 in ext.source_compids


def test_a_vehicle_lists_every_rangefinder_its_link_carries() -> None:
    fed = load_scenario("companion_feed").vehicles[0]
    assert [r.id for r in fed.all_rangefinders] == [0, 1] and fed.sensors.rangefinders == []
    own = load_scenario("wall_hover").vehicles[0]
    assert fed.uwb_ranging is None and own.all_rangefinders == own.sensors.rangefinders
    sc = parse_scenario("name: x\nworld: {anchors: [{id: 0, pos_ned_m: [0, 0, 0]}]}\n"
                        "vehicles: [{sysid: 1, external: {uwb: {rate_hz: 5}}}]")  # fmt: skip
    uwb = sc.vehicles[0].uwb_ranging
    assert uwb is not None and uwb.rate_hz == 5


def test_missing_file_is_one_line(tmp_path) -> None:
    with pytest.raises(InputError, match=r"nope\.yaml"):
        load_scenario(tmp_path / "nope.yaml")


def test_a_mistyped_name_lists_the_scenarios_there_are_not_an_internal_path() -> None:
    """Issue 36: ``secuav-sim wal_hover`` said ``.../secuav_common/scenarios/wal_hover.yaml: No such file``."""
    with pytest.raises(InputError) as err:
        load_scenario("wal_hover")
    text = str(err.value)
    assert "'wal_hover'" in text and "scenarios: anchors8, " in text and "wall_hover" in text, text
    assert "secuav_common" not in text and ".yaml" not in text, text
    with pytest.raises(InputError, match=r"^lab/nope: "):  # a path stays the user's path
        load_scenario("lab/nope")


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=200) | st.binary(max_size=200).map(lambda b: b.decode("latin-1")))
def test_garbage_documents_raise_only_input_error(text: str) -> None:
    try:
        parse_scenario(text, "fuzz.yaml")
    except InputError as err:
        assert str(err).startswith("fuzz.yaml")


@settings(max_examples=200, deadline=None)
@given(st.floats(-500, 500), st.floats(-500, 500), st.floats(-100, 100))
def test_geo_round_trip(north: float, east: float, down: float) -> None:
    home = Home()
    back = geodetic_to_ned(home, *ned_to_geodetic(home, north, east, down))
    assert math.dist(back, (north, east, down)) < 1e-6


def test_sensor_id_plan() -> None:
    assert anchor_sensor_id(3) == 13
    assert peer_sensor_id(2) == 52
    assert classify(4) == (SensorKind.RANGEFINDER, 4)
    assert classify(17) == (SensorKind.ANCHOR, 7)
    assert classify(52) == (SensorKind.PEER, 2)
    with pytest.raises(ValueError):
        classify(120)


def test_endpoint_urls() -> None:
    ep = parse_endpoint("udpin://0.0.0.0:14540")
    assert (ep.mode, ep.host, ep.port) == ("udpin", "0.0.0.0", 14540)
    assert str(parse_endpoint("udpout://127.0.0.1:14550")) == "udpout://127.0.0.1:14550"
    for bad in ["quic://1.2.3.4:5", "udpin://host", "udpout://h:99999", "14540"]:
        with pytest.raises(ValueError, match="endpoint"):
            parse_endpoint(bad)
