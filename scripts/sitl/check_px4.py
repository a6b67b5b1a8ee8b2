#!/usr/bin/env python3
"""The proxy in front of a real PX4 SITL (SIH, no Gazebo): what holds and what does not, as figures.

Not part of CI: it needs the binary that ``scripts/sitl/px4.sh build`` caches. For 1 and then 3
vehicles it starts ``px4.sh run N`` (SIH quadrotors from PX4 instance ``--instance`` on, so
PX4's own ports do not clash with another run; sysids 1..N), each sending its GCS link to the
proxy's ``udpin`` port and a second link of the same streams to this script directly, this
tree's real ``secuav-proxy``, and a pymavlink ground station on the proxy's ground port. The
profile biases SIH's one downward rangefinder (DISTANCE_SENSOR id 0) by +5 m, by quantity. The
flight: DO_SET_MODE to Hold (PX4 custom main mode AUTO, sub mode LOITER), arm,
MAV_CMD_NAV_TAKEOFF to 10 m above the ground (PX4 takes the altitude AMSL), then DO_SET_MODE to
AUTO.LAND; PX4 disarms itself on the ground. Each mode is also looked for in the HEARTBEAT, since
PX4's MAVLink module acknowledges DO_SET_MODE whether or not commander takes it. What is checked
and printed: sitl_check.py.

    .venv/bin/python scripts/sitl/check_px4.py [--vehicles 1,3] [--instance 3] [--keep DIR]

Exit status 0 when every figure that should hold held, 1 otherwise, 2 without a binary. See
docs/px4.md for its output.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

from sitl_check import TAKEOFF_M, Autopilot, Link, arguments, command, free_port, is_, main, mav, wait_for_text

from flightsim.api import FlightMode
from flightsim.mavlink.modes import custom_mode, main_sub

HERE = Path(__file__).resolve().parent
PX4_SH = HERE / "px4.sh"
NAN = float("nan")


def free_udp_block(n: int) -> int:
    """A port P such that P..P+n-1 are free on 127.0.0.1 (PX4 vehicle k sends to P+k)."""
    while True:
        base = free_port()
        socks = []
        try:
            for k in range(n):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind(("127.0.0.1", base + k))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()


class PX4(Autopilot):
    name = "PX4"
    firmware = "PX4 v"
    flight_name = "Hold"
    offsets_m = (5.0,)  # bias on DISTANCE_SENSOR id 0, SIH's downward sensor
    home_item = False  # PX4's mission starts at item 0; home is not an item

    def __init__(self, cache: Path, instance: int) -> None:
        self.cache = cache
        self.instance = instance
        self.proxy_port = self.direct_port = 0

    def launch(self, n: int, log: Path) -> subprocess.Popen[bytes]:
        self.proxy_port, self.direct_port = free_udp_block(n), free_udp_block(n)
        for k in range(n):  # stale logs would satisfy wait_ready
            (self.cache / "run" / str(self.instance + k) / "px4.log").unlink(missing_ok=True)
        env = dict(os.environ, PX4_INSTANCE=str(self.instance), SECUAV_PX4_PROXY_PORT=str(self.proxy_port),
                   SECUAV_PX4_DIRECT_PORT=str(self.direct_port))
        return subprocess.Popen(["bash", str(PX4_SH), "run", str(n)], stdout=log.open("wb"),
                                stderr=subprocess.STDOUT, start_new_session=True, env=env)

    def wait_ready(self, n: int) -> str | None:
        for k in range(n):
            log = self.cache / "run" / str(self.instance + k) / "px4.log"
            if not wait_for_text(log, "Startup script returned successfully", 1, 90):
                return f"PX4 instance {self.instance + k} did not finish its startup script; see {log}"
        return None

    def vehicle_urls(self, n: int) -> list[str]:
        return [f"udpin://127.0.0.1:{self.proxy_port + k}" for k in range(n)]

    def direct_url(self) -> str:
        return f"udpin:127.0.0.1:{self.direct_port}"

    def build_text(self) -> str:
        latest = self.cache / "latest"
        return (f"binary {latest / 'bin' / 'px4'} from {(latest / 'built-in').read_text().strip()}, "
                f"tree {(latest / 'commit').read_text().strip()}")

    def take_off(self, gcs: Link, sysid: int, out: dict[str, Any]) -> bool:
        out.setdefault("mode", set_mode(gcs, sysid, FlightMode.HOLD))
        pos = gcs.wait(is_("GLOBAL_POSITION_INT", sysid), 5.0, max(0, gcs.mark() - 500))
        if pos is None:
            return False
        if command(gcs, sysid, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) != "MAV_RESULT_ACCEPTED":
            return False
        ground_amsl_m = (pos.alt - pos.relative_alt) / 1000.0
        i = gcs.mark()
        ack = command(gcs, sysid, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, ground_amsl_m + TAKEOFF_M)
        out["takeoff"] = f"{ack}, {in_heartbeat(gcs, sysid, FlightMode.TAKEOFF, i)}"
        return ack == "MAV_RESULT_ACCEPTED"

    def land(self, gcs: Link, sysid: int) -> str:
        return set_mode(gcs, sysid, FlightMode.LAND)


def in_heartbeat(gcs: Link, sysid: int, mode: FlightMode, since: int) -> str:
    """Whether the vehicle's HEARTBEAT reports ``mode`` within 3 s of message ``since``."""
    seen = gcs.wait(lambda m: is_("HEARTBEAT", sysid)(m) and m.custom_mode == custom_mode(mode), 3.0, since)
    return f"{mode.name} {'in HEARTBEAT' if seen is not None else 'NOT IN HEARTBEAT'}"


def set_mode(gcs: Link, sysid: int, mode: FlightMode) -> str:
    """MAV_CMD_DO_SET_MODE with PX4's custom main and sub mode (px4_custom_mode.h), and whether the
    HEARTBEAT shows it: PX4's MAVLink module acknowledges DO_SET_MODE before commander sees it."""
    i = gcs.mark()
    ack = command(gcs, sysid, mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, *main_sub(mode))
    return f"{ack}, {in_heartbeat(gcs, sysid, mode, i)}"


if __name__ == "__main__":
    parser = arguments(__doc__.split("\n")[0])
    parser.add_argument("--instance", type=int, default=3,
                        help="first PX4 instance number (default 3: PX4's ports 18570+i etc. move with it)")
    args = parser.parse_args()
    cache = Path(os.environ.get("SECUAV_PX4_CACHE", Path.home() / ".cache/secuav/px4"))
    if not (cache / "latest" / "bin" / "px4").exists() and "PX4_BIN" not in os.environ:
        print(f"no PX4 SITL binary under {cache}/latest: run scripts/sitl/px4.sh build SOURCE first")
        sys.exit(2)
    sys.exit(main(PX4(cache, args.instance), args))
