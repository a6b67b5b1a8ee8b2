"""The ground station of ``secuav-demo command-tamper``: upload a mission, read it back, take off, fly it.

A plain pymavlink script behind ``secuav-proxy``, for ArduCopter (SITL or real) or ``secuav-sim``
(which answers like PX4). In order, each step logged as a JSON line with its wall time:

1. waits for the autopilot and its HOME_POSITION (asked for with MAV_CMD_REQUEST_MESSAGE);
2. uploads a small mission (MISSION_COUNT, answering each MISSION_REQUEST(_INT) with a MISSION_ITEM_INT):
   takeoff to ``--mission-alt``, one waypoint ``--wp-north``/``--wp-east`` metres from home, RTL. On
   ArduPilot item 0 is its home slot (ArduPilot fills it with its own home), so the mission proper is
   items 1..3; on PX4 it is items 0..2. Then reads it back (MISSION_REQUEST_LIST, MISSION_REQUEST_INT);
3. arms and takes off to ``--takeoff`` metres above home: ArduPilot in GUIDED with COMMAND_LONG
   MAV_CMD_NAV_TAKEOFF, param7 the altitude above home (what MAVProxy's ``takeoff`` sends); PX4 with
   COMMAND_INT in MAV_FRAME_GLOBAL_RELATIVE_ALT, z the altitude above home (PX4 reads a COMMAND_LONG's
   param7 as AMSL), retried until the autopilot accepts (its pre-arm checks pass);
4. waits until the climb is over (vertical speed under 0.2 m/s for 3 s), then MAV_CMD_MISSION_START;
5. waits until the waypoint is reached (MISSION_ITEM_REACHED, or MISSION_CURRENT past it), holds
   ``--dwell`` seconds and logs "done". It does not land: the demo stops the simulator.

It believes what the vehicle tells it, as any ground station does; the truth is the simulator's.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, field
from typing import Any

from pymavlink import mavutil

from demos.controllers.height_hold import GUIDED, Link, pymavlink_url
from demos.controllers.ranging import Log, run_logged
from secuav_common.geo import ned_to_geodetic
from secuav_common.scenario import Home

_M = mavutil.mavlink
ARM_TIMEOUT_S = 240.0  # ArduPilot arms once its EKF has converged and GPS is good (40-60 s after boot)
HOME_TIMEOUT_S = 180.0
STEP_TIMEOUT_S = 5.0  # one mission protocol answer
CLIMB_TIMEOUT_S = 45.0
STILL_M_S, STILL_S = 0.2, 3.0
WAYPOINT_TIMEOUT_S = 120.0
PX4_TAKEOFF = (4, 2)  # PX4 custom mode AUTO (4) / TAKEOFF (2): where NAV_TAKEOFF leaves it; arming needs a mode
PX4_HOLD = (4, 3)  # AUTO / LOITER ("Hold")
# what a read-back must give back exactly (MISSION_ITEM_INT fields; "current" is the autopilot's to set)
COMPARED = ("seq", "frame", "command", "autocontinue", "param1", "param2", "param3", "param4", "x", "y", "z",
            "mission_type")  # fmt: skip


def mission(home: Home, autopilot: str, north_m: float, east_m: float, alt_m: float) -> list[dict[str, Any]]:
    """The mission the ground station sends (MISSION_ITEM_INT fields): takeoff, one waypoint, RTL."""
    lat, lon, _ = ned_to_geodetic(home, north_m, east_m, 0.0)
    here = (round(home.lat_deg * 1e7), round(home.lon_deg * 1e7))
    rel = _M.MAV_FRAME_GLOBAL_RELATIVE_ALT
    items = [
        (_M.MAV_CMD_NAV_TAKEOFF, rel, *here, alt_m),
        (_M.MAV_CMD_NAV_WAYPOINT, rel, round(lat * 1e7), round(lon * 1e7), alt_m),
        (_M.MAV_CMD_NAV_RETURN_TO_LAUNCH, _M.MAV_FRAME_GLOBAL, 0, 0, 0.0),  # no position: ArduPilot reads back 0
    ]
    if autopilot == "ardupilot":  # item 0: ArduPilot's home slot, overwritten with its own home
        items.insert(0, (_M.MAV_CMD_NAV_WAYPOINT, _M.MAV_FRAME_GLOBAL, *here, home.alt_m))
    return [{"seq": i, "frame": frame, "command": cmd, "current": 0, "autocontinue": 1, "param1": 0.0,
             "param2": 0.0, "param3": 0.0, "param4": 0.0, "x": x, "y": y, "z": float(z), "mission_type": 0}
            for i, (cmd, frame, x, y, z) in enumerate(items)]  # fmt: skip


def first_compared(autopilot: str) -> int:
    """The first seq a read-back is compared from: ArduPilot answers item 0 with its own home."""
    return 1 if autopilot == "ardupilot" else 0


def differences(sent: list[dict[str, Any]], back: list[dict[str, Any]], start: int) -> list[str]:
    """The differences, one "seq N field: sent a, read b" per compared field (NaN equals NaN); [] when equal."""
    out = [] if len(sent) == len(back) else [f"count: sent {len(sent)}, read {len(back)}"]
    for s, b in zip(sent[start:], back[start:], strict=False):
        for k in COMPARED:
            a, c = s[k], b.get(k)
            same = a == c or (isinstance(a, float) and isinstance(c, float) and math.isnan(a) and math.isnan(c))
            if not same:
                out.append(f"seq {s['seq']} {k}: sent {a}, read {c}")
    return out


@dataclass
class Station(Link):
    """The height-hold controller's link, keeping also what the mission protocol and the climb need."""

    home: Home | None = None
    vz_m_s: float = math.nan
    inbox: list[Any] = field(default_factory=list)
    reached: set[int] = field(default_factory=set)
    current_seq: int = -1
    still_since: float | None = None

    def take(self, m: Any, now: float) -> None:
        super().take(m, now)
        if self.sysid and m.get_srcSystem() != self.sysid:
            return
        kind = m.get_type()
        if kind == "HOME_POSITION":
            self.home = Home(lat_deg=m.latitude * 1e-7, lon_deg=m.longitude * 1e-7, alt_m=m.altitude * 1e-3)
        elif kind == "GLOBAL_POSITION_INT":
            self.vz_m_s = m.vz / 100.0
        elif kind == "MISSION_ITEM_REACHED":
            self.reached.add(int(m.seq))
        elif kind == "MISSION_CURRENT":
            self.current_seq = int(m.seq)
        elif kind.startswith("MISSION_"):
            self.inbox.append(m)

    def expect(self, kinds: tuple[str, ...], timeout_s: float = STEP_TIMEOUT_S) -> Any | None:
        """The first mission-protocol message of one of ``kinds`` (taken off the inbox), None on timeout."""
        found: list[Any] = []

        def got() -> bool:
            for i, m in enumerate(self.inbox):
                if m.get_type() in kinds:
                    found.append(self.inbox.pop(i))
                    return True
            return False

        self.wait(got, timeout_s)
        return found[0] if found else None

    def item_send(self, it: dict[str, Any]) -> None:
        self.conn.mav.mission_item_int_send(
            self.sysid, self.compid, it["seq"], it["frame"], it["command"], it["current"], it["autocontinue"],
            it["param1"], it["param2"], it["param3"], it["param4"], it["x"], it["y"], it["z"], it["mission_type"],
        )  # fmt: skip


def upload(st: Station, items: list[dict[str, Any]]) -> int:
    """The mission protocol's upload; the MISSION_ACK's result (``MAV_MISSION_ACCEPTED`` is 0)."""
    st.inbox.clear()
    for _ in range(3):  # a lost MISSION_COUNT is sent again
        st.conn.mav.mission_count_send(st.sysid, st.compid, len(items), 0)
        while (m := st.expect(("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"))) is not None:
            if m.get_type() == "MISSION_ACK":
                return int(m.type)
            if 0 <= m.seq < len(items):
                st.item_send(items[m.seq])
    raise SystemExit("the mission upload got no MISSION_ACK")


def download(st: Station) -> list[dict[str, Any]]:
    """The mission protocol's download: the items as the vehicle answers them (MISSION_ITEM_INT fields)."""
    st.inbox.clear()
    count = None
    for _ in range(3):
        st.conn.mav.mission_request_list_send(st.sysid, st.compid, 0)
        count = st.expect(("MISSION_COUNT",))
        if count is not None:
            break
    if count is None:
        raise SystemExit("the mission download got no MISSION_COUNT")
    items: list[dict[str, Any]] = []
    for seq in range(int(count.count)):
        got = None
        for _ in range(3):
            st.conn.mav.mission_request_int_send(st.sysid, st.compid, seq, 0)
            got = st.expect(("MISSION_ITEM_INT",))
            if got is not None and got.seq == seq:
                break
        if got is None:
            raise SystemExit(f"the mission download got no item {seq}")
        d = got.to_dict()
        items.append({k: d[k] for k in (*COMPARED, "current")})
    st.conn.mav.mission_ack_send(st.sysid, st.compid, _M.MAV_MISSION_ACCEPTED, 0)
    return items


def set_px4_mode(st: Station, main: int, sub: int) -> int | None:
    return st.command(_M.MAV_CMD_DO_SET_MODE, _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)


def take_off(st: Station, autopilot: str, altitude_m: float, log: Log) -> str:
    """Arm and ask for ``altitude_m`` above home, retried until accepted; the message that carried it."""
    ok = _M.MAV_RESULT_ACCEPTED
    end = time.monotonic() + ARM_TIMEOUT_S
    while time.monotonic() < end:
        # again each time: SITL reads its RC mode switch once RC input starts, which can undo an early GUIDED
        mode = st.set_mode(GUIDED) if autopilot == "ardupilot" else set_px4_mode(st, *PX4_HOLD)
        if mode == ok and st.command(_M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ok:
            log.write("event", event="armed")
            if autopilot == "ardupilot":
                sent = "COMMAND_LONG"
                result = st.command(_M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, altitude_m)
            else:
                sent = "COMMAND_INT"
                result = command_int(st, _M.MAV_CMD_NAV_TAKEOFF, altitude_m)
            log.write("event", event="takeoff-sent", message=sent, altitude_m=altitude_m, result=result)
            if result == ok:
                return sent
        st.wait(lambda: False, 2.0)
    raise SystemExit(f"the vehicle did not arm and take off within {ARM_TIMEOUT_S:.0f} s")


def command_int(st: Station, cmd: int, z: float, timeout_s: float = 3.0) -> int | None:
    """COMMAND_INT in MAV_FRAME_GLOBAL_RELATIVE_ALT with no position (x = y = 0) and ``z``; the ack's result."""
    st.acks.clear()
    st.conn.mav.command_int_send(st.sysid, st.compid, _M.MAV_FRAME_GLOBAL_RELATIVE_ALT, cmd, 0, 0,
                                 0.0, 0.0, 0.0, math.nan, 0, 0, z)  # fmt: skip
    st.wait(lambda: any(a.command == cmd for a in st.acks), timeout_s)
    return next((int(a.result) for a in st.acks if a.command == cmd), None)


def climbed(st: Station) -> bool:
    """True once the vertical speed has stayed under STILL_M_S for STILL_S above 1 m (call it in a loop)."""
    now = time.monotonic()
    moving = not (math.isfinite(st.vz_m_s) and abs(st.vz_m_s) < STILL_M_S and st.relative_alt_m > 1.0)
    if moving:
        st.still_since = None
        return False
    if st.still_since is None:
        st.still_since = now
    return now - st.still_since >= STILL_S


def fly(args: argparse.Namespace, log: Log) -> None:
    conn = mavutil.mavlink_connection(pymavlink_url(args.url), source_system=255, source_component=190,
                                      dialect="ardupilotmega")  # fmt: skip
    st = Station(conn)
    try:
        if not st.wait(lambda: st.sysid != 0, args.connect_timeout):
            raise SystemExit(f"no autopilot answered on {args.url}")
        log.write("event", event="connected", sysid=st.sysid)
        end = time.monotonic() + HOME_TIMEOUT_S
        while st.home is None and time.monotonic() < end:  # ArduPilot sets its home once GPS is good
            st.command(_M.MAV_CMD_REQUEST_MESSAGE, _M.MAVLINK_MSG_ID_HOME_POSITION, timeout_s=1.0)
            st.wait(lambda: st.home is not None, 2.0)
        if st.home is None:
            raise SystemExit(f"no HOME_POSITION within {HOME_TIMEOUT_S:.0f} s")
        home = st.home
        log.write("event", event="home", lat_deg=home.lat_deg, lon_deg=home.lon_deg, alt_m=home.alt_m)
        sent = mission(home, args.autopilot, args.wp_north, args.wp_east, args.mission_alt)
        result = upload(st, sent)
        log.write("event", event="mission-sent", items=sent, result=result)
        back = download(st)
        log.write("event", event="mission-read", items=back,
                  differences=differences(sent, back, first_compared(args.autopilot)))  # fmt: skip
        take_off(st, args.autopilot, args.takeoff, log)
        st.wait(lambda: climbed(st), CLIMB_TIMEOUT_S)
        log.write("event", event="climbed", vehicle_alt_m=round(st.relative_alt_m, 3))
        start = st.command(_M.MAV_CMD_MISSION_START, 0, 0)
        log.write("event", event="mission-start", result=start)
        wp = 1 + first_compared(args.autopilot)
        got = st.wait(lambda: wp in st.reached or st.current_seq > wp, WAYPOINT_TIMEOUT_S)
        log.write("event", event="waypoint-reached" if got else "waypoint-timeout", seq=wp)
        st.wait(lambda: False, args.dwell)
        log.write("event", event="done", vehicle_alt_m=round(st.relative_alt_m, 3))
    finally:
        conn.close()


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--url", default="udpin://127.0.0.1:14540", help="where the proxy's ground side sends")
    p.add_argument("--autopilot", choices=("ardupilot", "flightsim"), default="ardupilot")
    p.add_argument("--takeoff", type=float, default=5.0, help="takeoff altitude above home, metres")
    p.add_argument("--wp-north", type=float, default=0.0, help="the waypoint, metres north of home")
    p.add_argument("--wp-east", type=float, default=30.0, help="the waypoint, metres east of home")
    p.add_argument("--mission-alt", type=float, default=10.0, help="the mission's altitude above home, metres")
    p.add_argument("--dwell", type=float, default=2.0, help="seconds flown after the waypoint before 'done'")
    p.add_argument("--connect-timeout", type=float, default=60.0)
    p.add_argument("--log", help="write JSON lines (events) to this file")
    run_logged(fly, p.parse_args(argv))


if __name__ == "__main__":
    main()
