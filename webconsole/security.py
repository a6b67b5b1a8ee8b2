"""What keeps a web page the operator happens to visit from steering a vehicle (docs/security.md).

The console is a local web app: any page open in the same browser can send it
requests, and a DNS-rebinding name can even make the browser believe it *is*
the console's origin. Four layers, outermost first:

- **Host allow-list** (Starlette's ``TrustedHostMiddleware``): a request whose
  ``Host`` is not the listen address, ``localhost``, a loopback address or an
  ``--allowed-host`` gets 400 before anything else runs. A rebinding page sends
  its own name as ``Host``, so it never reaches the API.
- **Cross-site guard** (:class:`CrossSiteGuard`), for every request that can
  change something (any method but GET, HEAD, OPTIONS): a browser's
  ``Sec-Fetch-Site`` must say ``same-origin`` (or ``none``: typed by the user),
  an ``Origin`` must be the console's own, and the body must be declared
  ``application/json``. A cross-site HTML form can only send form encodings or
  ``text/plain``, and a script on another origin cannot send
  ``application/json`` without a CORS preflight that this app never answers,
  so none of them reaches a handler, with or without cached credentials.
  Scripts (curl, urllib) send neither header and pass with the right type. We
  use these checks instead of a cookie token because the API is also for
  scripts, which have no cookie jar, and the checks need no state.
- **Body cap**: a declared ``Content-Length`` over the cap is refused with 413
  before one byte is read (a chunked body is counted as it is read, in
  ``webconsole.api``, and refused at the cap).
- **Security headers** on every answer: a content security policy with no
  inline script (and no framing), ``nosniff``, no referrer.
"""

from __future__ import annotations

from collections.abc import Iterable

from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; connect-src 'self'; "
       "object-src 'none'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'")  # fmt: skip
SECURITY_HEADERS: list[tuple[bytes, bytes]] = [
    (b"content-security-policy", CSP.encode()),
    (b"x-frame-options", b"DENY"),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"cross-origin-opener-policy", b"same-origin"),
    (b"cross-origin-resource-policy", b"same-origin"),
]
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1", "[::1]")


def allowed_hosts(listen_host: str, extra: Iterable[str] = ()) -> list[str]:
    """The ``Host`` names the console answers to: its listen address, loopback names, and ``--allowed-host``."""
    hosts = [*LOOPBACK_NAMES, *extra]
    if listen_host not in ("0.0.0.0", "::", ""):  # a wildcard bind has no name of its own: say it with --allowed-host
        hosts.append(f"[{listen_host}]" if ":" in listen_host else listen_host)
    return sorted(set(hosts))


async def _refuse(scope: Scope, receive: Receive, send: Send, status: int, error: str) -> None:
    await JSONResponse({"ok": False, "error": error, "field": None}, status_code=status)(scope, receive, send)


class CrossSiteGuard:
    """Refuse state-changing requests a browser made for another site, and bodies over ``max_body`` bytes."""

    def __init__(self, app: ASGIApp, max_body: int) -> None:
        self.app = app
        self.max_body = max_body

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] in SAFE_METHODS:
            await self.app(scope, receive, send)
            return
        headers = {k.lower(): v for k, v in scope["headers"]}
        refusal = self._refusal(scope, headers)
        if refusal is not None:
            await _refuse(scope, receive, send, *refusal)
            return
        await self.app(scope, receive, send)

    def _refusal(self, scope: Scope, headers: dict[bytes, bytes]) -> tuple[int, str] | None:
        fetch_site = headers.get(b"sec-fetch-site", b"").decode("latin-1").lower()
        if fetch_site and fetch_site not in ("same-origin", "none"):
            return 403, f"cross-site request refused (Sec-Fetch-Site: {fetch_site})"
        origin = headers.get(b"origin")
        if origin is not None:
            own = f"{scope.get('scheme', 'http')}://{headers.get(b'host', b'').decode('latin-1')}"
            if origin.decode("latin-1").lower() != own.lower():
                return 403, f"cross-origin request refused (Origin: {origin.decode('latin-1')[:100]})"
        media = headers.get(b"content-type", b"").split(b";")[0].strip().lower()
        if media != b"application/json":
            return 415, "state-changing requests must send Content-Type: application/json"
        length = headers.get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > self.max_body):
            return 413, f"request body larger than {self.max_body} bytes"
        return None


class SecurityHeaders:
    """Add :data:`SECURITY_HEADERS` to every HTTP answer."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", []), *SECURITY_HEADERS]}
            await send(message)

        await self.app(scope, receive, with_headers)


def guarded(app: ASGIApp, hosts: Iterable[str], max_body: int) -> ASGIApp:
    """``app`` behind the layers of this module, outermost first: headers, Host, cross-site and size checks."""
    inner = CrossSiteGuard(app, max_body)
    return SecurityHeaders(TrustedHostMiddleware(inner, allowed_hosts=list(hosts)))
