"""An embedded amqtt broker for the control plane, and the secrets its clients read.

``secuav-proxy --broker embedded`` runs an amqtt broker bound to loopback in a
child process (so MQTT traffic never takes the forwarding loop's time); the
console, the demos and tests run it on their own loop. If something already listens on
the port (a mosquitto, or another SecUAV process's embedded broker) we use that
instead of failing, so two SecUAV processes can share one control plane, and say in
one line whose it is (the proxies and consoles whose online records say they are on it).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import socket
import sys
from pathlib import Path
from types import TracebackType
from typing import Any

from secuav_common.controlplane.address import BrokerAddress, parse_broker_url, redact
from secuav_common.loading import InputError
from secuav_common.ports import LOOPBACK, MQTT_PORT

__all__ = ["BrokerAddress", "EmbeddedBroker", "admits", "parse_broker_url", "read_secret", "redact", "secret_or_env"]

log = logging.getLogger(__name__)


def read_secret(path: str | Path, what: str) -> bytes:
    """A secret from a file that only its owner can read (as ssh demands of a private key); ``InputError`` else."""
    p = Path(path)
    try:
        mode = p.stat().st_mode
        data = p.read_bytes()
    except OSError as exc:
        raise InputError(str(p), what, str(path), f"cannot read: {exc.strerror or exc}") from None
    if mode & 0o077:
        reason = f"readable by others (mode {oct(mode & 0o777)}); chmod 600 it, as ssh demands of a private key"
        raise InputError(str(p), what, str(path), reason)
    return data


PASSWORD_VAR = "SECUAV_BROKER_PASSWORD"


def secret_or_env(path: str | Path | None, flag: str, env: str = PASSWORD_VAR) -> str | None:
    """A password from ``path`` (owner-readable only; ``flag`` names it in errors), else from ``env``, else none."""
    if path is not None:
        return read_secret(path, flag).decode("utf-8").strip()
    return os.environ.get(env) or None


def port_in_use(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.settimeout(0.2)
        return sock.connect_ex((host, port)) == 0


def amqtt_config(host: str, port: int, username: str | None = None, password: str | None = None) -> dict[str, Any]:
    """amqtt's configuration for one TCP listener on ``host:port``: anonymous, or one account when ``username``."""
    if username:
        auth = {"secuav_common.broker_auth.OneAccountAuthPlugin": {"username": username, "password": password or ""}}
    else:
        auth = {"amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}}
    return {"listeners": {"default": {"type": "tcp", "bind": f"{host}:{port}"}}, "plugins": auth}


PASSWORD_ENV = "SECUAV_EMBEDDED_BROKER_PASSWORD"  # how the broker process gets its password (never argv)


def quiet_amqtt() -> None:
    """amqtt warns for every client that connects and leaves without a CONNECT (our own port probe,
    health checks); that is not worth a line."""
    for name in ("amqtt", "transitions"):
        logging.getLogger(name).setLevel(logging.ERROR)


async def admits(
    host: str, port: int, username: str | None = None, password: str | None = None, timeout_s: float = 5.0
) -> bool:
    """Whether the broker at ``host:port`` lets this client in (no ``username``: an anonymous one)."""
    from secuav_common.controlplane.session import MqttError, Session

    session = Session(BrokerAddress(host, port), username=username, password=password, timeout_s=timeout_s)
    try:
        async with session.client():
            return True
    except MqttError:
        return False


OWNERS_WAIT_S = 0.5  # retained records follow the SUBACK at once; this long is plenty on loopback


async def owners(address: BrokerAddress, wait_s: float = OWNERS_WAIT_S) -> str:
    """Who uses the broker at ``address``, from the retained online records (docs/interfaces.md):
    ``"proxy lab-a (v1, v2), console 3f2a"``, or a few words saying there is none or they cannot be read."""
    from secuav_common.controlplane.session import MqttError, Session
    from secuav_common.controlplane.topics import CONSOLES_ONLINE, INSTANCES_ONLINE, parse

    seen: dict[str, str] = {}
    session = Session(address, timeout_s=2.0)
    try:
        async with session.client() as client:
            await client.subscribe([(INSTANCES_ONLINE, 0), (CONSOLES_ONLINE, 0)])
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(wait_s):
                    async for message in client.messages:
                        topic = parse(str(message.topic))
                        try:
                            record = json.loads(bytes(message.payload))  # type: ignore[arg-type]
                        except (TypeError, ValueError):
                            continue
                        if topic is None or topic.key is None or not isinstance(record, dict):
                            continue
                        if record.get("online") is not True:
                            seen.pop(f"{topic.scope} {topic.key}", None)
                            continue
                        vehicles = [v for v in record.get("vehicles") or () if isinstance(v, int)]
                        served = f" ({', '.join(f'v{v}' for v in vehicles)})" if vehicles else ""
                        seen[f"{topic.scope} {topic.key}"] = f"{topic.scope} {topic.key}{served}"
    except MqttError as exc:
        return f"unknown (cannot read its online records: {exc})"
    return ", ".join(seen.values()) or "none online (no SecUAV proxy or console says it is on it)"


class EmbeddedBroker:
    """``async with EmbeddedBroker(port=1883) as broker: ... broker.address``.

    Starts amqtt on ``host:port`` unless a broker already answers there, in
    which case it is reused (``broker.started`` is then False), except that a
    broker letting anonymous clients in is refused when ``username`` is given.
    With ``username`` the broker started has that one account (``password``)
    and refuses anyone else. With
    ``process=True`` amqtt runs in a child process (:mod:`secuav_common.broker_main`),
    as the proxy runs it: a flood of MQTT clients then cannot take time from the
    caller's event loop. Otherwise it runs on the caller's loop (tests, the demo's
    tap, the console: nothing there is time-critical).
    """

    def __init__(
        self,
        host: str = LOOPBACK,
        port: int = MQTT_PORT,
        *,
        process: bool = False,
        username: str | None = None,
        password: str | None = None,
    ) -> None:
        self.address = BrokerAddress(host, port, username, password)
        self.started = False
        self.process = process
        self._broker: object | None = None
        self._child: asyncio.subprocess.Process | None = None

    async def __aenter__(self) -> EmbeddedBroker:
        if port_in_use(self.address.host, self.address.port):
            if self.address.username and await admits(self.address.host, self.address.port):
                raise OSError(
                    f"a broker already listens on {self.address.url} and lets anyone in without a password; "
                    "refusing it because broker credentials are configured (stop it, or give another --broker)"
                )
            # Someone else's broker (another proxy's, a mosquitto): it works, but it may not be the one meant,
            # so say whose it is (on a shared host it may be another user's).
            log.warning("broker.reuse", extra={
                "url": self.address.url,
                "users": await owners(self.address),
                "detail": "a broker already listens here and is shared as it is (not started by this process); "
                "give --broker-port N for one of your own, or --broker mqtt://HOST:PORT to choose one",
            })  # fmt: skip
            return self
        if self.process:
            await self._start_child()
        else:
            from secuav_common.broker_cap import CappedBroker  # amqtt, lazily: only the embedding process needs it

            quiet_amqtt()
            a = self.address
            broker = CappedBroker(amqtt_config(a.host, a.port, a.username, a.password))
            await broker.start()
            self._broker = broker
        self.started = True
        where = "child process" if self.process else "this loop"
        log.info("broker.started", extra={"url": self.address.url, "runs_in": where})
        return self

    async def _start_child(self) -> None:
        """Start the broker process and wait for its ``ready``; its stdin is our lifeline (closed: it stops)."""
        a = self.address
        account = [a.username] if a.username else []
        env = {**os.environ, PASSWORD_ENV: a.password or ""} if a.username else None
        child = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "secuav_common.broker_main", a.host, str(a.port), *account,
            stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, env=env,
        )  # fmt: skip
        assert child.stdout is not None and child.stderr is not None
        try:
            line = await asyncio.wait_for(child.stdout.readline(), timeout=30.0)
        except TimeoutError:
            line = b""
        if line.strip() != b"ready":
            with contextlib.suppress(ProcessLookupError):
                child.kill()
            err = (await child.stderr.read()).decode(errors="replace").strip().splitlines()
            raise OSError(f"the embedded broker did not start on {self.address.url}: {err[-1] if err else 'no reason'}")
        self._child = child

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._broker is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._broker.shutdown(), timeout=3.0)  # type: ignore[attr-defined]
            self._broker = None
        child, self._child = self._child, None
        if child is not None and child.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                child.terminate()
            try:
                await asyncio.wait_for(child.wait(), timeout=3.0)
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    child.kill()
                await child.wait()
