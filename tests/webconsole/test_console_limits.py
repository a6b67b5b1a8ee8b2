"""Nobody on the network locks the operator out of the console (issue 36's hostile review, each reproduced).

The app is the real one, served by uvicorn on loopback as ``secuav-console``
serves it (``webconsole.connections.server_config``). Each test failed on the
console before issue 36.
"""

from __future__ import annotations

import asyncio
import socket
import time

import pytest

from secuav_common.broker import BrokerAddress
from tests.webconsole.test_console_api import serve
from tests.webconsole.test_console_security import _open_stream, raw
from webconsole.api import StreamSlots
from webconsole.fleet import Fleet, Session

pytestmark = pytest.mark.timeout(60)


def _offline_console() -> tuple[Fleet, Session]:
    fleet = Fleet([])
    return fleet, Session(BrokerAddress("127.0.0.1", 1), fleet, "http://test/")


async def until(check: object, limit_s: float, what: str) -> None:
    deadline = time.monotonic() + limit_s
    while not check():  # type: ignore[operator]
        assert time.monotonic() < deadline, f"{what}: not within {limit_s} s"
        await asyncio.sleep(0.05)


async def test_head_requests_never_take_an_event_stream_slot() -> None:
    """The review's four HEADs (a no-cors fetch from another origin can send them) locked the operator out."""
    fleet, session = _offline_console()
    slots = StreamSlots(per_client=4, total=32)
    async with serve(fleet, session, streams=slots) as base:
        for _ in range(8):
            status, headers, body = await asyncio.to_thread(raw, base, "HEAD", "/api/stream?vehicle=1")
            assert status == 200 and headers["content-type"].startswith("text/event-stream") and body == b""
        assert not slots.open, slots.open
        status, conn = await asyncio.to_thread(_open_stream, base)  # the operator's own stream
        try:
            assert status == 200
        finally:
            conn.close()


def _stalled_stream(base: str) -> socket.socket:
    """Ask for a stream and never read it (a tiny receive window, so the console's sends back up soon)."""
    host, port = base.removeprefix("http://").split(":")
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect((host, int(port)))
    sock.sendall(f"GET /api/stream?vehicle=1 HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode())
    return sock


async def test_a_stream_nobody_reads_gives_its_slot_back() -> None:
    fleet, session = _offline_console()
    for sysid in range(1, 201):  # a big fleet table, so that the unread updates fill the buffers quickly
        fleet.on_message(f"secuav/v{sysid}/stats", {"downlink": {"frames_in": 1, "frames_out": 1}})
    slots = StreamSlots(per_client=2, total=4)
    async with serve(fleet, session, streams=slots, stream_send_timeout_s=0.5) as base:
        socks = [await asyncio.to_thread(_stalled_stream, base) for _ in range(2)]
        try:
            await until(lambda: slots.open.get("127.0.0.1") == 2, 10, "both streams open")
            await until(lambda: not slots.open, 40, "the unread streams cut off")
            status, conn = await asyncio.to_thread(_open_stream, base)
            conn.close()
            assert status == 200
        finally:
            for sock in socks:
                sock.close()
