"""``secuav-console``: the live web console (see ``webconsole.api`` for what it serves).

    secuav-console                                   # 127.0.0.1:8080, embedded broker on 127.0.0.1:1883
    secuav-console --broker-port 1884                # its own broker on 127.0.0.1:1884 (a shared host)
    secuav-console --scenario wall_hover --broker mqtt://127.0.0.1:1883
    secuav-console --listen 0.0.0.0:8443 --password-file console.pw --tls-cert c.pem --tls-key k.pem \
                   --allowed-host console.lab.example

It binds 127.0.0.1 by default; on any other address it refuses to start
without a password of at least 12 characters (``--password-file`` or
``SECUAV_CONSOLE_PASSWORD``), which the browser then asks for (HTTP Basic) and
scripts send as a Bearer token, and without TLS (``--tls-cert``/``--tls-key``)
unless told ``--insecure-http``. It answers only to the Host names it knows:
its listen address, loopback names and each ``--allowed-host`` (docs/security.md).
Forwarded headers (``X-Forwarded-For``) are believed only from a ``--trusted-proxy``.
Stops cleanly on Ctrl-C or SIGTERM: the console's online record says offline
and the proxies stop publishing readings.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import ipaddress
import logging
import os
import signal
import socket
import sys
from collections.abc import Sequence
from pathlib import Path

from secuav_common.broker import EmbeddedBroker, parse_broker_url, redact, secret_or_env
from secuav_common.controlplane.address import with_port
from secuav_common.extras import require
from secuav_common.loading import InputError
from secuav_common.logs import add_common_flags, cli_error, setup_logging
from secuav_common.ports import MQTT_PORT
from secuav_common.scenario import load_scenario

PROG = "secuav-console"
DEFAULT_LISTEN = "127.0.0.1:8080"
MIN_PASSWORD = 12
log = logging.getLogger(PROG)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="Watch and steer SecUAV attacks live in a browser.")
    add_common_flags(p)
    p.add_argument("--listen", default=DEFAULT_LISTEN, metavar="HOST:PORT",
                   help=f"where the page is served (default {DEFAULT_LISTEN}; another address needs a password)")
    p.add_argument("--broker", default="embedded", metavar="URL",
                   help="embedded (default: amqtt on 127.0.0.1:1883 or --broker-port, or the broker already there) "
                   "or mqtt://HOST:PORT")
    p.add_argument("--broker-port", type=int, metavar="N",
                   help="the broker's port: --broker embedded starts it on 127.0.0.1:N (default 1883), "
                   "a --broker URL without a port gets N")
    p.add_argument("--broker-username", metavar="NAME",
                   help="broker account; with --broker embedded that broker then admits this account only")
    p.add_argument("--broker-password-file", metavar="F", type=Path,
                   help="broker password from F (mode 600); SECUAV_BROKER_PASSWORD works too")
    p.add_argument("--scenario", action="append", default=[], metavar="F",
                   help="scenario file or bundled name, for the top view and true readings (repeatable)")
    p.add_argument("--password-file", metavar="F", type=Path,
                   help="password for the page and API (mode 600); SECUAV_CONSOLE_PASSWORD works too")
    p.add_argument("--allowed-host", action="append", default=[], metavar="NAME",
                   help="a further Host name the console answers to (repeatable; loopback names always work)")
    p.add_argument("--tls-cert", metavar="F", type=Path, help="serve HTTPS with this certificate (PEM)")
    p.add_argument("--tls-key", metavar="F", type=Path, help="the certificate's private key (PEM)")
    p.add_argument("--trusted-proxy", action="append", default=[], metavar="ADDR",
                   help="a reverse proxy (address or network) whose X-Forwarded-For/-Proto headers are believed "
                        "(repeatable; from anyone else they are ignored)")
    p.add_argument("--insecure-http", action="store_true",
                   help="beyond loopback, serve plain HTTP anyway (the password then crosses the network in clear)")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    p.add_argument("-q", "--quiet", action="store_true", help="warnings and errors only")
    return p  # fmt: skip


def parse_listen(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"--listen {text!r}: expected HOST:PORT, e.g. {DEFAULT_LISTEN}")
    return host.strip("[]") or "127.0.0.1", int(port)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


async def serve(args: argparse.Namespace, host: str, port: int, password: str | None,
                broker_password: str | None) -> int:  # fmt: skip
    import uvicorn

    from webconsole.api import build_app
    from webconsole.connections import quiet_accept_errors, raise_file_limit, server_config
    from webconsole.fleet import Fleet, Session
    from webconsole.security import allowed_hosts

    scenarios = [load_scenario(s) for s in args.scenario]
    try:  # bound here, before anything starts: a busy port is one line, not uvicorn's traceback
        listener = socket.create_server((host, port), family=socket.AF_INET6 if ":" in host else socket.AF_INET,
                                        backlog=2048)  # fmt: skip
    except OSError as exc:
        why = os.strerror(exc.errno) if exc.errno else str(exc)
        return _fail(f"cannot serve on {host}:{port}: {why} (another program listens there? "
                     "choose another with --listen HOST:PORT)", 1)  # fmt: skip
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    async with contextlib.AsyncExitStack() as stack:
        if args.broker == "embedded":
            embedded = EmbeddedBroker(port=args.broker_port or MQTT_PORT, username=args.broker_username,
                                      password=broker_password)  # fmt: skip
            broker = await stack.enter_async_context(embedded)
            address = broker.address
        else:
            address = parse_broker_url(with_port(args.broker, args.broker_port))
        scheme = "https" if args.tls_cert else "http"
        url = f"{scheme}://{host if ':' not in host else f'[{host}]'}:{port}/"
        fleet = Fleet(scenarios)
        session = Session(address, fleet, url, username=args.broker_username, password=broker_password)
        mqtt = asyncio.create_task(session.run(), name="console-mqtt")
        app = build_app(fleet, session, password, hosts=allowed_hosts(host, args.allowed_host))
        tls = {"ssl_certfile": str(args.tls_cert), "ssl_keyfile": str(args.tls_key)} if args.tls_cert else {}
        raise_file_limit()
        quiet_accept_errors(loop)
        server = uvicorn.Server(server_config(app, host, port, trusted_proxies=args.trusted_proxy, **tls))
        server.install_signal_handlers = lambda: None  # type: ignore[method-assign]  # ours above
        web = asyncio.create_task(server.serve(sockets=[listener]), name="console-http")
        await asyncio.sleep(0)
        while not server.started and not web.done():
            await asyncio.sleep(0.05)
        if web.done():  # the TLS files did not load, say
            mqtt.cancel()
            return _fail(f"cannot serve on {host}:{port}: {web.exception() or 'the server stopped at start'}", 1)
        log.info("console.ready", extra={"url": url, "broker": redact(address.url),
                                         "auth": "password" if password else "none (loopback only)",
                                         "tls": bool(args.tls_cert),
                                         "scenarios": ",".join(s.name for s in scenarios) or "none"})  # fmt: skip
        print(f"{PROG}: {url}", file=sys.stderr, flush=True)
        await stop.wait()
        await session.aclose()
        server.should_exit = True
        mqtt.cancel()
        await asyncio.wait([web, mqtt], timeout=3.0)
    return 0


def _fail(message: str, code: int = 2) -> int:
    return cli_error(PROG, message, code)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    require("secuav-console")
    try:
        host, port = parse_listen(args.listen)
        if args.broker_port is not None and not 0 < args.broker_port < 65536:
            raise ValueError(f"--broker-port {args.broker_port}: outside 1..65535")
        if args.broker != "embedded":
            parse_broker_url(with_port(args.broker, args.broker_port))
        for name in args.scenario:
            load_scenario(name)
        password = secret_or_env(args.password_file, "--password-file", "SECUAV_CONSOLE_PASSWORD")
        broker_password = secret_or_env(args.broker_password_file, "--broker-password-file")
    except (InputError, ValueError) as exc:
        return _fail(str(exc))
    for proxy in args.trusted_proxy:
        try:
            ipaddress.ip_network(proxy, strict=False)
        except ValueError:
            return _fail(f"--trusted-proxy {proxy}: expected an IP address or network (e.g. 127.0.0.1, 10.0.0.0/8)")
    if bool(args.tls_cert) != bool(args.tls_key):
        return _fail("--tls-cert and --tls-key go together")
    for flag, path in (("--tls-cert", args.tls_cert), ("--tls-key", args.tls_key)):
        if path is not None and not path.is_file():
            return _fail(f"{flag} {path}: no such file")
    if not is_loopback(host) and not password:
        return _fail(f"--listen {args.listen}: serving beyond this machine needs a password "
                     "(--password-file F or SECUAV_CONSOLE_PASSWORD)")  # fmt: skip
    if password is not None and len(password) < MIN_PASSWORD:
        return _fail(f"the console password is {len(password)} characters long; use at least {MIN_PASSWORD}")
    if not is_loopback(host) and not args.tls_cert and not args.insecure_http:
        return _fail(f"--listen {args.listen}: serving beyond this machine needs TLS (--tls-cert F --tls-key F; "
                     "docs/security.md says how to make one), or --insecure-http to send the password in clear")
    setup_logging(args.verbose, args.quiet, noisy=("aiomqtt", "asyncio", "amqtt", "transitions", "uvicorn"),
                  json_lines=args.log_json)  # fmt: skip
    try:
        return asyncio.run(serve(args, host, port, password, broker_password))
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
