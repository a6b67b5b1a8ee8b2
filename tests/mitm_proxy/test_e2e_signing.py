"""``--signing-key``: signed MAVLink 2 through the daemon, checked by pymavlink's own signature code.

A vehicle signs with the link key (pymavlink); the proxy rewrites DISTANCE_SENSOR
per profile and re-signs it; a ground parser holding the same key and refusing
unsigned frames accepts every frame, and reads the profile's value. Without the
key the proxy leaves signed frames alone (forwarded as they came, counted), and
says so once in its log and for as long as it lasts in the ``attack/state`` it
publishes (issue 27, item 3): an attack that does nothing must not look like one
that works.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
from collections.abc import Callable
from pathlib import Path

import aiomqtt
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mitm_proxy.app import Proxy, stats_line
from mitm_proxy.config import LinkConfig, ProxyConfig
from secuav_common.broker import EmbeddedBroker
from secuav_common.controlplane.payloads import request_bytes
from tests.support.udp_peers import Peer

# Each test runs on the compiled fast path and on the pure-Python one (proxy_path, tests/conftest.py).
pytestmark = [pytest.mark.timeout(30), pytest.mark.usefixtures("proxy_path")]
KEY = os.urandom(32)
PROFILE = ("name: sixty\nrules:\n  - target: {message: DISTANCE_SENSOR, field: current_distance}\n"
           "    kind: set\n    value: 0.6\n")  # fmt: skip


def signer(sysid: int, compid: int) -> mavlink2.MAVLink:
    mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.signing.secret_key = KEY
    mav.signing.link_id = 1
    mav.signing.sign_outgoing = True
    mav.signing.timestamp = 1_000_000
    return mav


def strict_parser() -> mavlink2.MAVLink:
    """A receiver with the key that rejects anything unsigned or wrongly signed."""
    mav = mavlink2.MAVLink(None)
    mav.signing.secret_key = KEY
    mav.signing.allow_unsigned_callback = lambda _mav, _msgid: False
    mav.robust_parsing = True
    return mav


@pytest.mark.parametrize("with_key", [True, False])
async def test_signed_frames_rewritten_and_resigned_or_left_alone(
    with_key: bool, udp_port: Callable[[], int], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    key_file = tmp_path / "link.key"
    key_file.write_bytes(KEY)
    key_file.chmod(0o600)
    profile = tmp_path / "sixty.yaml"
    profile.write_text(PROFILE)
    gcs, vehicle = Peer(), Peer()
    veh = udp_port()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[f"udpout://127.0.0.1:{gcs.port}"])
    cfg = ProxyConfig(links=[link], broker="none", profile=profile, signing_key=key_file if with_key else None)
    try:
        async with Proxy(cfg) as proxy:
            mav = signer(1, 1)
            sent = [mav.distance_sensor_encode(1000 + i, 10, 4000, 250, 0, 0, 0, 0).pack(mav) for i in range(5)]
            sent.append(mav.heartbeat_encode(2, 12, 0, 0, 3).pack(mav))
            for frame in sent:
                vehicle.send(frame, veh)
            got, _ = await gcs.frames()
            full = proxy.stats_snapshot()[1]
            snap = full["downlink"]
            state = proxy.slots[1].state
    finally:
        gcs.close()
        vehicle.close()
    assert len(got) == len(sent)
    parser = strict_parser()
    msgs = [parser.parse_char(f) for f in got]
    assert all(m is not None and m.get_type() != "BAD_DATA" for m in msgs), msgs
    distances = [m.current_distance for m in msgs if m.get_type() == "DISTANCE_SENSOR"]
    if with_key:
        assert distances == [60] * 5 and snap["resigned"] == 5 and snap["rewritten"] == 5
        assert got[-1] == sent[-1]  # untargeted: byte for byte
    said = [r for r in caplog.records if r.getMessage() == "attack.signed_no_key"]
    if with_key:
        assert said == [] and _signing(state.warnings) == [] and _signing(full["warnings"]) == []
    else:
        assert distances == [250] * 5 and got == sent  # no key: never modified
        assert snap["signed_untouched"] == 5 and snap["rewritten"] == 0
        # ... and said: once in the log, naming the system and the option, and in the state while it lasts
        assert len(said) == 1 and said[0].levelno == logging.WARNING
        assert said[0].sysid == 1 and "--signing-key" in said[0].detail  # type: ignore[attr-defined]
        (warning,) = _signing(state.warnings)
        assert warning.startswith("attack.signed_no_key:") and "system 1" in warning and "--signing-key" in warning
        assert _signing(full["warnings"]) == [warning] and "attack.signed_no_key" in stats_line(1, full)["warnings"]


async def test_the_published_attack_state_says_the_signed_stream_defeats_the_profile(
    udp_port: Callable[[], int], tcp_port: Callable[[], int], tmp_path: Path
) -> None:
    """What a console reads: ``secuav/v1/attack/state`` on a real broker carries the warning, and a new profile
    that targets nothing signed takes it away."""
    profile = tmp_path / "sixty.yaml"
    profile.write_text(PROFILE)
    veh, mqtt = udp_port(), tcp_port()
    gcs, vehicle = Peer(), Peer()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[f"udpout://127.0.0.1:{gcs.port}"])
    cfg = ProxyConfig(links=[link], broker=f"mqtt://127.0.0.1:{mqtt}", profile=profile)
    states: list[dict[str, object]] = []
    try:
        async with EmbeddedBroker(port=mqtt), aiomqtt.Client("127.0.0.1", mqtt) as client:
            await client.subscribe("secuav/v1/attack/state")

            async def listen() -> None:
                async for msg in client.messages:
                    states.append(json.loads(bytes(msg.payload)))  # type: ignore[arg-type]

            listener = asyncio.create_task(listen())
            async with Proxy(cfg) as proxy:
                assert proxy.control is not None
                await proxy.control.wait_connected(10)
                mav = signer(1, 1)
                for i in range(5):
                    vehicle.send(mav.distance_sensor_encode(1000 + i, 10, 4000, 250, 0, 0, 0, 0).pack(mav), veh)
                await gcs.frames()
                await asyncio.sleep(0.5)  # the control plane polls the states 5 times a second
                with_warning = list(states)
                await client.publish("secuav/v1/attack/set", request_bytes(None, "clear"))
                await asyncio.sleep(0.8)
            listener.cancel()
    finally:
        gcs.close()
        vehicle.close()
    assert _signing(with_warning[0]["warnings"]) == []  # the profile at start, before any frame
    last = with_warning[-1]
    assert last["profile"] == "sixty" and len(_signing(last["warnings"])) == 1
    assert _signing(last["warnings"])[0].startswith("attack.signed_no_key: system 1")
    assert states[-1]["profile"] is None and states[-1]["warnings"] == []  # cleared with the profile


async def test_three_signed_vehicles_on_one_ground_port_all_hear_the_gcs(
    udp_port: Callable[[], int], tmp_path: Path
) -> None:
    """A signed GCS HEARTBEAT (no target) reaches every vehicle: each link judges replays on its own."""
    key_file = tmp_path / "link.key"
    key_file.write_bytes(KEY)
    key_file.chmod(0o600)
    gcs_port = udp_port()
    vehicles = {sysid: (Peer(), udp_port()) for sysid in (1, 2, 3)}
    links = [LinkConfig(sysid=s, vehicle=f"udpin://127.0.0.1:{p}", ground=[f"udpin://127.0.0.1:{gcs_port}"])
             for s, (_peer, p) in vehicles.items()]  # fmt: skip
    gcs = Peer()
    try:
        async with Proxy(ProxyConfig(links=links, broker="none", signing_key=key_file)) as proxy:
            for sysid, (peer, port) in vehicles.items():  # each vehicle speaks first, so the proxy knows it
                peer.send(signer(sysid, 1).heartbeat_encode(2, 12, 0, 0, 3).pack(signer(sysid, 1)), port)
            await asyncio.sleep(0.2)
            mav = signer(255, 190)
            sent = [mav.heartbeat_encode(6, 8, 0, 0, 4).pack(mav) for _ in range(5)]
            for frame in sent:
                gcs.send(frame, gcs_port)
            got = {sysid: (await peer.frames())[0] for sysid, (peer, _port) in vehicles.items()}
            stale = sum(proxy.stats_snapshot()[s]["uplink"]["bad"].get("stale_signature", 0) for s in vehicles)
    finally:
        gcs.close()
        for peer, _port in vehicles.values():
            peer.close()
    assert stale == 0
    for sysid, frames in got.items():
        assert frames == sent, f"vehicle {sysid} got {len(frames)} of {len(sent)}"
        parser = strict_parser()
        assert all(parser.parse_char(f).get_type() == "HEARTBEAT" for f in frames)


def _signing(warnings: object) -> list[str]:
    """The signing warnings among a state's (a DISTANCE_SENSOR profile also says RANGEFINDER stays true)."""
    return [w for w in warnings if str(w).startswith("attack.signed_no_key")]  # type: ignore[attr-defined]
