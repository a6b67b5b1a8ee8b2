"""Real brokers and an MQTT observer for the control-plane tests (no tests here).

``Mosquitto`` runs the real binary on a loopback port from a two-line config
and can be stopped and started again on the same port (the broker-restart
test); ``Observer`` is a plain aiomqtt client that records every message on
its topics and waits for the one a test expects; ``attack_cli`` runs the real
``secuav-attack`` as a user would.
"""

from __future__ import annotations

import asyncio
import contextlib
import getpass
import json
import os
import shutil
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiomqtt
import pytest

MOSQUITTO = shutil.which("mosquitto") or ("/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None)
# Skipped where mosquitto is missing, except in CI: .ci/run installs it, so missing there is a setup bug
# and the test runs and fails (Mosquitto() says why) instead of passing as a skip.
needs_mosquitto = pytest.mark.skipif(
    MOSQUITTO is None and not os.environ.get("CI"), reason="the mosquitto binary is not installed"
)


def wait_port(port: int, up: bool, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            sock.settimeout(0.2)
            if (sock.connect_ex(("127.0.0.1", port)) == 0) == up:
                return
        time.sleep(0.05)
    raise TimeoutError(f"port {port} still {'closed' if up else 'open'} after {timeout_s} s")


class Mosquitto:
    """The real mosquitto on ``127.0.0.1:port``; ``stop()``/``start()`` for the restart test.

    ``extra`` lines go into its config (TLS files, a password file). It runs as
    the current user: started as root, mosquitto would otherwise switch to its
    own user, which cannot read pytest's private temporary directories.
    """

    def __init__(self, port: int, workdir: Path, extra: str = "") -> None:
        assert MOSQUITTO is not None, "the mosquitto binary is not installed (apt-get install mosquitto)"
        self.port = port
        self.url = f"mqtt://127.0.0.1:{port}"
        self.config = workdir / "mosquitto.conf"
        anonymous = "false" if "password_file" in extra else "true"
        self.config.write_text(
            f"user {getpass.getuser()}\nlistener {port} 127.0.0.1\nallow_anonymous {anonymous}\n"
            f"persistence false\n{extra}"
        )
        self.log = workdir / "mosquitto.log"
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        with self.log.open("ab") as out:
            self.proc = subprocess.Popen([MOSQUITTO, "-c", str(self.config)], stdout=out, stderr=subprocess.STDOUT)
        wait_port(self.port, up=True)

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
            self.proc = None
        wait_port(self.port, up=False)

    def __enter__(self) -> Mosquitto:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


@dataclass
class Observer:
    """Subscribes to ``topics``; ``messages`` keeps (topic, decoded JSON or raw bytes, retain flag)."""

    port: int
    topics: list[str]
    messages: list[tuple[str, Any, bool]] = field(default_factory=list)
    client: aiomqtt.Client | None = None
    _task: asyncio.Task[None] | None = None
    _ready: asyncio.Event = field(default_factory=asyncio.Event)
    _new: asyncio.Event = field(default_factory=asyncio.Event)

    async def __aenter__(self) -> Observer:
        self._task = asyncio.create_task(self._run())
        await asyncio.wait_for(self._ready.wait(), 10.0)
        return self

    async def __aexit__(self, *exc: object) -> None:
        assert self._task is not None
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
            await self._task

    async def _run(self) -> None:
        async with aiomqtt.Client("127.0.0.1", self.port, identifier=f"test-{uuid.uuid4().hex[:8]}") as client:
            self.client = client
            for topic in self.topics:
                await client.subscribe(topic, qos=1)
            self._ready.set()
            async for message in client.messages:
                raw = bytes(message.payload) if isinstance(message.payload, bytes | bytearray) else b""
                try:
                    body: Any = json.loads(raw)
                except ValueError:
                    body = raw
                self.messages.append((str(message.topic), body, bool(message.retain)))
                self._new.set()

    async def publish(self, topic: str, payload: Any, retain: bool = False) -> None:
        assert self.client is not None
        data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
        await self.client.publish(topic, data, qos=1, retain=retain)

    def on(self, topic: str) -> list[Any]:
        return [body for t, body, _ in self.messages if t == topic]

    async def wait_for(
        self, topic: str, match: Callable[[Any], bool] = lambda _: True, timeout_s: float = 10.0, start: int = 0
    ) -> Any:
        """The first message on ``topic`` (from index ``start``) that ``match`` accepts."""
        deadline = time.monotonic() + timeout_s
        while True:
            for t, body, _ in self.messages[start:]:
                if t == topic and match(body):
                    return body
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(f"nothing on {topic} matched within {timeout_s} s; got {self.on(topic)[-3:]}")
            self._new.clear()
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._new.wait(), min(remaining, 0.2))

    async def request(self, topic: str, payload: Any, timeout_s: float = 10.0) -> dict[str, Any]:
        """Publish a set request with a fresh request_id; the state that answers it."""
        request_id = uuid.uuid4().hex
        body = {"request_id": request_id, **payload} if isinstance(payload, dict) else {"request_id": request_id}
        start = len(self.messages)
        await self.publish(topic, body)
        state_topic = topic.rsplit("/", 1)[0] + "/state"
        return await self.wait_for(
            state_topic, lambda b: isinstance(b, dict) and b.get("request_id") == request_id, timeout_s, start
        )


OPENSSL = shutil.which("openssl")
MOSQUITTO_PASSWD = shutil.which("mosquitto_passwd")


def make_tls_files(workdir: Path) -> tuple[Path, Path, Path]:
    """A throwaway CA and a server certificate for 127.0.0.1 (CA file, server cert, server key), via openssl."""
    assert OPENSSL is not None
    ca_key, ca, key, csr, cert = (workdir / n for n in ("ca.key", "ca.crt", "server.key", "server.csr", "server.crt"))
    ext = workdir / "san.ext"
    ext.write_text("subjectAltName = IP:127.0.0.1\n")

    def run(*args: str) -> None:
        subprocess.run([OPENSSL, *args], check=True, capture_output=True, timeout=60)

    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(ca_key), "-out", str(ca), "-days", "2",
        "-subj", "/CN=secuav-test-ca")  # fmt: skip
    run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out", str(csr), "-subj", "/CN=127.0.0.1")
    run("x509", "-req", "-in", str(csr), "-CA", str(ca), "-CAkey", str(ca_key), "-CAcreateserial", "-out", str(cert),
        "-days", "2", "-extfile", str(ext))  # fmt: skip
    return ca, cert, key


def make_password_file(workdir: Path, user: str, password: str) -> Path:
    assert MOSQUITTO_PASSWD is not None
    path = workdir / "passwd"
    subprocess.run([MOSQUITTO_PASSWD, "-b", "-c", str(path), user, password], check=True, capture_output=True)
    return path


async def attack_cli(*args: str, timeout_s: float = 60) -> tuple[int, str]:
    """Run ``secuav-attack`` as a subprocess without blocking the loop (streams keep flowing meanwhile);
    its exit code and its stdout and stderr together."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "mitm_proxy.tools.attack_cli", *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
    )  # fmt: skip
    out, _ = await asyncio.wait_for(proc.communicate(), timeout_s)
    return proc.returncode or 0, out.decode()
