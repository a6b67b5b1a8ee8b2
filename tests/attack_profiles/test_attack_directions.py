"""Directions first-class (issue 33, items 1 and 8): which way a profile changes frames, what it leaves true
on the wire in each direction, and the deployment switch that forbids changes toward the vehicle."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from attack_profiles.directions import check_no_uplink, describe, directions_of
from attack_profiles.profile import Profile, parse_profile
from attack_profiles.quantities import NOT_COVERED
from attack_profiles.true_copy import findings, message_names, true_copies, vehicle_reports
from mavframe import codec
from secuav_common.loading import InputError


def prof(*rules: dict[str, Any]) -> Profile:
    return parse_profile({"name": "p", "rules": list(rules)}, "p.yaml")


def ds(direction: str | None = None, sensor_id: Any = None, **kw: Any) -> dict[str, Any]:
    target: dict[str, Any] = {"message": "DISTANCE_SENSOR"}
    if direction is not None:
        target["direction"] = direction
    if sensor_id is not None:
        target["sensor_id"] = sensor_id
    return {"target": target, "kind": "bias", "offset": 5.0, **kw}


def test_a_profile_touches_the_union_of_its_rules_directions() -> None:
    assert directions_of(prof(ds())) == ["downlink"]  # the default stays toward the ground
    assert directions_of(prof(ds("uplink"))) == ["uplink"]
    assert directions_of(prof(ds("both"))) == ["downlink", "uplink"]
    assert directions_of(prof(ds("uplink"), ds())) == ["downlink", "uplink"]
    assert directions_of(prof()) == [] and directions_of(None) == []
    assert describe(["uplink"]) == "toward the vehicle" and describe(["downlink"]) == "toward the ground"
    assert describe(["uplink", "downlink"]) == "toward the ground and toward the vehicle"
    assert describe([]) == "nothing"


def test_the_no_uplink_switch_names_the_first_rule_toward_the_vehicle() -> None:
    check_no_uplink(prof(ds(), ds("downlink")), "p.yaml")  # toward the ground only: fine
    for direction in ("uplink", "both"):
        with pytest.raises(InputError) as err:
            check_no_uplink(prof(ds(), ds(direction)), "p.yaml")
        text = str(err.value)
        assert text.startswith("p.yaml: rules[1].target.direction: bias on DISTANCE_SENSOR would change frames "
                               "toward the vehicle") and "--no-uplink-attacks" in text and "\n" not in text
        assert f"(got '{direction}')" in text


def test_a_rule_toward_the_vehicle_leaves_no_true_twin_and_says_the_autopilot_reports_the_lie() -> None:
    # ArduPilot echoes a MAVLink rangefinder it was fed as its own DISTANCE_SENSOR and RANGEFINDER
    uplink = prof(ds("uplink"))
    assert true_copies(uplink) == [] and findings(uplink) == []
    (note,) = vehicle_reports(uplink)
    assert note.startswith("rules[0] feed the vehicle a false rangefinder distance (DISTANCE_SENSOR, toward the ")
    assert "reports the lie itself" in note and "RANGEFINDER" in note
    assert vehicle_reports(prof(ds())) == []  # toward the ground: nothing is fed to the autopilot
    # a quantity rule toward the vehicle is not told what the vehicle's own messages leave uncovered
    q = prof({"target": {"quantity": "rangefinder", "direction": "uplink"}, "kind": "bias", "offset": 1.0})
    assert true_copies(q) == [] and len(vehicle_reports(q)) == 1


def test_a_rule_on_both_directions_is_judged_on_its_downlink_part_and_noted_for_its_uplink_part() -> None:
    both = prof(ds("both"))
    (warning,) = true_copies(both)
    assert "RANGEFINDER.distance still carries the true value if the vehicle sends it" in warning
    assert len(vehicle_reports(both)) == 1


def test_without_a_vehicle_the_warning_is_a_condition_and_with_one_only_what_it_sent() -> None:
    (f,) = findings(prof(ds(sensor_id=0)))
    assert f.text() == ("rules[0] rewrite rangefinder distance in DISTANCE_SENSOR; RANGEFINDER.distance still "
                        "carries the true value if the vehicle sends it (target quantity: rangefinder rewrites "
                        "them all)")  # fmt: skip
    assert f.text(set()) is None and f.text({"DISTANCE_SENSOR", "ATTITUDE"}) is None  # flightsim, PX4
    assert f.text({"RANGEFINDER"}) == ("rules[0] rewrite rangefinder distance in DISTANCE_SENSOR; "
                                       "RANGEFINDER.distance still carries the true value (target quantity: "
                                       "rangefinder rewrites them all)")  # fmt: skip
    (q,) = findings(prof({"target": {"quantity": "altitude"}, "kind": "bias", "offset": 1.0}))
    assert "if the vehicle sends them" in (q.text() or "")
    seen = q.text({"NAV_CONTROLLER_OUTPUT"})
    assert seen is not None and seen.endswith(": NAV_CONTROLLER_OUTPUT.alt_error") and "SCALED" not in seen


def test_anchor_and_peer_links_are_never_the_primary_downward_rangefinder() -> None:
    # UWB anchor links 11 and 14 (the flagship demo's): RANGEFINDER cannot carry them
    assert true_copies(prof(ds(sensor_id=[11, 14]))) == []
    assert true_copies(prof(ds(sensor_id={"first": 10, "last": 17}))) == []
    assert true_copies(prof(ds(sensor_id=51))) == []
    (warning,) = true_copies(prof(ds(sensor_id=[2, 11])))  # id 2 may be the lowest-id downward one
    assert "RANGEFINDER.distance (if sensor 2, 11 is the vehicle's lowest-id downward rangefinder)" in warning
    assert len(true_copies(prof(ds()))) == 1  # every id: id 0 among them


def test_every_uncovered_carrier_names_messages_of_the_dialect() -> None:
    assert message_names("SCALED_PRESSURE*.press_abs, HIGHRES_IMU.abs_pressure") == {
        "SCALED_PRESSURE", "SCALED_PRESSURE2", "SCALED_PRESSURE3", "HIGHRES_IMU"}  # fmt: skip
    for quantity, items in NOT_COVERED.items():
        for name, _ in items:
            names = message_names(name)
            assert names and names <= set(codec.BY_NAME), (quantity, name)


@given(st.lists(st.sampled_from(["downlink", "uplink", "both"]), min_size=1, max_size=5))
def test_uplink_rules_never_add_a_true_copy_warning(directions: list[str]) -> None:
    """Adding rules toward the vehicle never changes what is said about the ground."""
    ground = [ds(d, sensor_id=0) for d in directions if d != "uplink"]
    mixed = [ds(d, sensor_id=0) for d in directions]
    if ground:
        assert len(true_copies(prof(*mixed))) == len(true_copies(prof(*ground))) == 1
    else:
        assert true_copies(prof(*mixed)) == []
    assert len(vehicle_reports(prof(*mixed))) == sum(d != "downlink" for d in directions)


def test_validate_says_the_directions_words_the_warning_as_a_condition_and_notes_the_echo(tmp_path: Path) -> None:
    path = tmp_path / "p.yaml"
    path.write_text("name: p\nrules:\n  - {target: {message: DISTANCE_SENSOR, sensor_id: 0, direction: both}, "
                    "kind: bias, offset: 5}\n", encoding="utf-8")  # fmt: skip
    done = subprocess.run([sys.executable, "-m", "attack_profiles", "validate", str(path)], capture_output=True,
                          text=True, timeout=60)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.rstrip().endswith("changes frames toward the ground and toward the vehicle)")
    lines = done.stderr.splitlines()
    assert any(ln.startswith("warning: rules[0] rewrite") and "if the vehicle sends it" in ln for ln in lines)
    assert any(ln.startswith("note: rules[0] feed the vehicle a false rangefinder distance") for ln in lines)


def test_frame_operations_name_every_direction_they_write() -> None:
    """An injection toward the vehicle is uplink; a mission shift that hides itself also rewrites the read-back
    toward the ground, and the no-uplink switch refuses both."""
    from attack_profiles.resolve import resolve_profile

    assert directions_of(resolve_profile("inject-rtl")) == ["uplink"]
    assert directions_of(resolve_profile("mission-shift")) == ["downlink", "uplink"]
    assert directions_of(resolve_profile("mission-shift", {"hide": False})) == ["uplink"]
    for name in ("inject-rtl", "mission-shift", "takeoff-altitude", "vehicle-rangefinder-bias"):
        with pytest.raises(InputError, match=r"rules\[0\]"):
            check_no_uplink(resolve_profile(name), name)
