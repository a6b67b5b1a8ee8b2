"""Quantity targets on a recorded PX4 SIH flight (docs/px4.md): after the attack stage no message
still carries the true value of an attacked quantity among those the profile maps, the frames PX4
sends that the dialect does not define pass byte for byte, and what is known to reveal the range
anyway (ALTITUDE.bottom_clearance, moved by the altitude, not by the rangefinder) is what the
profile is warned about."""

from __future__ import annotations

from pathlib import Path

from attack_profiles.profile import parse_profile
from attack_profiles.true_copy import true_copies
from mavframe import tlog
from tests.support.quantity_streams import recorded_through_stage

PX4_TLOG = Path(__file__).resolve().parents[2] / "data" / "px4-sih-takeoff-land.tlog"


def test_recorded_px4_flight_keeps_no_true_copy() -> None:
    report = recorded_through_stage(PX4_TLOG)
    s = report.shifted
    # Every carrier PX4 sends was rewritten: its one rangefinder, and each height and position.
    for name in ("DISTANCE_SENSOR.current_distance", "GLOBAL_POSITION_INT.alt", "GLOBAL_POSITION_INT.relative_alt",
                 "GLOBAL_POSITION_INT.lat", "GLOBAL_POSITION_INT.lon", "LOCAL_POSITION_NED.x",
                 "LOCAL_POSITION_NED.y", "LOCAL_POSITION_NED.z", "VFR_HUD.alt", "GPS_RAW_INT.lat",
                 "GPS_RAW_INT.alt", "ALTITUDE.altitude_amsl", "ALTITUDE.altitude_local",
                 "ALTITUDE.bottom_clearance"):  # fmt: skip
        assert s[name] > 0, name
    # parameters, mission, attitude, and the ids ardupilotmega lacks (#8, #380, #410, #411, #436, #441)
    assert report.exact > 10_000
    ids = {e.header.msgid for e in tlog.read(PX4_TLOG)}
    assert {8, 380, 410, 411, 436, 441} <= ids


def test_a_rangefinder_attack_on_px4_is_warned_of_the_fused_clearance() -> None:
    profile = parse_profile({"name": "p", "rules": [
        {"target": {"quantity": "rangefinder", "sensor_id": 0}, "kind": "bias", "offset": 5.0}]}, "p.yaml")
    (warning,) = true_copies(profile)
    assert "ALTITUDE.bottom_clearance" in warning and "ALTITUDE.altitude_terrain" in warning
