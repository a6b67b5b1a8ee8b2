"""Shared fixtures: loopback ports that nobody else is using."""

from __future__ import annotations

import socket
from collections.abc import Callable

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
