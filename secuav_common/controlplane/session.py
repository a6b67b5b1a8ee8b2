"""One MQTT session for every SecUAV process: connect, serve, and on trouble reconnect with backoff.

``Session(address, identifier=...)`` holds what a connection needs: the broker
address (``mqtts://`` turns TLS on; a CA file does too, for a private CA),
the account, the keepalive and the last will. :meth:`Session.client` is the one
place an ``aiomqtt.Client`` is made; a one-shot command (``secuav-attack``)
uses it directly, a service hands :meth:`Session.run` the coroutine that
serves one connection and gets reconnects for free: when the broker goes away
the session says so once (``mqtt.unavailable``), retries with a growing
backoff, and says ``mqtt.reconnected`` when it is back.

What arrives leaves this module as plain :class:`Message` tuples (:func:`messages`):
aiomqtt's own message type stops here, so a new major version of aiomqtt (its
next drops paho) touches this file, not the control plane behind it.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass
from typing import NamedTuple

import aiomqtt

from secuav_common.controlplane.address import BrokerAddress
from secuav_common.controlplane.payloads import MAX_PACKET_BYTES
from secuav_common.logs import RateLimitedLog

MqttError = aiomqtt.MqttError
Client = aiomqtt.Client


@dataclass(frozen=True, slots=True)
class LastWill:
    """What the broker publishes (retained, QoS 1) when the connection dies without a goodbye."""

    topic: str
    payload: bytes


Serve = Callable[[aiomqtt.Client], Awaitable[None]]


class Message(NamedTuple):
    """One message as it arrived: its topic, its payload as bytes (empty for none), whether it was retained."""

    topic: str
    payload: bytes
    retain: bool


async def messages(client: aiomqtt.Client) -> AsyncIterator[Message]:
    """The messages ``client`` receives, as they arrive, in plain terms."""
    async for message in client.messages:
        body = message.payload
        payload = bytes(body) if isinstance(body, bytes | bytearray) else str(body or "").encode()
        yield Message(str(message.topic), payload, bool(message.retain))


class PacketTooLarge(OSError):
    """An incoming MQTT packet declared more bytes than we read: the connection is dropped unread."""


def cap_incoming(client: aiomqtt.Client, limit: int, said: RateLimitedLog | None = None) -> None:
    """Drop the connection on an incoming packet whose fixed header declares more than ``limit`` bytes,
    before its body is read (a broker without a size limit would otherwise make us hold any message).

    paho reads a packet's fixed header, then its body with ``_sock_recv``; the hook sits there, on this
    client's own paho instance (aiomqtt builds one per client). An OSError from it is what paho does with a
    failed read: the connection is lost, and :meth:`Session.run` reconnects with backoff; ``said`` logs
    ``mqtt.packet_too_large`` (once per 10 s, with the count: a retained one comes back at each reconnect).
    tests/secuav_common/test_common_broker_limits.py checks the hook still holds with the paho that is installed.
    """
    paho = client._client
    recv = paho._sock_recv

    def capped(bufsize: int) -> bytes:
        state = paho._in_packet  # replaced by a fresh dict after each packet: looked up each time
        if state["have_remaining"] and state["remaining_length"] > limit:
            if said is not None:
                said.event("mqtt.packet_too_large", bytes=state["remaining_length"], limit=limit)
            raise PacketTooLarge(f"an incoming MQTT packet of {state['remaining_length']} bytes is larger than "
                                 f"{limit} bytes; connection dropped unread")  # fmt: skip
        return recv(bufsize)

    paho._sock_recv = capped


class Session:
    """One client identity on one broker; see the module doc."""

    def __init__(
        self,
        address: BrokerAddress,
        *,
        identifier: str | None = None,
        username: str | None = None,
        password: str | None = None,
        tls_ca: str | None = None,
        tls_insecure: bool = False,
        will: Callable[[], LastWill] | LastWill | None = None,
        keepalive_s: int = 10,
        timeout_s: float = 5.0,
        backoff_s: tuple[float, float] = (0.2, 5.0),
        log: logging.Logger | None = None,
        client_log: logging.Logger | None = None,
        max_in_flight: int | None = None,
    ) -> None:
        """``username``/``password`` given here win over those in the URL; ``tls_ca`` (a CA file) or an
        ``mqtts://`` address turns TLS on, ``tls_insecure`` skips the host name check. ``will`` may be a
        callable, asked again at every connection attempt (the record it carries may have changed)."""
        self.address = address
        self.identifier = identifier
        self.username = username if username is not None else address.username
        self.password = password if password is not None else address.password
        self.tls = address.tls or tls_ca is not None
        self.tls_ca = tls_ca
        self.tls_insecure = tls_insecure
        self._will = will
        self.keepalive_s = keepalive_s
        self.timeout_s = timeout_s
        self.backoff_s = backoff_s
        self.log = log or logging.getLogger(__name__)
        self._too_large = RateLimitedLog(self.log)
        self._client_log = client_log
        self._max_in_flight = max_in_flight
        self.connected = asyncio.Event()
        self.connections = 0  # successful connects, for tests and the log
        self.current: aiomqtt.Client | None = None  # the live client while connected

    def client(self) -> aiomqtt.Client:
        """A client for one connection attempt (``async with session.client() as client: ...``)."""
        will = self._will() if callable(self._will) else self._will
        client = aiomqtt.Client(
            self.address.host,
            self.address.port,
            username=self.username,
            password=self.password,
            identifier=self.identifier,
            will=None if will is None else aiomqtt.Will(will.topic, will.payload, qos=1, retain=True),
            keepalive=self.keepalive_s,
            timeout=self.timeout_s,
            tls_params=aiomqtt.TLSParameters(ca_certs=self.tls_ca) if self.tls else None,
            tls_insecure=self.tls_insecure if self.tls else None,
            **({"logger": self._client_log} if self._client_log is not None else {}),
        )
        if self._max_in_flight is not None:
            # aiomqtt warns above 10 publishes in flight; a caller that batches says how many it means.
            client.pending_calls_threshold = self._max_in_flight
        cap_incoming(client, MAX_PACKET_BYTES, self._too_large)
        return client

    async def run(self, serve: Serve, on_down: Callable[[], None] | None = None) -> None:
        """Connect, ``await serve(client)``, and on any failure reconnect with backoff, until cancelled.

        A broker failure (``MqttError``) is logged once per outage; anything else ``serve`` raises is a
        bug, logged with its traceback, and retried the same way. ``on_down`` runs after each lost session.
        """
        url = self.address.url
        delay_s = self.backoff_s[0]
        down_since: float | None = None
        attempts = 0
        while True:
            try:
                async with self.client() as client:
                    self.current = client
                    if down_since is not None:
                        down_s = round(time.monotonic() - down_since, 2)
                        self.log.info("mqtt.reconnected", extra={"url": url, "down_s": down_s, "attempts": attempts})
                    down_since, attempts, delay_s = None, 0, self.backoff_s[0]
                    await serve(client)
            except Exception as exc:  # MqttError is the broker; anything else is our bug: logged, retried
                attempts += 1
                if down_since is None:
                    down_since = time.monotonic()
                    if not isinstance(exc, aiomqtt.MqttError):
                        self.log.exception("control.failed", extra={"url": url})
                    self.log.warning("mqtt.unavailable", extra={"url": url, "error": str(exc)})
                else:
                    self.log.debug("mqtt.retry", extra={"url": url, "error": str(exc), "attempt": attempts})
            finally:
                self.current = None
                self.connected.clear()
                if on_down is not None:
                    on_down()
            await asyncio.sleep(delay_s)
            delay_s = min(delay_s * 2, self.backoff_s[1])

    def mark_connected(self) -> None:
        """``serve`` calls this once it has subscribed and announced itself: the session is ready."""
        self.connections += 1
        self.connected.set()
