"""PX4 SIH for the demos: the cached binary, and one vehicle started the way ``scripts/sitl/px4.sh run`` does.

Nothing of PX4 is in the package: ``scripts/sitl/px4.sh build`` caches a build in ``~/.cache/secuav/px4``
(docs/px4.md). A demo that flies PX4 and finds no binary stops with :class:`NoPx4`, which ``secuav-demo``
turns into one line and exit 3, as it does for ArduPilot.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PX4_SH = ROOT / "scripts" / "sitl" / "px4.sh"
PARAMS_DIR = ROOT / "scripts" / "sitl" / "px4"
DEFAULT_INSTANCE = 5  # PX4's ports 18570+I and run folder; check_px4.py uses 3, check_inputs.py 4
BUILD_HINT = "build one with scripts/sitl/px4.sh build SOURCE (docs/px4.md)"
STARTED = "Startup script returned successfully"


class NoPx4(RuntimeError):
    """No usable PX4 SITL binary (or no px4.sh to run it); the message says what to do."""


def cache_dir() -> Path:
    return Path(os.environ.get("SECUAV_PX4_CACHE") or Path.home() / ".cache" / "secuav" / "px4")


def find_binary(given: str | os.PathLike[str] | None = None) -> Path:
    """``given``, else ``$PX4_BIN``, else the cache's newest build; :class:`NoPx4` if it is not there."""
    if given:
        path, origin = Path(given), "--sitl-binary"
    elif os.environ.get("PX4_BIN"):
        path, origin = Path(os.environ["PX4_BIN"]), "PX4_BIN"
    else:
        path, origin = cache_dir() / "latest" / "bin" / "px4", "the cache"
    if not (path.is_file() and os.access(path, os.X_OK)):
        raise NoPx4(f"no PX4 SITL binary at {path} ({origin}): {BUILD_HINT}")
    if not (path.parent.parent / "etc").is_dir():
        raise NoPx4(f"{path}: no etc/ beside its bin/ (PX4's rcS and airframes): {BUILD_HINT}")
    if not PX4_SH.is_file():
        raise NoPx4(f"{PX4_SH}: missing; the PX4 demos run from a source checkout of SecUAV")
    return path


def build_info(binary: Path) -> dict[str, str]:
    """What ``px4.sh build`` wrote beside the binary: the tree's ``git describe``."""
    commit = binary.parent.parent / "commit"
    return {"commit": commit.read_text(encoding="utf-8").strip() if commit.is_file() else "?"}


@dataclass(frozen=True, slots=True)
class Px4Options:
    binary: Path
    instance: int = DEFAULT_INSTANCE


class Px4:
    """One SIH quadrotor (sysid 1), its GCS link to ``proxy_port`` and a second, direct link to ``direct_port``."""

    def __init__(self, opts: Px4Options, params: Path, proxy_port: int, direct_port: int, log: Path) -> None:
        self.opts, self.params, self.log = opts, params, log
        self.proxy_port, self.direct_port = proxy_port, direct_port
        self.run_log = cache_dir() / "run" / str(opts.instance) / "px4.log"
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        self.run_log.unlink(missing_ok=True)
        env = dict(os.environ, PX4_BIN=str(self.opts.binary), PX4_INSTANCE=str(self.opts.instance),
                   SECUAV_PX4_PROXY_PORT=str(self.proxy_port), SECUAV_PX4_DIRECT_PORT=str(self.direct_port),
                   SECUAV_PX4_PARAMS=str(self.params))  # fmt: skip
        self.proc = subprocess.Popen(["bash", str(PX4_SH), "run", "1"], stdout=self.log.open("wb"),
                                     stderr=subprocess.STDOUT, start_new_session=True, env=env)  # fmt: skip

    def wait_started(self, timeout_s: float = 120.0, stop: threading.Event | None = None) -> None:
        """Until PX4's startup script has run; ``stop`` set: ``RuntimeError`` at once."""
        stop = stop or threading.Event()
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.run_log.is_file() and STARTED in self.run_log.read_text(errors="replace"):
                return
            if self.proc is not None and self.proc.poll() is not None:
                break
            if stop.wait(0.5):
                raise RuntimeError("stopped while PX4 was starting")
        raise RuntimeError(f"PX4 did not finish its startup script in {timeout_s:.0f} s: see {self.run_log}")

    def stop(self) -> None:
        """SIGTERM to px4.sh's process group (it stops its px4), then SIGKILL if it lingers."""
        proc, self.proc = self.proc, None
        if proc is None or proc.poll() is not None:
            return
        for sig, wait_s in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 5.0)):
            try:
                os.killpg(proc.pid, sig)
            except ProcessLookupError:
                return
            try:
                proc.wait(wait_s)
                return
            except subprocess.TimeoutExpired:
                continue
