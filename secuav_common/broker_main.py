"""The embedded MQTT broker as its own process: ``python -m secuav_common.broker_main HOST PORT [USERNAME]``.

A service that embeds the broker (``secuav-proxy --broker embedded``) runs it
here, not on its own event loop: amqtt then cannot take the forwarding loop's
time, however many clients flood it, and on a multi-core machine it runs beside
the proxy. The process prints ``ready`` once it listens, and stops on SIGTERM,
SIGINT, or when its standard input closes (the parent is gone, even killed).
With a USERNAME only that account gets in, with the password from the
environment variable ``SECUAV_EMBEDDED_BROKER_PASSWORD``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import sys

from secuav_common.broker import PASSWORD_ENV, amqtt_config, quiet_amqtt


async def serve(host: str, port: int, username: str | None = None) -> int:
    from secuav_common.broker_cap import CappedBroker

    quiet_amqtt()
    # Nothing reads this process's stderr once it is ready: no warning may go there (a full pipe would stop it).
    logging.getLogger().addHandler(logging.NullHandler())
    broker = CappedBroker(amqtt_config(host, port, username, os.environ.get(PASSWORD_ENV) if username else None))
    await broker.start()
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)

    class ParentGone(asyncio.Protocol):
        def connection_lost(self, exc: Exception | None) -> None:
            stop.set()

    await loop.connect_read_pipe(ParentGone, sys.stdin)
    print("ready", flush=True)
    await stop.wait()
    with contextlib.suppress(Exception):
        await asyncio.wait_for(broker.shutdown(), timeout=3.0)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) not in (2, 3) or not args[1].isdigit():
        print("usage: python -m secuav_common.broker_main HOST PORT [USERNAME]", file=sys.stderr)
        return 2
    job = serve(args[0], int(args[1]), args[2] if len(args) == 3 else None)
    try:
        import uvloop
    except ImportError:
        return asyncio.run(job)
    return uvloop.run(job)


if __name__ == "__main__":
    sys.exit(main())
