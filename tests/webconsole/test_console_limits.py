"""Nobody on the network locks the operator out of the console (issue 36's hostile review, each reproduced).

The app is the real one, served by uvicorn on loopback as ``secuav-console``
serves it (``webconsole.connections.server_config``). Each test failed on the
console before issue 36.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import http.client
import logging
import socket
import time

import pytest

from secuav_common.broker import BrokerAddress
from tests.support.console import open_stream, raw, serve
from webconsole import api
from webconsole.api import StreamSlots
from webconsole.connections import ConnectionLimits
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
        status, conn = await asyncio.to_thread(open_stream, base)  # the operator's own stream
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
            status, conn = await asyncio.to_thread(open_stream, base)
            conn.close()
            assert status == 200
        finally:
            for sock in socks:
                sock.close()


def _wrong_password(base: str, forwarded_for: str) -> int:
    bad = "Basic " + base64.b64encode(b"x:guess").decode()
    status, _, _ = raw(base, "GET", "/api/vehicles", b"", {"Authorization": bad, "X-Forwarded-For": forwarded_for})
    return status


async def test_forwarded_headers_count_only_from_a_trusted_proxy(caplog: pytest.LogCaptureFixture) -> None:
    """The review: a new X-Forwarded-For each time made 30 wrong passwords all 401, never 429."""
    fleet, session = _offline_console()
    caplog.set_level(logging.WARNING, logger="secuav-console")
    async with serve(fleet, session, password="correct horse battery") as base:
        statuses = [await asyncio.to_thread(_wrong_password, base, f"10.9.0.{i}") for i in range(8)]
        assert statuses == [401] * 5 + [429] * 3, statuses  # all from 127.0.0.1, whatever the header says
    assert {r.client for r in caplog.records if r.getMessage() == "console.login_failed"} == {"127.0.0.1"}  # type: ignore[attr-defined]
    caplog.clear()
    async with serve(fleet, session, password="correct horse battery", trusted_proxies=["127.0.0.1"]) as base:
        statuses = [await asyncio.to_thread(_wrong_password, base, f"10.9.0.{i}") for i in range(8)]
        assert statuses == [401] * 8, statuses  # behind a trusted proxy, each client is counted on its own
    clients = [r.client for r in caplog.records if r.getMessage() == "console.login_failed"]  # type: ignore[attr-defined]
    assert clients == [f"10.9.0.{i}" for i in range(8)]


def _half_request(base: str, source: str) -> socket.socket:
    """The slowloris: connect from ``source`` and send part of a request's headers, never the rest."""
    host, port = base.removeprefix("http://").split(":")
    sock = socket.socket()
    sock.bind((source, 0))
    sock.settimeout(10)
    sock.connect((host, int(port)))
    with contextlib.suppress(OSError):  # refused connections may be gone already
        sock.sendall(f"GET /api/vehicles HTTP/1.1\r\nHost: {host}:{port}\r\nX-a: ".encode())
    return sock


def _closed(sock: socket.socket) -> bool:
    """Whether the console hung up (nothing is ever answered to half a request)."""
    try:
        return sock.recv(1024) == b""
    except ConnectionResetError:
        return True
    except TimeoutError:
        return False


def _operator(base: str) -> int:
    host, port = base.removeprefix("http://").split(":")
    conn = http.client.HTTPConnection(host, int(port), timeout=10, source_address=("127.0.0.2", 0))
    try:
        conn.request("GET", "/api/vehicles")
        return conn.getresponse().status
    finally:
        conn.close()


async def test_half_sent_requests_are_refused_past_a_share_and_timed_out(caplog: pytest.LogCaptureFixture) -> None:
    """The review: 1,100 half-sent requests from one address locked the operator out (uvicorn never times them
    out), and the "Too many open files" tracebacks wrote 331 MB of log in 35 s."""
    fleet, session = _offline_console()
    caplog.set_level(logging.WARNING, logger="secuav-console")
    limits = ConnectionLimits(per_address=8, total=64, header_timeout_s=1.0)
    async with serve(fleet, session, limits=limits) as base:
        socks = [await asyncio.to_thread(_half_request, base, "127.0.0.1") for _ in range(40)]
        try:
            assert await asyncio.to_thread(_operator, base) == 200  # another address is served meanwhile
            closed = await asyncio.gather(*(asyncio.to_thread(_closed, s) for s in socks))
            assert all(closed)  # 32 refused at once, the other 8 closed after the header timeout
        finally:
            for sock in socks:
                sock.close()
    refused = [r for r in caplog.records if r.getMessage() == "console.connection_refused"]
    timed_out = [r for r in caplog.records if r.getMessage() == "console.read_timeout"]
    assert len(refused) == 1 and len(timed_out) == 1, [r.getMessage() for r in caplog.records]


async def test_a_body_sent_too_slowly_is_answered_408(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(api, "BODY_TIMEOUT_S", 0.5)
    fleet, session = _offline_console()
    fleet.on_message("secuav/proxy/lab/online", {"instance": "lab", "online": True, "vehicles": [1]})
    fleet.on_message("secuav/v1/stats", {"downlink": {}})
    async with serve(fleet, session) as base:
        host, port = base.removeprefix("http://").split(":")

        def slow_post() -> bytes:
            with socket.create_connection((host, int(port)), timeout=10) as sock:
                sock.sendall(f"POST /api/vehicles/1/attack/mode HTTP/1.1\r\nHost: {host}:{port}\r\n"
                             "Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{".encode())  # fmt: skip
                return sock.recv(4096)

        answer = await asyncio.to_thread(slow_post)
        assert answer.startswith(b"HTTP/1.1 408"), answer[:200]
