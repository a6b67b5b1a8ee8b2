"""The embedded broker: started when the port is free; someone else's broker is reused, with a warning."""

from __future__ import annotations

import logging

import pytest

from secuav_common.broker import EmbeddedBroker, admits
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
    assert warnings[0].__dict__["users"].startswith("none online")  # nobody's online record on it


async def test_the_proxys_broker_runs_in_its_own_process_and_dies_with_its_parent(tmp_path: object) -> None:
    """``process=True`` (what ``secuav-proxy --broker embedded`` uses): a real broker in a child process that
    clients use as any other, and that stops when its parent is killed outright, freeing the port."""
    import asyncio
    import subprocess
    import sys
    import time

    import aiomqtt

    from secuav_common.broker import port_in_use

    port = free_tcp_port()
    async with EmbeddedBroker(port=port, process=True) as broker:
        assert broker.started and broker._child is not None and broker._child.pid
        async with aiomqtt.Client("127.0.0.1", port) as a, aiomqtt.Client("127.0.0.1", port) as b:
            await b.subscribe("t")
            await a.publish("t", b"hello")
            async with asyncio.timeout(5):
                message = await anext(aiter(b.messages))
            assert message.payload == b"hello"
    assert not port_in_use("127.0.0.1", port)  # a clean stop frees the port

    # A parent killed with SIGKILL cannot stop its child: the child notices its stdin closing.
    parent = subprocess.Popen([sys.executable, "-c", (
        "import asyncio, sys\n"
        "from secuav_common.broker import EmbeddedBroker\n"
        "async def main():\n"
        f"    async with EmbeddedBroker(port={port}, process=True):\n"
        "        print('up', flush=True)\n"
        "        await asyncio.sleep(3600)\n"
        "asyncio.run(main())\n")], stdout=subprocess.PIPE)  # fmt: skip
    assert parent.stdout is not None and parent.stdout.readline().strip() == b"up"
    assert port_in_use("127.0.0.1", port)
    parent.kill()
    parent.wait(10)
    deadline = time.monotonic() + 10
    while port_in_use("127.0.0.1", port):
        assert time.monotonic() < deadline, "the orphaned broker is still listening"
        await asyncio.sleep(0.1)


@pytest.mark.parametrize("process", [False, True], ids=["on-this-loop", "child-process"])
async def test_with_an_account_only_that_account_gets_in(process: bool) -> None:
    port = free_tcp_port()
    async with EmbeddedBroker(port=port, process=process, username="op", password="two words") as broker:
        assert broker.started
        assert not await admits("127.0.0.1", port, None, None)
        assert not await admits("127.0.0.1", port, "op", "wrong")
        assert not await admits("127.0.0.1", port, "other", "two words")
        assert await admits("127.0.0.1", port, "op", "two words")


async def test_an_anonymous_broker_is_not_reused_when_credentials_are_configured() -> None:
    port = free_tcp_port()
    async with EmbeddedBroker(port=port):
        with pytest.raises(OSError, match="lets anyone in without a password"):
            async with EmbeddedBroker(port=port, username="op", password="pw"):
                pass
    checking = EmbeddedBroker(port=port, username="op", password="pw")
    async with checking, EmbeddedBroker(port=port, username="op", password="pw") as again:  # it checks: reused
        assert checking.started and not again.started

