"""A proxy's recording says which profile was in force from which frame on, and which way it changed frames."""

from __future__ import annotations

import asyncio
import json
import socket
from collections.abc import Callable
from pathlib import Path

import pytest

from attack_profiles.profile import parse_profile
from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from tests.support.frames_support import heartbeat, pack

pytestmark = pytest.mark.usefixtures("proxy_path")  # each test on the fast path and the Python one (tests/conftest.py)

UPLINK = {"name": "feed-lie", "rules": [{"target": {"message": "DISTANCE_SENSOR", "direction": "uplink"},
                                         "kind": "bias", "offset": 5.0}]}  # fmt: skip


async def test_profiles_json_follows_every_install_with_its_directions(
    tmp_path: Path, udp_port: Callable[[], int]
) -> None:
    start = tmp_path / "start.yaml"
    start.write_text("name: ground\nrules:\n  - {target: {message: DISTANCE_SENSOR}, kind: bias, offset: 1}\n")
    veh = udp_port()
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{veh}", ground=[f"udpout://127.0.0.1:{udp_port()}"])
    cfg = ProxyConfig(links=[link], broker="none", record=tmp_path / "rec", profile=start)
    async with Proxy(cfg) as proxy:
        slot = proxy.slots[1]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for _ in range(3):
                sock.sendto(pack(heartbeat()), ("127.0.0.1", veh))
            for _ in range(100):  # the three frames reach the recording
                await asyncio.sleep(0.02)
                if proxy.recorders[0].original_count == 3:
                    break
        assert slot.offer(parse_profile(UPLINK, "up.yaml")).ok
        assert slot.offer(None).ok  # cleared
    entries = json.loads((tmp_path / "rec" / "v1" / "profiles.json").read_text())
    assert [(e["profile"], e["directions"], e["original"]) for e in entries] == [
        ("ground", ["downlink"], 0), ("feed-lie", ["uplink"], 3), (None, [], 3)]  # fmt: skip
    assert entries[1]["hash"] == parse_profile(UPLINK, "up.yaml").content_hash() and entries[2]["hash"] is None
