"""Two real flightsim vehicles through one proxy: one GCS endpoint carries both, uplink goes by target_system.

The formation scenario's two vehicles (sysid 1 and 2) each have a link; both
links forward to one shared GCS port (QGroundControl's 14550 in the port plan)
and to their own API port. A PARAM_REQUEST_READ sent on the shared port to
sysid 2 is answered by vehicle 2 alone; the same request on vehicle 1's API
port is answered by vehicle 1.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from flightsim.runner import RunConfig, SimRunner
from mitm_proxy.app import Proxy
from mitm_proxy.cli import build_parser, config_from_args
from secuav_common.scenario import load_scenario
from secuav_common.urls import Endpoint
from tests.support.udp_peers import Peer

pytestmark = [pytest.mark.slow, pytest.mark.timeout(60)]
REPO = Path(__file__).resolve().parents[2]


async def collect(peer: Peer, seconds: float) -> tuple[list[bytes], tuple[str, int] | None]:
    """Frames a peer receives in ``seconds`` (live telemetry never goes quiet), and the last sender."""
    loop = asyncio.get_running_loop()
    end = loop.time() + seconds
    out: list[bytes] = []
    sender = None
    while (left := end - loop.time()) > 0:
        try:
            data, sender = await asyncio.wait_for(loop.sock_recvfrom(peer.sock, 65535), left)
        except TimeoutError:
            break
        out.append(data)
    return out, sender


def decode(datagrams: list[bytes]) -> list[mavlink2.MAVLink_message]:
    parser = mavlink2.MAVLink(None)
    return [m for d in datagrams for m in (parser.parse_buffer(d) or [])]


async def test_two_vehicles_share_the_gcs_port(udp_port: Callable[[], int]) -> None:
    scenario = str(REPO / "scenarios/formation.yaml")
    veh = [udp_port(), udp_port()]
    gcs, api1, api2 = Peer(), Peer(), Peer()
    argv = ["--scenario", scenario, "--broker", "none"]
    for v, api in zip(veh, (api1, api2), strict=True):
        argv += ["--link", f"udpin://127.0.0.1:{v}", f"udpout://127.0.0.1:{api.port}", f"udpout://127.0.0.1:{gcs.port}"]
    cfg = config_from_args(build_parser().parse_args(argv))
    assert [ln.sysid for ln in cfg.links] == [1, 2]
    try:
        async with Proxy(cfg) as proxy:
            stop = asyncio.Event()
            run = RunConfig(load_scenario(scenario), [Endpoint("udpout", "127.0.0.1", p) for p in veh])
            async with SimRunner(run) as runner:
                task = asyncio.create_task(runner.run(stop))
                try:
                    got, proxy_addr = await collect(gcs, 1.5)
                    assert {m.get_srcSystem() for m in decode(got)} == {1, 2}
                    assert proxy_addr is not None
                    g = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
                    gcs.reply(g.param_request_read_encode(2, 1, b"MIS_TAKEOFF_ALT", -1).pack(g), proxy_addr)
                    answers = [m for m in decode((await collect(gcs, 1.0))[0]) if m.get_type() == "PARAM_VALUE"]
                    assert answers and {m.get_srcSystem() for m in answers} == {2}
                    _, api1_proxy = await collect(api1, 0.2)
                    assert api1_proxy is not None
                    api1.reply(g.param_request_read_encode(1, 1, b"MIS_TAKEOFF_ALT", -1).pack(g), api1_proxy)
                    answers = [m for m in decode((await collect(gcs, 1.0))[0]) if m.get_type() == "PARAM_VALUE"]
                    assert answers and {m.get_srcSystem() for m in answers} == {1}
                finally:
                    stop.set()
                    await asyncio.wait_for(task, 5.0)
            snap = proxy.stats_snapshot()
    finally:
        for p in (gcs, api1, api2):
            p.close()
    assert snap[1]["uplink"]["frames_out"] == 1 and snap[2]["uplink"]["frames_out"] == 1
