"""MQTT payloads are capped before they are read (issue 36, finding 3): the embedded broker, our clients, and
the compose stack's mosquitto with its ACL. Real brokers on loopback; each test failed before issue 36.

The review: one retained 30 MB message on ``secuav/console/<x>/online`` (which
the ``viewer`` account could publish) took every proxy from 66 to 160 MB.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import re
import subprocess
import warnings
from pathlib import Path

import aiomqtt
import pytest

from secuav_common.broker import EmbeddedBroker, amqtt_config
from secuav_common.controlplane.address import BrokerAddress
from secuav_common.controlplane.payloads import MAX_PACKET_BYTES
from secuav_common.controlplane.session import Session
from tests.conftest import free_tcp_port
from tests.support.brokers import Mosquitto, needs_mosquitto

pytestmark = pytest.mark.timeout(60)
REPO = Path(__file__).resolve().parents[2]
BIG = b"x" * (4 * MAX_PACKET_BYTES)  # ~1 MB: enough to show, small enough for a quick test


async def _heard(port: int, topic: str, seconds: float, last: str = "", **account: str) -> list[tuple[str, int]]:
    """(topic, size) of every message a fresh subscriber to ``topic`` gets (retained first) within ``seconds``
    or until one on ``last`` came."""
    got: list[tuple[str, int]] = []
    async with aiomqtt.Client("127.0.0.1", port, **account) as client:  # type: ignore[arg-type]
        await client.subscribe(topic)
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(seconds):
                async for message in client.messages:
                    got.append((str(message.topic), len(bytes(message.payload))))  # type: ignore[arg-type]
                    if got[-1][0] == last:
                        break
    return got


async def _publish(port: int, topic: str, payload: bytes, retain: bool = True, **account: str) -> bool:
    """Publish once (QoS 1); False when the broker cut the connection instead of acknowledging."""
    try:
        async with aiomqtt.Client("127.0.0.1", port, timeout=2, **account) as client:  # type: ignore[arg-type]
            await client.publish(topic, payload, qos=1, retain=retain)
        return True
    except aiomqtt.MqttError:
        return False


@pytest.mark.parametrize("process", [False, True], ids=["in-loop", "child-process"])
async def test_the_embedded_broker_never_reads_an_oversized_message(process: bool) -> None:
    port = free_tcp_port()
    async with EmbeddedBroker(port=port, process=process):
        watcher = asyncio.create_task(_heard(port, "secuav/console/+/online", 20, "secuav/console/ok/online"))
        await asyncio.sleep(0.5)
        assert not await _publish(port, "secuav/console/evil/online", BIG)  # cut off at its fixed header
        assert await _publish(port, "secuav/console/ok/online", b'{"online": true}')  # the broker is fine
        assert await watcher == [("secuav/console/ok/online", 16)]
        assert set(await _heard(port, "secuav/console/+/online", 0.5)) == {("secuav/console/ok/online", 16)}  # kept


async def test_our_client_drops_an_oversized_packet_unread_from_a_broker_without_a_limit(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Behind a broker that takes anything (amqtt as it comes), a SecUAV session still never holds a big message:
    it drops the connection on the packet's header, says so once, reconnects, and goes on."""
    from amqtt.broker import Broker

    caplog.set_level(logging.INFO, logger="test.session")
    port = free_tcp_port()
    broker = Broker(amqtt_config("127.0.0.1", port))
    await broker.start()
    got: list[int] = []
    session = Session(BrokerAddress("127.0.0.1", port), backoff_s=(0.1, 0.2), log=logging.getLogger("test.session"))

    async def serve(client: aiomqtt.Client) -> None:
        await client.subscribe("secuav/console/+/online")
        session.mark_connected()
        async for message in client.messages:
            got.append(len(bytes(message.payload)))  # type: ignore[arg-type]

    task = asyncio.create_task(session.run(serve))
    try:
        await asyncio.wait_for(session.connected.wait(), 10)
        assert await _publish(port, "secuav/console/evil/online", BIG, retain=False)  # this broker takes it
        for _ in range(100):
            if session.connections >= 2:
                break
            await asyncio.sleep(0.1)
        assert session.connections >= 2  # dropped on the big packet's header, and back
        assert await _publish(port, "secuav/console/ok/online", b"{}", retain=False)
        for _ in range(50):
            if got:
                break
            await asyncio.sleep(0.1)
        assert got == [2]
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await broker.shutdown()
    said = [r for r in caplog.records if r.getMessage() == "mqtt.packet_too_large"]
    assert len(said) == 1 and said[0].bytes > MAX_PACKET_BYTES  # type: ignore[attr-defined]


@pytest.mark.mosquitto
@needs_mosquitto
async def test_the_compose_broker_caps_packets_and_the_viewer_publishes_nothing(tmp_path: Path) -> None:
    secrets = tmp_path / "secrets"
    env = {**os.environ, "SECUAV_SECRETS_DIR": str(secrets)}
    subprocess.run(["bash", str(REPO / "docker" / "users.sh")], env=env, check=True, capture_output=True, timeout=60)
    pw = {name: (secrets / name).read_text().strip() for name in ("operator", "viewer")}
    conf = (REPO / "docker" / "mosquitto.conf").read_text()
    limits = "".join(f"{m.group(0)}\n" for m in re.finditer(r"^(max_packet_size|message_size_limit) \d+$", conf, re.M))
    assert "max_packet_size" in limits
    port = free_tcp_port()
    extra = f"password_file {secrets / 'mosquitto.passwd'}\nacl_file {REPO / 'docker' / 'mosquitto.acl'}\n{limits}"
    operator = {"username": "operator", "password": pw["operator"]}
    viewer = {"username": "viewer", "password": pw["viewer"]}
    with Mosquitto(port, tmp_path, extra=extra):
        watcher = asyncio.create_task(_heard(port, "secuav/console/+/online", 20, "secuav/console/op/online",
                                             **operator))  # fmt: skip
        await asyncio.sleep(0.5)
        await _publish(port, "secuav/console/viewer/online", b'{"online": true}', **viewer)  # the ACL drops it
        assert not await _publish(port, "secuav/console/big/online", BIG, **operator)  # cut off, even an operator
        assert await _publish(port, "secuav/console/op/online", b'{"online": true}', **operator)
        assert await watcher == [("secuav/console/op/online", 16)]
        assert set(await _heard(port, "secuav/console/+/online", 0.5, **viewer)) == {("secuav/console/op/online", 16)}


async def test_the_subscription_table_survives_a_subscribe_during_a_loop_that_awaits() -> None:
    """amqtt walks its subscription table with awaits inside the loop; a new topic arriving meanwhile raised
    "dictionary changed size during iteration" in a plain dict. The embedded broker's table walks a copy."""
    from secuav_common.broker_cap import CappedBroker, SnapshotDict

    plain: dict[str, list[object]] = {"a": [], "b": []}
    with pytest.raises(RuntimeError, match="changed size"):
        for _topic in plain:
            await asyncio.sleep(0)
            plain["c"] = []
    table = SnapshotDict({"a": [], "b": []})
    walked = []
    for topic in table:
        await asyncio.sleep(0)
        table[f"new-{topic}"] = []
        walked.append(topic)
    for topic, _subs in table.items():
        table.pop(topic)
    assert walked == ["a", "b"] and table == {}
    with warnings.catch_warnings():  # amqtt's own DeprecationWarning about psutil, not ours
        warnings.simplefilter("ignore", DeprecationWarning)
        broker = CappedBroker({"listeners": {"default": {"type": "tcp", "bind": "127.0.0.1:0"}}})
    assert isinstance(broker._subscriptions, SnapshotDict)
