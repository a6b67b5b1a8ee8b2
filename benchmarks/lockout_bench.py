"""Issue 36's hostile review, replayed against the real services on loopback: one figure per finding.

Each case starts the real command (``python -m webconsole``, ``python -m mitm_proxy``,
``python -m secuav_common.broker_main``) on free loopback ports, attacks it from
127.0.0.0/8 for a bounded time, and prints what the review measured:

- ``head``: event-stream slots taken by HEAD requests (the operator's stream after 4 HEADs; anyone's after
  32 HEADs from 127.0.0.2-9);
- ``garbage``: how often a ground station on a ``tcpin`` endpoint is evicted while another client loops
  connect-and-garbage for ``--seconds``;
- ``seats``: how long a spectator from another address is refused while one address holds 16 silent
  connections, and the log lines and bytes of a connect-and-garbage loop;
- ``retained``: the proxy's resident memory after a 30 MB retained message on ``secuav/console/x/online``;
- ``slowloris``: with ``ulimit -n 1024``, 1,100 half-sent requests from one address, then the operator's
  request from another (answered or not, and in how long), and the console's log bytes;
- ``forwarded``: 30 wrong passwords from 127.0.0.1, each with a new ``X-Forwarded-For`` (how many got 429),
  and event streams opened the same way (the cap is 4 per client).

Nothing here asserts; run it against another tree with ``PYTHONPATH=OTHER_TREE`` for the before figures:

    .venv/bin/python benchmarks/lockout_bench.py [--cases head,garbage,...] [--seconds 10]
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import http.client
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

PASSWORD = "correct horse battery staple"
GARBAGE = b"\xfd\x00" * 8192
TREE = Path(__file__).resolve().parents[1]  # main() sets it to the tree that imports resolve to


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_port(port: int, limit_s: float = 30.0) -> None:
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise RuntimeError(f"nothing listens on 127.0.0.1:{port}")


@contextlib.contextmanager
def service(args: list[str], log: Path, port: int, nofile: int | None = None) -> Iterator[subprocess.Popen[bytes]]:
    cmd = [sys.executable, "-m", *args]
    if nofile is not None:
        cmd = ["prlimit", f"--nofile={nofile}:{nofile}", *cmd]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    with log.open("wb") as out:  # run from the tree under test: ``-m`` puts the working directory first
        proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=out, stderr=subprocess.STDOUT, env=env, cwd=TREE)
    try:
        wait_port(port)
        yield proc
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def console(log: Path, nofile: int | None = None, password: bool = False) -> tuple[int, object]:
    port = free_port()
    args = ["webconsole", "--broker", "mqtt://127.0.0.1:1", "--listen", f"127.0.0.1:{port}"]
    if password:
        os.environ["SECUAV_CONSOLE_PASSWORD"] = PASSWORD
    else:
        os.environ.pop("SECUAV_CONSOLE_PASSWORD", None)
    return port, service(args, log, port, nofile)


def request(port: int, method: str, path: str, source: str = "127.0.0.1", headers: dict[str, str] | None = None,
            timeout: float = 10.0, keep: bool = False) -> tuple[int, http.client.HTTPConnection | None]:  # fmt: skip
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout, source_address=(source, 0))
    conn.request(method, path, headers=headers or {})
    status = conn.getresponse().status
    if keep:
        return status, conn
    conn.close()
    return status, None


def case_head(tmp: Path, _seconds: float) -> None:
    for heads, sources in ((4, ["127.0.0.1"]), (32, [f"127.0.0.{i}" for i in range(2, 10)])):
        port, svc = console(tmp / "head.log")
        with svc:  # type: ignore[attr-defined]
            for i in range(heads):
                request(port, "HEAD", "/api/stream?vehicle=1", sources[i % len(sources)])
            who = "127.0.0.1" if heads == 4 else "127.0.0.10"
            status, conn = request(port, "GET", "/api/stream?vehicle=1", who, keep=True)
            if conn is not None:
                conn.close()
        print(f"head: after {heads} HEADs from {sources[0]}{'..' + sources[-1] if len(sources) > 1 else ''}, "
              f"a stream for {who}: {status}")  # fmt: skip


def gcs_session(port: int, seconds: float) -> int:
    """A ground station on 127.0.0.2: heartbeat at 10 Hz, reconnecting at once when cut off. Returns the cuts."""
    from pymavlink.dialects.v20 import common as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    beat = mav.heartbeat_encode(6, 8, 0, 0, 4).pack(mav)
    cuts = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        sock = socket.socket()
        sock.bind(("127.0.0.2", 0))
        sock.settimeout(2)
        try:
            sock.connect(("127.0.0.1", port))
        except OSError:  # the listener's backlog is full of the flooder's connections: try again
            sock.close()
            continue
        try:
            while time.monotonic() < end:
                sock.sendall(beat)
                time.sleep(0.1)
            return cuts
        except OSError:  # cut off after it was admitted: an eviction
            cuts += 1
        finally:
            sock.close()
    return cuts


def garbage_loop(port: int, seconds: float) -> int:
    n, end = 0, time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=2) as sock:
                n += 1
                with contextlib.suppress(OSError):
                    for _ in range(8):
                        sock.sendall(GARBAGE)
        except OSError:
            time.sleep(0.01)
    return n


def proxy(tmp: Path, name: str, ground: str, broker: str = "none") -> tuple[int, object]:
    gport, vport = free_port(), free_port()
    args = ["mitm_proxy", "--broker", broker, "--vehicle", f"udpin://127.0.0.1:{vport}",
            "--ground", ground.format(port=gport)]  # fmt: skip
    return gport, service(args, tmp / f"{name}.log", gport)


async def _both(port: int, seconds: float) -> tuple[int, int]:
    cuts = asyncio.to_thread(gcs_session, port, seconds)
    loops = asyncio.to_thread(garbage_loop, port, seconds)
    return await asyncio.gather(cuts, loops)  # type: ignore[return-value]


def case_garbage(tmp: Path, seconds: float) -> None:
    gport, svc = proxy(tmp, "garbage", "tcpin://127.0.0.1:{port}")
    with svc:  # type: ignore[attr-defined]
        cuts, loops = asyncio.run(_both(gport, seconds))
    print(f"garbage: ground station evicted {cuts} times in {seconds:g} s while another client made {loops} "
          "connect-and-garbage connections")  # fmt: skip


def case_seats(tmp: Path, seconds: float) -> None:
    gport, svc = proxy(tmp, "seats", "tcpin://127.0.0.1:{port}")
    with svc:  # type: ignore[attr-defined]
        squatters = [socket.create_connection(("127.0.0.1", gport)) for _ in range(16)]
        time.sleep(0.5)
        t0 = time.monotonic()
        admitted = None
        while time.monotonic() - t0 < 2 * seconds and admitted is None:
            sock = socket.socket()
            sock.bind(("127.0.0.2", 0))
            sock.settimeout(1.0)
            tried = time.monotonic() - t0
            sock.connect(("127.0.0.1", gport))
            try:
                if sock.recv(1) == b"":
                    raise ConnectionResetError
            except TimeoutError:  # held open, not cut off: admitted (the proxy sends nothing without a vehicle)
                admitted = tried
            except OSError:
                time.sleep(0.5)
            finally:
                sock.close()
        for sock in squatters:
            sock.close()
    print("seats: spectator from 127.0.0.2 with 16 silent connections from 127.0.0.1: "
          + (f"admitted after {admitted:.1f} s of tries (one a second)" if admitted is not None
             else f"refused for {2 * seconds:g} s and more"))  # fmt: skip
    gport, svc = proxy(tmp, "loglines", "tcpin://127.0.0.1:{port}")
    log = tmp / "loglines.log"
    with svc:  # type: ignore[attr-defined]
        before = log.stat().st_size
        lines_before = log.read_bytes().count(b"\n")
        loops = garbage_loop(gport, seconds)
        time.sleep(0.5)
        data = log.read_bytes()
    lines = data.count(b"\n") - lines_before
    print(f"seats: a {seconds:g} s connect-and-garbage loop: {loops} connections, "
          f"{lines} log lines, {(len(data) - before) / 1e6:.2f} MB of log")


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


async def _retained(port: int, size: int) -> None:
    import aiomqtt

    with contextlib.suppress(aiomqtt.MqttError):
        async with aiomqtt.Client("127.0.0.1", port, timeout=10) as client:
            await client.publish("secuav/console/x/online", b"x" * size, qos=1, retain=True)


def case_retained(tmp: Path, seconds: float) -> None:
    bport = free_port()
    with service(["secuav_common.broker_main", "127.0.0.1", str(bport)], tmp / "broker.log", bport) as broker:
        gport, vport = free_port(), free_port()
        args = ["mitm_proxy", "--broker", f"mqtt://127.0.0.1:{bport}", "--vehicle", f"udpin://127.0.0.1:{vport}",
                "--ground", f"udpout://127.0.0.1:{gport}"]  # fmt: skip
        with service(args, tmp / "retained.log", bport) as proc:
            time.sleep(3)
            base, bbase = rss_mb(proc.pid), rss_mb(broker.pid)
            asyncio.run(_retained(bport, 30 * 1024 * 1024))
            peak = base
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                peak = max(peak, rss_mb(proc.pid))
                time.sleep(0.1)
            held, bheld = rss_mb(proc.pid), rss_mb(broker.pid)
    print(f"retained: a 30 MB retained message: proxy {base:.0f} MB -> peak {peak:.0f} MB, {held:.0f} MB held "
          f"after {seconds:g} s; broker {bbase:.0f} -> {bheld:.0f} MB")  # fmt: skip


def half_requests(port: int, n: int) -> list[socket.socket]:
    socks = []
    for _ in range(n):
        sock = socket.socket()
        sock.settimeout(5)
        try:
            sock.connect(("127.0.0.1", port))
            sock.sendall(b"GET /api/vehicles HTTP/1.1\r\nHost: 127.0.0.1\r\nX-a: ")
        except OSError:
            sock.close()
            continue
        socks.append(sock)
    return socks


def case_slowloris(tmp: Path, seconds: float) -> None:
    log = tmp / "slowloris.log"
    port, svc = console(log, nofile=1024, password=True)
    auth = {"Authorization": "Bearer " + PASSWORD}
    with svc:  # type: ignore[attr-defined]
        t0 = time.monotonic()
        socks = half_requests(port, 1100)
        opened = time.monotonic() - t0
        t1 = time.monotonic()
        try:
            status, _ = request(port, "GET", "/api/vehicles", "127.0.0.2", auth, timeout=seconds)
            answer = f"{status} in {(time.monotonic() - t1) * 1000:.0f} ms"
        except OSError as exc:
            answer = f"no answer ({type(exc).__name__} after {time.monotonic() - t1:.1f} s)"
        time.sleep(1)
        for sock in socks:
            sock.close()
        size = log.stat().st_size
    print(f"slowloris: ulimit -n 1024, 1100 half-sent requests from 127.0.0.1 ({opened:.1f} s to send); "
          f"the operator's request from 127.0.0.2: {answer}; console log {size / 1e6:.2f} MB")


def case_forwarded(tmp: Path, _seconds: float) -> None:
    port, svc = console(tmp / "forwarded.log", password=True)
    bad = "Basic " + base64.b64encode(b"x:guess").decode()
    with svc:  # type: ignore[attr-defined]
        statuses = [request(port, "GET", "/api/vehicles", headers={"Authorization": bad,
                                                                    "X-Forwarded-For": f"10.9.{i}.1"})[0]
                    for i in range(30)]  # fmt: skip
        good = {"Authorization": "Bearer " + PASSWORD}
    port, svc = console(tmp / "forwarded2.log", password=True)
    with svc:  # type: ignore[attr-defined]
        opened = []
        for i in range(8):
            status, conn = request(port, "GET", "/api/stream?vehicle=1",
                                   headers={**good, "X-Forwarded-For": f"10.8.{i}.1"}, keep=True)  # fmt: skip
            opened.append((status, conn))
        streams = sum(1 for s, _ in opened if s == 200)
        for _, conn in opened:
            if conn is not None:
                conn.close()
    print(f"forwarded: 30 wrong passwords, a new X-Forwarded-For each: {statuses.count(401)} x 401, "
          f"{statuses.count(429)} x 429; 8 streams the same way: {streams} opened (cap 4 per client)")


CASES = {"head": case_head, "garbage": case_garbage, "seats": case_seats, "retained": case_retained,
         "slowloris": case_slowloris, "forwarded": case_forwarded}  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}")
    ap.add_argument("--seconds", type=float, default=10.0, help="how long each attack runs")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/secuav-lockout-bench"))
    args = ap.parse_args()
    args.workdir.mkdir(parents=True, exist_ok=True)
    import webconsole

    global TREE
    TREE = Path(webconsole.__file__).resolve().parents[1]
    print(f"tree: {TREE}")
    for name in args.cases.split(","):
        CASES[name.strip()](args.workdir, args.seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
