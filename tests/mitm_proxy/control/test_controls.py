"""The runtime switches (``mitm_proxy.control``) without a broker: topic routing, atomic route sets, one verdict."""

from __future__ import annotations

from typing import Any

import pytest

from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.control.mode import ModeSwitch
from mitm_proxy.control.routes import RoutesSwitch
from mitm_proxy.control.secure import NoSecure
from mitm_proxy.control.switches import Controls, Target, vehicle_controls
from mitm_proxy.net.factory import make_endpoint
from mitm_proxy.net.rules import EndpointRules, rules_from_query, rules_to_query
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from secuav_common.loading import InputError
from secuav_common.urls import parse_endpoint


def _endpoints() -> dict[str, Any]:
    eps = [
        make_endpoint(parse_endpoint("udpin://127.0.0.1:14540"), "vehicle:14540", "vehicle"),
        make_endpoint(parse_endpoint("udpout://127.0.0.1:14550?deny=ATTITUDE"), "ground:14550", "ground"),
        make_endpoint(parse_endpoint("udpout://127.0.0.1:14551"), "ground:14551", "ground"),
    ]
    return {ep.name: ep for ep in eps}


def _registry() -> tuple[Controls, dict[str, Any]]:
    slots = {1: AttackSwitch(AttackSlot(1)), 2: AttackSwitch(AttackSlot(2))}
    controls = vehicle_controls("bench", slots, {s: AttackStage(slot.slot) for s, slot in slots.items()})
    endpoints = _endpoints()
    controls.add(RoutesSwitch("bench", endpoints))
    return controls, endpoints


def test_every_set_topic_finds_its_control_and_state_topic() -> None:
    controls, _ = _registry()
    cases = {
        "secuav/v1/attack/set": (AttackSwitch, "secuav/v1/attack/state"),
        "secuav/v2/attack/mode/set": (ModeSwitch, "secuav/v2/attack/mode/state"),
        "secuav/v2/secure/set": (NoSecure, "secuav/v2/secure/state"),
        "secuav/proxy/routes/set": (RoutesSwitch, "secuav/proxy/bench/routes/state"),
        "secuav/proxy/bench/routes/set": (RoutesSwitch, "secuav/proxy/bench/routes/state"),
    }
    for topic, (cls, state_topic) in cases.items():
        target = controls.route(topic)
        assert isinstance(target, Target) and isinstance(target.control, cls), topic
        assert target.state_topic == state_topic
    assert controls.route("secuav/v7/attack/set") == "v7"  # a vehicle we do not serve: logged by the plane
    for foreign in ("secuav/proxy/other/routes/set", "secuav/v1/attack/state", "secuav/v1/nothing/set",
                    "other/v1/attack/set", "secuav/v1/attack/set/x"):  # fmt: skip
        assert controls.route(foreign) is None, foreign
    subs = controls.subscriptions()
    assert "secuav/+/attack/mode/set" in subs and "secuav/proxy/bench/routes/set" in subs
    assert [t.state_topic for t in controls.states()][:3] == [
        "secuav/v1/attack/state", "secuav/v1/attack/mode/state", "secuav/v1/secure/state"]  # fmt: skip


@pytest.mark.parametrize("name", ["", "a/b", "x+", "#", "a b", "x" * 65])
def test_an_instance_name_must_be_one_topic_level(name: str) -> None:
    with pytest.raises(ValueError, match="instance name"):
        Controls(name)


def test_a_route_set_is_all_or_nothing() -> None:
    controls, eps = _registry()
    routes = controls.route("secuav/proxy/routes/set")
    assert isinstance(routes, Target)
    ok = routes.control.handle({"endpoints": {"ground:14551": {"listen_only": True, "down": {"deny": ["ATTITUDE"]}},
                                              "udpout://127.0.0.1:14550": None}}, "r1")  # fmt: skip
    assert ok.ok and ok.request_id == "r1"
    assert eps["ground:14551"].gate.rules.listen_only and eps["ground:14550"].gate.rules.empty
    assert ok.endpoints["ground:14551"].rules == {"listen_only": True, "down": {"deny": ["ATTITUDE"]}}

    before = {name: ep.gate.rules for name, ep in eps.items()}
    bad_sets = {
        "unknown endpoint": ({"endpoints": {"ground:14550": None, "ground:9": None}}, "endpoints.ground:9: no such"),
        "bad message": ({"endpoints": {"ground:14550": {"down": {"deny": ["NOPE"]}}}}, "endpoints.ground:14550.down"),
        "vehicle listen-only": ({"endpoints": {"vehicle:14540": {"listen_only": True}}}, "only a ground endpoint"),
        "unknown field": ({"endpoints": {"ground:14550": None}, "extra": 1}, "extra: unknown field"),
        "not an object": (["ground:14550"], "expected"),
        "unknown rule": ({"endpoints": {"ground:14550": {"listen": True}}}, "listen"),
    }
    for label, (payload, error) in bad_sets.items():
        state = routes.control.handle(payload, label)
        assert not state.ok and state.error is not None and error in state.error, (label, state.error)
        assert {name: ep.gate.rules for name, ep in eps.items()} == before, label  # nothing half-applied


def test_every_change_of_mode_goes_through_its_switch_and_leaves_one_verdict() -> None:
    slot = AttackSwitch(AttackSlot(1))
    stage = AttackStage(slot.slot)
    mode = ModeSwitch(1, stage)
    state = mode.handle("bypass", "r1")
    assert state.mode == "bypass" and state.request_id == "r1" and state.ok and not stage.enabled
    refused = mode.handle({"mode": "off"}, "r2")
    assert refused.error is not None and refused.error.startswith('mode: must be "on" or "bypass"')
    assert refused.mode == "bypass"  # the refused request changed nothing
    state = mode.set(True, source="--attack")  # the app switches through the same door
    assert state.mode == "on" and state.request_id is None and state.ok and stage.enabled
    assert mode.state == state


def test_one_verdict_per_switch_whatever_the_door() -> None:
    slot = AttackSwitch(AttackSlot(1))
    assert slot.offer_payload({"library": "drift"}, "mqtt-1").ok
    refused = slot.offer_payload({"library": "no-such-profile"}, "mqtt-2")
    assert not refused.ok and refused.request_id == "mqtt-2" and refused.profile == "drift"
    assert slot.offer(None, "reload").ok and slot.state.profile is None and slot.state.request_id == "reload"
    assert slot.verdict.request_id == "reload" and slot.verdict.ok


def test_secure_without_a_secure_stage_says_how_to_get_one() -> None:
    secure = NoSecure(1)
    assert secure.state.available is False and secure.state.ok
    refused = secure.handle({"estimator": "secekf"}, "r")
    assert not refused.ok and refused.error is not None and "--scenario" in refused.error


@pytest.mark.parametrize(
    "query",
    ["deny=ATTITUDE", "listen_only=true", "allow_up=HEARTBEAT,76&deny_sysid_up=7", "deny_compid=1&allow=0,30", ""],
)
def test_rules_survive_the_url_spelling_round_trip(query: str) -> None:
    rules = rules_from_query(query, "RULES")
    assert rules_from_query(rules_to_query(rules), "RULES") == rules
    assert isinstance(rules, EndpointRules)


def test_a_bad_rule_query_names_the_option() -> None:
    with pytest.raises(InputError, match="option denyy"):
        rules_from_query("denyy=ATTITUDE", "RULES")
    with pytest.raises(InputError, match="listen_only"):
        rules_from_query("listen_only=maybe", "RULES")
