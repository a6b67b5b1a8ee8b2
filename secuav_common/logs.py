"""The services' log format: one greppable event per line, structured fields as key=value."""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterable

_STD_ATTRS = set(logging.LogRecord("", 0, "", 0, "", None, None).__dict__) | {"message", "asctime"}


class KeyValueFormatter(logging.Formatter):
    """``12:00:01.234 INFO proxy.stats sysid=1 down=120/120 ...``: the event name, then its ``extra`` fields."""

    def format(self, record: logging.LogRecord) -> str:
        stamp = time.strftime("%H:%M:%S", time.localtime(record.created)) + f".{int(record.msecs):03d}"
        extras = " ".join(f"{k}={v}" for k, v in record.__dict__.items() if k not in _STD_ATTRS)
        line = f"{stamp} {record.levelname} {record.getMessage()}" + (f" {extras}" if extras else "")
        if record.exc_info:
            line += "\n" + self.formatException(record.exc_info)
        return line


def setup_logging(verbose: int, quiet: bool, noisy: Iterable[str]) -> None:
    """Key=value lines on stderr; INFO by default, ``-q`` warnings only, ``-v`` debug (``-vv`` also ``noisy``)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(KeyValueFormatter())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO)
    if verbose < 2:
        for name in noisy:
            logging.getLogger(name).setLevel(logging.WARNING)
