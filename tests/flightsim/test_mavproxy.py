"""Real MAVProxy against the simulator: it loads every parameter and names the modes as PX4's.

MAVProxy runs as users run it (``--master=udpin:...``, non-interactive); the
test reads its console output while the vehicle arms, takes off and holds.
"""

from __future__ import annotations

import asyncio
import shutil
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.support.live_sim import live_sim

pytest.importorskip("MAVProxy", reason="MAVProxy comes with the project's test extras")


async def _lines_until(stream: asyncio.StreamReader, seen: list[str], wanted: str, timeout_s: float) -> None:
    async def read() -> None:
        while not any(wanted in line for line in seen):
            raw = await stream.readline()
            if not raw:
                raise AssertionError(f"MAVProxy ended before printing {wanted!r}: {seen[-20:]}")
            seen.append(raw.decode(errors="replace").strip())

    try:
        await asyncio.wait_for(read(), timeout_s)
    except TimeoutError:
        raise AssertionError(f"MAVProxy did not print {wanted!r} within {timeout_s} s: {seen[-20:]}") from None


@pytest.mark.timeout(60)
async def test_mavproxy_loads_all_parameters_and_shows_px4_mode_names(
    udp_port: Callable[[], int], tmp_path: Path
) -> None:
    mavproxy = shutil.which("mavproxy.py", path=str(Path(sys.executable).parent))
    assert mavproxy is not None
    port = udp_port()
    async with live_sim("anchors8", [port]) as runner:
        v = runner.sim.vehicles[1]
        proc = await asyncio.create_subprocess_exec(
            sys.executable, mavproxy, f"--master=udpin:127.0.0.1:{port}", "--non-interactive",
            f"--state-basedir={tmp_path}", "--cmd=module unload terrain; param fetch",
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT, cwd=tmp_path,
        )  # fmt: skip
        assert proc.stdout is not None
        seen: list[str] = []
        try:
            await _lines_until(proc.stdout, seen, "Mode MANUAL", 20)
            count = len(v.params())
            await _lines_until(proc.stdout, seen, f"Received {count} parameters", 15)
            assert v.arm().ok and v.takeoff().ok
            await _lines_until(proc.stdout, seen, "ARMED", 5)
            await _lines_until(proc.stdout, seen, "Mode TAKEOFF", 5)
            await _lines_until(proc.stdout, seen, "Mode LOITER", 15)
        finally:
            proc.terminate()
            await asyncio.wait_for(proc.wait(), 10)
    text = "\n".join(seen)
    assert "FTP: request timed out" not in text  # FTP is answered, so the parameter fetch falls back at once
    assert "fence breach" not in text
    saved = (tmp_path / "mav.parm").read_text() if (tmp_path / "mav.parm").exists() else ""
    saved_names = {line.split()[0] for line in saved.splitlines() if line.strip() and not line.startswith("#")}
    assert saved_names == {p.name for p in v.params()}
