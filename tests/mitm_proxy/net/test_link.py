"""Links on real loopback sockets: the shared GCS endpoint routes uplink by target_system, delays use the loop.

Vehicles and ground stations here are plain UDP sockets speaking real MAVLink
(frames packed by pymavlink); the proxy is the real one, in-process.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavframe.frames import split
from mavframe.layout import TARGET_SYSTEM_OFFSETS as TARGET_OFFSETS
from mavframe.layout import target_system
from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from tests.support.udp_peers import Peer, command, distance, heartbeat, packer

# Each test runs on the compiled fast path and on the pure-Python one (proxy_path, tests/conftest.py).
pytestmark = [pytest.mark.timeout(30), pytest.mark.usefixtures("proxy_path")]


@contextlib.asynccontextmanager
async def two_vehicles(udp_port: Callable[[], int], **extra: object) -> AsyncIterator[tuple[Proxy, list[int], Peer]]:
    """Links for sysids 1 and 2, each listening on its own port, both forwarding to one GCS."""
    gcs = Peer()
    ports = [udp_port(), udp_port()]
    links = [LinkConfig(sysid=i + 1, vehicle=f"udpin://127.0.0.1:{p}", ground=[f"udpout://127.0.0.1:{gcs.port}"])
             for i, p in enumerate(ports)]  # fmt: skip
    try:
        async with Proxy(ProxyConfig(links=links, broker="none", **extra)) as proxy:  # type: ignore[arg-type]
            yield proxy, ports, gcs
    finally:
        gcs.close()


def test_target_offsets_match_pymavlink() -> None:
    """The routing table reads target_system where pymavlink packs it, for every message that has one."""
    mav = packer(255, 190)
    for msgid, offset in TARGET_OFFSETS.items():
        cls = mavlink2.mavlink_map.get(msgid)
        if cls is None:
            continue
        lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
        args: list[object] = []
        for name, kind in zip(cls.fieldnames, cls.fieldtypes, strict=True):
            value: object = 0.0 if kind in ("float", "double") else 0
            if kind == "char":
                value = b""
            elif lengths[name]:
                value = [value] * lengths[name]
            args.append(value)
        msg = cls(*args)
        msg.target_system = 77
        frame = msg.pack(mav)
        header, raw = split(frame).frames[0]
        assert target_system(header, raw) == 77, (cls.msgname, offset)
    assert len(TARGET_OFFSETS) > 50


async def test_shared_gcs_routes_uplink_by_target_system(udp_port: Callable[[], int]) -> None:
    async with two_vehicles(udp_port) as (proxy, ports, gcs):
        v1, v2 = Peer(), Peer()
        try:
            v1.send(heartbeat(packer(1)), ports[0])
            v2.send(heartbeat(packer(2)), ports[1])
            got, proxy_addr = await gcs.frames()
            assert sorted(f[5] for f in got) == [1, 2]  # both vehicles through one GCS endpoint
            assert proxy_addr is not None
            g = packer(255, 190)
            to1, to2, to_all, hb = command(g, 1), command(g, 2), command(g, 0), heartbeat(g)
            gcs.reply(to2, proxy_addr)
            gcs.reply(to1 + to2, proxy_addr)  # one datagram, one command for each vehicle
            gcs.reply(to_all, proxy_addr)
            gcs.reply(hb, proxy_addr)
            stray = command(g, 9)
            gcs.reply(stray, proxy_addr)  # no such vehicle here: everyone gets it, as a broadcast would
            got1, _ = await v1.frames()
            got2, _ = await v2.frames()
            assert got1 == [to1, to_all, hb, stray]
            assert got2 == [to2, to2, to_all, hb, stray]
            snap = proxy.stats_snapshot()
            assert (snap[1]["uplink"]["frames_out"], snap[2]["uplink"]["frames_out"]) == (4, 5)
        finally:
            v1.close()
            v2.close()


async def test_delayed_frames_leave_later_and_the_rest_at_once(udp_port: Callable[[], int], tmp_path: Path) -> None:
    profile = tmp_path / "delay.yaml"
    profile.write_text("name: d\nrules:\n  - target: {message: DISTANCE_SENSOR, field: current_distance}\n"
                       "    kind: delay\n    delay_s: 0.25\n    start_s: 0\n")  # fmt: skip
    async with two_vehicles(udp_port, profile=profile) as (proxy, ports, gcs):
        v1 = Peer()
        loop = asyncio.get_running_loop()
        try:
            mav = packer(1)
            ds, hb = distance(mav, 321), heartbeat(mav)
            t0 = loop.time()
            v1.send(ds + hb, ports[0])
            data, _ = await asyncio.wait_for(loop.sock_recvfrom(gcs.sock, 65535), 1.0)
            t_hb = loop.time() - t0
            assert [f for _h, f in split(data).frames] == [hb]
            data, _ = await asyncio.wait_for(loop.sock_recvfrom(gcs.sock, 65535), 1.0)
            t_ds = loop.time() - t0
            assert data == ds  # delayed, not changed
            assert t_hb < 0.1 and 0.24 <= t_ds < 0.5, (t_hb, t_ds)
            snap = proxy.stats_snapshot()[1]
            assert snap["downlink"]["delayed"] == 1 and snap["pending_delayed"] == 0
        finally:
            v1.close()
