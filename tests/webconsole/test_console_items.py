"""The operator's console as a new user found it (issue 36): what the page and the API say must be true.

Real console app over uvicorn on loopback, a real broker, the proxy's own
control plane answering.
"""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
import time

import pytest

from tests.support.console import Bench, call

pytestmark = pytest.mark.timeout(60)


async def test_after_a_proxy_stops_its_vehicle_is_404_not_500(bench: Bench) -> None:
    """The review: ``GET /api/vehicles/1`` was a 500 (StopIteration) and a POST waited 5 s for a 504."""
    await bench.plane.aclose()  # a clean stop: the proxy's online record says offline
    for _ in range(100):
        if not bench.fleet.owners():
            break
        await asyncio.sleep(0.05)
    assert not bench.fleet.owners()
    status, answer = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/attack/mode", {"mode": "bypass"})
    assert status == 404 and "stopped" in answer["error"], answer  # said at once (a timeout would be 504)
    for _ in range(3):  # the row lingers offline for a while, then leaves the fleet: never a 500
        status, answer = await asyncio.to_thread(call, bench.base, "/api/vehicles/1")
        assert status in (200, 404), (status, answer)
    bench.fleet.vehicles[1].stats_at = time.monotonic() - 3600  # as if the 30 s had passed
    status, answer = await asyncio.to_thread(call, bench.base, "/api/vehicles/1")
    assert status == 404 and answer["error"].startswith("no vehicle 1"), answer


def test_a_busy_port_is_one_line() -> None:
    """The review: about 40 lines of uvicorn traceback; the proxy and the simulator say it in one line."""
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        run = subprocess.run([sys.executable, "-m", "webconsole", "--broker", "mqtt://127.0.0.1:1", "--listen",
                              f"127.0.0.1:{port}"], capture_output=True, text=True, timeout=30)  # fmt: skip
    assert run.returncode == 1
    assert run.stderr.splitlines() == [f"secuav-console: error: cannot serve on 127.0.0.1:{port}: Address already in "
                                       "use (another program listens there? choose another with --listen HOST:PORT)"]
