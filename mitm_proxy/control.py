"""The proxy's MQTT session: connect, serve, reconnect, publish.

Topics and payloads: docs/interfaces.md#mqtt-control-plane-json-payloads-vehicle-key-vsysid.

This module is the transport; what a request does is :mod:`mitm_proxy.controls`
(one :class:`~mitm_proxy.controls.Control` per runtime switch, registered once
in a :class:`~mitm_proxy.controls.Controls`). One background task keeps one
MQTT session: it subscribes to every control's ``set`` topic, hands each
decoded request to its control, and publishes the control's state on the
retained ``.../state`` topic next to it. It also publishes each link's stats at
1 Hz, the proxy instance's retained ``secuav/proxy/<instance>/online`` record
(a last will says ``online: false`` if the process dies), the single-proxy
``secuav/proxy/online`` flag, and whatever other producers hand to
:meth:`ControlPlane.publish_nowait`.

The data path never waits for MQTT: requests run between two frames on the
event loop, and every outgoing message goes through an outbox that drops
rather than blocks. When the broker goes away the plane logs it once, retries
with a growing backoff, and on reconnect republishes every state, so a client
that subscribes later still reads the truth.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import hashlib
import json
import logging
import math
import re
import time
import uuid
from collections import deque
from collections.abc import Callable
from types import TracebackType
from typing import Any

import aiomqtt

from mitm_proxy.controls import (
    PREFIX,
    Controls,
    RequestError,
    Target,
    default_instance,
    parse_vehicle_key,
    proxy_topic,
    vehicle_topic,
)
from secuav_common.broker import parse_broker_url

log = logging.getLogger(__name__)
# paho logs every packet at DEBUG; keep that out of ``-v`` unless someone asks for this logger by name.
_CLIENT_LOG = logging.getLogger(f"{__name__}.mqtt")
if _CLIENT_LOG.level == logging.NOTSET:
    _CLIENT_LOG.setLevel(logging.INFO)

CONSOLE_ONLINE = f"{PREFIX}/console/+/online"  # a console's retained record: the proxy then publishes readings
ONLINE_TOPIC = f"{PREFIX}/proxy/online"  # the single-proxy flag; fleets read each instance's online record
MAX_PAYLOAD_BYTES = 64 * 1024
DRAIN_BATCH = 64  # messages published concurrently by the outbox drain
MAX_UNKNOWN_LOGGED = 100  # unknown vehicle keys logged (once each); junk topics cannot grow the set
__all__ = ["ONLINE_TOPIC", "PREFIX", "ControlPlane", "Outbox", "RequestError", "default_instance",
           "parse_vehicle_key", "proxy_topic", "vehicle_topic"]  # fmt: skip

# A request id the CLI puts first in its JSON, so an oversized or broken payload can still be answered.
_REQUEST_ID_PREFIX = re.compile(rb'\A\s*\{\s*"request_id"\s*:\s*"([A-Za-z0-9_.:@/-]{1,100})"')


def decode_payload(raw: bytes) -> tuple[Any, str | None]:
    """JSON payload and its ``request_id``; :class:`RequestError` says why a payload is refused.

    The size is checked before anything is decoded, so a flood of huge
    messages costs a length comparison each.
    """
    if len(raw) > MAX_PAYLOAD_BYTES:
        raise RequestError(f"payload of {len(raw)} bytes is larger than {MAX_PAYLOAD_BYTES} bytes")
    if not raw.strip():
        raise RequestError("empty payload; send JSON null to clear")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RequestError(f"payload is not UTF-8 text (byte {exc.start})") from None
    try:
        payload = json.loads(text)
    except (ValueError, RecursionError) as exc:
        where = f" at line {exc.lineno} column {exc.colno}" if isinstance(exc, json.JSONDecodeError) else ""
        if isinstance(exc, json.JSONDecodeError):
            reason = exc.msg
        elif isinstance(exc, RecursionError):
            reason = "nested too deeply"
        else:  # e.g. an integer of thousands of digits (Python's int parsing limit)
            reason = str(exc).split(";")[0]
        raise RequestError(f"payload is not JSON: {reason}{where}") from None
    request_id = payload.get("request_id") if isinstance(payload, dict) else None
    if request_id is not None and not isinstance(request_id, str):
        request_id = json.dumps(request_id)[:100]
    return payload, request_id


def salvage_request_id(raw: bytes) -> str | None:
    """The request id of a refused payload, when it leads the JSON object (as ``secuav-attack`` writes it)."""
    m = _REQUEST_ID_PREFIX.match(raw[:200])
    return m.group(1).decode() if m else None


class Outbox:
    """Messages waiting for the broker; appending never blocks and never grows without bound.

    Retained topics keep only their latest value (that is all a subscriber
    would read anyway) and are never dropped; other messages sit in a bounded
    queue that drops its oldest entry when full and counts it.
    """

    def __init__(self, maxlen: int) -> None:
        self.retained: dict[str, bytes] = {}
        self.queue: deque[tuple[str, bytes]] = deque(maxlen=maxlen)
        self.dropped = 0
        self.wakeup = asyncio.Event()

    def put(self, topic: str, payload: bytes, retain: bool) -> None:
        if retain:
            self.retained.pop(topic, None)  # re-insert: retained states go out in the order they changed
            self.retained[topic] = payload
        else:
            if len(self.queue) == self.queue.maxlen:
                self.dropped += 1
            self.queue.append((topic, payload))
        self.wakeup.set()

    def take(self) -> tuple[str, bytes, bool] | None:
        if self.retained:
            topic = next(iter(self.retained))
            return topic, self.retained.pop(topic), True
        if self.queue:
            topic, payload = self.queue.popleft()
            return topic, payload, False
        self.wakeup.clear()
        return None

    def put_back(self, topic: str, payload: bytes, retain: bool) -> None:
        """A message the broker did not take (connection lost): it goes out first after the reconnect."""
        if retain:
            self.retained.setdefault(topic, payload)
        elif len(self.queue) < (self.queue.maxlen or 0):
            self.queue.appendleft((topic, payload))
        else:
            self.dropped += 1


def _finite(node: Any) -> Any:
    """NaN and infinities as JSON null: estimates mark missing readings with NaN, and JSON has no NaN."""
    if isinstance(node, float) and not math.isfinite(node):
        return None
    if isinstance(node, dict):
        return {k: _finite(v) for k, v in node.items()}
    if isinstance(node, list | tuple):
        return [_finite(v) for v in node]
    return node


def _json_bytes(payload: Any) -> bytes:
    """Compact, strict JSON; numpy scalars and other odd values fall back to ``str``."""
    if isinstance(payload, bytes):
        return payload
    try:
        return json.dumps(payload, separators=(",", ":"), allow_nan=False, default=_plain).encode()
    except ValueError:  # a NaN somewhere: the slow path only then
        return json.dumps(_finite(payload), separators=(",", ":"), allow_nan=False, default=_plain).encode()


def _plain(value: Any) -> Any:
    item = getattr(value, "item", None)  # numpy scalar -> Python number
    if callable(item):
        with contextlib.suppress(Exception):
            plain = item()
            return None if isinstance(plain, float) and not math.isfinite(plain) else plain
    tolist = getattr(value, "tolist", None)  # numpy array -> list
    if callable(tolist):
        with contextlib.suppress(Exception):
            return _finite(tolist())
    return str(value)


class ControlPlane:
    """``async with ControlPlane(url, controls, stats=...) as plane:`` runs the MQTT side in the background.

    ``controls`` is the registry of runtime switches (:mod:`mitm_proxy.controls`); the
    plane only moves their requests and states. ``broker_url`` None disables MQTT
    (``--broker none``): the plane then does nothing and :meth:`publish_nowait`
    discards. ``describe()`` adds fields to the instance's online record.
    Username/password given here win over those in the URL; ``tls_ca`` (a CA file)
    or an ``mqtts://`` URL turns TLS on, ``tls_insecure`` skips the host name check.
    """

    def __init__(
        self,
        broker_url: str | None,
        controls: Controls,
        *,
        stats: Callable[[], dict[int, dict[str, Any]]],
        describe: Callable[[], dict[str, Any]] | None = None,
        on_watchers: Callable[[int], None] | None = None,
        username: str | None = None,
        password: str | None = None,
        tls_ca: str | None = None,
        tls_insecure: bool = False,
        stats_interval_s: float = 1.0,
        outbox_size: int = 1000,
        backoff_s: tuple[float, float] = (0.2, 5.0),
        keepalive_s: int = 10,
    ) -> None:
        self.address = parse_broker_url(broker_url) if broker_url is not None else None
        self.controls = controls
        self.instance = controls.instance
        self._stats = stats
        self._describe = describe  # extra fields of the online record (endpoints, pid...)
        self._on_watchers = on_watchers  # told how many consoles watch when that changes
        self.watchers: set[str] = set()  # consoles whose retained online record says true
        self._username = username if username is not None else (self.address.username if self.address else None)
        self._password = password if password is not None else (self.address.password if self.address else None)
        self._tls = self.address is not None and (self.address.tls or tls_ca is not None)
        self._tls_ca = tls_ca
        self._tls_insecure = tls_insecure
        self.stats_interval_s = stats_interval_s
        self._backoff_s = backoff_s
        self._keepalive_s = keepalive_s
        self.outbox = Outbox(outbox_size)
        self.connected = asyncio.Event()
        self.connections = 0  # successful connects, for tests and the log
        self._task: asyncio.Task[None] | None = None
        self._restore_handler: Callable[[], None] | None = None
        self._client: aiomqtt.Client | None = None
        self._unknown: set[str] = set()  # vehicle keys already logged
        self._unencodable: set[str] = set()  # topics whose payload could not be made JSON (logged once)
        self._handled: dict[str, deque[bytes]] = {}  # topic -> digests of recent requests (retained replays)
        self._stats_failing = False
        self._published: dict[str, dict[str, Any]] = {}  # state topic -> the state last queued
        self._online_since = time.time()
        self.state_poll_s = 0.2
        self.online_topic = proxy_topic(self.instance, "online")
        self.identifier = f"secuav-proxy-{self.instance}-{uuid.uuid4().hex[:6]}"

    # -- lifecycle ------------------------------------------------------------------------------------

    async def __aenter__(self) -> ControlPlane:
        if self.address is not None:
            self._install_race_filter()
            self._task = asyncio.create_task(self.run(), name="control-plane")
        return self

    def _install_race_filter(self) -> None:
        """Keep aiomqtt's dead-socket race out of the log.

        When the broker vanishes while a publish is under way, aiomqtt has
        already scheduled ``loop.add_writer`` for the closed socket; the loop
        then reports EBADF with a traceback, or EPERM when the kernel has
        meanwhile handed the number to a regular file (say a recording) that
        epoll cannot watch. The session's own error says the same thing once,
        so that report is dropped and everything else passes on to the handler
        that was there before.
        """
        loop = asyncio.get_running_loop()
        previous = loop.get_exception_handler()

        def handler(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
            exc = context.get("exception")
            text = repr(context.get("handle", ""))
            stale_fd = isinstance(exc, OSError) and exc.errno in (errno.EBADF, errno.EPERM)
            if stale_fd and ("add_writer" in text or "add_reader" in text):
                log.debug("mqtt.socket_race", extra={"error": repr(exc)})
                return
            if previous is not None:
                previous(loop, context)
            else:
                loop.default_exception_handler(context)

        loop.set_exception_handler(handler)
        self._restore_handler = lambda: loop.set_exception_handler(previous)

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        """Say ``online false`` while we still can (a clean disconnect does not fire the will), then stop."""
        client = self._client
        if client is not None and self.connected.is_set():
            with contextlib.suppress(aiomqtt.MqttError, asyncio.TimeoutError):
                await asyncio.wait_for(asyncio.gather(
                    client.publish(self.online_topic, self._online_record(False), qos=1, retain=True),
                    client.publish(ONLINE_TOPIC, b"false", qos=1, retain=True),
                ), 0.5)  # fmt: skip
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        if self._restore_handler is not None:
            self._restore_handler()
            self._restore_handler = None

    async def wait_connected(self, timeout_s: float) -> None:
        await asyncio.wait_for(self.connected.wait(), timeout_s)

    # -- for other producers --------------------------------------------------------------------------

    def publish_nowait(self, topic: str, payload: Any, retain: bool = False) -> None:
        """Queue ``payload`` (bytes, or anything JSON) for ``topic``; never waits, drops the oldest when full."""
        if self.address is None:
            return
        try:
            data = _json_bytes(payload)
        except Exception as exc:  # a producer's odd payload must not raise into the data path
            if topic not in self._unencodable:
                self._unencodable.add(topic)
                log.error("control.unencodable", extra={"topic": topic, "error": repr(exc)})
            return
        self.outbox.put(topic, data, retain)

    def publish_states(self, force: bool = False) -> None:
        """Queue every control's retained state that changed since it was last queued (all with ``force``).

        A change made outside MQTT (the ``--profile`` file reload, ``--attack bypass`` at start) is
        found this way too, without any wiring: :meth:`_state_loop` calls this a few times a second.
        """
        for target in self.controls.states():
            try:
                state = target.control.state()
            except Exception:  # a control's bug: its set requests still get answers
                log.debug("control.state_failed", extra={"topic": target.state_topic}, exc_info=True)
                continue
            if force or state != self._published.get(target.state_topic):
                self._publish(target, state)

    def _publish(self, target: Target, state: dict[str, Any]) -> None:
        self._published[target.state_topic] = state
        self.publish_nowait(target.state_topic, state, retain=True)

    def _online_record(self, online: bool) -> bytes:
        """``secuav/proxy/<instance>/online``: who this proxy is and which vehicles it serves."""
        record: dict[str, Any] = {"instance": self.instance, "online": online, "since": self._online_since,
                                  "vehicles": self.controls.vehicles}  # fmt: skip
        if online and self._describe is not None:
            with contextlib.suppress(Exception):
                record.update(self._describe())
        return _json_bytes(record)

    @property
    def dropped(self) -> int:
        return self.outbox.dropped

    # -- the session ----------------------------------------------------------------------------------

    def _client_for_attempt(self) -> aiomqtt.Client:
        assert self.address is not None
        tls_params = aiomqtt.TLSParameters(ca_certs=self._tls_ca) if self._tls else None
        client = aiomqtt.Client(
            self.address.host,
            self.address.port,
            username=self._username,
            password=self._password,
            identifier=self.identifier,
            will=aiomqtt.Will(self.online_topic, self._online_record(False), qos=1, retain=True),
            keepalive=self._keepalive_s,
            timeout=5.0,
            tls_params=tls_params,
            tls_insecure=self._tls_insecure if self._tls else None,
            logger=_CLIENT_LOG,
        )
        # aiomqtt warns above 10 publishes in flight; the drain has up to DRAIN_BATCH by design.
        client.pending_calls_threshold = DRAIN_BATCH + 16
        return client

    async def run(self) -> None:
        """Connect, serve, and on any broker failure reconnect with backoff, until cancelled."""
        assert self.address is not None
        url = self.address.url
        delay_s = self._backoff_s[0]
        down_since: float | None = None
        attempts = 0
        while True:
            try:
                async with self._client_for_attempt() as client:
                    self._client = client
                    if down_since is not None:
                        log.info(
                            "mqtt.reconnected",
                            extra={"url": url, "down_s": round(time.monotonic() - down_since, 2), "attempts": attempts},
                        )
                    down_since, attempts, delay_s = None, 0, self._backoff_s[0]
                    await self._serve(client)
            except Exception as exc:  # MqttError is the broker; anything else is our bug: logged, retried
                attempts += 1
                if down_since is None:
                    down_since = time.monotonic()
                    if not isinstance(exc, aiomqtt.MqttError):
                        log.exception("control.failed", extra={"url": url})
                    log.warning("mqtt.unavailable", extra={"url": url, "error": str(exc)})
                else:
                    log.debug("mqtt.retry", extra={"url": url, "error": str(exc), "attempt": attempts})
            finally:
                self._client = None
                self.connected.clear()
            await asyncio.sleep(delay_s)
            delay_s = min(delay_s * 2, self._backoff_s[1])

    async def _serve(self, client: aiomqtt.Client) -> None:
        await client.publish(self.online_topic, self._online_record(True), qos=1, retain=True)
        await client.publish(ONLINE_TOPIC, b"true", qos=1, retain=True)
        topics = self.controls.subscriptions()
        if self._on_watchers is not None:
            topics.append(CONSOLE_ONLINE)
        await client.subscribe([(t, 1) for t in topics])
        self.publish_states(force=True)
        self.connections += 1
        self.connected.set()
        log.info("mqtt.connected", extra={"url": self.address.url if self.address else None})
        tasks = [
            asyncio.create_task(self._receive(client), name="control-receive"),
            asyncio.create_task(self._drain(client), name="control-drain"),
            asyncio.create_task(self._stats_loop(), name="control-stats"),
            asyncio.create_task(self._state_loop(), name="control-states"),
        ]
        try:
            done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_EXCEPTION)
            for task in done:
                task.result()  # re-raise the MqttError that ended the session
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    async def _drain(self, client: aiomqtt.Client) -> None:
        """Send what the outbox holds; a batch goes out concurrently, which costs about a third less
        CPU per message than one await per publish (measured: ~120 vs ~180 us through aiomqtt)."""
        while True:
            item = self.outbox.take()
            if item is None:
                await self.outbox.wakeup.wait()
                continue
            batch = [item]
            while len(batch) < DRAIN_BATCH and (more := self.outbox.take()) is not None:
                batch.append(more)
            try:
                await asyncio.gather(*(client.publish(t, p, qos=1 if r else 0, retain=r) for t, p, r in batch))
            except BaseException:
                for topic, payload, retain in reversed(batch):  # the session ended: they go first next time
                    self.outbox.put_back(topic, payload, retain)
                raise

    async def _stats_loop(self) -> None:
        while True:
            await asyncio.sleep(self.stats_interval_s)
            try:
                snapshot = self._stats()
            except Exception as exc:  # a stats bug must not end the control plane
                if not self._stats_failing:
                    log.error("stats.failed", extra={"error": repr(exc)})
                self._stats_failing = True
                continue
            self._stats_failing = False
            for sysid, body in snapshot.items():
                self.publish_nowait(vehicle_topic(sysid, "stats"), body)

    async def _state_loop(self) -> None:
        while True:
            await asyncio.sleep(self.state_poll_s)
            self.publish_states()

    async def _receive(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            body = message.payload
            raw = bytes(body) if isinstance(body, bytes | bytearray) else ("" if body is None else str(body)).encode()
            self.handle(str(message.topic), raw, retained=message.retain)
            # A burst of queued requests would otherwise run back to back (the queue hands them
            # over without yielding); let the datagrams that arrived meanwhile go first.
            await asyncio.sleep(0)

    def _console(self, topic: str, raw: bytes) -> None:
        """A console came or went (its retained record, or its last will)."""
        try:
            online = bool(json.loads(raw).get("online")) if raw and len(raw) < 4096 else False
        except (ValueError, AttributeError):
            online = False
        before = len(self.watchers)
        (self.watchers.add if online else self.watchers.discard)(topic)
        if len(self.watchers) != before and self._on_watchers is not None:
            log.info("console.watchers", extra={"count": len(self.watchers), "topic": topic})
            self._on_watchers(len(self.watchers))

    # -- requests (sans-I/O: tests call handle() directly) ---------------------------------------------

    def handle(self, topic: str, raw: bytes, retained: bool = False) -> None:
        """Apply one ``.../set`` message and queue the resulting state."""
        if topic.startswith(CONSOLE_ONLINE[:-8]) and topic.endswith("/online"):
            self._console(topic, raw)
            return
        target = self.controls.route(topic)
        if target is None:
            return
        if isinstance(target, str):
            if target not in self._unknown and len(self._unknown) < MAX_UNKNOWN_LOGGED:
                self._unknown.add(target)
                log.warning("control.unknown_vehicle", extra={"topic": topic, "known": self.controls.vehicles})
            return
        if len(raw) <= MAX_PAYLOAD_BYTES:  # an oversized one is refused below without reading it
            digest = hashlib.sha256(raw).digest()
            seen = self._handled.setdefault(topic, deque(maxlen=64))
            if retained and digest in seen:
                # Someone published this request retained; we applied it when it arrived and the
                # broker hands it to us again after every reconnect. Re-applying it would undo
                # whatever came later, so only a retained request we never saw counts.
                return
            seen.append(digest)
        control = target.control
        if raw.strip() in control.bare_words:
            raw = json.dumps(raw.strip().decode()).encode()  # `mosquitto_pub -m bypass`: the word without quotes
        try:
            payload, request_id = decode_payload(raw)
        except RequestError as exc:
            self._publish(target, control.refuse(str(exc), salvage_request_id(raw)))
            return
        self._publish(target, control.handle(payload, request_id))
