"""The console against the browser it runs in and against greedy clients (issue 28's findings, each reproduced).

The app is the real one (uvicorn on loopback, a real broker, the proxy's own
control plane answering); the hostile page runs in a real headless chromium.
Each test failed on the console before ``webconsole.security``.
"""

from __future__ import annotations

import asyncio
import base64
import http.client
import http.server
import logging
import socket
import ssl
import subprocess
import sys
import time
from pathlib import Path

import pytest

from secuav_common.broker import BrokerAddress
from tests.conftest import free_tcp_port
from tests.support.console import Bench, call, open_stream, raw, serve
from webconsole.api import MAX_BODY, StreamSlots
from webconsole.fleet import Fleet, Session

pytestmark = pytest.mark.timeout(120)


def mode_of(base: str) -> str:
    status, rows = call(base, "/api/vehicles")
    assert status == 200
    return rows[0]["mode"]


async def test_a_cross_site_post_never_reaches_the_proxy(bench: Bench) -> None:
    body = b'{"mode":"bypass"}'
    path = "/api/vehicles/1/attack/mode"
    attempts = [
        ({"Content-Type": "text/plain", "Origin": "https://evil.example"}, 403),  # the review's request
        ({"Content-Type": "text/plain"}, 415),  # a form's encoding, no Origin sent
        ({"Content-Type": "application/x-www-form-urlencoded"}, 415),
        ({"Content-Type": "application/json", "Origin": "https://evil.example"}, 403),
        ({"Content-Type": "application/json", "Origin": "null"}, 403),  # a sandboxed frame or a data: page
        ({"Content-Type": "application/json", "Sec-Fetch-Site": "cross-site"}, 403),
        ({"Content-Type": "application/json", "Sec-Fetch-Site": "same-site"}, 403),  # another port of this host
    ]
    for headers, want in attempts:
        status, _, answer = await asyncio.to_thread(raw, bench.base, "POST", path, body, headers)
        assert status == want, (headers, status, answer)
    assert await asyncio.to_thread(mode_of, bench.base) == "on"
    # The console's own page (same origin) and scripts (no Origin, JSON) still work.
    own = {"Content-Type": "application/json", "Origin": bench.base, "Sec-Fetch-Site": "same-origin"}
    status, _, _ = await asyncio.to_thread(raw, bench.base, "POST", path, body, own)
    assert status == 200 and await asyncio.to_thread(mode_of, bench.base) == "bypass"
    status, _, _ = await asyncio.to_thread(raw, bench.base, "POST", path, b'{"mode":"on"}',
                                           {"Content-Type": "application/json; charset=utf-8"})  # fmt: skip
    assert status == 200 and await asyncio.to_thread(mode_of, bench.base) == "on"


async def test_a_rebinding_name_gets_nothing(bench: Bench) -> None:
    port = bench.base.rsplit(":", 1)[1]
    for host in (f"attacker.example:{port}", "attacker.example", f"127.0.0.1.nip.io:{port}"):
        status, _, answer = await asyncio.to_thread(raw, bench.base, "GET", "/api/vehicles", b"", {"Host": host})
        assert status == 400 and b"sysid" not in answer, (host, status, answer)
    for host in (f"127.0.0.1:{port}", f"localhost:{port}"):
        status, _, _ = await asyncio.to_thread(raw, bench.base, "GET", "/api/vehicles", b"", {"Host": host})
        assert status == 200, host


def _declare_and_wait(base: str, length: int) -> bytes:
    """Send headers declaring ``length`` bytes of body, then a few bytes, and read whatever comes back."""
    host, port = base.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=10) as sock:
        sock.sendall(f"POST /api/vehicles/1/attack HTTP/1.1\r\nHost: {host}:{port}\r\n"
                     f"Content-Type: application/json\r\nContent-Length: {length}\r\n\r\n{{".encode())  # fmt: skip
        return sock.recv(4096)


def _chunked(base: str, total: int) -> bytes:
    host, port = base.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=10) as sock:
        sock.sendall(f"POST /api/vehicles/1/attack HTTP/1.1\r\nHost: {host}:{port}\r\n"
                     "Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n".encode())  # fmt: skip
        chunk = b" " * 65536
        sent = 0
        try:
            while sent < total:
                sock.sendall(b"%x\r\n%s\r\n" % (len(chunk), chunk))
                sent += len(chunk)
        except OSError:  # the server answered and closed while we were still sending: what we want
            pass
        return sock.recv(4096)


async def test_a_huge_body_is_refused_before_it_is_read(bench: Bench) -> None:
    t0 = time.monotonic()
    answer = await asyncio.to_thread(_declare_and_wait, bench.base, 500_000_000)
    assert answer.startswith(b"HTTP/1.1 413"), answer[:200]
    assert time.monotonic() - t0 < 8  # answered on the headers alone, not after a 10 s read timeout
    answer = await asyncio.to_thread(_chunked, bench.base, 8 * MAX_BODY)  # no length declared: counted as it comes
    assert answer.startswith(b"HTTP/1.1 413"), answer[:200]


async def test_every_answer_carries_the_security_headers(bench: Bench) -> None:
    for path in ("/", "/api/vehicles", "/static/app.js"):
        status, headers, _ = await asyncio.to_thread(raw, bench.base, "GET", path)
        assert status == 200, path
        csp = headers["content-security-policy"]
        script_src = next(d for d in csp.split(";") if d.strip().startswith("script-src"))
        assert "unsafe-inline" not in script_src and "frame-ancestors 'none'" in csp, csp
        assert headers["x-content-type-options"] == "nosniff" and headers["x-frame-options"] == "DENY"


async def test_event_streams_are_capped_per_client_and_in_all() -> None:
    fleet = Fleet([])
    session = Session(BrokerAddress("127.0.0.1", 1), fleet, "http://test/")
    slots = StreamSlots(per_client=3, total=5)
    async with serve(fleet, session, streams=slots) as base:
        opened = [await asyncio.to_thread(open_stream, base) for _ in range(4)]
        assert [s for s, _ in opened] == [200, 200, 200, 429]
        for _, conn in opened:
            conn.close()
        for _ in range(100):  # the server notices the closed streams
            if not slots.open:
                break
            await asyncio.sleep(0.1)
        assert not slots.open
        assert slots.take("10.0.0.9") is None and slots.take("10.0.0.8") is None  # two held by other clients
        opened = [await asyncio.to_thread(open_stream, base) for _ in range(4)]
        assert [s for s, _ in opened] == [200, 200, 200, 429]  # 5 in all
        for _, conn in opened:
            conn.close()


async def test_wrong_passwords_are_throttled_and_logged(caplog: pytest.LogCaptureFixture) -> None:
    fleet = Fleet([])
    session = Session(BrokerAddress("127.0.0.1", 1), fleet, "http://test/")
    good = "Basic " + base64.b64encode(b"x:correct horse battery").decode()
    bad = "Basic " + base64.b64encode(b"x:guess").decode()
    caplog.set_level(logging.WARNING, logger="secuav-console")
    async with serve(fleet, session, password="correct horse battery") as base:
        statuses = [(await asyncio.to_thread(call, base, "/api/vehicles", None, bad))[0] for _ in range(8)]
        assert statuses[:5] == [401] * 5 and statuses[5:] == [429] * 3, statuses
        assert (await asyncio.to_thread(call, base, "/api/vehicles", None, good))[0] == 429  # even the right one waits
        status, headers, _ = await asyncio.to_thread(raw, base, "GET", "/api/vehicles", b"", {"Authorization": bad})
        assert status == 429 and int(headers["retry-after"]) >= 1
    failures = [r for r in caplog.records if r.getMessage() == "console.login_failed"]
    assert len(failures) == 5 and failures[-1].failures == 5 and failures[0].client == "127.0.0.1"  # type: ignore[attr-defined]


def _console(args: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "webconsole", "--broker", "mqtt://127.0.0.1:1", *args],
                          capture_output=True, text=True, timeout=30)  # fmt: skip


def test_beyond_loopback_needs_tls_and_a_real_password(tmp_path: Path) -> None:
    pw = tmp_path / "pw"
    pw.write_text("short")
    pw.chmod(0o600)
    run = _console(["--listen", "127.0.0.1:1", "--password-file", str(pw)])
    assert run.returncode == 2 and "at least 12" in run.stderr
    pw.write_text("a sane long password")
    run = _console(["--listen", "0.0.0.0:18080", "--password-file", str(pw)])
    assert run.returncode == 2 and "needs TLS" in run.stderr and "--insecure-http" in run.stderr
    run = _console(["--listen", "0.0.0.0:18080", "--password-file", str(pw), "--tls-cert", str(tmp_path / "no.pem"),
                    "--tls-key", str(tmp_path / "no.key")])  # fmt: skip
    assert run.returncode == 2 and "no such file" in run.stderr


def test_the_console_serves_https_with_a_given_certificate(tmp_path: Path) -> None:
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj", "/CN=127.0.0.1",
                    "-addext", "subjectAltName=IP:127.0.0.1", "-keyout", str(key), "-out", str(cert)],
                   check=True, capture_output=True)  # fmt: skip
    port = free_tcp_port()
    proc = subprocess.Popen([sys.executable, "-m", "webconsole", "--broker", "mqtt://127.0.0.1:1", "--listen",
                             f"127.0.0.1:{port}", "--tls-cert", str(cert), "--tls-key", str(key)],
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        context = ssl.create_default_context(cafile=str(cert))
        deadline = time.monotonic() + 30
        while True:
            try:
                conn = http.client.HTTPSConnection("127.0.0.1", port, context=context, timeout=5)
                conn.request("GET", "/api/vehicles")
                response = conn.getresponse()
                break
            except (ConnectionRefusedError, ssl.SSLError, OSError):
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise
                time.sleep(0.2)
        assert response.status == 200 and response.read() == b"[]"
        conn.close()
    finally:
        proc.terminate()
        proc.wait(10)


async def test_a_page_in_the_browser_cannot_steer_a_vehicle(
    bench: Bench,
    browser: object,
    hostile_page: tuple[int, list[str]],
) -> None:
    """The review's two browser attacks: a no-cors fetch and a script-less text/plain form, from another origin."""
    port, pages = hostile_page
    target = f"{bench.base}/api/vehicles/1/attack/mode"
    pages[0] = f"""<!doctype html><html><body>
<form id="f" method="POST" action="{target}" enctype="text/plain">
<input type="hidden" name='{{"mode":"bypass","x":"' value='"}}'></form>
<script>
fetch("{target}", {{method: "POST", mode: "no-cors", headers: {{"Content-Type": "text/plain"}},
                    body: '{{"mode":"bypass"}}'}})
  .catch(() => null).finally(() => {{ document.title = "fetched"; document.getElementById("f").submit(); }});
</script></body></html>"""
    driver = browser
    await asyncio.to_thread(driver.get, f"http://127.0.0.1:{port}/")  # type: ignore[attr-defined]
    deadline = time.monotonic() + 20

    def url() -> str:  # in a thread: chromedriver waits for a navigation to load, and the console runs on this loop
        return str(driver.current_url)  # type: ignore[attr-defined]

    while bench.base not in (now := await asyncio.to_thread(url)):  # the form was submitted
        assert time.monotonic() < deadline, now
        await asyncio.sleep(0.1)
    await asyncio.sleep(0.5)
    assert await asyncio.to_thread(mode_of, bench.base) == "on"
    # The same browser, on the console's own page, can still switch it: the guard refuses sites, not the operator.
    await asyncio.to_thread(driver.get, bench.base + "/")  # type: ignore[attr-defined]
    result = await asyncio.to_thread(
        driver.execute_async_script,  # type: ignore[attr-defined]
        "const done = arguments[0]; fetch('/api/vehicles/1/attack/mode', {method: 'POST', "
        "headers: {'Content-Type': 'application/json'}, body: JSON.stringify({mode: 'bypass'})})"
        ".then(r => done(r.status), e => done(String(e)));",
    )
    assert result == 200 and await asyncio.to_thread(mode_of, bench.base) == "bypass"


async def test_a_malformed_stats_message_breaks_neither_the_session_nor_the_api(bench: Bench) -> None:
    """The review's two messages: one killed the console's broker session for good, the other every view."""
    for body in ({"downlink": {"frames_in": "x"}}, {"downlink": [1]}, {"downlink": {"latency_ms": {"p99": "slow"}}}):
        bench.plane.publish_nowait("secuav/v1/stats", body)
    await asyncio.sleep(1.0)
    status, rows = await asyncio.to_thread(call, bench.base, "/api/vehicles")
    assert status == 200 and rows[0]["online"], rows
    status, ack = await asyncio.to_thread(call, bench.base, "/api/vehicles/1/attack/mode", {"mode": "bypass"})
    assert status == 200 and ack["mode"] == "bypass"  # the session still sends and hears acknowledgements
    status, conn = await asyncio.to_thread(open_stream, bench.base)
    try:
        assert status == 200
        first = await asyncio.to_thread(conn.sock.recv, 65536)  # type: ignore[union-attr]
        assert b"event: update" in first
    finally:
        conn.close()
