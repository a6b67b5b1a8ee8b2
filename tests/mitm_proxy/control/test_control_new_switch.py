"""A runtime switch is one small piece per audience: this module declares a ``note`` switch (its wire contract,
its proxy side, its ``secuav-attack`` verb), registers each with its own audience, and nothing else in the
repository changes, yet the real proxy serves it over a real broker and ``secuav-attack`` lists and runs its verb.

The note is a short text a vehicle carries (``secuav/v<N>/note/set`` ``{"text": ...}``, retained
``.../note/state``); its request model holds it to 40 characters, checked by the proxy, not by the CLI, so
the proxy's refusal and the CLI's exit 1 are both seen.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest
from pydantic import BaseModel, ConfigDict, Field

from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from mitm_proxy.control import switches as proxy_side
from mitm_proxy.control.link import SwitchHost
from mitm_proxy.control.switch import Switch
from mitm_proxy.tools import attack_cli, verbs
from mitm_proxy.tools.verbs import State, SwitchVerbs, Verb
from secuav_common.broker import EmbeddedBroker
from secuav_common.controlplane import switches
from secuav_common.controlplane.contract import SwitchContract
from secuav_common.controlplane.payloads import PayloadError, decode
from tests.support.brokers import Observer

pytestmark = pytest.mark.timeout(60)


# -- the wire contract: what a new secuav_common/controlplane/switches/note.py would hold ----------------------


class NoteRequest(BaseModel):
    """``.../note/set``."""

    model_config = ConfigDict(extra="forbid")
    text: str = Field(max_length=40)
    request_id: str | None = None


class NoteState(BaseModel):
    """``.../note/state`` (retained)."""

    model_config = ConfigDict(extra="allow")
    sysid: int
    text: str | None = None
    since: float | None = None
    request_id: str | None = None
    ok: bool = True
    error: str | None = None


CONTRACT = SwitchContract(kind="note", scope="vehicle", state_model=NoteState, request_model=NoteRequest)


# -- the command line: what a new mitm_proxy/tools/verbs/note.py would hold ------------------------------------


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("text", metavar="TEXT")


def _request(args: argparse.Namespace) -> dict[str, Any]:
    return {"text": args.text}


def _done(key: str, state: State, args: argparse.Namespace) -> str:
    return f"ok: {key} note {state.get('text')!r}"


def _status(key: str, states: dict[str, State | None]) -> list[str]:
    note = states.get("note/state")
    return [f"{key}: note {note.get('text')!r}"] if isinstance(note, dict) and note.get("text") else []


VERBS = SwitchVerbs(CONTRACT, (Verb("note", "leave a short note on a vehicle", _done, _arguments, _request),),
                    status=_status)  # fmt: skip


# -- the proxy side: what a new mitm_proxy/control/note.py would hold -------------------------------------------


class NoteSwitch(Switch[NoteState]):
    contract = CONTRACT

    def __init__(self, sysid: int) -> None:
        super().__init__()
        self.sysid = sysid
        self.text: str | None = None
        self._since: float | None = None

    @classmethod
    def build(cls, host: SwitchHost, sysid: int | None) -> NoteSwitch | None:
        return None if sysid is None else cls(sysid)

    def apply(self, payload: Any, source: str) -> None:
        assert isinstance(payload, NoteRequest)  # the request model was checked before apply
        self.text, self._since = payload.text, time.time()

    def current(self) -> dict[str, Any]:
        return {"sysid": self.sysid, "text": self.text, "since": self._since}


# -- the proof ------------------------------------------------------------------------------------------


@pytest.fixture
def note_switch() -> Iterator[SwitchContract]:
    """Registered with each audience for one test only: the other tests see the built-in switches alone."""
    switches.register(CONTRACT)
    proxy_side.register(NoteSwitch)
    verbs.register(VERBS)
    try:
        yield CONTRACT
    finally:
        verbs.unregister(CONTRACT.kind)
        proxy_side.unregister(CONTRACT.kind)
        switches.unregister(CONTRACT.kind)


@dataclass
class Bench:
    url: str
    port: int
    proxy: Proxy


@pytest.fixture
async def bench(
    note_switch: SwitchContract, tcp_port: Callable[[], int], udp_port: Callable[[], int]
) -> AsyncIterator[Bench]:
    """The real proxy (two links, real UDP endpoints on loopback) on a real embedded broker."""
    port = tcp_port()
    links = [LinkConfig(sysid=s, vehicle=f"udpin://127.0.0.1:{udp_port()}",
                        ground=[f"udpout://127.0.0.1:{udp_port()}"]) for s in (1, 2)]  # fmt: skip
    url = f"mqtt://127.0.0.1:{port}"
    async with EmbeddedBroker(port=port), Proxy(ProxyConfig(links=links, broker=url, instance="lab")) as proxy:
        assert proxy.control is not None
        await proxy.control.wait_connected(10)
        yield Bench(url, port, proxy)


async def cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = await asyncio.to_thread(attack_cli.main, list(argv))
    out, err = capsys.readouterr()
    return code, out, err


async def test_the_proxy_subscribes_applies_and_publishes_a_switch_declared_in_one_module(bench: Bench) -> None:
    assert bench.proxy.control is not None
    controls = bench.proxy.control.controls
    assert "secuav/+/note/set" in controls.subscriptions()
    assert all(isinstance(controls.vehicle(s, "note"), NoteSwitch) for s in (1, 2))

    async with Observer(bench.port, ["secuav/+/note/state"]) as obs:
        first = await obs.wait_for("secuav/v1/note/state")  # published, retained, at connect
        assert first == {"sysid": 1, "text": None, "since": None, "request_id": None, "ok": True, "error": None}

        await obs.publish("secuav/v2/note/set", {"request_id": "n1", "text": "hello"})
        state = await obs.wait_for("secuav/v2/note/state", lambda b: b.get("request_id") == "n1")
        assert state["ok"] and state["text"] == "hello" and state["sysid"] == 2
        assert controls.vehicle(2, "note").text == "hello"  # type: ignore[union-attr]
        assert controls.vehicle(1, "note").text is None  # type: ignore[union-attr]

        # The request model is checked before the switch sees the request: the field and the value are named.
        await obs.publish("secuav/v2/note/set", {"request_id": "n2", "txt": "typo"})
        refused = await obs.wait_for("secuav/v2/note/state", lambda b: b.get("request_id") == "n2")
        assert not refused["ok"] and refused["text"] == "hello"  # the old note stays
        assert refused["error"].startswith("text: Field required")

    # A consumer decodes the state with the switch's own model, found through the registry.
    assert isinstance(decode("secuav/v2/note/state", json.dumps(state).encode()), NoteState)
    with pytest.raises(PayloadError, match="secuav/v2/note/state: sysid"):
        decode("secuav/v2/note/state", b'{"text": "no sysid"}')


async def test_secuav_attack_lists_and_runs_the_new_verb(bench: Bench, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        await cli(capsys, "--help")
    assert "leave a short note on a vehicle" in capsys.readouterr().out

    code, out, err = await cli(capsys, "note", "left at the wall", "--vehicle", "1", "--broker", bench.url)
    assert (code, out) == (0, "ok: v1 note 'left at the wall'\n"), err

    code, out, err = await cli(capsys, "note", "x" * 41, "--vehicle", "1", "--broker", bench.url)
    assert code == 1 and out == ""  # refused by the proxy: the request model allows 40 characters
    assert err.startswith("secuav-attack: v1: rejected: text: String should have at most 40 characters")

    code, out, err = await cli(capsys, "note", "everyone", "--broker", bench.url)  # every vehicle on the broker
    assert code == 0 and out.splitlines() == ["ok: v1 note 'everyone'", "ok: v2 note 'everyone'"], err

    code, out, err = await cli(capsys, "status", "--broker", bench.url)
    assert code == 0 and "v2: note 'everyone'" in out.splitlines(), err
    code, out, err = await cli(capsys, "status", "--json", "--broker", bench.url)
    assert code == 0 and json.loads(out)["vehicles"]["v1"]["note/state"]["text"] == "everyone"


def test_without_it_the_built_in_switches_are_all_there_is() -> None:
    assert [s.kind for s in switches.contracts()] == ["attack", "attack/mode", "secure", "routes"]
    assert [v.name for _, v in verbs.verbs()] == ["apply", "clear", "mode", "secure", "routes"]


def test_a_kind_or_verb_cannot_be_taken_twice(note_switch: SwitchContract) -> None:
    other = SwitchContract(kind="note", scope="vehicle", state_model=NoteState, request_model=NoteRequest)
    with pytest.raises(ValueError, match="registered twice"):
        switches.register(other)

    class Other(NoteSwitch):
        contract = other

    with pytest.raises(ValueError, match="registered twice"):
        proxy_side.register(Other)
    thief = SwitchVerbs(SwitchContract(kind="other", scope="vehicle", state_model=NoteState, request_model=NoteRequest),
                        (Verb("mode", "?", _done),))  # fmt: skip
    with pytest.raises(ValueError, match="verb 'mode' belongs to another switch"):
        verbs.register(thief)
