#!/usr/bin/env python3
"""The proxy in front of a real ArduCopter SITL: what holds and what does not, as figures.

Not part of CI: it needs the SITL binary that ``scripts/sitl/ardupilot.sh build`` makes.
For 1 and then 3 vehicles it starts ``ardupilot.sh run N`` (vehicle i on tcp 5760+10*i, the
parameters of demos/ardupilot/rangefinders.parm: three downward rangefinders), this tree's real
``secuav-proxy`` dialling every vehicle, and a pymavlink ground station on the proxy's ground
port, plus a direct pymavlink link to vehicle 1's second port (tcp 5762) to compare against.
The profile biases each rangefinder by its own offset (+5, +6, +7 m for ids 0, 1, 2), by
quantity: DISTANCE_SENSOR of that id and RANGEFINDER (#173), which ArduPilot fills from the
first downward rangefinder. The flight is GUIDED, an armed MAV_CMD_NAV_TAKEOFF to 10 m, and
LAND. What is checked and printed: sitl_check.py.

    .venv/bin/python scripts/sitl/check_ardupilot.py [--vehicles 1,3] [--keep DIR] [--tlog-out F]

Exit status 0 when every figure that should hold held, 1 otherwise, 2 without a binary. See
docs/ardupilot.md for its output.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from sitl_check import TAKEOFF_M, Autopilot, Link, arguments, command, main, mav, wait_for_text

HERE = Path(__file__).resolve().parent
SITL_SH = HERE / "ardupilot.sh"
GUIDED, LAND = 4, 9  # ArduCopter custom modes


class ArduCopter(Autopilot):
    name = "ArduPilot"
    firmware = "ArduCopter V"
    flight_name = "GUIDED"
    offsets_m = (5.0, 6.0, 7.0)  # bias on DISTANCE_SENSOR id 0, 1, 2
    home_item = True

    def __init__(self, cache: Path) -> None:
        self.cache = cache

    def launch(self, n: int, log: Path) -> subprocess.Popen[bytes]:
        for i in range(n):  # stale logs would satisfy wait_ready
            (self.cache / "run" / str(i) / "sitl.log").unlink(missing_ok=True)
        return subprocess.Popen(["bash", str(SITL_SH), "run", str(n)], stdout=log.open("wb"),
                                stderr=subprocess.STDOUT, start_new_session=True)

    def wait_ready(self, n: int) -> str | None:
        for i in range(n):
            if not wait_for_text(self.cache / "run" / str(i) / "sitl.log", "Waiting for connection", 1, 60):
                return f"SITL instance {i} did not open tcp {5760 + 10 * i}; see {self.cache}/run/{i}/sitl.log"
        return None

    def vehicle_urls(self, n: int) -> list[str]:
        return [f"tcp://127.0.0.1:{5760 + 10 * i}" for i in range(n)]

    def direct_url(self) -> str:
        return "tcp:127.0.0.1:5762"

    def build_text(self) -> str:
        latest = self.cache / "latest"
        return f"binary {latest / 'arducopter'} built from {(latest / 'commit').read_text().strip()}"

    def take_off(self, gcs: Link, sysid: int, out: dict[str, Any]) -> bool:
        # GUIDED again each time: SITL reads its RC mode switch once RC input starts, which can put
        # it back in STABILIZE after an early GUIDED
        mode = set_mode(gcs, sysid, GUIDED)
        out.setdefault("mode", mode)
        if command(gcs, sysid, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) != "MAV_RESULT_ACCEPTED":
            return False
        out["takeoff"] = command(gcs, sysid, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, TAKEOFF_M)
        return bool(out["takeoff"] == "MAV_RESULT_ACCEPTED")

    def land(self, gcs: Link, sysid: int) -> str:
        return set_mode(gcs, sysid, LAND)

    def carriers(self, m: Any) -> list[tuple[int, float]]:
        if m.get_type() == "RANGEFINDER":
            return [(0, float(m.distance))]  # ArduPilot fills it from the first downward rangefinder
        return super().carriers(m)


def set_mode(gcs: Link, sysid: int, mode: int) -> str:
    return command(gcs, sysid, mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode)


if __name__ == "__main__":
    args = arguments(__doc__.split("\n")[0]).parse_args()
    cache = Path(os.environ.get("SECUAV_ARDUPILOT_CACHE", Path.home() / ".cache/secuav/ardupilot"))
    if not (cache / "latest" / "arducopter").exists() and "ARDUPILOT_BIN" not in os.environ:
        print(f"no SITL binary under {cache}/latest: run scripts/sitl/ardupilot.sh build SOURCE first")
        sys.exit(2)
    sys.exit(main(ArduCopter(cache), args))
