"""Real flightsim, real secuav-proxy, real MAVSDK on loopback: fly through the proxy, then check every value.

One flight (to keep the suite short): connect, health, arm, take off, hover,
land, with the attack stage first bypassed (profile loaded, not applied) and
then switched to active at runtime, as the control plane does. MAVSDK reads
each DISTANCE_SENSOR with its id (MavlinkDirect); the proxy's recording of
what the vehicle sent is the reference, so a reading MAVSDK saw must equal the
vehicle's reading exactly in bypass and exactly the vehicle's reading plus the
profile's bias once the stage is active. A raw UDP socket on a second ground
endpoint checks byte-exactness: every frame the profile does not target is the
vehicle's frame, byte for byte, in the vehicle's order.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import struct
from collections import Counter
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.telemetry import FlightMode

from flightsim.runner import RunConfig, SimRunner
from mavframe.frames import split
from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from secuav_common.scenario import load_scenario
from secuav_common.urls import Endpoint

DISTANCE_SENSOR = 132
LOCAL_POSITION_NED = 32
BIAS_M = 1.5
NORTH_BIAS_M = 3.0
ATTACKED_IDS = range(5)  # the wall sensors; other DISTANCE_SENSOR ids of the scenario pass untouched
PROFILE = f"""
name: e2e-bias
rules:
  - target: {{message: DISTANCE_SENSOR, sensor_id: {{first: 0, last: 4}}, field: current_distance}}
    kind: bias
    offset_m: {BIAS_M}
    start_s: 0
  - target: {{message: LOCAL_POSITION_NED, field: x}}
    kind: bias
    offset_m: {NORTH_BIAS_M}
    start_s: 0
"""

pytestmark = [pytest.mark.slow, pytest.mark.timeout(150)]


class Capture(asyncio.DatagramProtocol):
    """A bare ground endpoint: keeps every datagram the proxy sends it."""

    def __init__(self) -> None:
        self.data: list[bytes] = []

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.data.append(data)


def tlog_frames(path: Path) -> list[bytes]:
    """Frames of a .tlog (8-byte big-endian µs stamp + one frame, repeated)."""
    blob = path.read_bytes()
    out, i = [], 0
    while i < len(blob):
        i += 8
        v2 = blob[i] == 0xFD  # header 10 + CRC 2 (+ signature 13) for v2; header 6 + CRC 2 for v1
        n = blob[i + 1] + (12 + (13 if blob[i + 2] & 1 else 0) if v2 else 8)
        out.append(blob[i : i + n])
        i += n
    return out


def lpos_x(frame: bytes) -> tuple[int, float]:
    """(time_boot_ms, x) of a v2 LOCAL_POSITION_NED frame."""
    payload = frame[10 : 10 + frame[1]].ljust(28, b"\0")
    t_ms, x = struct.unpack_from("<If", payload)
    return t_ms, x


def ds_key(frame: bytes) -> tuple[int, int, int]:
    """(sensor id, time_boot_ms, current_distance cm) of a v2 DISTANCE_SENSOR frame (payload may be truncated)."""
    payload = frame[10 : 10 + frame[1]].ljust(39, b"\0")
    time_boot_ms, _min, _max, current = struct.unpack_from("<IHHH", payload)
    return payload[11], time_boot_ms, current  # uint32 time, 3 x uint16, type, id


@contextlib.asynccontextmanager
async def stack(tmp_path: Path, udp_port: Callable[[], int]) -> AsyncIterator[tuple[Proxy, SimRunner, int, Capture]]:
    veh, api, raw = udp_port(), udp_port(), udp_port()
    profile = tmp_path / "bias.yaml"
    profile.write_text(PROFILE)
    cfg = ProxyConfig(
        links=[LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}",
                          ground=[f"udpout://127.0.0.1:{api}", f"udpout://127.0.0.1:{raw}"])],
        attack="bypass", profile=profile, record=tmp_path / "rec", broker="none",
    )  # fmt: skip
    loop = asyncio.get_running_loop()
    cap = Capture()
    transport, _ = await loop.create_datagram_endpoint(lambda: cap, local_addr=("127.0.0.1", raw))
    stop = asyncio.Event()
    try:
        async with Proxy(cfg) as proxy:
            run = RunConfig(load_scenario("wall_hover"), [Endpoint("udpout", "127.0.0.1", veh)])
            async with SimRunner(run) as runner:
                task = asyncio.create_task(runner.run(stop))
                try:
                    yield proxy, runner, api, cap
                finally:
                    stop.set()
                    await asyncio.wait_for(task, 5.0)
    finally:
        transport.close()


async def first(aiter: AsyncIterator[Any], pred: Callable[[Any], bool], timeout_s: float) -> Any:
    async def go() -> Any:
        async for item in aiter:
            if pred(item):
                return item
        return None

    return await asyncio.wait_for(go(), timeout_s)


async def test_fly_through_the_proxy_bypass_then_attack(tmp_path: Path, udp_port: Callable[[], int]) -> None:
    seen: list[tuple[str, int, int, int]] = []  # (phase, id, time_boot_ms, current_distance) as MAVSDK saw them
    north: list[tuple[str, int, float]] = []  # (phase, time_boot_ms, LOCAL_POSITION_NED.x) as MAVSDK saw them
    phase = "bypass"
    async with stack(tmp_path, udp_port) as (proxy, runner, api, cap):
        vehicle = runner.sim.vehicles[1]
        stage = proxy.stages[1]
        async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
            await m.add_any_connection(f"udpin://127.0.0.1:{api}")
            system = await m.first_autopilot(timeout_s=15)
            assert system is not None, "MAVSDK found no autopilot through the proxy"
            tel, action, direct = TelemetryAsync(system), ActionAsync(system), MavlinkDirectAsync(system)

            async def watch() -> None:
                async for msg in direct.subscribe_message("DISTANCE_SENSOR"):
                    f = json.loads(msg.fields_json)
                    seen.append((phase, int(f["id"]), int(f["time_boot_ms"]), int(f["current_distance"])))

            async def watch_position() -> None:
                async for msg in direct.subscribe_message("LOCAL_POSITION_NED"):
                    f = json.loads(msg.fields_json)
                    north.append((phase, int(f["time_boot_ms"]), float(f["x"])))

            watchers = [asyncio.create_task(watch()), asyncio.create_task(watch_position())]
            await first(tel.subscribe_health_all_ok(), bool, 20)
            await action.arm()
            await action.takeoff()
            await first(tel.subscribe_flight_mode(), lambda mode: mode == FlightMode.HOLD, 20)
            assert vehicle.armed and -vehicle.truth.pos_ned_m[2] > 2.0
            await asyncio.sleep(1.0)
            phase = "switching"
            stage.active = True  # what secuav/v1/attack/set with the bypass flag off does
            await asyncio.sleep(0.3)
            phase = "attack"
            await asyncio.sleep(2.0)
            phase = "landing"
            await action.land()
            await first(tel.subscribe_in_air(), lambda in_air: not in_air, 30)
            for w in watchers:
                w.cancel()
            assert not vehicle.crashed
        snap = proxy.stats_snapshot()[1]
    # -- what the vehicle sent (the proxy's original recording) is the reference
    original = [f for f in tlog_frames(tmp_path / "rec/v1/original.tlog") if f[5] == 1]  # sysid 1: the vehicle
    truth = {k[:2]: k[2] for k in (ds_key(f) for f in original if f[0] == 0xFD and f[7] == DISTANCE_SENSOR)}
    by_phase: dict[str, int] = {}
    for ph, sid, t_ms, cm in seen:
        if ph in ("bypass", "attack"):
            assert (sid, t_ms) in truth, (sid, t_ms)
            attacked = ph == "attack" and sid in ATTACKED_IDS
            want = truth[(sid, t_ms)] + (round(BIAS_M * 100) if attacked else 0)
            assert cm == want, (ph, sid, t_ms, cm, truth[(sid, t_ms)])
            key = f"{ph}{'+' if attacked else ''}"
            by_phase[key] = by_phase.get(key, 0) + 1
    assert by_phase.get("bypass", 0) > 20 and by_phase.get("attack+", 0) > 20, by_phase
    # -- position: MAVSDK's north is the vehicle's, then the vehicle's plus the bias (float32 on the wire)
    x_true = dict(lpos_x(f) for f in original if f[0] == 0xFD and f[7] == LOCAL_POSITION_NED)
    checked = Counter()
    for ph, t_ms, x in north:
        if ph in ("bypass", "attack"):
            want = x_true[t_ms] + (NORTH_BIAS_M if ph == "attack" else 0.0)
            assert x == pytest.approx(want, abs=2e-6 * max(1.0, abs(want))), (ph, t_ms, x, x_true[t_ms])
            checked[ph] += 1
    assert checked["bypass"] > 10 and checked["attack"] > 10, checked
    assert snap["downlink"]["rewritten"] > 0 and snap["uplink"]["frames_in"] > 0
    # -- byte-exactness on the raw ground endpoint: untargeted frames are the vehicle's, in order
    sent_raw = [f for d in cap.data for _h, f in split(d).frames]
    targeted = (DISTANCE_SENSOR, LOCAL_POSITION_NED)
    untargeted_in = [f for f in original if f[7] not in targeted]
    untargeted_out = [f for f in sent_raw if f[7] not in targeted]
    assert len(untargeted_out) > 500
    assert untargeted_out == untargeted_in[: len(untargeted_out)]
    assert len(untargeted_in) - len(untargeted_out) <= 2  # at most what was in flight at teardown
