"""Log lines split the same way whatever the values (logfmt quoting), --log-json is JSON, --version everywhere."""

from __future__ import annotations

import json
import logging
import re
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from secuav_common.logs import JsonFormatter, KeyValueFormatter

PAIR = re.compile(r'(\w+)=("(?:[^"\\]|\\.)*"|[^\s"]+)')


def _record(**extra: object) -> logging.LogRecord:
    record = logging.LogRecord("proxy", logging.INFO, __file__, 1, "proxy.ready", None, None)
    record.__dict__.update(extra)
    return record


@given(st.dictionaries(st.from_regex(r"[a-z][a-z_]{0,8}", fullmatch=True), st.text(max_size=30), max_size=5))
def test_every_value_comes_back_from_a_logfmt_line(fields: dict[str, str]) -> None:
    fields = {k: v for k, v in fields.items() if k not in logging.LogRecord("", 0, "", 0, "", None, None).__dict__}
    line = KeyValueFormatter().format(_record(**fields))
    rest = line.split(" proxy.ready", 1)[1]
    parsed = {k: json.loads(v) if v.startswith('"') else v for k, v in PAIR.findall(rest)}
    assert parsed == fields


def test_json_lines_carry_the_event_and_its_fields() -> None:
    doc = json.loads(JsonFormatter().format(_record(sysid=1, broker="mqtt://127.0.0.1:1883")))
    assert doc["event"] == "proxy.ready" and doc["sysid"] == 1 and doc["level"] == "INFO"
    assert doc["ts"].endswith("+00:00")


@pytest.mark.parametrize(
    "command",
    ["secuav-sim", "secuav-proxy", "secuav-attack", "secuav-eval", "secuav-demo", "secuav-study", "secuav-record"],
)
def test_version_on_every_command(command: str) -> None:
    exe = Path(sys.executable).parent / command
    done = subprocess.run([str(exe), "--version"], capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0 and re.fullmatch(rf"{command} \d+\.\d+\.\d+\S*\n", done.stdout), done


def test_a_rate_limited_event_is_one_line_per_window_with_the_count(caplog: pytest.LogCaptureFixture) -> None:
    """What an outsider can repeat at will (issue 36: 125,961 lines in 10 s) is a line per 10 s, counted."""
    from secuav_common.logs import RateLimitedLog

    now = [0.0]
    events = RateLimitedLog(logging.getLogger("test.rate"), every_s=10.0, clock=lambda: now[0])
    caplog.set_level(logging.INFO, logger="test.rate")
    for i in range(1000):  # 1000 events over 25 s, and another kind once
        now[0] = i * 0.025
        events.event("endpoint.client_evicted", peer="127.0.0.1")
    events.event("endpoint.client_refused")
    lines = [(r.getMessage(), r.count) for r in caplog.records]  # type: ignore[attr-defined]
    assert lines == [("endpoint.client_evicted", 1), ("endpoint.client_evicted", 400),
                     ("endpoint.client_evicted", 400), ("endpoint.client_refused", 1)]  # fmt: skip
    assert events.totals == {"endpoint.client_evicted": 1000, "endpoint.client_refused": 1} and events.lines == 4
