"""The secure stage says when the vehicle's rangefinders are not the scenario's (issue 27, item 2).

In front of ArduPilot SITL, ``--scenario wall_hover --secure secekf`` ran a whole
flight with no rewrite and no word: the scenario expects forward DISTANCE_SENSOR
ids 0-4 (and a downward 5), ArduPilot sent downward ids 0-2. The pure check is
tested on the scenarios' layouts; then the real proxy on loopback gets the
recorded ArduPilot stream (tests/data/ardupilot-copter-guided.tlog) at its own
pace, and must log ``secure.layout_mismatch`` once, keep it in the stats, the
stats line and the ``secure/state`` it publishes on a real broker, and drop it
when readings that fit the layout arrive; a stream that fits never raises it.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import aiomqtt
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavframe import tlog
from mavframe.layout import DISTANCE_SENSOR
from mitm_proxy.app import Proxy, stats_line
from mitm_proxy.config import LinkConfig, ProxyConfig
from mitm_proxy.stages.secure.config import config_from_payload
from mitm_proxy.stages.secure.layout import build_layout
from mitm_proxy.stages.secure.match import CODE, LayoutCheck, id_ranges
from secuav_common.broker import EmbeddedBroker
from secuav_common.scenario import load_scenario
from tests.support.udp_peers import Peer

REPO = Path(__file__).resolve().parents[3]
TLOG = REPO / "tests/data/ardupilot-copter-guided.tlog"
FORWARD, DOWN = 0, 25  # MAV_SENSOR_ORIENTATION


def check_for(scenario: str, estimator: str = "secekf", grace_s: float = 3.0) -> LayoutCheck:
    layout = build_layout(config_from_payload(estimator, "test"), load_scenario(scenario), 1)
    return LayoutCheck(layout, grace_s)


# -- the check on its own ----------------------------------------------------------------------------------------


def test_ardupilot_downward_ids_against_the_wall_group_are_named_at_once_then_the_missing_ones() -> None:
    check = check_for("wall_hover")
    assert check.take(0, DOWN, 0.0)  # a group sensor facing down where the scenario mounts it forward: at once
    text = check.mismatch
    assert text is not None and text.startswith(CODE + ":")
    assert "0-4 forward (0)" in text and "0 down (25)" in text and "facing another way: 0" in text
    assert not check.take(1, DOWN, 0.5) or "0-1 down (25)" in (check.mismatch or "")
    check.take(2, DOWN, 1.0)
    assert "never seen" not in (check.mismatch or "")  # the grace period is not over
    assert check.take(0, DOWN, 3.1)  # now 3 and 4 were never seen
    assert "never seen: 3-4" in (check.mismatch or "") and "facing another way: 0-2" in (check.mismatch or "")
    assert check.fields["arrived"] == "0-2 down (25)"


def test_a_stream_that_fits_raises_nothing_and_a_mismatch_clears_when_readings_fit() -> None:
    check = check_for("wall_hover")
    for t in range(100):  # flightsim's wall_hover set: 0-4 forward, 5 down, for 5 s
        for sid in range(6):
            check.take(sid, DOWN if sid == 5 else FORWARD, t * 0.05)
            assert check.mismatch is None
    late = check_for("wall_hover")
    late.take(0, FORWARD, 0.0)
    late.take(0, FORWARD, 3.5)
    assert "never seen: 1-4" in (late.mismatch or "")
    for sid in range(1, 5):
        late.take(sid, FORWARD, 3.6)
    assert late.mismatch is None
    turned = check_for("wall_hover")
    turned.take(2, DOWN, 0.0)
    assert turned.mismatch is not None
    assert turned.take(2, FORWARD, 0.1) and turned.mismatch is None  # the same id, now as the scenario mounts it


def test_an_anchors_group_needs_some_anchor_range_not_every_one() -> None:
    check = check_for("anchors8")
    check.take(0, DOWN, 0.0)  # the height laser fits the scenario
    assert check.mismatch is None
    check.take(0, DOWN, 3.5)
    assert check.mismatch is not None and "never seen: 10-17" in check.mismatch and "UWB anchor" in check.mismatch
    check.take(12, 100, 3.6)  # one anchor range is enough: the others may be out of reach
    assert check.mismatch is None
    silent = check_for("anchors8")
    silent.take(11, 100, 0.0)
    silent.take(11, 100, 10.0)
    assert silent.mismatch is None


def test_id_ranges_fold_runs() -> None:
    assert id_ranges([4, 0, 1, 2, 7, 9, 10]) == "0-2, 4, 7, 9-10"
    assert id_ranges([]) == ""


# -- the real proxy on loopback ----------------------------------------------------------------------------------


def ardupilot_window(seconds: float) -> list[tuple[float, bytes]]:
    """The recorded ArduCopter frames from its first DISTANCE_SENSOR on, for ``seconds``, with their offsets."""
    entries = [e for e in tlog.TlogReader(TLOG.read_bytes()) if e.header.sysid == 1]
    t0 = next(e.t_s for e in entries if e.header.msgid == DISTANCE_SENSOR)
    return [(e.t_s - t0, e.raw) for e in entries if 0.0 <= e.t_s - t0 < seconds]


async def replay(frames: list[tuple[float, bytes]], peer: Peer, port: int) -> None:
    """Send each frame at its recorded offset (several per wake-up: the log's pace, not a busy loop)."""
    start = time.monotonic()
    for offset, raw in frames:
        wait = offset - (time.monotonic() - start)
        if wait > 0.005:
            await asyncio.sleep(wait)
        peer.send(raw, port)


def wall_set(mav: mavlink2.MAVLink, t_ms: int) -> list[bytes]:
    """One round of wall_hover's rangefinders as flightsim sends them: 0-4 forward at 5 m, 5 down at 2.5 m."""
    return [mav.distance_sensor_encode(t_ms, 10, 4000, 250 if sid == 5 else 500 + sid, 0, sid,
                                       DOWN if sid == 5 else FORWARD, 0, signal_quality=100).pack(mav)
            for sid in range(6)]  # fmt: skip


async def send_wall_sets(peer: Peer, port: int, seconds: float, hz: float = 20.0) -> None:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    start = time.monotonic()
    n = 0
    # At least ``seconds`` of wall time (the layout check's grace runs on the proxy's clock) AND at least
    # ``seconds * hz`` sets: on a loaded machine the sleeps overshoot, and the counts the tests check must not
    # depend on how busy it is.
    while time.monotonic() - start < seconds or n < seconds * hz:
        for frame in wall_set(mav, int(n * 1000 / hz)):
            peer.send(frame, port)
        n += 1
        await asyncio.sleep(1.0 / hz)


def mismatch_records(caplog: pytest.LogCaptureFixture) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.getMessage() == "secure.layout_mismatch"]


@pytest.mark.timeout(60)
async def test_the_ardupilot_stream_through_the_proxy_is_called_a_mismatch_until_fitting_readings_arrive(
    udp_port: Callable[[], int], tcp_port: Callable[[], int], caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    veh, mqtt = udp_port(), tcp_port()
    gcs, vehicle = Peer(), Peer()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[f"udpout://127.0.0.1:{gcs.port}"])
    cfg = ProxyConfig(links=[link], broker=f"mqtt://127.0.0.1:{mqtt}", scenario="wall_hover", secure="secekf")
    states: list[dict[str, Any]] = []
    try:
        async with EmbeddedBroker(port=mqtt), aiomqtt.Client("127.0.0.1", mqtt) as client:
            await client.subscribe("secuav/v1/secure/state")

            async def listen() -> None:
                async for msg in client.messages:
                    states.append(json.loads(bytes(msg.payload)))  # type: ignore[arg-type]

            listener = asyncio.create_task(listen())
            async with Proxy(cfg) as proxy:
                assert proxy.control is not None
                await proxy.control.wait_connected(10)
                await replay(ardupilot_window(4.0), vehicle, veh)  # past the 3 s grace: 3 and 4 never seen
                await asyncio.sleep(0.5)  # the control plane polls states 5 times a second
                during = proxy.stats_snapshot()[1]
                line = stats_line(1, during)
                state_during = proxy.secure[1].state
                await send_wall_sets(vehicle, veh, 0.5)  # now the scenario's sensors arrive
                await asyncio.sleep(0.5)
                after = proxy.stats_snapshot()[1]
                state_after = proxy.secure[1].state
            listener.cancel()
    finally:
        gcs.close()
        vehicle.close()
    records = mismatch_records(caplog)
    assert len(records) == 1, [r.getMessage() for r in caplog.records]  # said once, at once
    rec = records[0]
    assert rec.levelno == logging.WARNING and rec.sysid == 1 and rec.scenario == "wall-hover"  # type: ignore[attr-defined]
    assert rec.arrived.startswith("0") and "down (25)" in rec.arrived  # type: ignore[attr-defined]
    assert "0-4 forward (0)" in rec.expected  # type: ignore[attr-defined]
    # ... and kept saying: the stats, the stats line, the state and what the broker carried
    (warning,) = during["warnings"]
    assert warning.startswith(CODE) and "never seen: 3-4" in warning and "0-2 down (25)" in warning
    assert line["warnings"] == CODE
    assert state_during.warnings == [warning]
    published = [s.get("warnings") for s in states]
    assert [warning] in published
    assert during["secure"]["substituted_frames"] == 0  # what the warning explains
    # fitting readings clear it, everywhere
    assert after["warnings"] == [] and state_after.warnings == []
    assert published[-1] == []
    assert any(r.getMessage() == "secure.layout_match" for r in caplog.records)


@pytest.mark.timeout(60)
async def test_a_stream_that_fits_the_scenario_raises_no_warning(
    udp_port: Callable[[], int], caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    veh = udp_port()
    gcs, vehicle = Peer(), Peer()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[f"udpout://127.0.0.1:{gcs.port}"])
    cfg = ProxyConfig(links=[link], broker="none", scenario="wall_hover", secure="secekf")
    try:
        async with Proxy(cfg) as proxy:
            await send_wall_sets(vehicle, veh, 3.5)  # past the grace period
            await asyncio.sleep(0.2)
            snap = proxy.stats_snapshot()[1]
            state = proxy.secure[1].state
    finally:
        gcs.close()
        vehicle.close()
    assert mismatch_records(caplog) == []
    assert snap["warnings"] == [] and state.warnings == [] and "warnings" not in stats_line(1, snap)
    assert snap["secure"]["readings"] > 300 and snap["secure"]["substituted_frames"] > 0  # the stage works


@pytest.mark.timeout(60)
async def test_a_signed_stream_without_the_key_is_named_instead_of_a_mismatch(
    udp_port: Callable[[], int], caplog: pytest.LogCaptureFixture
) -> None:
    """The pipeline hands the stage no signed frame without the key: the stage says why it sees nothing."""
    caplog.set_level(logging.INFO)
    veh = udp_port()
    gcs, vehicle = Peer(), Peer()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[f"udpout://127.0.0.1:{gcs.port}"])
    cfg = ProxyConfig(links=[link], broker="none", scenario="wall_hover", secure="secekf")
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.signing.secret_key, mav.signing.link_id, mav.signing.sign_outgoing = bytes(range(32)), 1, True
    mav.signing.timestamp = 1_000_000
    try:
        async with Proxy(cfg) as proxy:
            for n in range(10):
                for frame in wall_set(mav, n * 50):
                    vehicle.send(frame, veh)
            await gcs.frames()
            snap = proxy.stats_snapshot()[1]
            state = proxy.secure[1].state
    finally:
        gcs.close()
        vehicle.close()
    assert mismatch_records(caplog) == []
    (warning,) = state.warnings
    assert warning.startswith("secure.signed_no_key: vehicle 1") and "--signing-key" in warning
    assert snap["warnings"] == [warning] and snap["secure"]["signed_untouched"] == 60
    assert [r.getMessage() for r in caplog.records].count("secure.signed_no_key") == 1
