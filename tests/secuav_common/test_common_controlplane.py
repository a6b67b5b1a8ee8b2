"""The control plane's one home: the topic grammar, payload decoding, the session's TLS, request/acknowledge.

The grammar is checked against docs/interfaces.md's topics spelled out by hand
and by a property test (every topic the builders write parses back to what
built it); the session against a real amqtt broker that speaks only TLS, with
the simulator's truth publisher as the client (``mqtts://`` must mean TLS).
"""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from secuav_common.controlplane.address import parse_broker_url
from secuav_common.controlplane.payloads import PayloadError, decode, loads_request, request_bytes, validate
from secuav_common.controlplane.requests import Acks, AckTimeout
from secuav_common.controlplane.session import Session
from secuav_common.controlplane.topics import (
    ANY,
    CONSOLES_ONLINE,
    INSTANCES_ONLINE,
    PROXY_ONLINE,
    Topic,
    build,
    console_topic,
    parse,
    proxy_topic,
    vehicle_topic,
)

OPENSSL = shutil.which("openssl")

# Every topic of docs/interfaces.md, as a user would type it, and what it means.
DOCUMENTED = {
    "secuav/v3/attack/set": Topic("vehicle", "v3", "attack", "set"),
    "secuav/v3/attack/state": Topic("vehicle", "v3", "attack", "state"),
    "secuav/v3/attack/mode/set": Topic("vehicle", "v3", "attack/mode", "set"),
    "secuav/v3/attack/mode/state": Topic("vehicle", "v3", "attack/mode", "state"),
    "secuav/v3/secure/set": Topic("vehicle", "v3", "secure", "set"),
    "secuav/v3/secure/state": Topic("vehicle", "v3", "secure", "state"),
    "secuav/v3/stats": Topic("vehicle", "v3", "stats"),
    "secuav/v3/estimate": Topic("vehicle", "v3", "estimate"),
    "secuav/v3/truth": Topic("vehicle", "v3", "truth"),
    "secuav/v3/readings": Topic("vehicle", "v3", "readings"),
    "secuav/proxy/lab-1/online": Topic("proxy", "lab-1", "online"),
    "secuav/proxy/routes/set": Topic("proxy", None, "routes", "set"),
    "secuav/proxy/lab-1/routes/set": Topic("proxy", "lab-1", "routes", "set"),
    "secuav/proxy/lab-1/routes/state": Topic("proxy", "lab-1", "routes", "state"),
    "secuav/console/c1/online": Topic("console", "c1", "online"),
    "secuav/proxy/online": Topic("proxy", None, "online"),
}


def test_every_documented_topic_parses_and_is_built_back_byte_for_byte() -> None:
    for topic, meaning in DOCUMENTED.items():
        assert parse(topic) == meaning, topic
        assert build(meaning.scope, meaning.key, meaning.leaf, meaning.verb) == topic
    assert parse("secuav/v3/attack/set").sysid == 3 and parse("secuav/v300/attack/set").sysid is None  # type: ignore[union-attr]
    assert vehicle_topic(3, "attack/mode", "state") == "secuav/v3/attack/mode/state"
    assert proxy_topic(None, "routes", "set") == "secuav/proxy/routes/set"
    assert console_topic("c1") == "secuav/console/c1/online"
    assert (PROXY_ONLINE, INSTANCES_ONLINE, CONSOLES_ONLINE) == (
        "secuav/proxy/online", "secuav/proxy/+/online", "secuav/console/+/online")  # fmt: skip
    assert vehicle_topic(ANY, "attack", "state") == "secuav/+/attack/state"


@pytest.mark.parametrize("foreign", ["other/v1/attack/set", "secuav/v1", "secuav//attack/set", "secuav/v1/a/b/c/set",
                                     "secuav/proxy/a/b/c", "secuav/v1/set", ""])  # fmt: skip
def test_what_is_not_ours_parses_to_none(foreign: str) -> None:
    assert parse(foreign) is None


LEVEL = st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789_.-", min_size=1, max_size=12).filter(
    lambda s: s not in ("set", "state", "proxy", "console")
)


@given(
    scope=st.sampled_from(["vehicle", "proxy", "console"]),
    key=LEVEL,
    leaf=st.one_of(LEVEL, st.tuples(LEVEL, LEVEL).map("/".join)),
    verb=st.sampled_from([None, "set", "state"]),
)
def test_a_built_topic_parses_back_to_its_parts(scope: str, key: str, leaf: str, verb: str | None) -> None:
    if scope != "vehicle":
        leaf = leaf.split("/")[0]  # proxy and console leaves have one level
    topic = build(scope, key, leaf, verb)  # type: ignore[arg-type]
    assert parse(topic) == Topic(scope, key, leaf, verb)  # type: ignore[arg-type]


def test_a_message_that_does_not_fit_its_topic_names_topic_field_and_value() -> None:
    with pytest.raises(PayloadError, match=r"secuav/v1/attack/state: ok: .*\(got \"perhaps\"\)"):
        decode("secuav/v1/attack/state", b'{"sysid": 1, "ok": "perhaps"}')
    with pytest.raises(PayloadError, match="secuav/v1/truth: pos_ned_m"):
        decode("secuav/v1/truth", b'{"pos_ned_m": [1, 2]}')
    with pytest.raises(PayloadError, match="not JSON"):
        decode("secuav/v1/stats", b"{")
    with pytest.raises(PayloadError, match="larger than"):
        decode("secuav/v1/readings", b" " * (300 * 1024))
    state = validate("secuav/v1/attack/mode/state", {"sysid": 1, "mode": "bypass", "new_field": 1})
    assert state.mode == "bypass" and state.model_extra == {"new_field": 1}  # newer proxies may add fields
    assert validate("secuav/proxy/online", True) is True
    assert validate("secuav/v1/unknown-leaf", {"x": 1}) == {"x": 1}  # no model: passed on as it is


def test_a_request_leads_with_its_id_and_reads_back() -> None:
    raw = request_bytes({"mode": "on"}, "r1")
    assert raw == b'{"request_id": "r1", "mode": "on"}'
    assert loads_request(raw) == ({"request_id": "r1", "mode": "on"}, "r1")
    assert request_bytes(None, "r2") == b'{"request_id": "r2"}'


async def test_an_acknowledgement_resolves_only_its_own_request_on_a_state_topic() -> None:
    acks = Acks("t-")

    class Loopback:
        """Publishing answers at once, as a proxy would, on the state topic next to the set topic."""

        async def publish(self, topic: str, payload: bytes, qos: int = 0) -> None:
            body = json.loads(payload)
            asyncio.get_running_loop().call_soon(acks.feed, topic, {"request_id": "other", "ok": True})
            if "silent" not in topic:
                state = topic.removesuffix("/set") + "/state"
                asyncio.get_running_loop().call_soon(acks.feed, topic, body)  # the request itself is no answer
                asyncio.get_running_loop().call_soon(acks.feed, state, {**body, "ok": True})

    state = await acks.request(Loopback(), "secuav/v1/attack/mode/set", {"mode": "on"}, 1.0)  # type: ignore[arg-type]
    assert state["ok"] and state["mode"] == "on" and state["request_id"].startswith("t-")
    with pytest.raises(AckTimeout, match="secuav/v1/silent/state"):
        await acks.request(Loopback(), "secuav/v1/silent/set", {}, 0.2)  # type: ignore[arg-type]


def _tls_files(workdir: Path) -> tuple[Path, Path, Path]:
    """A throwaway CA and a certificate for 127.0.0.1 signed by it: (CA file, server cert, server key)."""
    assert OPENSSL is not None
    ca_key, ca, key, csr, cert = (workdir / n for n in ("ca.key", "ca.crt", "srv.key", "srv.csr", "srv.crt"))
    (workdir / "san.ext").write_text("subjectAltName = IP:127.0.0.1\n")

    def run(*args: str) -> None:
        subprocess.run([OPENSSL, *args], check=True, capture_output=True, timeout=60)

    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(ca_key), "-out", str(ca), "-days", "2",
        "-subj", "/CN=secuav-test-ca")  # fmt: skip
    run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out", str(csr), "-subj", "/CN=127.0.0.1")
    run("x509", "-req", "-in", str(csr), "-CA", str(ca), "-CAkey", str(ca_key), "-CAcreateserial", "-out", str(cert),
        "-days", "2", "-extfile", str(workdir / "san.ext"))  # fmt: skip
    return ca, cert, key


@pytest.mark.timeout(60)
@pytest.mark.skipif(OPENSSL is None, reason="needs the openssl binary")
async def test_the_simulators_truth_goes_over_tls_when_the_address_says_mqtts(
    tmp_path: Path, tcp_port: Callable[[], int]
) -> None:
    from amqtt.broker import Broker

    from flightsim.api import State
    from flightsim.truth import MqttTruth, TruthSample

    ca, cert, key = _tls_files(tmp_path)
    port = tcp_port()
    listener = {"type": "tcp", "bind": f"127.0.0.1:{port}", "ssl": True, "certfile": str(cert), "keyfile": str(key)}
    anonymous = {"amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}}
    broker = Broker({"listeners": {"default": listener}, "plugins": anonymous})
    await broker.start()
    try:
        plain = MqttTruth(parse_broker_url(f"mqtt://127.0.0.1:{port}"))
        secure = MqttTruth(parse_broker_url(f"mqtts://127.0.0.1:{port}"), tls_ca=str(ca))
        reader = Session(parse_broker_url(f"mqtts://127.0.0.1:{port}"), tls_ca=str(ca))
        async with reader.client() as client:
            await client.subscribe("secuav/+/truth")
            plain.start()
            secure.start()
            assert secure.session is not None
            await asyncio.wait_for(secure.session.connected.wait(), 20)
            zero = (0.0, 0.0, 0.0)
            state = State(1.5, (1.0, 2.0, -3.0), zero, zero, (1.0, 0.0, 0.0, 0.0), zero, zero)
            secure.publish(TruthSample(7, state, False))
            message = await asyncio.wait_for(anext(aiter(client.messages)), 10)
            assert str(message.topic) == "secuav/v7/truth"
            body = decode(str(message.topic), bytes(message.payload))  # type: ignore[arg-type]
            assert body.pos_ned_m == [1.0, 2.0, -3.0] and body.sysid == 7
            await asyncio.sleep(0.5)
            assert not plain.connected  # plain MQTT does not get through a TLS listener
        await plain.close()
        await secure.close()
    finally:
        await broker.shutdown()
