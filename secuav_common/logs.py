"""The services' log format: one greppable event per line, structured fields as key=value (logfmt).

``12:00:01.234 INFO proxy.stats sysid=1 down=120/120 profile="wall spoof"``: the
event name, then its ``extra`` fields; a value with a space, a quote, an ``=``
or nothing in it is quoted, so every line splits the same way. ``--log-json``
writes one JSON object per line instead, for log shippers.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Iterable
from datetime import UTC, datetime
from typing import Any

_STD_ATTRS = set(logging.LogRecord("", 0, "", 0, "", None, None).__dict__) | {"message", "asctime", "taskName"}
_SPECIAL = frozenset('"=\\')


def logfmt_value(value: Any) -> str:
    text = str(value)
    if text and not any(c in _SPECIAL or c.isspace() or not c.isprintable() for c in text):
        return text
    return json.dumps(text, ensure_ascii=False)


def _extras(record: logging.LogRecord) -> dict[str, Any]:
    return {k: v for k, v in record.__dict__.items() if k not in _STD_ATTRS}


class KeyValueFormatter(logging.Formatter):
    """``12:00:01.234 INFO proxy.stats sysid=1 down=120/120 ...``: the event name, then its ``extra`` fields."""

    def format(self, record: logging.LogRecord) -> str:
        stamp = time.strftime("%H:%M:%S", time.localtime(record.created)) + f".{int(record.msecs):03d}"
        extras = " ".join(f"{k}={logfmt_value(v)}" for k, v in _extras(record).items())
        line = f"{stamp} {record.levelname} {record.getMessage()}" + (f" {extras}" if extras else "")
        if record.exc_info:
            line += "\n" + self.formatException(record.exc_info)
        return line


class JsonFormatter(logging.Formatter):
    """One JSON object per line: ``{"ts", "level", "logger", "event", ...extra fields}``."""

    def format(self, record: logging.LogRecord) -> str:
        doc: dict[str, Any] = {
            "ts": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds"),
            "level": record.levelname,
            "logger": record.name,
            "event": record.getMessage(),
            **_extras(record),
        }
        if record.exc_info:
            doc["exception"] = self.formatException(record.exc_info)
        return json.dumps(doc, default=str, ensure_ascii=False)


def setup_logging(verbose: int, quiet: bool, noisy: Iterable[str], *, json_lines: bool = False) -> None:
    """Lines on stderr; INFO by default, ``-q`` warnings only, ``-v`` debug (``-vv`` also ``noisy``)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter() if json_lines else KeyValueFormatter())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO)
    if verbose < 2:
        for name in noisy:
            logging.getLogger(name).setLevel(logging.WARNING)


def version() -> str:
    """The installed secuav version (``unknown`` when run from a tree that was never installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("secuav")
    except PackageNotFoundError:
        return "unknown"


def add_common_flags(parser: argparse.ArgumentParser, *, log_flags: bool = True) -> None:
    """``--version`` on every command; ``--log-json`` on the services."""
    parser.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    if log_flags:
        parser.add_argument("--log-json", action="store_true", help="log one JSON object per line (for log shippers)")


def cli_error(prog: str, message: str, code: int = 2) -> int:
    """Print ``PROG: error: MESSAGE`` on stderr (argparse's shape) and return ``code`` for ``main``."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    return code


class RateLimitedLog:
    """At most one line per event name every ``every_s`` seconds, the rest counted into the next line.

    For events an outsider can make happen at will (a refused connection, an evicted
    client): the first one is logged at once, and while they keep coming, one line
    every ``every_s`` says how many there were (``count``: since the last line).
    ``totals`` keeps every event's count for stats and tests.
    """

    def __init__(self, logger: logging.Logger, every_s: float = 10.0, clock: Any = time.monotonic) -> None:
        self.logger, self.every_s, self.clock = logger, every_s, clock
        self.totals: dict[str, int] = {}
        self.lines = 0  # lines written: what the rate limit keeps small
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def event(self, name: str, level: int = logging.WARNING, **fields: Any) -> bool:
        """Count one ``name``; log it (with ``count``) unless a line for it went out less than ``every_s`` ago."""
        self.totals[name] = self.totals.get(name, 0) + 1
        held = self._held.get(name, 0) + 1
        now = self.clock()
        last = self._last.get(name)
        if last is not None and now - last < self.every_s:
            self._held[name] = held
            return False
        self._last[name], self._held[name] = now, 0
        self.lines += 1
        self.logger.log(level, name, extra={**fields, "count": held})
        return True
