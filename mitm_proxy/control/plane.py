"""The proxy's MQTT session: connect, serve, reconnect, publish.

Topics and payloads: docs/interfaces.md#mqtt-control-plane-json-payloads-vehicle-key-vsysid.

This module is the transport; what a request does is :mod:`mitm_proxy.control.switches`
(one :class:`~mitm_proxy.control.switch.Switch` per runtime switch, registered once
in a :class:`~mitm_proxy.control.switches.Controls`). One background task keeps one
MQTT session: it subscribes to every control's ``set`` topic, hands each
decoded request to its control, and publishes the control's state on the
retained ``.../state`` topic next to it. It also publishes each link's stats at
1 Hz, the proxy instance's retained ``secuav/proxy/<instance>/online`` record
(a last will says ``online: false`` if the process dies), the single-proxy
``secuav/proxy/online`` flag, and whatever other producers hand to
:meth:`ControlPlane.publish_nowait`.

The data path never waits for MQTT: a request is decoded and validated in a
worker thread and installed between two frames on the event loop, requests
past ``REQUESTS_PER_S`` per set topic (a large one counting as one per 4 kB)
are dropped, requests handed over as
retained (left on the broker) are ignored, and every outgoing message goes
through an outbox that drops rather than blocks. When the broker goes away the plane logs it once, retries
with a growing backoff, and on reconnect republishes every state, so a client
that subscribes later still reads the truth.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import json
import logging
import time
import uuid
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType
from typing import Any

from pydantic import BaseModel

from mitm_proxy.control.switches import Controls, Target, default_instance
from secuav_common.controlplane.address import parse_broker_url
from secuav_common.controlplane.payloads import (
    MAX_PAYLOAD_BYTES,
    PayloadError,
    RequestError,
    dumps,
    loads_request,
    salvage_request_id,
    validate,
)
from secuav_common.controlplane.session import Client, LastWill, MqttError, Session, messages
from secuav_common.controlplane.topics import (
    CONSOLES_ONLINE,
    PROXY_ONLINE,
    parse,
    parse_vehicle_key,
    proxy_topic,
    vehicle_topic,
)
from secuav_common.loading import InputError

log = logging.getLogger(__name__)
# paho logs every packet at DEBUG; keep that out of ``-v`` unless someone asks for this logger by name.
_CLIENT_LOG = logging.getLogger("mitm_proxy.control.mqtt")
if _CLIENT_LOG.level == logging.NOTSET:
    _CLIENT_LOG.setLevel(logging.INFO)

ONLINE_TOPIC = PROXY_ONLINE  # the single-proxy flag; fleets read each instance's online record
DRAIN_BATCH = 64  # messages published concurrently by the outbox drain
MAX_UNKNOWN_LOGGED = 100  # unknown vehicle keys logged (once each); junk topics cannot grow the set
# Requests per set topic: MQTT 3.1.1 does not say who sent a message, so the limit is per switch. A person
# or a script sends a few a second; a flood past this is dropped unread (counted, logged once).
REQUESTS_PER_S = 10.0
REQUEST_BURST = 20
# A request costs one more token per 4 kB: checking and building a profile costs ~2 ms per kB, so a flood of
# the largest profiles (64 kB, 17 tokens) is held to one every 1.7 s, while small requests keep 10 a second.
REQUEST_BYTES_PER_TOKEN = 4096
REQUEST_BACKLOG = 64  # requests waiting to be checked and applied; past this they are dropped (counted)
__all__ = ["MAX_PAYLOAD_BYTES", "ONLINE_TOPIC", "ControlPlane", "Outbox", "RequestError", "default_instance",
           "parse_vehicle_key", "proxy_topic", "vehicle_topic"]  # fmt: skip


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


class ControlPlane:
    """``async with ControlPlane(url, controls, stats=...) as plane:`` runs the MQTT side in the background.

    ``controls`` is the registry of runtime switches (:mod:`mitm_proxy.control.switches`); the
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
        self.stats_interval_s = stats_interval_s
        self.outbox = Outbox(outbox_size)
        self._task: asyncio.Task[None] | None = None
        self._restore_handler: Callable[[], None] | None = None
        self._unknown: set[str] = set()  # vehicle keys already logged
        self._unencodable: set[str] = set()  # topics whose payload could not be made JSON (logged once)
        self._retained_logged: set[str] = set()  # topics whose retained request was ignored (logged once)
        self.retained_ignored = 0
        self._rate = _RateLimit(REQUESTS_PER_S, REQUEST_BURST)
        self._rate_logged: set[str] = set()
        self.rate_limited = 0
        self.committed = 0  # requests checked and answered (accepted or refused)
        self._stats_failing = False
        self._published: dict[str, BaseModel] = {}  # state topic -> the state last queued
        self._online_since = time.time()
        self.state_poll_s = 0.2
        self.online_topic = proxy_topic(self.instance, "online")
        self.identifier = f"secuav-proxy-{self.instance}-{uuid.uuid4().hex[:6]}"
        self.session = None if self.address is None else Session(
            self.address, identifier=self.identifier, username=username, password=password, tls_ca=tls_ca,
            tls_insecure=tls_insecure, will=lambda: LastWill(self.online_topic, self._online_record(False)),
            keepalive_s=keepalive_s, backoff_s=backoff_s, log=log, client_log=_CLIENT_LOG,
            max_in_flight=DRAIN_BATCH + 16,  # the drain has up to DRAIN_BATCH publishes in flight by design
        )  # fmt: skip
        self.connected = asyncio.Event() if self.session is None else self.session.connected

    @property
    def connections(self) -> int:
        """Successful connects, for tests and the log."""
        return 0 if self.session is None else self.session.connections

    @property
    def _client(self) -> Client | None:
        return None if self.session is None else self.session.current

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
            with contextlib.suppress(MqttError, asyncio.TimeoutError):
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
            data = dumps(payload)
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
                state = target.control.state
            except Exception:  # a control's bug: its set requests still get answers
                log.debug("control.state_failed", extra={"topic": target.state_topic}, exc_info=True)
                continue
            if force or state != self._published.get(target.state_topic):
                self._publish(target, state)

    def _publish(self, target: Target, state: BaseModel) -> None:
        self._published[target.state_topic] = state
        self.publish_nowait(target.state_topic, state, retain=True)

    def _online_record(self, online: bool) -> bytes:
        """``secuav/proxy/<instance>/online``: who this proxy is and which vehicles it serves."""
        record: dict[str, Any] = {"instance": self.instance, "online": online, "since": self._online_since,
                                  "vehicles": self.controls.vehicles}  # fmt: skip
        if online and self._describe is not None:
            with contextlib.suppress(Exception):
                record.update(self._describe())
        return dumps(record)

    @property
    def dropped(self) -> int:
        return self.outbox.dropped

    # -- the session ----------------------------------------------------------------------------------

    async def run(self) -> None:
        """Connect, serve, and on any broker failure reconnect with backoff, until cancelled."""
        assert self.session is not None
        await self.session.run(self._serve)

    async def _serve(self, client: Client) -> None:
        await client.publish(self.online_topic, self._online_record(True), qos=1, retain=True)
        await client.publish(ONLINE_TOPIC, b"true", qos=1, retain=True)
        topics = self.controls.subscriptions()
        if self._on_watchers is not None:
            topics.append(CONSOLES_ONLINE)
        await client.subscribe([(t, 1) for t in topics])
        self.publish_states(force=True)
        assert self.session is not None
        self.session.mark_connected()
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

    async def _drain(self, client: Client) -> None:
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

    async def _receive(self, client: Client) -> None:
        """Take messages as they arrive (so the rate limit sees their real rate); requests queue for :meth:`_work`."""
        backlog: asyncio.Queue[Request] = asyncio.Queue(maxsize=REQUEST_BACKLOG)
        worker = asyncio.create_task(self._work(backlog), name="control-requests")
        try:
            async for topic, raw, retained in messages(client):
                request = self.accept(topic, raw, retained, time.monotonic())
                if request is None:
                    continue
                try:
                    backlog.put_nowait(request)
                except asyncio.QueueFull:
                    self.rate_limited += 1
                    self._log_once(self._rate_logged, "<backlog>", "control.backlog_full", backlog=REQUEST_BACKLOG)
        finally:
            worker.cancel()

    async def _work(self, backlog: asyncio.Queue[Request]) -> None:
        while True:
            request = await backlog.get()
            # Decoding and validating (a 55 kB profile takes tens of ms) run in a worker thread, so the
            # frames keep flowing; only the install, one assignment, runs on the loop. One at a time, in
            # the order they came.
            self.commit(request, await asyncio.to_thread(request.prepare))
            # A burst of queued requests would otherwise run back to back; let the datagrams that arrived
            # meanwhile go first.
            await asyncio.sleep(0)

    def _console(self, topic: str, raw: bytes) -> None:
        """A console came or went (its retained record, or its last will)."""
        try:
            online = len(raw) < 4096 and bool(validate(topic, json.loads(raw)).online) if raw else False
        except (ValueError, PayloadError):  # a record that does not fit counts as a console gone
            online = False
        before = len(self.watchers)
        (self.watchers.add if online else self.watchers.discard)(topic)
        if len(self.watchers) != before and self._on_watchers is not None:
            log.info("console.watchers", extra={"count": len(self.watchers), "topic": topic})
            self._on_watchers(len(self.watchers))

    # -- requests (sans-I/O: tests call handle() directly) ---------------------------------------------

    def handle(self, topic: str, raw: bytes, retained: bool = False) -> None:
        """Apply one ``.../set`` message and queue the resulting state (decode, check and apply in one go)."""
        request = self.accept(topic, raw, retained, time.monotonic())
        if request is not None:
            self.commit(request, request.prepare())

    def accept(self, topic: str, raw: bytes, retained: bool, now_s: float) -> Request | None:
        """Route one message: a request to prepare and commit, or None (console presence, unknown, retained,
        over the rate limit: each counted, logged once)."""
        parsed = parse(topic)
        if parsed is not None and parsed.scope == "console" and parsed.key is not None and parsed.leaf == "online":
            self._console(topic, raw)
            return None
        target = self.controls.route(topic)
        if target is None:
            return None
        if isinstance(target, str):
            if target not in self._unknown and len(self._unknown) < MAX_UNKNOWN_LOGGED:
                self._unknown.add(target)
                log.warning("control.unknown_vehicle", extra={"topic": topic, "known": self.controls.vehicles})
            return None
        if retained:
            # A request someone left retained on the broker is handed to every proxy that subscribes, at
            # its start and after each reconnect: taking it would let a stale or planted request override
            # what the command line set (a retained routes/set lifting listen_only before anyone asked).
            # Only requests sent while we listen count (docs/interfaces.md).
            self.retained_ignored += 1
            self._log_once(self._retained_logged, topic, "control.retained_request_ignored")
            return None
        if not self._rate.take(topic, now_s, 1 + len(raw) // REQUEST_BYTES_PER_TOKEN):
            self.rate_limited += 1
            self._log_once(self._rate_logged, topic, "control.rate_limited",
                           limit_per_s=REQUESTS_PER_S, burst=REQUEST_BURST)  # fmt: skip
            return None
        return Request(target, raw, topic)

    def commit(self, request: Request, prepared: Prepared) -> None:
        """Apply a prepared request on the event loop (between two frames) and queue the state."""
        target, control = request.target, request.target.control
        payload, request_id, error = prepared
        self.committed += 1
        if error is not None:
            self._publish(target, control.refuse(error, request_id))
            return
        self._publish(target, control.handle(payload, request_id))

    def _log_once(self, seen: set[str], topic: str, event: str, **extra: Any) -> None:
        if topic not in seen and len(seen) < MAX_UNKNOWN_LOGGED:
            seen.add(topic)
            log.warning(event, extra={"topic": topic, **extra})


Prepared = tuple[Any, "str | None", "str | None"]  # payload ready to apply, request id, or why it is refused


@dataclass(slots=True)
class Request:
    """One ``.../set`` message on its way: :meth:`prepare` (decode and check: any thread) then commit."""

    target: Target
    raw: bytes
    topic: str

    def prepare(self) -> Prepared:
        """Decode the JSON and let the switch check it (a profile is validated here); never raises."""
        control = self.target.control
        raw = self.raw
        if raw.strip() in control.bare_words:
            raw = json.dumps(raw.strip().decode()).encode()  # `mosquitto_pub -m bypass`: the word without quotes
        try:
            payload, request_id = loads_request(raw)
        except RequestError as exc:
            return None, salvage_request_id(raw), str(exc)
        try:
            return control.prepare(payload, self.topic), request_id, None
        except (RequestError, InputError) as exc:
            return None, request_id, str(exc)
        except Exception as exc:  # a library bug must not end the control plane; the old setting stays
            log.exception("control.prepare_failed", extra={"request_id": request_id})
            return None, request_id, f"internal error: {exc!r}"


class _RateLimit:
    """A token bucket per topic: ``burst`` requests at once, ``per_s`` a second after that."""

    def __init__(self, per_s: float, burst: int, max_topics: int = 1024) -> None:
        self.per_s, self.burst, self.max_topics = per_s, burst, max_topics
        self.buckets: dict[str, tuple[float, float]] = {}  # topic -> (tokens, when counted)

    def take(self, topic: str, now_s: float, cost: int = 1) -> bool:
        tokens, then = self.buckets.get(topic, (float(self.burst), now_s))
        tokens = min(float(self.burst), tokens + (now_s - then) * self.per_s)
        if len(self.buckets) >= self.max_topics and topic not in self.buckets:
            self.buckets.clear()  # routed topics are few; this only bounds junk
        if tokens < cost:
            self.buckets[topic] = (tokens, now_s)
            return False
        self.buckets[topic] = (tokens - cost, now_s)
        return True
