"""The embedded broker: started when the port is free; someone else's broker is reused, with a warning."""

from __future__ import annotations

import logging

import pytest

from secuav_common.broker import EmbeddedBroker
from tests.conftest import free_tcp_port


async def test_a_broker_already_there_is_reused_and_said_so(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, "secuav_common.broker")
    port = free_tcp_port()
    async with EmbeddedBroker(port=port) as first:
        assert first.started
        async with EmbeddedBroker(port=port) as second:
            assert not second.started
    warnings = [r for r in caplog.records if r.getMessage() == "broker.reuse"]
    assert len(warnings) == 1 and warnings[0].levelno == logging.WARNING
    assert f"127.0.0.1:{port}" in warnings[0].__dict__["url"]
