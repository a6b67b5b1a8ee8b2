"""The control plane and ``secuav-attack`` against a mosquitto that wants TLS and a password."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.control.plane import ControlPlane
from mitm_proxy.control.switches import vehicle_controls
from mitm_proxy.stages.attack_slot import AttackSlot
from mitm_proxy.tools import attack_cli
from tests.support.brokers import (
    MOSQUITTO,
    MOSQUITTO_PASSWD,
    OPENSSL,
    Mosquitto,
    make_password_file,
    make_tls_files,
)

pytestmark = [
    pytest.mark.timeout(90),
    pytest.mark.mosquitto,
    pytest.mark.skipif(
        MOSQUITTO is None or OPENSSL is None or MOSQUITTO_PASSWD is None,
        reason="needs the mosquitto, mosquitto_passwd and openssl binaries",
    ),
]


def no_stats() -> dict[int, dict[str, Any]]:
    return {}


@pytest.fixture
def secured(tcp_port: Callable[[], int], tmp_path: Path) -> Iterator[tuple[int, Path]]:
    """mosquitto on a TLS listener with user ``secuav`` / ``s3cret``; yields (port, CA file)."""
    ca, cert, key = make_tls_files(tmp_path)
    passwd = make_password_file(tmp_path, "secuav", "s3cret")
    port = tcp_port()
    extra = f"cafile {ca}\ncertfile {cert}\nkeyfile {key}\npassword_file {passwd}\n"
    with Mosquitto(port, tmp_path, extra):
        yield port, ca


async def test_tls_and_password_from_plane_to_cli(
    secured: tuple[int, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    port, ca = secured
    slots = {1: AttackSwitch(AttackSlot(1))}
    controls = vehicle_controls("t", slots)
    plane = ControlPlane(f"mqtts://127.0.0.1:{port}", controls, stats=no_stats, username="secuav", password="s3cret",
                         tls_ca=str(ca))  # fmt: skip
    async with plane:
        await plane.wait_connected(15)
        await asyncio.sleep(0.3)
        url = f"mqtts://secuav:s3cret@127.0.0.1:{port}"
        code = await asyncio.to_thread(attack_cli.main, ["apply", "drift", "--broker", url, "--tls-ca", str(ca)])
        out, err = capsys.readouterr()
        assert code == 0, err
        assert out.startswith("ok: v1 drift (hash ") and slots[1].state.profile == "drift"

        wrong = f"mqtts://secuav:nope@127.0.0.1:{port}"
        args = ["status", "--timeout", "2", "--broker", wrong, "--tls-ca", str(ca)]
        code = await asyncio.to_thread(attack_cli.main, args)
        _, err = capsys.readouterr()
        assert code == 3 and "cannot use the broker" in err


async def test_a_wrong_password_or_an_unknown_ca_never_connects_and_is_logged_once(
    secured: tuple[int, Path], caplog: pytest.LogCaptureFixture, tmp_path: Path
) -> None:
    caplog.set_level(logging.WARNING, logger="mitm_proxy.control")
    port, ca = secured
    (tmp_path / "other").mkdir()
    other_ca, _, _ = make_tls_files(tmp_path / "other")  # a CA that did not sign the broker's certificate
    cases = [
        {"username": "secuav", "password": "wrong", "tls_ca": str(ca)},
        {"username": "secuav", "password": "s3cret", "tls_ca": str(other_ca)},
    ]
    for options in cases:
        caplog.clear()
        controls = vehicle_controls("t", {1: AttackSwitch(AttackSlot(1))})
        plane = ControlPlane(f"mqtts://127.0.0.1:{port}", controls, stats=no_stats, backoff_s=(0.1, 0.2),
                             **options)  # type: ignore[arg-type]  # fmt: skip
        async with plane:
            await asyncio.sleep(1.5)  # several attempts
            assert not plane.connected.is_set() and plane.connections == 0
        assert [r.getMessage() for r in caplog.records].count("mqtt.unavailable") == 1
