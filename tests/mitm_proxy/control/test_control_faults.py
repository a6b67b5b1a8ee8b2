"""The control plane when the broker is slow, absent or restarts: it never blocks its callers and comes back."""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.control.plane import ControlPlane, Outbox
from mitm_proxy.control.switches import vehicle_controls
from mitm_proxy.stages.attack_slot import AttackSlot
from tests.support.brokers import Mosquitto, Observer, needs_mosquitto

pytestmark = pytest.mark.timeout(60)
SET1, STATE1 = "secuav/v1/attack/set", "secuav/v1/attack/state"


def no_stats() -> dict[int, dict[str, Any]]:
    return {}


def test_outbox_keeps_the_latest_retained_value_and_bounds_the_rest() -> None:
    box = Outbox(maxlen=3)
    for i in range(5):
        box.put("secuav/v1/estimate", str(i).encode(), retain=False)
    box.put("secuav/v1/attack/state", b"old", retain=True)
    box.put("secuav/v1/attack/state", b"new", retain=True)
    assert box.dropped == 2
    taken = [box.take() for _ in range(5)]
    assert taken == [
        ("secuav/v1/attack/state", b"new", True),
        ("secuav/v1/estimate", b"2", False),
        ("secuav/v1/estimate", b"3", False),
        ("secuav/v1/estimate", b"4", False),
        None,
    ]
    assert not box.wakeup.is_set()


@needs_mosquitto
@pytest.mark.mosquitto
async def test_publish_never_blocks_while_the_broker_is_down_and_delivers_after(
    tcp_port: Callable[[], int], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    port = tcp_port()
    slots = {1: AttackSwitch(AttackSlot(1))}
    plane = ControlPlane(
        f"mqtt://127.0.0.1:{port}", vehicle_controls("t", slots), stats=no_stats, outbox_size=100, backoff_s=(0.1, 0.3)
    )
    async with plane:
        started = time.perf_counter()
        for i in range(5000):
            plane.publish_nowait("secuav/v1/estimate", {"i": i})
        elapsed_s = time.perf_counter() - started
        assert plane.dropped == 4900 and len(plane.outbox.queue) == 100
        print(f"publish_nowait with no broker: {elapsed_s / 5000 * 1e6:.1f} us per call")
        with Mosquitto(port, tmp_path):
            async with Observer(port, ["secuav/v1/#"]) as obs:
                await plane.wait_connected(10)
                last = await obs.wait_for("secuav/v1/estimate", lambda b: b == {"i": 4999})
                assert last == {"i": 4999}
                assert (await obs.wait_for(STATE1))["sysid"] == 1
    # The queued hundred went out in batches, without aiomqtt's "pending publish calls" warnings.
    assert [r.getMessage() for r in caplog.records if r.name.startswith("mitm_proxy.control.mqtt")] == []
    assert [r.getMessage() for r in caplog.records].count("mqtt.unavailable") == 1


@needs_mosquitto
@pytest.mark.mosquitto
async def test_broker_restart_reconnects_republishes_and_keeps_serving(
    tcp_port: Callable[[], int], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="mitm_proxy.control")
    port = tcp_port()
    broker = Mosquitto(port, tmp_path)
    slots = {1: AttackSwitch(AttackSlot(1))}
    plane = ControlPlane(f"mqtt://127.0.0.1:{port}", vehicle_controls("t", slots), stats=no_stats, backoff_s=(0.1, 0.5))
    broker.start()
    try:
        async with plane:
            await plane.wait_connected(10)
            async with Observer(port, ["secuav/v1/#"]) as obs:
                assert (await obs.request(SET1, {"library": "distance-stuck"}))["ok"]

            broker.stop()  # persistence is off: the restarted broker has forgotten every retained state
            await asyncio.sleep(1.5)  # several reconnect attempts while it is down
            assert not plane.connected.is_set()
            broker.start()
            await plane.wait_connected(10)
            assert plane.connections == 2

            async with Observer(port, ["secuav/v1/#", "secuav/proxy/online"]) as obs:
                state = await obs.wait_for(STATE1)  # republished by the plane after the reconnect
                assert state["profile"] == "distance-stuck"
                assert await obs.wait_for("secuav/proxy/online") is True
                again = await obs.request(SET1, {"library": "drift"})
                assert again["ok"] and slots[1].engine is not None and slots[1].engine.profile.name == "drift"
    finally:
        broker.stop()
    messages = [r.getMessage() for r in caplog.records]
    assert messages.count("mqtt.unavailable") == 1  # one line per outage, not per attempt
    assert messages.count("mqtt.reconnected") == 1


@needs_mosquitto
@pytest.mark.mosquitto
async def test_a_retained_request_is_applied_once_not_on_every_reconnect(
    tcp_port: Callable[[], int], tmp_path: Path
) -> None:
    port = tcp_port()
    slots = {1: AttackSwitch(AttackSlot(1))}
    plane = ControlPlane(f"mqtt://127.0.0.1:{port}", vehicle_controls("t", slots), stats=no_stats, backoff_s=(0.1, 0.3))
    with Mosquitto(port, tmp_path):
        async with plane:
            await plane.wait_connected(10)
            async with Observer(port, ["secuav/v1/#"]) as obs:
                await obs.publish(SET1, {"library": "drift", "request_id": "kept"}, retain=True)
                assert (await obs.wait_for(STATE1, lambda b: b["request_id"] == "kept"))["ok"]
                assert (await obs.request(SET1, {"library": "distance-stuck"}))["ok"]
            # Drop the session without restarting the broker: the retained request comes back.
            assert plane._client is not None
            plane._client._client.socket().shutdown(2)
            for _ in range(100):
                if plane.connections == 2 and plane.connected.is_set():
                    break
                await asyncio.sleep(0.1)
            assert plane.connections == 2
            await asyncio.sleep(0.5)  # the broker has handed the retained request over by now
            assert slots[1].engine is not None and slots[1].engine.profile.name == "distance-stuck"


_ALIAS_BOMB = "".join(
    f"{name}: &{name} [{', '.join([f'*{prev}'] * 9) if prev else ', '.join(['lol'] * 9)}]\n"
    for prev, name in zip(["", "a", "b", "c", "d", "e", "f"], ["a", "b", "c", "d", "e", "f", "g"], strict=True)
)


async def test_in_the_real_proxy_a_flood_of_bad_requests_loses_no_frame_and_a_swap_lands_between_frames(
    udp_port: Callable[[], int], tcp_port: Callable[[], int]
) -> None:
    import socket

    from pymavlink.dialects.v20 import common as mavlink2

    from mavframe.frames import split
    from mitm_proxy.app import Proxy
    from mitm_proxy.config import LinkConfig, ProxyConfig
    from mitm_proxy.control.plane import REQUEST_BURST, REQUESTS_PER_S
    from secuav_common.broker import EmbeddedBroker

    FRAMES = 800
    mqtt, veh = tcp_port(), udp_port()
    ground = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ground.bind(("127.0.0.1", 0))
    ground.setblocking(False)
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    link = LinkConfig(
        sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[f"udpout://127.0.0.1:{ground.getsockname()[1]}"]
    )
    sent: list[tuple[float, bytes]] = []
    received: list[bytes] = []
    loop = asyncio.get_running_loop()

    async def stream() -> None:
        for i in range(FRAMES):  # 4 s at 200 Hz
            frame = mav.distance_sensor_encode(i, 20, 1000, 250, 0, 0, 0, 0).pack(mav)
            sent.append((time.monotonic(), frame))
            vehicle.sendto(frame, ("127.0.0.1", veh))
            await asyncio.sleep(0.005)

    async def collect() -> None:
        while True:
            data, _ = await loop.sock_recvfrom(ground, 65535)
            received.extend(f for _h, f in split(data).frames)

    try:
        async with (
            EmbeddedBroker(port=mqtt),
            Proxy(ProxyConfig(links=[link], broker=f"mqtt://127.0.0.1:{mqtt}")) as proxy,
        ):
            await proxy.control.wait_connected(10)
            async with Observer(mqtt, ["secuav/v1/attack/state"]) as obs:
                collector = asyncio.create_task(collect())
                streamer = asyncio.create_task(stream())
                await asyncio.sleep(0.3)
                for i in range(40):
                    await obs.publish(SET1, b"\xff\x00" * 100 + bytes([i]))
                    await obs.publish(SET1, b'{"request_id": "big", "x": "' + b"y" * 70_000 + b'"}')
                # Past the first REQUEST_BURST tokens (a large request costs one per 4 kB) the flood was dropped
                # unread; the bucket refills in 2 s.
                await asyncio.sleep(REQUEST_BURST / REQUESTS_PER_S + 0.2)
                assert 40 < proxy.control.rate_limited < 80
                # The hostile review's YAML alias bomb (a few hundred bytes that expand to gigabytes), a
                # document nested past Python's recursion limit and a 5000-digit integer: refused at once.
                await obs.publish(SET1, json.dumps(_ALIAS_BOMB).encode())
                bomb_state = await obs.wait_for(STATE1, lambda b: "aliases" in (b["error"] or ""))
                assert not bomb_state["ok"]
                await obs.publish(SET1, b"[" * 30_000 + b"]" * 30_000)
                deep = await obs.wait_for(STATE1, lambda b: "nested too deeply" in (b["error"] or ""))
                await obs.publish(SET1, b'{"x": ' + b"9" * 5000 + b"}")
                huge = await obs.wait_for(STATE1, lambda b: "digits" in (b["error"] or ""))
                assert not deep["ok"] and not huge["ok"]
                bias = {"name": "plus-1m", "rules": [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0,
                        "field": "current_distance"}, "kind": "bias", "offset_m": 1.0}]}  # fmt: skip
                state = await obs.request(SET1, bias)
                acked_s = time.monotonic()
                assert state["ok"] and state["profile"] == "plus-1m"
                await streamer
                await asyncio.sleep(0.3)
                collector.cancel()
    finally:
        ground.close()
        vehicle.close()

    assert len(received) == len(sent) == FRAMES  # nothing lost, nothing added
    parser = mavlink2.MAVLink(None)
    values = [parser.decode(bytearray(f)).current_distance for f in received]
    swapped = next(i for i, v in enumerate(values) if v != 250)
    assert values[swapped:] == [350] * (FRAMES - swapped)  # every frame after the swap, none half-way
    assert received[:swapped] == [f for _t, f in sent[:swapped]]  # before it: byte for byte
    assert sent[swapped - 1][0] < acked_s  # the swap happened before the acknowledgement went out


def test_publish_nowait_turns_nan_and_numpy_into_json_and_never_raises(caplog: pytest.LogCaptureFixture) -> None:
    import json

    import numpy as np

    plane = ControlPlane("mqtt://127.0.0.1:1", vehicle_controls("t", {1: AttackSwitch(AttackSlot(1))}), stats=no_stats)
    estimate = {"pos_ned_m": np.array([1.0, np.nan, -2.0]), "t_s": np.float64(3.5), "attacked": [np.int64(12)]}
    plane.publish_nowait("secuav/v1/estimate", estimate)
    plane.publish_nowait("secuav/v1/estimate", {"range_m": float("nan"), "ok": True})
    assert [json.loads(p) for _t, p in plane.outbox.queue] == [
        {"pos_ned_m": [1.0, None, -2.0], "t_s": 3.5, "attacked": [12]},
        {"range_m": None, "ok": True},
    ]
    loop: dict[str, Any] = {}
    loop["self"] = loop
    for _ in range(3):
        plane.publish_nowait("secuav/v1/estimate", loop)  # unencodable: dropped, logged once
    assert len(plane.outbox.queue) == 2
    assert [r.getMessage() for r in caplog.records].count("control.unencodable") == 1


async def test_aiomqtts_dead_socket_race_stays_out_of_the_log_and_other_errors_do_not(
    caplog: pytest.LogCaptureFixture,
) -> None:
    import os
    import resource
    import tempfile

    caplog.set_level(logging.DEBUG)
    loop = asyncio.get_running_loop()
    plane = ControlPlane(
        "mqtt://127.0.0.1:1", vehicle_controls("t", {1: AttackSwitch(AttackSlot(1))}), stats=no_stats,
        backoff_s=(30.0, 30.0),
    )
    async with plane:
        # What aiomqtt does when the broker vanishes mid-publish: add_writer scheduled for a socket closed since.
        # The number must be one nothing else can get meanwhile (aiomqtt's connect thread opens files and
        # sockets, and the kernel hands out the lowest free number): the highest one the process may use.
        fd = resource.getrlimit(resource.RLIMIT_NOFILE)[0] - 1
        with pytest.raises(OSError):
            os.fstat(fd)  # not open
        loop.call_soon(loop.add_writer, fd, lambda: None)
        # The same race after the number went to a regular file (a recording): epoll refuses it with EPERM.
        with tempfile.TemporaryFile() as reused:
            loop.call_soon(loop.add_writer, reused.fileno(), lambda: None)
            await asyncio.sleep(0.02)

        def other_bug() -> None:
            raise RuntimeError("someone else's bug")

        loop.call_soon(other_bug)
        await asyncio.sleep(0.05)
    errors = [r for r in caplog.records if r.name == "asyncio" and r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "someone else's bug" in repr(errors[0].exc_info)
    assert [r.getMessage() for r in caplog.records].count("mqtt.socket_race") == 2
    assert loop.get_exception_handler() is None  # put back as it was
