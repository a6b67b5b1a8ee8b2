"""The host side of docker/smoke.sh: a pymavlink ground station on the proxy's published port.

    python docker/smoke_client.py HOST:PORT SECONDS

Sends a HEARTBEAT every second (the proxy's ground endpoint listens and answers
whoever speaks first), reads for SECONDS, and prints one JSON line: messages by
type and the mean valid DISTANCE_SENSOR reading in metres per sensor id.
"""

from __future__ import annotations

import json
import sys
import time
from collections import Counter, defaultdict

from pymavlink import mavutil


def main() -> int:
    where, seconds = sys.argv[1], float(sys.argv[2])
    gcs = mavutil.mavlink_connection(f"udpout:{where}", source_system=255, source_component=190)
    counts: Counter[str] = Counter()
    ranges: dict[int, list[float]] = defaultdict(list)
    end = time.monotonic() + seconds
    beat = 0.0
    while time.monotonic() < end:
        if time.monotonic() >= beat:
            gcs.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            beat = time.monotonic() + 1.0
        msg = gcs.recv_match(blocking=True, timeout=0.2)
        if msg is None or msg.get_type() == "BAD_DATA":
            continue
        counts[msg.get_type()] += 1
        if msg.get_type() == "DISTANCE_SENSOR" and msg.min_distance <= msg.current_distance <= msg.max_distance:
            ranges[msg.id].append(msg.current_distance / 100.0)  # a dropout ("no target") is no range
    gcs.close()
    means = {str(k): round(sum(v) / len(v), 3) for k, v in sorted(ranges.items())}
    print(json.dumps({"messages": sum(counts.values()), "by_type": dict(counts.most_common(8)), "range_m": means}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
