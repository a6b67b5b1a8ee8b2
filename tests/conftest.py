"""Shared fixtures: loopback ports that nobody else is using; every test leaves the logging set-up as it found it."""

from __future__ import annotations

import logging
import socket
from collections.abc import Callable, Iterator

import pytest


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that was free a moment ago."""
    return _free_port(socket.SOCK_DGRAM)


def free_tcp_port() -> int:
    return _free_port(socket.SOCK_STREAM)


@pytest.fixture
def udp_port() -> Callable[[], int]:
    return free_udp_port


@pytest.fixture
def tcp_port() -> Callable[[], int]:
    return free_tcp_port


@pytest.fixture(autouse=True)
def _logging_as_found() -> Iterator[None]:
    """A command's ``main()`` run in-process sets up logging for the whole process (secuav_common.logs): its
    handler writes to the stderr of that moment, a test's capture, and replaces pytest's own. Undone after each
    test (pytest's capture handlers come and go per phase and are left to it), so the next test logs where
    pytest expects."""
    root = logging.getLogger()
    before, level = set(root.handlers), root.level
    levels = {name: lg.level for name, lg in logging.root.manager.loggerDict.items() if isinstance(lg, logging.Logger)}
    yield
    for handler in root.handlers[:]:
        if handler not in before and not type(handler).__module__.startswith("_pytest"):
            root.removeHandler(handler)
    root.setLevel(level)
    for name, lg in logging.root.manager.loggerDict.items():
        if isinstance(lg, logging.Logger) and name in levels:
            lg.setLevel(levels[name])
