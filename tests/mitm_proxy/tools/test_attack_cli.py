"""``secuav-attack apply|clear|status`` end to end: the CLI, a real broker, an in-process ControlPlane."""

from __future__ import annotations

import asyncio
import json
import sys
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from attack_profiles import library
from attack_profiles.profile import load_profile
from mavframe.frames import split
from mavframe.packet import Direction, Header, Packet
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.control.plane import ControlPlane
from mitm_proxy.control.switches import vehicle_controls
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from mitm_proxy.tools import attack_cli
from secuav_common.broker import EmbeddedBroker
from tests.support.frames_support import mavlink, pack

pytestmark = pytest.mark.timeout(60)
REPO = Path(__file__).resolve().parents[3]


@dataclass
class Bench:
    url: str
    slots: dict[int, AttackSlot]
    plane: ControlPlane
    stages: dict[int, AttackStage]


def stats() -> dict[int, dict[str, Any]]:
    return {
        1: {
            "downlink": {"frames_in": 10, "frames_out": 9, "rewritten": 3, "dropped": 1, "bad_total": 0},
            "uplink": {"frames_in": 2, "frames_out": 2, "rewritten": 0, "dropped": 0, "bad_total": 0},
            "latency_ms": {"p50": 0.31, "p99": 0.72},
        }
    }


@pytest.fixture
async def bench(tcp_port: Callable[[], int]) -> AsyncIterator[Bench]:
    port = tcp_port()
    slots = {1: AttackSwitch(AttackSlot(1)), 2: AttackSwitch(AttackSlot(2))}
    stages = {sysid: AttackStage(slot.slot) for sysid, slot in slots.items()}
    async with EmbeddedBroker(port=port):
        url = f"mqtt://127.0.0.1:{port}"
        async with ControlPlane(url, vehicle_controls("t", slots, stages), stats=stats) as plane:
            await plane.wait_connected(10)
            await asyncio.sleep(0.3)  # the initial retained states reach the broker
            yield Bench(url, slots, plane, stages)


async def cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    """Run the CLI in a worker thread (it runs its own event loop), as a user would, and capture it."""
    code = await asyncio.to_thread(attack_cli.main, list(argv))
    out, err = capsys.readouterr()
    return code, out, err


async def test_apply_a_library_profile_to_one_vehicle(bench: Bench, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = await cli(capsys, "apply", "wall-spoof", "--vehicle", "1", "--broker", bench.url)
    expected = library.load("wall-spoof")
    assert code == 0, err
    assert out == f"ok: v1 wall-spoof (hash {expected.content_hash()[:12]}), changing frames toward the ground\n"
    assert bench.slots[1].state.hash == expected.content_hash() and bench.slots[1].engine is not None
    assert bench.slots[2].engine is None


async def test_apply_a_file_with_parameters_to_every_vehicle(
    bench: Bench, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    path = tmp_path / "spoof.yaml"
    path.write_text(library.text("wall-spoof"), encoding="utf-8")
    code, out, err = await cli(capsys, "apply", str(path), "--param", "rate_per_s=0.5", "--broker", bench.url)
    expected = load_profile(path, rate_per_s=0.5)
    assert code == 0, err
    want = f"wall-spoof (hash {expected.content_hash()[:12]}), changing frames toward the ground"
    assert sorted(out.splitlines()) == [f"ok: v{n} {want}" for n in (1, 2)]
    assert all(slot.state.hash == expected.content_hash() for slot in bench.slots.values())


async def test_a_profile_the_proxy_rejects_exits_1_with_its_reason(
    bench: Bench, capsys: pytest.CaptureFixture[str]
) -> None:
    assert (await cli(capsys, "apply", "drift", "--vehicle", "2", "--broker", bench.url))[0] == 0
    engine = bench.slots[2].engine
    # Valid on its own, but this proxy has no scenario for the anchors' positions.
    code, out, err = await cli(capsys, "apply", "anchors-coordinated", "--vehicle", "2", "--broker", bench.url)
    assert code == 1 and out == ""
    assert err.startswith("secuav-attack: v2: rejected: ") and "needs a scenario" in err
    assert bench.slots[2].engine is engine


async def test_a_bad_file_fails_before_anything_is_sent(
    bench: Bench, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("name: bad\nrules:\n  - kind: bias\n", encoding="utf-8")
    code, out, err = await cli(capsys, "apply", str(path), "--vehicle", "1", "--broker", bench.url)
    assert code == 1 and out == "" and str(path) in err and "rules[0]" in err
    assert bench.slots[1].state.request_id is None  # the proxy never heard of it


async def test_clear_and_status(bench: Bench, capsys: pytest.CaptureFixture[str]) -> None:
    assert (await cli(capsys, "apply", "distance-stuck", "--broker", bench.url))[0] == 0
    code, out, _ = await cli(capsys, "status", "--broker", bench.url)
    lines = out.splitlines()
    assert code == 0 and lines[0].startswith("proxy t: online since ") and lines[0].endswith("; vehicles v1, v2")
    assert any(line.startswith("v1: attack distance-stuck (hash ") for line in lines)
    assert "v1: secure not available in this proxy" in lines
    stats_lines = [line for line in lines if line.startswith("v1: downlink 10 in/9 out, rewritten 3, dropped 1, bad 0")]
    assert len(stats_lines) == 1 and "latency p50 0.31 ms p99 0.72 ms" in stats_lines[0]

    bench.stages[2].enabled = False  # bypassed (over attack/mode/set, or by the app)
    await asyncio.sleep(0.5)
    code, out, _ = await cli(capsys, "status", "--vehicle", "2", "--broker", bench.url)
    assert code == 0 and any(line.startswith("v2: attack distance-stuck (hash ") and "(bypassed)" in line
                             for line in out.splitlines())  # fmt: skip

    code, out, err = await cli(capsys, "clear", "--vehicle", "1", "--broker", bench.url)
    assert (code, out) == (0, "ok: v1 cleared\n"), err
    assert bench.slots[1].engine is None and bench.slots[2].engine is not None

    code, out, _ = await cli(capsys, "status", "--vehicle", "1", "--json", "--broker", bench.url)
    report = json.loads(out)
    assert code == 0 and report["online"] is True and list(report["vehicles"]) == ["v1"]
    assert report["vehicles"]["v1"]["attack/state"]["profile"] is None
    assert report["vehicles"]["v1"]["stats"]["downlink"]["frames_in"] == 10


async def test_an_unknown_vehicle_fails_at_once_with_exit_3(bench: Bench, capsys: pytest.CaptureFixture[str]) -> None:
    """The proxies' online records list the vehicles they serve: none serves v7, so nothing is sent and
    nobody waits for an acknowledgement that cannot come (issue 36)."""
    code, out, err = await cli(capsys, "apply", "drift", "--vehicle", "7", "--timeout", "1", "--broker", bench.url)
    assert code == 3 and out == ""
    assert f"v7: no proxy on the broker at {bench.url} serves vehicle 7 (" in err and "serves v1, v2)" in err, err
    assert "no acknowledgement" not in err


async def test_no_broker_and_no_proxy_exit_3(capsys: pytest.CaptureFixture[str], tcp_port: Callable[[], int]) -> None:
    port = tcp_port()
    code, _, err = await cli(capsys, "status", "--timeout", "1", "--broker", f"mqtt://127.0.0.1:{port}")
    assert code == 3 and err.startswith(f"secuav-attack: cannot use the broker at mqtt://127.0.0.1:{port}")

    async with EmbeddedBroker(port=port):
        code, _, err = await cli(capsys, "apply", "drift", "--timeout", "1", "--broker", f"mqtt://127.0.0.1:{port}")
        assert code == 3 and "no proxy on the broker" in err
        code, _, err = await cli(capsys, "status", "--timeout", "1", "--broker", f"mqtt://127.0.0.1:{port}")
        assert code == 3 and "no state for any vehicle" in err

    code, _, err = await cli(capsys, "clear", "--broker", "http://127.0.0.1:1")
    assert code == 2 and "scheme must be mqtt://" in err


async def test_the_console_command_as_a_process(bench: Bench) -> None:
    """What a shell user runs: a separate process, its exit code and its one line."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "mitm_proxy.tools.attack_cli", "apply", "gps-glitch", "--vehicle", "1",
        "--broker", bench.url,
        cwd=REPO, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    out, err = await asyncio.wait_for(proc.communicate(), 30)
    assert proc.returncode == 0, err.decode()
    assert out.decode().startswith("ok: v1 gps-glitch (hash ")
    assert bench.slots[1].state.profile == "gps-glitch"


def test_status_names_every_instance_and_warns_about_a_shared_sysid() -> None:
    board = attack_cli.Board()
    board.latest.update({
        "secuav/proxy/lab-a/online": {"instance": "lab-a", "online": True, "since": 0, "vehicles": [1, 2], "pid": 7,
                                      "host": "h"},
        "secuav/proxy/lab-b/online": {"instance": "lab-b", "online": True, "since": 0, "vehicles": [2]},
        "secuav/proxy/old/online": {"instance": "old", "online": False, "since": 0, "vehicles": [1]},
    })  # fmt: skip
    lines = attack_cli._instance_lines(board)
    assert lines[0] == "proxy lab-a: online since 1970-01-01 00:00:00Z pid 7 on h; vehicles v1, v2"
    assert lines[2].startswith("proxy old: offline")
    assert lines[3].startswith("warning: v2 is served by 2 online proxies (lab-a, lab-b)")
    assert len(lines) == 4  # v1's other claimant is offline: no warning


async def test_status_prints_the_warning_of_an_attack_that_cannot_act(
    bench: Bench, capsys: pytest.CaptureFixture[str]
) -> None:
    """A signed stream and no key (issue 27): the pipeline tells the stage, the state says it, status prints it."""
    assert (await cli(capsys, "apply", "distance-stuck", "--vehicle", "1", "--broker", bench.url))[0] == 0
    bench.stages[1].signed_untouched(Header(2, 132, 1, 1, 0, 39, 1, True))  # what the pipeline does without a key
    await asyncio.sleep(0.5)  # the plane publishes changed states 5 times a second
    code, out, _ = await cli(capsys, "status", "--vehicle", "1", "--broker", bench.url)
    warned = [line for line in out.splitlines() if line.startswith("v1: warning: attack.signed_no_key")]
    assert code == 0 and len(warned) == 1, out
    # distance-stuck rewrites DISTANCE_SENSOR only; RANGEFINDER, which would stay true, is not sent yet: no warning
    assert "attack.true_copy" not in out and "changing frames toward the ground" in out, out
    ((header, raw),) = split(pack(mavlink.MAVLink_rangefinder_message(4.2, 1.1))).frames  # ArduPilot's twin arrives
    bench.stages[1].process(Packet(raw, header, Direction.DOWNLINK, 0, 0.0), 0.0)
    await asyncio.sleep(0.5)
    code, out, _ = await cli(capsys, "status", "--vehicle", "1", "--broker", bench.url)
    assert "v1: warning: attack.true_copy: rules[0]" in out and "RANGEFINDER.distance still carries" in out, out
    assert "attack.signed_no_key: system 1 signs its frames (DISTANCE_SENSOR among them)" in warned[0]
    assert "--signing-key" in warned[0]
    assert (await cli(capsys, "apply", "distance-stuck", "--vehicle", "1", "--broker", bench.url))[0] == 0
    code, out, _ = await cli(capsys, "status", "--vehicle", "1", "--broker", bench.url)
    assert "signed_no_key" not in out  # a new profile starts with a clean slate
