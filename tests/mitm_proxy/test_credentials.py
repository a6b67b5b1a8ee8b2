"""Broker credentials never need the command line (ps shows it) and never reach a log line."""

from __future__ import annotations

from pathlib import Path

import pytest

from mitm_proxy.cli import build_parser, config_from_args
from secuav_common.broker import redact
from secuav_common.loading import InputError


def _config(*argv: str) -> object:
    return config_from_args(build_parser().parse_args(["--broker", "mqtt://op@127.0.0.1:1883", *argv]))


def test_password_from_a_private_file(tmp_path: Path) -> None:
    secret = tmp_path / "broker.pass"
    secret.write_text("s3cret with spaces\n")
    secret.chmod(0o600)
    assert _config("--broker-password-file", str(secret)).broker_password == "s3cret with spaces"
    secret.chmod(0o644)
    with pytest.raises(InputError, match=r"broker\.pass: --broker-password-file: readable by others"):
        _config("--broker-password-file", str(secret))


def test_password_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SECUAV_BROKER_PASSWORD", "from-env")
    assert _config().broker_password == "from-env"
    assert _config("--broker-password", "flag-wins").broker_password == "flag-wins"
    monkeypatch.delenv("SECUAV_BROKER_PASSWORD")
    assert _config().broker_password is None


@pytest.mark.parametrize(
    ("url", "shown"),
    [
        ("mqtt://op:hunter2@broker:1883", "mqtt://op:***@broker:1883"),
        ("mqtts://op:p%40ss@10.0.0.5", "mqtts://op:***@10.0.0.5"),
        ("mqtt://op@broker:1883", "mqtt://op@broker:1883"),
        ("embedded", "embedded"),
    ],
)
def test_logged_broker_urls_hide_the_password(url: str, shown: str) -> None:
    assert redact(url) == shown
