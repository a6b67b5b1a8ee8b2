"""Start and stop the processes of one demo run: simulator, proxy, controller.

Every process writes its output to ``<out>/<name>.log``. Teardown sends SIGINT
(what Ctrl-C does), waits, and only then kills, so each service gets to stop
cleanly and say so in its log.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import sys
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

from demos.catalog import API_OFFSET, GCS_OFFSET, MQTT_OFFSET, PROXY_OFFSET
from secuav_common.ports import GCS_PORT, GROUND_API_BASE, MQTT_PORT, PROXY_VEHICLE_BASE

log = logging.getLogger(__name__)
BIN = Path(sys.executable).parent
STOP_TIMEOUT_S = 5.0


@dataclass(frozen=True, slots=True)
class Ports:
    """Loopback ports of one run; the defaults are the port plan of docs/interfaces.md for vehicle 0."""

    proxy_vehicle: int = PROXY_VEHICLE_BASE  # the simulator sends here, the proxy listens
    api: int = GROUND_API_BASE  # the proxy forwards here, the MAVSDK controller listens
    gcs: int = GCS_PORT  # the proxy also forwards here (QGroundControl, MAVProxy)
    mqtt: int = MQTT_PORT

    @classmethod
    def block(cls, base: int) -> Ports:
        """The ports of ``--base-port base`` (:mod:`demos.catalog` says which offset is which)."""
        return cls(base + PROXY_OFFSET, base + API_OFFSET, base + GCS_OFFSET, base + MQTT_OFFSET)

    @property
    def broker_url(self) -> str:
        return f"mqtt://127.0.0.1:{self.mqtt}"


def tool(name: str) -> str:
    """A console script of this installation (next to the running interpreter), else from PATH."""
    candidate = BIN / name
    return str(candidate) if candidate.exists() else name


class Processes:
    """``async with Processes(out) as procs: await procs.start("sim", [...])``; all stopped on exit."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.running: dict[str, asyncio.subprocess.Process] = {}

    async def start(self, name: str, argv: list[str]) -> asyncio.subprocess.Process:
        self.out.mkdir(parents=True, exist_ok=True)
        with open(self.out / f"{name}.log", "wb") as sink:  # the child keeps its own descriptor
            proc = await asyncio.create_subprocess_exec(
                *argv, stdout=sink, stderr=asyncio.subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"}
            )
        log.info("demo.start", extra={"service": name, "pid": proc.pid, "argv": " ".join(argv)})
        self.running[name] = proc
        return proc

    def check_alive(self) -> None:
        """Raise with the process's log tail if a service died under us."""
        for name, proc in self.running.items():
            if proc.returncode is not None and not name.startswith("controller"):
                tail = (self.out / f"{name}.log").read_text(errors="replace").splitlines()[-8:]
                raise RuntimeError(f"{name} exited with {proc.returncode}:\n  " + "\n  ".join(tail))

    async def stop(self, name: str) -> int | None:
        proc = self.running.pop(name, None)
        if proc is None:
            return None
        if proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGINT)
            try:
                await asyncio.wait_for(proc.wait(), STOP_TIMEOUT_S)
            except TimeoutError:
                log.warning("demo.kill", extra={"service": name})
                with contextlib.suppress(ProcessLookupError):
                    proc.kill()
                await proc.wait()
        return proc.returncode

    async def __aenter__(self) -> Processes:
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        for name in reversed(list(self.running)):  # controller first, simulator last
            await self.stop(name)
