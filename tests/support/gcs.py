"""A small blocking ground station on pymavlink's ``mavutil``, as MAVProxy and scripts use it.

Tests run it in a worker thread (``asyncio.to_thread``) while the simulator
ticks in the event loop, so blocking reads never stall the vehicle.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from pymavlink import mavutil

Message = object
GCS_SYSID, GCS_COMPID = 255, 190


class Gcs:
    def __init__(self, port: int, target_system: int = 1) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", source_system=GCS_SYSID, source_component=GCS_COMPID
        )
        self.target = target_system
        self.texts: list[str] = []

    @property
    def mav(self) -> mavutil.mavlink.MAVLink:
        return self.conn.mav

    def close(self) -> None:
        self.conn.close()

    def recv(
        self, kind: str | list[str], timeout_s: float = 3.0, cond: Callable[[object], bool] | None = None
    ) -> object:
        """The next message of ``kind`` from our vehicle meeting ``cond``; fails after ``timeout_s``."""
        kinds = [kind] if isinstance(kind, str) else kind
        end = time.monotonic() + timeout_s
        while True:
            left = end - time.monotonic()
            if left <= 0:
                raise AssertionError(f"no {kinds} within {timeout_s} s")
            msg = self.conn.recv_match(blocking=True, timeout=min(left, 0.2))
            if msg is None or msg.get_srcSystem() != self.target:
                continue
            if msg.get_type() == "STATUSTEXT":
                self.texts.append(msg.text)
            if msg.get_type() in kinds and (cond is None or cond(msg)):
                return msg

    def expect_text(self, contains: str, timeout_s: float = 2.0) -> str:
        """A STATUSTEXT containing ``contains`` (case-insensitive), seen already or arriving soon."""
        want = contains.lower()
        for text in self.texts:
            if want in text.lower():
                return text
        return str(self.recv("STATUSTEXT", timeout_s, lambda m: want in m.text.lower()).text)

    def drain(self) -> None:
        while self.conn.recv_match(blocking=False) is not None:
            pass

    def heartbeat_mode(self, timeout_s: float = 3.0) -> str:
        """The mode name MAVProxy would show for the next HEARTBEAT."""
        hb = self.recv("HEARTBEAT", timeout_s)
        return str(mavutil.mode_string_v10(hb))

    def wait_mode(self, name: str, timeout_s: float) -> None:
        self.recv("HEARTBEAT", timeout_s, lambda m: mavutil.mode_string_v10(m) == name)

    def command(self, command: int, *params: float, timeout_s: float = 2.0) -> int:
        """COMMAND_LONG; the MAV_RESULT of its COMMAND_ACK."""
        p = list(params) + [math.nan] * (7 - len(params))
        self.mav.command_long_send(self.target, 1, command, 0, *p)
        ack = self.recv("COMMAND_ACK", timeout_s, lambda m: m.command == command)
        return int(ack.result)

    def set_px4_mode(self, name: str) -> int:
        """DO_SET_MODE the way MAVProxy's ``mode NAME`` does for PX4 (pymavlink's px4_map)."""
        base, main, sub = mavutil.px4_map[name]
        return self.command(mavutil.mavlink.MAV_CMD_DO_SET_MODE, base, main, sub)
