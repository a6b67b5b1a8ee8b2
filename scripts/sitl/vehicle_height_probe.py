#!/usr/bin/env python3
"""ArduCopter SITL holding its height on companion-fed MAVLink rangefinders, and a bias on some feeds.

The attack-on case of issue 33's first demo, flown once, without the demo around it (docs/vehicle-inputs.md).
Not part of CI: it needs the binary ``scripts/sitl/ardupilot.sh build`` caches.

    .venv/bin/python scripts/sitl/vehicle_height_probe.py [--biased 0,1,2] [--bias 2] [--instance 6]

It starts ``ardupilot.sh run 1`` with demos/ardupilot/vehicle-rangefinders.parm (three MAVLink rangefinders,
EKF3's height from them), ``secuav-proxy`` in front of it, and a companion on the proxy's ground side that
sends DISTANCE_SENSOR ids 0, 1, 2 (at 9.7, 10.3, 10.0 Hz) computed from SIM_STATE's true height (plus the
rangefinder's 0.1 m ground clearance), read on SITL's second port, which the proxy does not carry. Through
the proxy: GUIDED, arm, take-off to 5 m (retried until ArduPilot's pre-arm checks pass); once the autopilot's
height has held 10 s, the feeds named by ``--biased`` ramp to ``--bias`` m more over 4 s, 20 s are flown,
then LAND. Printed: the true height and the autopilot's (LOCAL_POSITION_NED) before and after the bias.
Exit status 0 when the flight was flown (whatever the heights did), 1 otherwise, 2 without a binary.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from check_inputs import BIN, COMPANION, HERE, ROOT, Feeder, InputPath, Reader, connect, heartbeat, mav, send_distance
from sitl_check import free_port, stop, wait_for_text

GUIDED, LAND = 4, 9
TAKEOFF_M = 5.0
CLEARANCE_M = 0.1  # RNGFND1_GNDCLEAR's default: what a downward rangefinder reads on the ground
TYPES = {"SIM_STATE", "LOCAL_POSITION_NED", "HEARTBEAT", "COMMAND_ACK", "RANGEFINDER", "STATUSTEXT"}


def command(link: Reader, cmd: int, *params: float) -> int | None:
    """COMMAND_LONG to the autopilot; its COMMAND_ACK result, or None after 3 s."""
    t0 = time.time()
    p = [*params, *[0.0] * (7 - len(params))]
    link.send(lambda m: m.command_long_send(link.sysid, 1, cmd, 0, *p))
    end = time.monotonic() + 3
    while time.monotonic() < end:
        with link.lock:
            acks = [m for t, m in link.seen.get("COMMAND_ACK", ()) if t >= t0 and m.command == cmd]
        if acks:
            return int(acks[-1].result)
        time.sleep(0.05)
    return None


def median_since(link: Reader, kind: str, value: object, t0: float, t1: float) -> float | None:
    got = [value(m) for t, m in list(link.seen.get(kind, ())) if t0 <= t <= t1]  # type: ignore[operator]
    return statistics.median(got) if got else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--biased", default="0,1,2", help="DISTANCE_SENSOR ids to bias (default 0,1,2)")
    parser.add_argument("--bias", type=float, default=2.0, help="metres added to them (default 2)")
    parser.add_argument("--instance", type=int, default=6, help="SITL instance (default 6: tcp 5820, 5822)")
    args = parser.parse_args(argv)
    cache = Path(os.environ.get("SECUAV_ARDUPILOT_CACHE", Path.home() / ".cache/secuav/ardupilot"))
    if not (cache / "latest" / "arducopter").exists() and "ARDUPILOT_BIN" not in os.environ:
        print(f"no SITL binary under {cache}/latest: run scripts/sitl/ardupilot.sh build SOURCE first")
        return 2
    biased = {int(x) for x in args.biased.split(",") if x}
    work = Path(os.environ.get("TMPDIR", "/tmp")) / f"secuav-height-probe-{os.getpid()}"
    work.mkdir(parents=True, exist_ok=True)
    log = cache / "run" / str(args.instance) / "sitl.log"
    log.unlink(missing_ok=True)
    env = dict(os.environ, SITL_INSTANCE=str(args.instance),
               SITL_EXTRA_PARM=str(ROOT / "demos" / "ardupilot" / "vehicle-rangefinders.parm"))
    sitl = subprocess.Popen(["bash", str(HERE / "ardupilot.sh"), "run", "1"], stdout=(work / "sitl-run.log").open("wb"),
                            stderr=subprocess.STDOUT, start_new_session=True, env=env)  # fmt: skip
    proxy = None
    links: dict[str, Reader] = {}
    feeder = None
    try:
        if not wait_for_text(log, "Waiting for connection", 1, 60):
            print(f"FAIL: SITL did not start: see {log}")
            return 1
        ground = free_port()
        cmd = [str(BIN / "secuav-proxy"), "--vehicle", f"tcp://127.0.0.1:{5760 + 10 * args.instance}",
               "--ground", f"udpout://127.0.0.1:{ground}", "--broker", "none"]  # fmt: skip
        proxy = subprocess.Popen(cmd, stdout=(work / "proxy.log").open("wb"), stderr=subprocess.STDOUT,
                                 start_new_session=True)
        links["proxy"] = Reader("proxy", connect(f"udpin:127.0.0.1:{ground}", 1), 1, TYPES).start()
        links["direct"] = Reader("direct", connect(f"tcp:127.0.0.1:{5762 + 10 * args.instance}", 1), 1, TYPES).start()
        gcs, truth = links["proxy"], links["direct"]
        while gcs.latest("HEARTBEAT") is None:
            gcs.send(heartbeat)
            time.sleep(1)
        for _ in range(10):
            truth.send(lambda m: m.command_long_send(1, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                                     mav.MAVLINK_MSG_ID_SIM_STATE, 50_000, 0, 0, 0, 0, 0))  # fmt: skip
            time.sleep(1)
            if truth.latest("SIM_STATE") is not None:
                break
        feeder = Feeder(truth, "SIM_STATE", links)
        for sensor_id, rate in ((0, 9.7), (1, 10.3), (2, 10.0)):
            feeder.add(InputPath(f"id {sensor_id}", "DISTANCE_SENSOR", "", CLEARANCE_M, 0.0, 0.0, rate,
                                 send_distance(sensor_id), []), "proxy")  # fmt: skip
        feeder.start()
        print(f"companion {COMPANION} feeding ids 0, 1, 2 through the proxy; taking off to {TAKEOFF_M:g} m", flush=True)
        t_arm = time.monotonic()
        while True:
            if time.monotonic() - t_arm > 180:
                print("FAIL: ArduPilot did not arm and take off within 180 s")
                return 1
            ok = mav.MAV_RESULT_ACCEPTED
            if (command(gcs, mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED) == ok
                    and command(gcs, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ok
                    and command(gcs, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, TAKEOFF_M) == ok):
                break
            time.sleep(2)
        print(f"armed and taking off {time.monotonic() - t_arm:.0f} s after the first try", flush=True)
        end = time.monotonic() + 60
        while time.monotonic() < end:
            lp = gcs.latest("LOCAL_POSITION_NED")
            if lp is not None and -lp.z > TAKEOFF_M - 0.3:
                break
            time.sleep(0.2)
        time.sleep(10)

        def heights(t0: float, t1: float) -> tuple[float | None, float | None]:
            assert feeder is not None and feeder.ref is not None
            ref = feeder.ref.alt_m
            true = median_since(truth, "SIM_STATE", lambda m: m.alt - ref, t0, t1)
            est = median_since(gcs, "LOCAL_POSITION_NED", lambda m: -m.z, t0, t1)
            return true, est

        t_bias = time.time()
        before = heights(t_bias - 5, t_bias)
        for sensor_id in biased:
            feeder.offsets[f"id {sensor_id}"].to(CLEARANCE_M + args.bias, t_bias, 4.0)
        time.sleep(20)
        t_after = time.time()
        after = heights(t_after - 5, t_after)
        rf = median_since(gcs, "RANGEFINDER", lambda m: m.distance, t_after - 5, t_after)
        command(gcs, mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, LAND)
        ids = ", ".join(str(i) for i in sorted(biased)) or "none"

        def fmt(x: float | None) -> str:
            return "none" if x is None else f"{x:.2f}"

        print(f"biased ids {ids} by +{args.bias:g} m (ramped over 4 s), 20 s flown; medians of the last 5 s:")
        print(f"  true height (SIM_STATE):             before {fmt(before[0])} m, after {fmt(after[0])} m")
        print(f"  autopilot's height (LOCAL_POSITION): before {fmt(before[1])} m, after {fmt(after[1])} m")
        print(f"  autopilot's RANGEFINDER after: {fmt(rf)} m")
        texts = [m.text for _, m in gcs.seen.get("STATUSTEXT", ()) if "EKF" in m.text or "ange" in m.text]
        print("  its STATUSTEXT about the EKF or the rangefinder: " + ("; ".join(texts[-6:]) or "none"))
        time.sleep(8)
        return 0
    finally:
        if feeder is not None:
            feeder.stop()
        for link in links.values():
            link.close()
        stop(proxy)
        time.sleep(0.5)
        stop(sitl)


if __name__ == "__main__":
    sys.exit(main())
