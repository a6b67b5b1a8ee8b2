"""ArduCopter SITL fed three MAVLink rangefinders through the proxy: a lie toward the vehicle, and the secure
stage on the uplink (issue 33, items 1 and 5). Not in CI: it needs the SITL binary (docs/ardupilot.md).

SITL runs with ``RNGFND1..3_TYPE 10`` (MAVLink rangefinders, facing down). A companion sends
DISTANCE_SENSOR ids 0, 1, 2 reading ``--distance`` metres (1 cm noise) at 10 Hz to the proxy's ground
endpoint; the proxy forwards them to SITL. What the autopilot made of them is read back from its own
RANGEFINDER (#173) and DISTANCE_SENSOR on the downlink. Four cases, one SITL:

- ``clean``: no profile;
- ``lie all``: ``+3 m`` on every DISTANCE_SENSOR toward the vehicle (``direction: uplink``);
- ``lie one``: ``+3 m`` on id 2 only, the last of each burst: ArduPilot's MAVLink rangefinders (this build)
  do not tell DISTANCE_SENSOR ids apart, every one of them takes each message of its orientation, so the
  last message of a burst is what all of them hold when the autopilot reads them;
- ``lie one, secure``: the same, with ``--secure secekf --secure-direction uplink --scenario ardupilot_height``.

    .venv/bin/python scripts/sitl/check_uplink_secure.py [--seconds 20] [--distance 3.0]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from demos.sitl import Sitl, find_binary, tcp_port

ROOT = Path(__file__).resolve().parents[2]
PARAMS = "".join(f"RNGFND{i}_TYPE 10\nRNGFND{i}_ORIENT 25\nRNGFND{i}_MIN 0.2\nRNGFND{i}_MAX 40\n" for i in (1, 2, 3))


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_instance() -> int:
    """A SITL instance whose tcp ports are free (other users of this machine run SITL too)."""
    for instance in range(31, 90):
        if all(_free(tcp_port(instance) + k) for k in range(4)):
            return instance
    raise SystemExit("no free SITL instance")


def profile(ids: list[int] | None) -> dict[str, object]:
    target: dict[str, object] = {"message": "DISTANCE_SENSOR", "direction": "uplink"}
    if ids is not None:
        target["sensor_id"] = ids
    return {"name": "feed-lie", "rules": [{"target": target, "kind": "bias", "offset": 3.0}]}


def run_case(name: str, sitl_port: int, extra: list[str], seconds: float, distance_m: float,
             tmp: Path) -> dict[str, object]:  # fmt: skip
    companion_port = free_port(socket.SOCK_DGRAM)
    log = tmp / f"{name.replace(' ', '_').replace(',', '')}.log"
    argv = [sys.executable, "-m", "mitm_proxy", "--broker", "none", "--vehicle", f"tcp://127.0.0.1:{sitl_port}",
            "--ground", f"udpin://127.0.0.1:{companion_port}", *extra]  # fmt: skip
    with log.open("wb") as sink:
        proxy = subprocess.Popen(argv, cwd=ROOT, stdout=sink, stderr=subprocess.STDOUT,
                                 env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.settimeout(0.02)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=197)  # the companion: the vehicle's sysid, MAV_COMP 197
    parser = mavlink.MAVLink(None)
    rng = random.Random(1)
    rangefinder: list[float] = []
    echoed: dict[int, list[float]] = {}
    try:
        time.sleep(3.0)  # the proxy connects to SITL
        start = time.monotonic()
        boot_ms = 0
        while time.monotonic() - start < seconds:
            boot_ms += 100
            for sid in range(3):
                cm = round((distance_m + rng.gauss(0.0, 0.01)) * 100)
                sock.sendto(bytes(mav.distance_sensor_encode(boot_ms, 20, 4000, cm, 0, sid, 25, 0).pack(mav)),
                            ("127.0.0.1", companion_port))  # fmt: skip
            end = time.monotonic() + 0.1
            while time.monotonic() < end:
                try:
                    data = sock.recv(65536)
                except TimeoutError:
                    continue
                for byte in data:
                    msg = parser.parse_char(bytes([byte]))
                    if msg is None or time.monotonic() - start < seconds / 2:  # the second half: settled
                        continue
                    if msg.get_type() == "RANGEFINDER":
                        rangefinder.append(msg.distance)
                    elif msg.get_type() == "DISTANCE_SENSOR":
                        echoed.setdefault(msg.id, []).append(msg.current_distance / 100.0)
    finally:
        proxy.send_signal(signal.SIGTERM)
        try:
            proxy.wait(10)
        finally:
            if proxy.poll() is None:
                proxy.kill()
        sock.close()

    def spread(xs: list[float]) -> dict[str, float | int]:
        return {"n": len(xs), "median_m": round(statistics.median(xs), 3), "min_m": round(min(xs), 3),
                "max_m": round(max(xs), 3)} if xs else {"n": 0}  # fmt: skip

    return {"case": name, "fed_m": distance_m, "autopilot_RANGEFINDER": spread(rangefinder),
            "autopilot_DISTANCE_SENSOR": {str(k): spread(v) for k, v in sorted(echoed.items())}, "log": str(log)}


async def main_async(args: argparse.Namespace) -> int:
    binary = find_binary(args.sitl_binary)
    instance = free_instance()
    with tempfile.TemporaryDirectory(prefix="secuav-uplink-") as d:
        tmp = Path(d)
        extra = tmp / "mavlink-rangefinders.parm"
        extra.write_text(PARAMS, encoding="utf-8")
        lie_all, lie_one = tmp / "lie-all.json", tmp / "lie-one.json"
        lie_all.write_text(json.dumps(profile(None)), encoding="utf-8")
        lie_one.write_text(json.dumps(profile([2])), encoding="utf-8")
        secure = ["--scenario", "ardupilot_height", "--secure", "secekf", "--secure-direction", "uplink"]
        cases = [("clean", []), ("lie all", ["--profile", str(lie_all)]), ("lie one", ["--profile", str(lie_one)]),
                 ("lie one, secure", ["--profile", str(lie_one), *secure])]  # fmt: skip
        async with Sitl(binary, instance, extra_params=[extra]) as sitl:
            await sitl.ready(120)
            await asyncio.sleep(5.0)  # parameters loaded, EKF up
            for name, flags in cases:
                result = await asyncio.to_thread(run_case, name, tcp_port(instance), flags, args.seconds,
                                                 args.distance, tmp)  # fmt: skip
                print(json.dumps(result), flush=True)
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="per case (the second half is measured)")
    ap.add_argument("--distance", type=float, default=3.0, help="what the companion's rangefinders read, m")
    ap.add_argument("--sitl-binary", default=None)
    return asyncio.run(main_async(ap.parse_args()))


if __name__ == "__main__":
    sys.exit(main())
