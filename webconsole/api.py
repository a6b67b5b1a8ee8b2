"""The console's HTTP side: the page, its JSON API and its live stream (Starlette, served by uvicorn).

=========================================  ===================================================
``GET /``                                  the page (static files, no CDN: works offline)
``GET /api/vehicles``                      one row per vehicle (``Fleet.summary``)
``GET /api/vehicles/{sysid}``              that row plus the scenario's world for the top view
``GET /api/library``                       the library profiles with their parameters and defaults
``GET /api/estimators``                    what ``secure`` accepts
``GET /api/estimators/params``             every estimator with its declared parameters (default, range)
``POST /api/vehicles/{sysid}/attack``      ``{"profile": name | object | YAML text | null, "params": {}}``
``POST /api/vehicles/{sysid}/switches/{kind}``  any declared vehicle switch: the body is its request
``POST /api/vehicles/{sysid}/attack/mode``  ``switches/attack/mode`` (older URL): ``{"mode": "on" | "bypass"}``
``POST /api/vehicles/{sysid}/secure``      ``switches/secure`` (older URL): ``{"estimator": name | "off"}``
``GET /api/stream?vehicle=N``              server-sent events, 12.5 per second: the fleet, N's new samples, the broker
=========================================  ===================================================

A POST answers with the proxy's own acknowledgement (``ok``, ``error``), or 422
when the request never left the console (a profile that does not validate, a
request that does not fit its switch's request model, the one check of its
shape: the body names the ``field``), or 504 when no proxy answered in time. What guards
the app against other web pages and greedy clients is in ``webconsole.security``
and docs/security.md: POSTs must be JSON from the console's own origin, bodies
are capped before they are read (413), event streams are capped per client and
in all (429), and wrong passwords are throttled (429) and logged. Profiles are
checked here with the same pydantic model the proxy uses (the one the profile
JSON Schema is generated from), so nothing invalid reaches the broker.
"""

from __future__ import annotations

import asyncio
import base64
import binascii
import hmac
import json
import logging
import time
from collections import Counter, OrderedDict
from collections.abc import AsyncIterator, Callable, Iterable
from pathlib import Path
from typing import Any

from pydantic import ValidationError
from sse_starlette.sse import EventSourceResponse, SendTimeoutError
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles
from starlette.types import ASGIApp, Receive, Scope, Send

from attack_profiles import library
from attack_profiles.control import profile_from_payload
from attack_profiles.profile import parse_profile, parse_text
from secuav_common.controlplane import switches
from secuav_common.controlplane.address import redact
from secuav_common.controlplane.contract import SwitchContract
from secuav_common.controlplane.payloads import MAX_PAYLOAD_BYTES, request_bytes
from secuav_common.controlplane.topics import vehicle_topic
from secuav_common.loading import InputError, first_error, parse_document
from secuav_common.logs import RateLimitedLog
from webconsole.fleet import AckTimeout, Fleet, Session
from webconsole.security import LOOPBACK_NAMES, guarded
from webconsole.world import world_json

STATIC = Path(__file__).resolve().parent / "static"
STREAM_PERIOD_S = 0.08  # 12.5 updates a second, on a fixed schedule (the issue asks for 10 or more)
BACKFILL_S = 120.0  # a page that (re)connects gets this much history at once
MAX_BODY = 256 * 1024
BODY_TIMEOUT_S = 10.0  # a request's body must arrive within this (the headers' limit is webconsole.connections)
MAX_STREAMS_PER_CLIENT = 4  # a few tabs of one operator
MAX_STREAMS = 32  # every update is built once per stream: this bounds the console's work
STREAM_SEND_TIMEOUT_S = 15.0  # a stream whose client has read nothing for this long (buffers full) is cut off
LOGIN_FREE_FAILURES = 5  # wrong passwords from one address before it must wait (2 s, doubling)
LOGIN_MAX_WAIT_S = 300.0
log = logging.getLogger("secuav-console")


class RequestTooLarge(Exception):
    pass


class RequestTimeout(Exception):
    pass


def _error(status: int, error: str, field: str | None = None) -> JSONResponse:
    return JSONResponse({"ok": False, "error": error, "field": field}, status_code=status)


def profile_request(body: Any) -> dict[str, Any] | None:
    """The ``attack/set`` payload for a page or API request, validated here; raises ``InputError``.

    ``profile``: a library name (with ``params`` for its declared parameters), a profile object,
    profile text (YAML or JSON, as pasted or uploaded), or ``null`` to clear.
    """
    if not isinstance(body, dict):
        raise InputError("request", "", body, 'expected {"profile": ..., "params": {...}}')
    profile, params = body.get("profile"), body.get("params") or {}
    if not isinstance(params, dict):
        raise InputError("request", "params", params, "must be a mapping of parameter name to value")
    if profile is None:
        return None
    if isinstance(profile, str) and profile.strip() in library.names():
        name = profile.strip()
        library.load(name, **params)  # the same check the proxy makes
        return {"library": name, "parameters": params}
    if isinstance(profile, str):
        text = profile.strip()
        if "\n" not in text and ":" not in text:
            raise InputError("profile", "", text, f"no such library profile (have: {', '.join(library.names())})")
        data = parse_text(text, "profile", trusted=False)
    elif isinstance(profile, dict):
        data = profile
    else:
        raise InputError("request", "profile", profile, "a library name, a profile object or text, or null")
    checked = parse_profile(data, "profile", **params)
    payload = json.loads(checked.canonical_json())
    profile_from_payload(payload, "profile")  # exactly what the proxy will run
    return payload


def switch_request(contract: SwitchContract, body: Any) -> dict[str, Any] | None:
    """The ``<kind>/set`` payload for ``POST /api/vehicles/{sysid}/switches/{kind}`` (and its aliases): the body
    read by the switch's request model, the one check of its shape, and sent as the model has it; raises
    ``InputError`` naming the field.

    A ``request_id`` in the body is dropped: the console gives each request its own, and waits for that.
    """
    try:
        checked = contract.check(body)
    except ValidationError as exc:
        raise first_error(exc, "request") from None
    payload = checked.model_dump(mode="json", exclude_unset=True)
    if isinstance(payload, dict):
        payload.pop("request_id", None)
    elif payload is not None:  # the acknowledgement is found by the request id the console puts in the object
        raise InputError("request", "", body, f"expected a JSON object (the {contract.kind} request) or null")
    size = len(request_bytes(payload, "x" * 40))  # the console's ids are "console-" and 32 hex digits
    if size > MAX_PAYLOAD_BYTES:
        raise InputError("request", "", f"{size} bytes", f"the proxy accepts requests up to {MAX_PAYLOAD_BYTES} bytes")
    return payload


def library_json() -> list[dict[str, Any]]:
    out = []
    for name, description in library.describe():
        data = parse_document(library.text(name), f"library:{name}")
        params = data.get("parameters") or {} if isinstance(data, dict) else {}
        out.append({"name": name, "description": description, "parameters": params, "text": library.text(name)})
    return out


def estimators_json() -> list[dict[str, Any]]:
    """Every estimator (built-in, then the installed plugins') with its origin, summary and declared
    parameters (``estimators.registry.describe``); imports them all, so asked for once and kept."""
    import estimators  # numpy/scipy: only when asked
    from estimators import registry

    return [registry.describe(name) for name in estimators.names()]


class LoginThrottle:
    """Wrong passwords per client address: after a few, the address waits (doubling, up to five minutes)."""

    def __init__(self, free: int = LOGIN_FREE_FAILURES, max_wait_s: float = LOGIN_MAX_WAIT_S,
                 max_clients: int = 10_000) -> None:  # fmt: skip
        self.free, self.max_wait_s, self.max_clients = free, max_wait_s, max_clients
        self.failures: OrderedDict[str, tuple[int, float]] = OrderedDict()  # client -> (count, blocked until)

    def wait_s(self, client: str, now: float) -> float:
        """How long ``client`` must still wait before its next try is even checked (0: go ahead)."""
        _, until = self.failures.get(client, (0, 0.0))
        return max(0.0, until - now)

    def failed(self, client: str, now: float) -> int:
        count = self.failures.pop(client, (0, 0.0))[0] + 1
        wait = 0.0 if count < self.free else min(self.max_wait_s, 2.0 ** (count - self.free + 1))
        self.failures[client] = (count, now + wait)
        while len(self.failures) > self.max_clients:  # bounded memory: forget the longest-quiet address
            self.failures.popitem(last=False)
        return count

    def succeeded(self, client: str) -> None:
        self.failures.pop(client, None)


class BasicAuth:
    """HTTP Basic (any user name) or ``Authorization: Bearer`` with the console password; else 401.

    Wrong passwords are logged (``console.login_failed``, with the client's address) and
    throttled per address by :class:`LoginThrottle`: a throttled client gets 429 and
    ``Retry-After`` without its password being checked.
    """

    def __init__(self, app: ASGIApp, password: str, throttle: LoginThrottle | None = None) -> None:
        self.app = app
        self.password = password.encode()
        self.throttle = throttle or LoginThrottle()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        client = (scope.get("client") or ("?", 0))[0]
        now = time.monotonic()
        wait = self.throttle.wait_s(client, now)
        if wait > 0:
            response: Response = _error(429, f"too many wrong passwords; try again in {wait:.0f} s")
            response.headers["Retry-After"] = str(int(wait) + 1)
            await response(scope, receive, send)
            return
        header = dict(scope["headers"]).get(b"authorization", b"")
        if self._allowed(header):
            self.throttle.succeeded(client)
            await self.app(scope, receive, send)
            return
        if header:  # a page's first request carries no credentials: only a wrong password counts
            count = self.throttle.failed(client, now)
            log.warning("console.login_failed", extra={"client": client, "failures": count,
                                                       "path": scope.get("path", "")})  # fmt: skip
        response = Response("password required\n", status_code=401,
                            headers={"WWW-Authenticate": 'Basic realm="secuav-console"'})  # fmt: skip
        await response(scope, receive, send)

    def _allowed(self, header: bytes) -> bool:
        scheme, _, value = header.partition(b" ")
        if scheme.lower() == b"bearer":
            return hmac.compare_digest(value.strip(), self.password)
        if scheme.lower() == b"basic":
            try:
                _, _, given = base64.b64decode(value.strip(), validate=True).partition(b":")
            except (binascii.Error, ValueError):
                return False
            return hmac.compare_digest(given, self.password)
        return False


class StreamSlots:
    """Event streams open, per client address and in all; a stream past either cap is refused."""

    def __init__(self, per_client: int = MAX_STREAMS_PER_CLIENT, total: int = MAX_STREAMS) -> None:
        self.per_client, self.total = per_client, total
        self.open: Counter[str] = Counter()

    def take(self, client: str) -> str | None:
        """Reserve a stream for ``client``; returns why not, or None when reserved."""
        if sum(self.open.values()) >= self.total:
            return f"{self.total} event streams are open, the most this console serves"
        if self.open[client] >= self.per_client:
            return f"{self.per_client} event streams are open from {client}, the most one client may hold"
        self.open[client] += 1
        return None

    def give_back(self, client: str) -> None:
        self.open[client] -= 1
        if self.open[client] <= 0:
            del self.open[client]


async def json_body(request: Request) -> Any:
    """The request's body as JSON, counted as it arrives (a huge body is never held, a slow one not for long)."""
    chunks, size = [], 0
    try:
        async with asyncio.timeout(BODY_TIMEOUT_S):  # a body sent a byte at a time holds nothing for long
            async for chunk in request.stream():
                size += len(chunk)
                if size > MAX_BODY:
                    raise RequestTooLarge
                chunks.append(chunk)
    except TimeoutError:
        raise RequestTimeout from None
    raw = b"".join(chunks)
    try:
        return json.loads(raw or b"null")
    except ValueError as exc:
        raise InputError("request", "", None, f"not JSON: {exc}") from None


def _row_of(request: Request) -> dict[str, Any] | None:
    """The vehicle's fleet row; None once its proxy has stopped and it left the fleet (or it never came)."""
    sysid = int(request.path_params["sysid"])
    return next((r for r in request.app.state.fleet.summary() if r["sysid"] == sysid), None)


async def _send(request: Request, kind: str, translate: Callable[[Any], Any] | None = None) -> Response:
    """Read the body (``translate``: a route's own body shape into the switch's request), check it with the
    switch's request model, send it to the vehicle's ``<kind>/set`` and answer with the proxy's state."""
    state_of = request.app.state
    contract = switches.find("vehicle", kind)
    if contract is None:
        known_kinds = ", ".join(c.kind for c in switches.contracts() if c.scope == "vehicle")
        return _error(404, f"no vehicle switch {kind!r} (declared: {known_kinds})")
    sysid = int(request.path_params["sysid"])
    if not state_of.fleet.owners().get(sysid):  # nobody would answer: say so now rather than after the timeout
        if sysid in state_of.fleet.vehicles:
            return _error(404, f"no proxy serves vehicle {sysid} now (its proxy has stopped)")
        return _error(404, f"no vehicle {sysid} on the broker")
    try:
        body = await json_body(request)
        payload = switch_request(contract, body if translate is None else translate(body))
    except InputError as exc:
        return _error(422, str(exc), exc.field or None)
    except RequestTooLarge:
        return _error(413, f"request body larger than {MAX_BODY} bytes")
    except RequestTimeout:
        return _error(408, f"request body not complete within {BODY_TIMEOUT_S:g} s")
    try:
        state = await state_of.session.request(vehicle_topic(sysid, kind, "set"), payload, state_of.ack_timeout_s)
    except AckTimeout as exc:
        return _error(504, str(exc))
    return JSONResponse(state, status_code=200 if state.get("ok") else 409)


async def index(request: Request) -> Response:
    return FileResponse(STATIC / "index.html")


async def vehicles(request: Request) -> Response:
    return JSONResponse(request.app.state.fleet.summary())


async def vehicle(request: Request) -> Response:
    row = _row_of(request)
    if row is None:
        return _error(404, f"no vehicle {request.path_params['sysid']} on the broker")
    scenario = request.app.state.fleet.scenario_of(row["sysid"])
    return JSONResponse({**row, "world": world_json(scenario) if scenario is not None else None})


async def profiles(request: Request) -> Response:
    cache = request.app.state.library
    if not cache:
        cache.extend(library_json())
    return JSONResponse(cache)


async def estimators_list(request: Request) -> Response:
    import estimators  # numpy/scipy: only when asked

    return JSONResponse(["off", *estimators.names()])


async def estimator_params(request: Request) -> Response:
    cache = request.app.state.estimators
    if not cache:  # imports numpy, scipy and every plugin: off the loop, the streams keep going
        described = await asyncio.to_thread(estimators_json)
        if not cache:  # another request may have filled it meanwhile
            cache.extend(described)
    return JSONResponse(cache)


async def switch(request: Request) -> Response:
    """``POST /api/vehicles/{sysid}/switches/{kind}``: any declared vehicle switch; the body is its request."""
    return await _send(request, request.path_params["kind"])


async def attack(request: Request) -> Response:
    """``POST .../attack``: the ``attack`` switch, with the page's body (a library name, profile text...)."""
    return await _send(request, "attack", profile_request)


async def mode(request: Request) -> Response:
    """``POST .../attack/mode``: the generic route's ``attack/mode``, under its older URL."""
    return await _send(request, "attack/mode")


async def secure(request: Request) -> Response:
    """``POST .../secure``: the generic route's ``secure``, under its older URL."""
    return await _send(request, "secure")


async def stream(request: Request) -> Response:
    try:
        watched = int(request.query_params.get("vehicle", "0"))
    except ValueError:
        return _error(400, "vehicle: must be a sysid")
    if request.method != "GET":  # HEAD: the headers a stream would have, and no slot (nothing will run)
        return Response(status_code=200, media_type="text/event-stream", headers={"Cache-Control": "no-store"})
    state_of = request.app.state
    client = request.client.host if request.client else "?"
    refused = state_of.streams.take(client)
    if refused is not None:
        return _error(429, refused)
    return SlotStream(_updates(request, state_of.fleet, watched, state_of.session),
                      lambda: state_of.streams.give_back(client), ping=15,
                      send_timeout=state_of.stream_send_timeout_s)  # fmt: skip


ROUTES = [
    Route("/", index),
    Route("/api/vehicles", vehicles),
    Route("/api/vehicles/{sysid:int}", vehicle),
    Route("/api/vehicles/{sysid:int}/attack", attack, methods=["POST"]),
    Route("/api/vehicles/{sysid:int}/attack/mode", mode, methods=["POST"]),  # = switches/attack/mode
    Route("/api/vehicles/{sysid:int}/secure", secure, methods=["POST"]),  # = switches/secure
    Route("/api/vehicles/{sysid:int}/switches/{kind:path}", switch, methods=["POST"]),
    Route("/api/library", profiles),
    Route("/api/estimators", estimators_list),
    Route("/api/estimators/params", estimator_params),
    Route("/api/stream", stream),
    Mount("/static", StaticFiles(directory=STATIC), name="static"),
]


def build_app(fleet: Fleet, session: Session, password: str | None = None, ack_timeout_s: float = 5.0,
              hosts: Iterable[str] = LOOPBACK_NAMES, streams: StreamSlots | None = None,
              stream_send_timeout_s: float = STREAM_SEND_TIMEOUT_S) -> ASGIApp:  # fmt: skip
    """The ASGI application behind ``webconsole.security``'s guards (``hosts``: the Host names it answers
    to), and behind :class:`BasicAuth` when a password is given. The handlers above find what they serve
    in ``request.app.state``."""
    app = Starlette(routes=ROUTES)
    app.state.fleet, app.state.session, app.state.ack_timeout_s = fleet, session, ack_timeout_s
    app.state.streams, app.state.stream_send_timeout_s = streams or StreamSlots(), stream_send_timeout_s
    app.state.library, app.state.estimators = [], []  # asked for once, then kept
    return guarded(BasicAuth(app, password) if password else app, hosts, MAX_BODY)


class SlotStream(EventSourceResponse):
    """An event stream that gives its slot back when the response ends, however it ends.

    The slot is tied to the response, not to its generator: a response that never starts
    its generator (a client gone before the first byte) still gives it back. A client that
    stops reading is cut off once one send has waited ``send_timeout`` seconds (its socket
    buffers full), so a stream nobody reads cannot hold its slot either.
    """

    def __init__(self, content: AsyncIterator[dict[str, str]], release: Callable[[], None], **options: Any) -> None:
        super().__init__(content, **options)
        self._release: Callable[[], None] | None = release

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            await super().__call__(scope, receive, send)
        except SendTimeoutError:
            client = (scope.get("client") or ("?", 0))[0]
            stalled.event("console.stream_stalled", client=client, waited_s=self.send_timeout)
        finally:
            release, self._release = self._release, None
            if release is not None:
                release()


stalled = RateLimitedLog(log)


async def _updates(request: Request, fleet: Fleet, watched: int, session: Session) -> AsyncIterator[dict[str, str]]:
    """12.5 updates a second: the fleet table, the watched vehicle's samples since the last one, and whether
    the console reaches its broker (``broker``: ``connected``, ``url``; the page says "live" only then)."""
    broker_url = redact(session.address.url)
    cursor, first = 0, True
    loop = asyncio.get_running_loop()
    due = loop.time()
    while not await request.is_disconnected():
        view = fleet.vehicles.get(watched)
        samples: list[dict[str, Any]] = []
        if view is not None:
            samples = view.since(cursor, time.time() - BACKFILL_S if first else 0.0)
            if samples:
                cursor = samples[-1]["seq"]
            first = False
        payload = {"t": time.time(), "fleet": fleet.summary(), "vehicle": watched, "samples": samples,
                   "broker": {"connected": session.connected.is_set(), "url": broker_url}}
        yield {"event": "update", "data": json.dumps(payload, separators=(",", ":"), allow_nan=False, default=str)}
        due = max(due + STREAM_PERIOD_S, loop.time())  # a fixed schedule: the time spent here does not add up
        await asyncio.sleep(due - loop.time())

