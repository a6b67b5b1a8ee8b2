"""ArduCopter SITL for the bench: find the binary, start instances with the bench's parameters, read its truth.

Nothing of ArduPilot ships with SecUAV: ``scripts/sitl/ardupilot.sh build SOURCE`` (in a checkout) builds
the SITL binary and caches it in ``~/.cache/secuav/ardupilot/<commit>/`` beside ArduPilot's own
``copter.parm``, with ``latest`` pointing at the newest (docs/ardupilot.md). What a run needs besides is
in this package: the parameter file :data:`PARAMS` (three downward rangefinders and the stream rates the
bench needs) and the launch itself, used by ``secuav-demo height-hold`` and by
``scripts/sitl/ardupilot.sh run N`` (which runs ``python -m demos.sitl run N``).

Instance ``i`` serves MAVLink on tcp 5760+10*i (SERIAL0, where the proxy dials) and 5762+10*i (SERIAL1,
a direct link), runs from ``<cache>/run/<i>/`` with its log ``sitl.log`` there, and starts with ``-w``
(stored parameters wiped), so the parameter files decide every start.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import signal
import statistics
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

PARAMS = Path(__file__).resolve().parent / "ardupilot" / "rangefinders.parm"
HOME = "-35.363261,149.165230,584,353"  # ArduPilot's default: Canberra model flying club (lat,lon,alt,heading)
DEFAULT_INSTANCE = 7  # tcp 5830: out of the way of a SITL on the default 5760
READY = "Waiting for connection"  # SITL's line once its tcp port listens; it boots when something connects
BUILD_HINT = ("build one with 'scripts/sitl/ardupilot.sh build SOURCE' in a SecUAV checkout (docs/ardupilot.md), "
              "or name one with --sitl-binary or ARDUPILOT_BIN")  # fmt: skip


class NoSitl(RuntimeError):
    """No usable SITL binary (or no ``copter.parm`` for it); the message says what to run."""


def cache_dir() -> Path:
    return Path(os.environ.get("SECUAV_ARDUPILOT_CACHE") or Path.home() / ".cache" / "secuav" / "ardupilot")


def tcp_port(instance: int, serial: int = 0) -> int:
    """SITL's MAVLink port of SERIAL``serial`` (0 or 1) for ``-I instance``."""
    return 5760 + 10 * instance + 2 * serial


def find_binary(given: str | os.PathLike[str] | None = None) -> Path:
    """``given``, else ``$ARDUPILOT_BIN``, else the cache's newest build; :class:`NoSitl` if it is not there."""
    if given:
        path, origin = Path(given), "--sitl-binary"
    elif os.environ.get("ARDUPILOT_BIN"):
        path, origin = Path(os.environ["ARDUPILOT_BIN"]), "ARDUPILOT_BIN"
    else:
        path, origin = cache_dir() / "latest" / "arducopter", "the cache"
    if not (path.is_file() and os.access(path, os.X_OK)):
        raise NoSitl(f"no ArduCopter SITL binary at {path} ({origin}): {BUILD_HINT}")
    return path


def copter_defaults(binary: Path) -> Path:
    """ArduPilot's own copter parameters, kept beside each cached build (else the newest build's)."""
    for path in (binary.parent / "copter.parm", cache_dir() / "latest" / "copter.parm"):
        if path.is_file():
            return path
    raise NoSitl(f"no copter.parm beside {binary} or in {cache_dir() / 'latest'}: {BUILD_HINT}")


def build_info(binary: Path) -> dict[str, str]:
    """The ``version`` and ``commit`` the build script wrote beside the binary (absent: not said)."""
    return {k: (binary.parent / k).read_text().strip() for k in ("version", "commit") if (binary.parent / k).is_file()}


@dataclass(frozen=True, slots=True)
class SitlOptions:
    """How a demo runs SITL (``secuav-demo --sitl-binary --instance --speedup``)."""

    binary: Path
    instance: int = DEFAULT_INSTANCE
    speedup: float = 1.0


def command(binary: Path, instance: int, sysid: int = 1, speedup: float = 1.0, home: str = HOME,
            extra_params: Sequence[Path] = ()) -> list[str]:  # fmt: skip
    """The argv of one instance: a quad (``+``), ArduPilot's copter defaults, then :data:`PARAMS`, then extras."""
    defaults = ",".join(str(p) for p in (copter_defaults(binary), PARAMS, *extra_params))
    return [str(binary), "--model", "+", "--speedup", f"{speedup:g}", f"-I{instance}", "-w", "--home", home,
            "--defaults", defaults, "--sysid", str(sysid)]  # fmt: skip


class Sitl:
    """One SITL instance: ``async with Sitl(binary, 7) as sitl: await sitl.ready()``; stopped on exit.

    It runs in a session of its own, so a Ctrl-C meant for the caller does not reach it before the caller
    has stopped what talks to it; it is ended with SIGTERM (then SIGKILL) to that session's group.
    """

    def __init__(self, binary: Path, instance: int, sysid: int = 1, speedup: float = 1.0, home: str = HOME,
                 extra_params: Sequence[Path] = ()) -> None:  # fmt: skip
        self.argv = command(binary, instance, sysid, speedup, home, extra_params)
        self.instance = instance
        self.workdir = cache_dir() / "run" / str(instance)  # its eeprom.bin and logs
        self.log = self.workdir / "sitl.log"
        self.proc: asyncio.subprocess.Process | None = None

    async def __aenter__(self) -> Sitl:
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.log.unlink(missing_ok=True)  # a stale one would pass ready()
        with open(self.log, "wb") as sink:
            self.proc = await asyncio.create_subprocess_exec(
                *self.argv, cwd=self.workdir, stdout=sink, stderr=asyncio.subprocess.STDOUT, start_new_session=True
            )
        return self

    async def ready(self, timeout_s: float = 60.0) -> None:
        """Until SITL listens on its tcp port; ``RuntimeError`` naming its log if it stops or takes too long."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.log.exists() and READY in self.log.read_text(errors="replace"):
                return
            if self.proc is not None and self.proc.returncode is not None:
                raise RuntimeError(f"SITL instance {self.instance} exited ({self.proc.returncode}): see {self.log}")
            await asyncio.sleep(0.2)
        raise RuntimeError(f"SITL instance {self.instance} did not open tcp {tcp_port(self.instance)} "
                           f"within {timeout_s:.0f} s: see {self.log}")  # fmt: skip

    async def serial_open(self, serial: int, timeout_s: float = 30.0) -> None:
        """Until SITL listens on SERIAL``serial`` (it opens SERIAL1 and up only once SERIAL0 has a client)."""
        line = f"SERIAL{serial} on TCP port"
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if line in self.log.read_text(errors="replace"):
                return
            if self.proc is not None and self.proc.returncode is not None:
                raise RuntimeError(f"SITL instance {self.instance} exited ({self.proc.returncode}): see {self.log}")
            await asyncio.sleep(0.2)
        raise RuntimeError(f"SITL instance {self.instance} did not open SERIAL{serial} within {timeout_s:.0f} s: "
                           f"see {self.log}")  # fmt: skip

    async def __aexit__(self, *exc: object) -> None:
        proc = self.proc
        if proc is None or proc.returncode is not None:
            return
        for sig, wait_s in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 5.0)):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, sig)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(proc.wait(), wait_s)
                return


class Truth:
    """SITL's own state, never the autopilot's belief: SIM_STATE (#108) asked for at ``rate_hz`` on a port the
    proxy does not carry (SERIAL1), stamped on arrival (wall time) in a reader thread."""

    def __init__(self, port: int, sysid: int = 1, rate_hz: float = 20.0) -> None:
        self.port, self.sysid, self.rate_hz = port, sysid, rate_hz
        self.samples: list[tuple[float, float]] = []  # (wall s, altitude AMSL m)
        self.positions: list[tuple[float, float, float]] = []  # (wall s, latitude deg, longitude deg)
        self.error: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sitl-truth", daemon=True)

    def start(self) -> Truth:
        self._thread.start()
        return self

    def _connect(self) -> Any:
        from pymavlink import mavutil

        end = time.monotonic() + 60.0
        while not self._stop.is_set():
            try:
                return mavutil.mavlink_connection(f"tcp:127.0.0.1:{self.port}", source_system=254,
                                                  dialect="ardupilotmega", retries=0)  # fmt: skip
            except OSError:
                if time.monotonic() > end:
                    raise
                time.sleep(0.5)
        return None

    def _run(self) -> None:
        from pymavlink import mavutil

        try:
            conn = self._connect()
        except OSError as exc:
            self.error = f"no SITL on tcp {self.port}: {exc}"
            return
        if conn is None:
            return
        m = mavutil.mavlink
        asked = 0.0
        while not self._stop.is_set():
            if not self.samples and time.monotonic() - asked > 2.0:  # again until it comes (SITL may still boot)
                conn.mav.command_long_send(self.sysid, 1, m.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                           m.MAVLINK_MSG_ID_SIM_STATE, 1e6 / self.rate_hz, 0, 0, 0, 0, 0)  # fmt: skip
                asked = time.monotonic()
            msg = conn.recv_match(type="SIM_STATE", blocking=True, timeout=0.5)
            if msg is not None:
                now = time.time()
                self.samples.append((now, float(msg.alt)))
                # lat_int/lon_int (degE7, MAVLink 2 extensions) when sent; lat/lon are float degrees
                lat_e7, lon_e7 = getattr(msg, "lat_int", 0), getattr(msg, "lon_int", 0)
                latlon = (lat_e7 * 1e-7, lon_e7 * 1e-7) if lat_e7 or lon_e7 else (float(msg.lat), float(msg.lon))
                self.positions.append((now, *latlon))
        conn.close()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def heights(self, ground_before_s: float) -> tuple[list[tuple[float, float]], float]:
        """(wall s, true height above ground) and the ground's altitude: the median before ``ground_before_s``."""
        if not self.samples:
            raise RuntimeError(f"no SIM_STATE from SITL on tcp {self.port}: no ground truth to score")
        before = [a for t, a in self.samples if t < ground_before_s] or [a for _, a in self.samples[:20]]
        ground = statistics.median(before)
        return [(t, a - ground) for t, a in self.samples], ground


async def serve(binary: Path, n: int, first: int, speedup: float, home: str, extra: Sequence[Path]) -> int:
    """``n`` instances (vehicle k: sysid k+1, instance first+k) until one stops or we are told to stop."""
    async with contextlib.AsyncExitStack() as stack:
        sitls = [await stack.enter_async_context(Sitl(binary, first + k, k + 1, speedup, home, extra))
                 for k in range(n)]  # fmt: skip
        for k, s in enumerate(sitls):
            print(f"vehicle {k}: sysid {k + 1}, instance {s.instance}, MAVLink tcp://127.0.0.1:{tcp_port(s.instance)}, "
                  f"log {s.log}", flush=True)  # fmt: skip
        waits = [asyncio.ensure_future(s.proc.wait()) for s in sitls if s.proc is not None]
        try:
            await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for w in waits:
                w.cancel()
        print(f"a SITL instance stopped; see {cache_dir() / 'run'}/*/sitl.log", file=sys.stderr)
    return 1


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m demos.sitl", description="Run N ArduCopter SITL vehicles with "
                                "the bench's parameters (what scripts/sitl/ardupilot.sh run does).")  # fmt: skip
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="N vehicles (default 1); vehicle k on tcp 5760+10*(k+SITL_INSTANCE)")
    run.add_argument("n", nargs="?", type=int, default=1)
    sub.add_parser("params", help="print the path of the bench's parameter file")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Environment as ``ardupilot.sh`` documents it: ARDUPILOT_BIN, SECUAV_ARDUPILOT_CACHE, SITL_INSTANCE,
    SITL_SPEEDUP, SITL_HOME, SITL_EXTRA_PARM (comma-separated files applied after the bench's)."""
    args = build_parser().parse_args(argv)
    if args.command == "params":
        print(PARAMS)
        return 0
    env = os.environ
    try:
        first = int(env.get("SITL_INSTANCE", "0"))
        speedup = float(env.get("SITL_SPEEDUP", "1"))
    except ValueError as exc:
        print(f"demos.sitl: SITL_INSTANCE or SITL_SPEEDUP: {exc}", file=sys.stderr)
        return 2
    if args.n < 1 or first < 0:
        print(f"demos.sitl: run needs N >= 1 and SITL_INSTANCE >= 0, got {args.n} and {first}", file=sys.stderr)
        return 2
    extra = [Path(x) for x in env.get("SITL_EXTRA_PARM", "").split(",") if x]
    try:
        binary = find_binary()
        copter_defaults(binary)
    except NoSitl as exc:
        print(f"demos.sitl: {exc}", file=sys.stderr)
        return 3
    loop = asyncio.new_event_loop()
    task = loop.create_task(serve(binary, args.n, first, speedup, env.get("SITL_HOME") or HOME, extra))
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, task.cancel)
    try:
        return loop.run_until_complete(task)
    except asyncio.CancelledError:
        return 0
    finally:
        loop.close()


if __name__ == "__main__":
    sys.exit(main())
