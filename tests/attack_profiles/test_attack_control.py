"""Control-plane payloads: a profile, a library reference with parameters, or null."""

from __future__ import annotations

import pytest

from attack_profiles import library
from attack_profiles.control import profile_from_payload
from secuav_common.loading import InputError


def test_null_and_empty_clear() -> None:
    assert profile_from_payload(None) is None
    assert profile_from_payload({"request_id": "r1"}) is None


def test_library_reference_with_parameters() -> None:
    profile = profile_from_payload({"library": "type-a", "parameters": {"links": [12]}, "request_id": "r2"})
    assert profile == library.load("type-a", links=[12])


def test_full_profile_with_request_id() -> None:
    payload = {"name": "p", "rules": [{"target": {"message": "DISTANCE_SENSOR"}, "kind": "drop"}], "request_id": 7}
    profile = profile_from_payload(payload)
    assert profile is not None and profile.name == "p" and profile.source == "<mqtt>"


@pytest.mark.parametrize(
    ("payload", "match"),
    [
        ({"library": "nope"}, r"library: name: no such library profile"),
        ({"library": 3}, r"<mqtt>: library: must be a library profile name \(got 3\)"),
        ({"library": "type-a", "parameters": [1]}, r"<mqtt>: parameters: must be a mapping"),
        ({"library": "type-a", "rules": []}, r"<mqtt>: rules: not allowed with 'library'"),
        ({"library": "type-a", "parameters": {"link": [1]}}, r"library:type-a: link: not a parameter"),
        ([1], r"<mqtt>: profile: a profile must be a mapping"),
    ],
)
def test_bad_payloads_are_one_line_errors(payload: object, match: str) -> None:
    with pytest.raises(InputError, match=match):
        profile_from_payload(payload)
