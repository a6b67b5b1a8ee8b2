"""The daemon's wiring, end to end on loopback: uplink through the pipeline, profiles swapped over MQTT.

Vehicle and ground are pymavlink-packed frames on plain sockets; the proxy,
the attack engine, the control plane and the broker (amqtt) are the real ones.
"""

from __future__ import annotations

import asyncio
import json
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import aiomqtt
import pytest

from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from secuav_common.broker import EmbeddedBroker
from tests.support.udp_peers import Peer, distance, heartbeat, packer

# Each test runs on the compiled fast path and on the pure-Python one (proxy_path, tests/conftest.py).
pytestmark = [pytest.mark.timeout(40), pytest.mark.usefixtures("proxy_path")]


def cm_of(frame: bytes) -> int:
    """DISTANCE_SENSOR.current_distance of a v2 frame."""
    return int(struct.unpack_from("<H", frame[10 : 10 + frame[1]].ljust(14, b"\0"), 8)[0])


async def test_uplink_goes_through_the_pipeline(udp_port: Callable[[], int], tmp_path: Path) -> None:
    """A profile aimed at the uplink acts there and leaves the same message on the downlink alone."""
    profile = tmp_path / "up.yaml"
    profile.write_text("name: up\nrules:\n  - target: {message: DISTANCE_SENSOR, direction: uplink}\n    kind: drop\n")
    gcs, vehicle = Peer(), Peer()
    veh = udp_port()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[f"udpout://127.0.0.1:{gcs.port}"])
    try:
        async with Proxy(ProxyConfig(links=[link], broker="none", profile=profile)) as proxy:
            down = distance(packer(1), 250)
            vehicle.send(down, veh)
            got, proxy_addr = await gcs.frames()
            assert got == [down] and proxy_addr is not None
            g = packer(255, 190)
            up_ds, up_hb = distance(g, 123), heartbeat(g)
            gcs.reply(up_ds + up_hb, proxy_addr)
            assert (await vehicle.frames())[0] == [up_hb]
            snap = proxy.stats_snapshot()[1]
            assert snap["uplink"]["dropped"] == 1 and snap["downlink"]["dropped"] == 0
    finally:
        gcs.close()
        vehicle.close()


async def test_profile_swapped_over_mqtt_between_frames(udp_port: Callable[[], int],
                                                        tcp_port: Callable[[], int]) -> None:  # fmt: skip
    mqtt, veh = tcp_port(), udp_port()
    gcs, vehicle = Peer(), Peer()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[f"udpout://127.0.0.1:{gcs.port}"])
    states: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
    stats: list[dict[str, Any]] = []
    set_7m = {"name": "seven", "request_id": "r1",
              "rules": [{"target": {"message": "DISTANCE_SENSOR", "field": "current_distance"},
                         "kind": "set", "value": 7.0}]}  # fmt: skip
    try:
        async with EmbeddedBroker(port=mqtt), aiomqtt.Client("127.0.0.1", mqtt) as client:
            await client.subscribe("secuav/v1/attack/state")
            await client.subscribe("secuav/v1/stats")

            async def listen() -> None:
                async for msg in client.messages:
                    payload = json.loads(bytes(msg.payload))  # type: ignore[arg-type]
                    if str(msg.topic).endswith("stats"):
                        stats.append(payload)
                    else:
                        await states.put(payload)

            listener = asyncio.create_task(listen())
            cfg = ProxyConfig(links=[link], broker=f"mqtt://127.0.0.1:{mqtt}")
            async with Proxy(cfg) as proxy:
                await proxy.control.wait_connected(10)

                async def request(payload: Any, request_id: str) -> dict[str, Any]:
                    await client.publish("secuav/v1/attack/set", json.dumps(payload).encode())
                    while True:
                        state = await asyncio.wait_for(states.get(), 10)
                        if state.get("request_id") == request_id:
                            return state

                async def one_reading() -> int:
                    vehicle.send(distance(packer(1), 250), veh)
                    got, _ = await gcs.frames(0.2)
                    assert len(got) == 1
                    return cm_of(got[0])

                assert await one_reading() == 250
                state = await request(set_7m, "r1")
                assert state["ok"] and state["profile"] == "seven"
                assert await one_reading() == 700
                bad = await request({"name": "bad", "request_id": "r2",
                                     "rules": [{"target": {"message": "NOPE"}, "kind": "set", "value": 1}]}, "r2")
                assert not bad["ok"] and bad["profile"] == "seven" and "NOPE" in bad["error"]
                assert await one_reading() == 700  # the rejected profile left the old one running
                cleared = await request({"request_id": "r3"}, "r3")
                assert cleared["ok"] and cleared["profile"] is None
                assert await one_reading() == 250
                for _ in range(40):
                    if stats:
                        break
                    await asyncio.sleep(0.1)
            listener.cancel()
    finally:
        gcs.close()
        vehicle.close()
    assert stats and stats[-1]["downlink"]["frames_in"] >= 1 and "latency_ms" in stats[-1]
