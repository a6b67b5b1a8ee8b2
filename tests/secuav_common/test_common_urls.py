"""Endpoint URLs: every spelling MAVSDK, mavlink-router and mavutil users write, and a canonical form."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from secuav_common.urls import Endpoint, parse_endpoint


@pytest.mark.parametrize(
    ("url", "mode", "host", "port"),
    [
        ("tcp://127.0.0.1:5760", "tcp", "127.0.0.1", 5760),
        ("tcpin://0.0.0.0:5760", "tcpin", "0.0.0.0", 5760),
        ("udpin:127.0.0.1:14550", "udpin", "127.0.0.1", 14550),  # mavutil
        ("udpout:localhost:14550", "udpout", "localhost", 14550),
        ("tcp:127.0.0.1:5760", "tcp", "127.0.0.1", 5760),
        ("udp://127.0.0.1:14540", "udpin", "127.0.0.1", 14540),  # MAVSDK: udp:// listens
        ("udpin://[::1]:14550", "udpin", "::1", 14550),
        ("serial:///dev/ttyUSB0?baud=921600", "serial", "/dev/ttyUSB0", 921600),
        ("serial:///dev/ttyACM0", "serial", "/dev/ttyACM0", 57600),
        ("/dev/ttyUSB0,115200", "serial", "/dev/ttyUSB0", 115200),  # mavutil
    ],
)
def test_each_spelling_parses(url: str, mode: str, host: str, port: int) -> None:
    ep = parse_endpoint(url)
    assert (ep.mode, ep.host, ep.port) == (mode, host, port)
    assert parse_endpoint(str(ep)) == ep


def test_options_are_kept_and_printed_back() -> None:
    ep = parse_endpoint("udpout://127.0.0.1:14550?deny=DISTANCE_SENSOR,ATTITUDE&listen_only=true")
    assert ep.option("deny") == "DISTANCE_SENSOR,ATTITUDE"
    assert ep.option("listen_only") == "true"
    assert str(ep) == "udpout://127.0.0.1:14550?deny=DISTANCE_SENSOR,ATTITUDE&listen_only=true"
    assert ep.without_options() == Endpoint("udpout", "127.0.0.1", 14550)
    serial = parse_endpoint("serial:///dev/ttyUSB0?baud=57600&listen_only=true")
    assert serial.options == (("listen_only", "true"),)
    assert parse_endpoint(str(serial)) == serial


@pytest.mark.parametrize(
    ("url", "needle"),
    [
        ("quic://1.2.3.4:5", "scheme 'quic'"),
        ("udpin://host", "HOST:PORT"),
        ("udpout://h:99999", "outside 0..65535"),
        ("tcp://h:x", "port 'x'"),
        ("14540", "expected"),
        ("udpin://::1:14550", "brackets"),
        ("udpin://[::1:14550", "brackets"),
        ("serial://ttyUSB0", "device path"),
        ("serial:///dev/ttyUSB0?baud=fast", "baud 'fast'"),
        ("udpin://127.0.0.1:1?deny", "KEY=VALUE"),
        # MAVSDK's every-interface form: refused, saying what to write instead (issue 36)
        ("udp://:14540", "udpin://127.0.0.1:14540 (this machine only) or udpin://0.0.0.0:14540"),
        ("tcpin://:5760", "tcpin://127.0.0.1:5760"),
    ],
)
def test_a_bad_url_is_one_error_naming_it(url: str, needle: str) -> None:
    with pytest.raises(ValueError, match="endpoint") as err:
        parse_endpoint(url)
    assert needle in str(err.value) and url in str(err.value)


_hosts = st.one_of(
    st.from_regex(r"[a-z][a-z0-9-]{0,20}(\.[a-z0-9-]{1,10}){0,2}", fullmatch=True),
    st.ip_addresses(v=4).map(str),
    st.ip_addresses(v=6).map(str),
)
_opts = st.lists(
    st.tuples(st.sampled_from(["deny", "allow_up", "listen_only", "deny_sysid"]),
              st.from_regex(r"[A-Z0-9_,]{1,30}", fullmatch=True)),
    max_size=3,
)  # fmt: skip


@given(st.sampled_from(["udpin", "udpout", "tcp", "tcpin"]), _hosts, st.integers(0, 65535), _opts)
def test_printing_and_parsing_round_trip(mode: str, host: str, port: int, opts: list[tuple[str, str]]) -> None:
    ep = Endpoint(mode, host, port, tuple(opts))  # type: ignore[arg-type]
    assert parse_endpoint(str(ep)) == ep


@given(st.text(max_size=60))
def test_any_text_parses_or_raises_value_error(text: str) -> None:
    try:
        parse_endpoint(text)
    except ValueError as exc:
        assert "endpoint" in str(exc)
