"""The control plane against requests nobody should be able to make (issue 28, findings 6 and 8).

A request left retained on the broker must not change what the command line
set when a proxy starts (a spectator's listen-only lifted before anyone
asked), and a flood of requests is limited per set topic. Real broker (amqtt,
embedded), the real proxy, real UDP peers on loopback.
"""

from __future__ import annotations

import asyncio
import json
import socket
from collections.abc import Callable

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavframe.frames import split
from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from mitm_proxy.control.plane import REQUEST_BURST, REQUESTS_PER_S
from secuav_common.broker import EmbeddedBroker
from tests.support.brokers import Observer

pytestmark = pytest.mark.timeout(60)


def _udp() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    return sock


async def _frames(sock: socket.socket, quiet_s: float) -> list[bytes]:
    loop = asyncio.get_running_loop()
    out: list[bytes] = []
    while True:
        try:
            data, _ = await asyncio.wait_for(loop.sock_recvfrom(sock, 65535), quiet_s)
        except TimeoutError:
            return out
        out.extend(f for _h, f in split(data).frames)


async def test_requests_left_retained_on_the_broker_change_nothing_at_start(
    udp_port: Callable[[], int], tcp_port: Callable[[], int]
) -> None:
    mqtt, veh, gcs_port = tcp_port(), udp_port(), udp_port()
    vehicle, spectator = _udp(), _udp()
    ground = f"udpin://127.0.0.1:{gcs_port}?listen_only=true"
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[ground])
    try:
        async with EmbeddedBroker(port=mqtt):
            async with Observer(mqtt, ["secuav/#"]) as planter:  # what someone left behind before the proxy ran
                await planter.publish("secuav/proxy/routes/set", {"endpoints": {f"ground:{gcs_port}": None}},
                                      retain=True)  # fmt: skip
                await planter.publish("secuav/v1/attack/set", {"library": "distance-stuck"}, retain=True)
                await planter.publish("secuav/v1/attack/mode/set", {"mode": "bypass"}, retain=True)
            async with Proxy(ProxyConfig(links=[link], broker=f"mqtt://127.0.0.1:{mqtt}")) as proxy:
                await proxy.control.wait_connected(10)
                for _ in range(100):  # the broker hands the retained requests over right after the subscribe
                    if proxy.control.retained_ignored >= 3:
                        break
                    await asyncio.sleep(0.05)
                assert proxy.control.retained_ignored >= 3  # (amqtt hands one over per matching subscription)
                mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
                vehicle.sendto(mav.heartbeat_encode(2, 12, 0, 0, 4).pack(mav), ("127.0.0.1", veh))
                await asyncio.sleep(0.3)  # the vehicle's heartbeat reached the proxy: the spectator may answer
                gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
                arm = gcs.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(gcs)
                spectator.sendto(arm, ("127.0.0.1", gcs_port))
                got = await _frames(vehicle, quiet_s=1.0)
                parts = proxy.vehicles[1]
                assert proxy.links[0].grounds[0].gate.rules.listen_only  # what the command line said still holds
                assert parts.attack.engine is None and parts.stage.enabled  # no profile, not bypassed
                assert got == []  # the arm command never reached the vehicle
    finally:
        vehicle.close()
        spectator.close()


async def test_heavy_requests_do_not_hold_up_frames_and_a_flood_is_limited_per_topic(
    udp_port: Callable[[], int], tcp_port: Callable[[], int]
) -> None:
    mqtt, veh = tcp_port(), udp_port()
    vehicle, ground = _udp(), _udp()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}",
                      ground=[f"udpout://127.0.0.1:{ground.getsockname()[1]}"])  # fmt: skip
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    rules = [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": k % 6, "field": "current_distance"},
              "kind": "bias", "offset_m": 0.01 * k} for k in range(300)]  # a large valid profile (~40 kB)  # fmt: skip
    sent: list[bytes] = []
    try:
        async with EmbeddedBroker(port=mqtt), \
                Proxy(ProxyConfig(links=[link], broker=f"mqtt://127.0.0.1:{mqtt}")) as proxy:  # fmt: skip
            plane = proxy.control
            assert plane is not None
            await plane.wait_connected(10)
            collector = asyncio.create_task(_frames(ground, quiet_s=2.0))

            async def stream() -> None:
                for i in range(600):  # 3 s at 200 Hz
                    frame = mav.heartbeat_encode(2, 12, 0, i, 4).pack(mav)
                    sent.append(frame)
                    vehicle.sendto(frame, ("127.0.0.1", veh))
                    await asyncio.sleep(0.005)

            streamer = asyncio.create_task(stream())
            async with Observer(mqtt, ["secuav/v1/attack/state", "secuav/v1/attack/mode/state"]) as obs:
                assert obs.client is not None
                for k in range(3):  # heavy requests (10 tokens each), checked off the loop while the frames go on
                    await obs.publish("secuav/v1/attack/set", {"request_id": f"r{k}", "name": f"p{k}", "rules": rules})
                    await obs.wait_for("secuav/v1/attack/state", lambda b, k=k: b["request_id"] == f"r{k}")
                    await asyncio.sleep(1.0)  # within the budget: 10 tokens a second
                # 200 small requests at once on one topic (QoS 0: no waiting for the broker)
                committed = plane.committed
                t0 = asyncio.get_running_loop().time()
                await asyncio.gather(*(obs.client.publish("secuav/v1/attack/mode/set",
                                                          json.dumps({"request_id": f"m{k}", "mode": "on"}), qos=0)
                                       for k in range(200)))  # fmt: skip

                def answered() -> int:  # (the states themselves coalesce in the outbox: only the newest goes out)
                    return plane.committed - committed

                for _ in range(200):
                    if answered() + plane.rate_limited >= 200:
                        break
                    await asyncio.sleep(0.05)
                elapsed_s = asyncio.get_running_loop().time() - t0
                await streamer
            got = await collector
            assert answered() + plane.rate_limited == 200
            assert plane.rate_limited > 0 and answered() <= REQUEST_BURST + REQUESTS_PER_S * elapsed_s + 1
            assert proxy.vehicles[1].attack.engine is not None and proxy.vehicles[1].attack.engine.profile.name == "p2"
    finally:
        vehicle.close()
        ground.close()
    assert got == sent  # heartbeats are not targeted: every one forwarded, byte for byte, in order
