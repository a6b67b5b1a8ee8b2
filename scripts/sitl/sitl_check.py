"""The proxy in front of a real autopilot's SITL: what holds and what does not, as figures.

The shared half of ``check_ardupilot.py`` (ArduCopter SITL) and ``check_px4.py`` (PX4 SITL with
SIH); each of those describes its autopilot as an :class:`Autopilot` and calls :func:`main`. Not
part of CI: they need the SITL binaries that ``ardupilot.sh build`` and ``px4.sh build`` make.

For each vehicle count it starts the autopilot's N vehicles, this tree's real ``secuav-proxy``
dialling every vehicle, and a pymavlink ground station on the proxy's ground port, plus a direct
pymavlink link to vehicle 1 around the proxy to compare against. The proxy runs an inline profile
that biases each rangefinder by its own offset, targeted by quantity (``quantity: rangefinder``:
every message that carries it), and records (``--record``). Printed, per run:

- forwarding: every downlink frame no rule targets, as the proxy received it (its
  original.tlog, read back with pymavlink, not with the proxy's code), against what the ground
  station got: identical bytes, same order;
- message types and rates through the proxy against the direct link, over the same seconds;
- the full parameter list and a mission upload + read-back through the proxy;
- a take-off to 10 m and a landing;
- the attack: for each rangefinder, every message on the ground station's wire that carries
  its distance (DISTANCE_SENSOR of that id; RANGEFINDER #173, which ArduPilot fills from the
  first downward rangefinder), how many of those frames the proxy changed, and by how much.
  A message that carries the quantity and was left unchanged is reported as a true value
  left on the wire; ALTITUDE.bottom_clearance (PX4's fused height above ground, no rule's
  carrier) is compared with the true and the attacked reading, and where it reveals the truth
  the proxy must have named it when it applied the profile (attack.true_copy);
- then the secure stage (``--scenario wall_hover --secure secekf``) in front of a vehicle whose
  rangefinders are not the scenario's: whether the proxy says so.

Exit status 0 when every figure that should hold held (a true twin left on the wire or a
no-reading made valid fails it), 1 otherwise. See docs/ardupilot.md and docs/px4.md.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from abc import ABC, abstractmethod
from collections import Counter, defaultdict, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
os.environ.setdefault("MAVLINK_DIALECT", "ardupilotmega")
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
BIN = Path(sys.executable).parent
TARGETED = {"DISTANCE_SENSOR", "RANGEFINDER"}  # the messages the profile's rules (quantity: rangefinder) reach
TAKEOFF_M = 10.0
# AUTOPILOT_VERSION.flight_sw_version's last byte, as ArduPilot and PX4 both encode it (FIRMWARE_VERSION_TYPE)
VERSION_TYPES = {0: "-dev", 64: "-alpha", 128: "-beta", 192: "-rc", 255: ""}


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A loopback port nobody holds now, UDP by default (``socket.SOCK_STREAM``: TCP)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Ground:
    """The ground station's side of the proxy: ``udp`` (the proxy sends to it), ``tcpin`` (the proxy listens, the
    ground station dials it, as MAVProxy's ``--master tcp:``) or ``serial`` (a pty pair made by ``socat``: the
    proxy opens one end as a serial port, the ground station the other, as a telemetry radio would be)."""

    def __init__(self, kind: str, work: Path) -> None:
        self.kind, self.work = kind, work
        self.port = free_port(socket.SOCK_DGRAM if kind == "udp" else socket.SOCK_STREAM)
        self.socat: subprocess.Popen[bytes] | None = None
        if kind == "serial":
            ends = (work / "ground-proxy", work / "ground-gcs")
            for end in ends:
                end.unlink(missing_ok=True)
            self.socat = subprocess.Popen(["socat", *(f"pty,raw,echo=0,link={end}" for end in ends)],
                                          stderr=(work / "socat.log").open("wb"), start_new_session=True)
            deadline = time.monotonic() + 10
            while not all(end.exists() for end in ends) and time.monotonic() < deadline:
                time.sleep(0.1)

    def proxy_url(self) -> str:
        return {"udp": f"udpout://127.0.0.1:{self.port}", "tcpin": f"tcpin://127.0.0.1:{self.port}",
                "serial": f"serial://{self.work / 'ground-proxy'}?baud=921600"}[self.kind]

    def connect(self) -> Any:
        """The ground station's pymavlink connection (for ``tcpin``, once the proxy listens)."""
        kw: dict[str, Any] = {"source_system": 255, "source_component": 190, "dialect": "ardupilotmega"}
        if self.kind == "udp":
            conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.port}", **kw)
            # three PX4s send 1,300 frames/s: room for the reader thread's pauses on a loaded machine
            # (the kernel caps it at net.core.rmem_max; what still overflows is counted below)
            conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
            return conn
        if self.kind == "tcpin":
            return mavutil.mavlink_connection(f"tcp:127.0.0.1:{self.port}", retries=30, **kw)
        return mavutil.mavlink_connection(str(self.work / "ground-gcs"), baud=921600, **kw)

    def drops(self) -> int | None:
        """Datagrams the kernel dropped at the ground station's UDP socket (None: not a UDP ground side)."""
        return udp_drops(self.port, Path("/proc/net/udp").read_text()) if self.kind == "udp" else None

    def close(self) -> None:
        stop(self.socat)


@dataclass
class Seen:
    t_s: float
    msg: Any


@dataclass
class Link:
    """A pymavlink connection with a reader thread that keeps every message it receives."""

    name: str
    conn: Any
    msgs: list[Seen] = field(default_factory=list)
    bad: int = 0
    cond: threading.Condition = field(default_factory=threading.Condition)
    stop: bool = False

    def start(self) -> Link:
        threading.Thread(target=self._pump, name=self.name, daemon=True).start()
        return self

    def _pump(self) -> None:
        while not self.stop:
            try:
                m = self.conn.recv_msg()
            except (OSError, ConnectionError):
                time.sleep(0.05)
                continue
            if m is None:
                if self._closed_by_peer():
                    return  # pymavlink would read the closed TCP socket (and say "EOF") 500 times a second
                time.sleep(0.002)
                continue
            with self.cond:
                if m.get_type() == "BAD_DATA":
                    self.bad += 1
                else:
                    self.msgs.append(Seen(time.time(), m))
                self.cond.notify_all()

    def _closed_by_peer(self) -> bool:
        """A TCP connection whose peer closed it (readable, and nothing to read); never for UDP or serial."""
        sock = getattr(self.conn, "port", None)
        if not isinstance(self.conn, mavutil.mavtcp) or not isinstance(sock, socket.socket):
            return False
        try:
            ready, _, _ = select.select([sock], [], [], 0)
            return bool(ready) and sock.recv(1, socket.MSG_PEEK) == b""
        except (OSError, ValueError):
            return True

    def wait(self, pred: Callable[[Any], bool], timeout_s: float, since: int = 0) -> Any | None:
        """The first message from index ``since`` on for which ``pred`` holds, or None."""
        seen = self.wait_seen(pred, timeout_s, since)
        return None if seen is None else seen.msg

    def wait_seen(self, pred: Callable[[Any], bool], timeout_s: float, since: int = 0) -> Seen | None:
        """As :meth:`wait`, with the time the message arrived."""
        end = time.monotonic() + timeout_s
        i = since
        with self.cond:
            while True:
                while i < len(self.msgs):
                    if pred(self.msgs[i].msg):
                        return self.msgs[i]
                    i += 1
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self.cond.wait(left)

    def mark(self) -> int:
        with self.cond:
            return len(self.msgs)

    def close(self) -> None:
        self.stop = True
        time.sleep(0.1)
        self.conn.close()


def is_(type_: str, sysid: int, **fields: Any) -> Callable[[Any], bool]:
    def pred(m: Any) -> bool:
        return (m.get_type() == type_ and m.get_srcSystem() == sysid
                and all(getattr(m, k) == v for k, v in fields.items()))
    return pred


# --- the parts of the check -------------------------------------------------------------------


def fetch_params(gcs: Link, sysid: int) -> tuple[int, int, float]:
    """PARAM_REQUEST_LIST, then re-request missing indices as a GCS does; (got, count, seconds)."""
    t0 = time.monotonic()
    since = gcs.mark()
    gcs.conn.mav.param_request_list_send(sysid, 1)
    got: dict[int, str] = {}
    count = -1
    i = since
    quiet_since = time.monotonic()
    retries = 0
    while time.monotonic() - t0 < 120:
        m = gcs.wait(is_("PARAM_VALUE", sysid), 1.0, i)
        if m is not None:
            with gcs.cond:
                i = next(k for k in range(i, len(gcs.msgs)) if gcs.msgs[k].msg is m) + 1
            count = m.param_count
            if m.param_index < 65535:
                got[m.param_index] = m.param_id
            quiet_since = time.monotonic()
            if len(got) == count:
                break
            continue
        if count > 0 and time.monotonic() - quiet_since > 2 and retries < 5:
            retries += 1
            for idx in sorted(set(range(count)) - set(got))[:100]:
                gcs.conn.mav.param_request_read_send(sysid, 1, b"", idx)
            quiet_since = time.monotonic()
        elif retries >= 5:
            break
    return len(got), count, time.monotonic() - t0


def mission_roundtrip(gcs: Link, sysid: int, home: tuple[float, float],
                      home_item: bool) -> tuple[int, int, str]:
    """Upload 3 waypoints (after home as item 0 where the autopilot wants it), read them back;
    (waypoints sent, waypoints equal on read-back, ack)."""
    lat, lon = home
    first = 1 if home_item else 0
    items = [(0, mav.MAV_CMD_NAV_WAYPOINT, lat, lon, 0.0)] if home_item else []
    for k in range(1, 4):
        items.append((len(items), mav.MAV_CMD_NAV_WAYPOINT, lat + 0.0002 * k, lon + 0.0001 * k, 15.0 + k))
    frame = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    since = gcs.mark()
    gcs.conn.mav.mission_count_send(sysid, 1, len(items), 0)
    ack = "none"
    sent: set[int] = set()
    end = time.monotonic() + 20
    i = since
    while time.monotonic() < end:
        m = gcs.wait(lambda m: m.get_srcSystem() == sysid and m.get_type() in
                     ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"), 2.0, i)
        if m is None:
            continue
        with gcs.cond:
            i = next(k for k in range(i, len(gcs.msgs)) if gcs.msgs[k].msg is m) + 1
        if m.get_type() == "MISSION_ACK":
            ack = mav.enums["MAV_MISSION_RESULT"][m.type].name
            break
        seq, cmd, la, lo, alt = items[m.seq]
        gcs.conn.mav.mission_item_int_send(sysid, 1, seq, frame, cmd, 0, 1, 0, 0, 0, 0,
                                           int(la * 1e7), int(lo * 1e7), alt, 0)
        sent.add(m.seq)
    # read back
    i = gcs.mark()
    gcs.conn.mav.mission_request_list_send(sysid, 1, 0)
    c = gcs.wait(is_("MISSION_COUNT", sysid), 5.0, i)
    equal = 0
    if c is not None:
        for seq in range(first, c.count):
            i = gcs.mark()
            gcs.conn.mav.mission_request_int_send(sysid, 1, seq, 0)
            it = gcs.wait(is_("MISSION_ITEM_INT", sysid, seq=seq), 3.0, i)
            if it is None or seq >= len(items):
                continue
            _, cmd, la, lo, alt = items[seq]
            if (it.command == cmd and it.x == int(la * 1e7) and it.y == int(lo * 1e7)
                    and abs(it.z - alt) < 1e-3):
                equal += 1
        gcs.conn.mav.mission_ack_send(sysid, 1, 0, 0)
    return len(items) - first, equal, ack


def command(gcs: Link, sysid: int, cmd: int, *params: float) -> str:
    p = list(params) + [0.0] * (7 - len(params))
    i = gcs.mark()
    gcs.conn.mav.command_long_send(sysid, 1, cmd, 0, *p)
    a = gcs.wait(is_("COMMAND_ACK", sysid, command=cmd), 3.0, i)
    return "no ack" if a is None else mav.enums["MAV_RESULT"][a.result].name


def version_text(flight_sw_version: int, flight_custom_version: Iterable[int]) -> str:
    """AUTOPILOT_VERSION's version fields as text: '4.7.0-dev (git 2598e9d4)'.

    ArduPilot puts the first 8 characters of its git hash in ``flight_custom_version`` as text;
    PX4 puts the first 16 hex digits as a little-endian 64-bit number, so those are shown in hex,
    most significant first, cut to the same 8 digits.
    """
    v = flight_sw_version
    kind = VERSION_TYPES.get(v & 0xFF, f" (type {v & 0xFF})")
    raw = bytes(flight_custom_version)
    text = raw.split(b"\0")[0]
    git = text.decode() if text and all(0x21 <= c < 0x7F for c in text) else raw[::-1].hex()[:8]
    return f"{v >> 24}.{(v >> 16) & 0xFF}.{(v >> 8) & 0xFF}{kind} (git {git})"


def autopilot_version(gcs: Link, sysid: int) -> str:
    """AUTOPILOT_VERSION, asked for through the proxy."""
    i = gcs.mark()
    gcs.conn.mav.command_long_send(sysid, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                                   0, 0, 0, 0, 0, 0)
    m = gcs.wait(is_("AUTOPILOT_VERSION", sysid), 5.0, i)
    if m is None:
        return "? (no AUTOPILOT_VERSION)"
    return version_text(m.flight_sw_version, m.flight_custom_version)


def armed(m: Any) -> bool:
    return bool(m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)


class Autopilot(ABC):
    """What differs between autopilots: starting them, where they speak, how they fly, what they send."""

    name: str  # "ArduPilot", "PX4"
    firmware: str  # what goes before its version number: "ArduCopter V"
    flight_name: str  # the first flight step's name, as printed: "GUIDED"
    offsets_m: tuple[float, ...]  # the bias on each rangefinder, DISTANCE_SENSOR id 0, 1, ...
    home_item: bool  # the mission's item 0 is home, rewritten by the autopilot (ArduPilot)

    @abstractmethod
    def launch(self, n: int, log: Path) -> subprocess.Popen[bytes]:
        """Start n vehicles (sysids 1..n) in a process group of their own."""

    @abstractmethod
    def wait_ready(self, n: int) -> str | None:
        """None once every vehicle serves MAVLink, else what failed."""

    @abstractmethod
    def vehicle_urls(self, n: int) -> list[str]:
        """The proxy's --vehicle URL of each vehicle."""

    @abstractmethod
    def direct_url(self) -> str:
        """pymavlink's URL of a link to vehicle 1 that does not pass the proxy."""

    @abstractmethod
    def build_text(self) -> str:
        """Which binary, built from what."""

    @abstractmethod
    def take_off(self, gcs: Link, sysid: int, out: dict[str, Any]) -> bool:
        """One attempt to take off to TAKEOFF_M (results in ``out``); True once it is under way."""

    @abstractmethod
    def land(self, gcs: Link, sysid: int) -> str:
        """Ask for a landing; the command's result."""

    def carriers(self, m: Any) -> list[tuple[int, float]]:
        """(rangefinder index, metres) for every rangefinder distance a message carries."""
        t = m.get_type()
        if t == "DISTANCE_SENSOR" and m.id < len(self.offsets_m):
            return [(m.id, m.current_distance / 100.0)]
        return []


def fly(gcs: Link, sysids: list[int], ap: Autopilot) -> dict[int, dict[str, Any]]:
    """Take off to 10 m (retried until the autopilot lets it), hover, land, disarm."""
    out: dict[int, dict[str, Any]] = {s: {} for s in sysids}
    t0 = time.time()
    marks: dict[int, tuple[int, float]] = {}
    waiting = set(sysids)
    while waiting and time.time() - t0 < 150:
        for s in sorted(waiting):
            if ap.take_off(gcs, s, out[s]):
                out[s]["takeoff_after_s"] = round(time.time() - t0, 1)
                marks[s] = (gcs.mark(), time.time())
                waiting.discard(s)
        time.sleep(2)
    for s, (i, t_cmd) in marks.items():
        seen = gcs.wait_seen(lambda m, s=s: is_("GLOBAL_POSITION_INT", s)(m)
                             and m.relative_alt >= 1000 * (TAKEOFF_M - 0.5), 60.0, i)
        if seen is not None:
            out[s]["reached_m"] = round(seen.msg.relative_alt / 1000, 2)
            out[s]["climb_s"] = round(seen.t_s - t_cmd, 1)
    time.sleep(5)  # hover: the attack is measured through the whole flight
    for s in marks:
        out[s]["land"] = ap.land(gcs, s)
        marks[s] = (gcs.mark(), time.time())
    for s, (i, t_cmd) in marks.items():
        seen = gcs.wait_seen(lambda m, s=s: is_("HEARTBEAT", s)(m) and m.type == mav.MAV_TYPE_QUADROTOR
                             and not armed(m), 90.0, i)
        out[s]["landed_disarmed_s"] = None if seen is None else round(seen.t_s - t_cmd, 1)
    return out


def rates(msgs: Iterable[Seen], sysid: int, t0: float, t1: float) -> dict[str, float]:
    c = Counter(s.msg.get_type() for s in msgs if t0 <= s.t_s <= t1 and key(s.msg)[0] == sysid)
    return {k: v / (t1 - t0) for k, v in c.items()}


def read_tlog(path: Path) -> list[Any]:
    """Every message of a .tlog, read with pymavlink (an implementation other than the proxy's)."""
    log = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    out = []
    while True:
        m = log.recv_msg()
        if m is None:
            break
        if m.get_type() != "BAD_DATA":
            out.append(m)
    log.close()
    return out


def frame_header(frame: bytes) -> tuple[int, int, int, int] | None:
    """(sysid, compid, msgid, seq) of a MAVLink 2 (0xFD) or 1 (0xFE) frame, from its bytes; None otherwise."""
    if len(frame) >= 10 and frame[0] == 0xFD:
        return frame[5], frame[6], frame[7] | frame[8] << 8 | frame[9] << 16, frame[4]
    if len(frame) >= 6 and frame[0] == 0xFE:
        return frame[3], frame[4], frame[5], frame[2]
    return None


def key(m: Any) -> tuple[int, int, int, int]:
    """A message's (sysid, compid, msgid, seq). Read from its frame: on a message its dialect does not
    define (PX4's GNSS_INTEGRITY #441 and others in ardupilotmega) pymavlink leaves the header at 0."""
    h = frame_header(bytes(m.get_msgbuf()))
    return h if h is not None else (m.get_srcSystem(), m.get_srcComponent(), m.get_msgId(), m.get_seq())


@dataclass(frozen=True)
class InOrder:
    """What arrived against what was sent, both in order (see :func:`in_order`)."""

    matched: int  # received frames equal, byte for byte, to a sent one, in the order sent
    unmatched: int  # received frames equal to no sent frame still ahead: altered, reordered or invented
    missing: int  # sent frames skipped between two matched ones: lost on the way
    tail: int  # sent frames after the last matched one (the sender was stopped before they were read)
    first_unmatched: int | None  # index, among the received frames, of the first unmatched one


def in_order(sent: list[bytes], received: list[bytes]) -> InOrder:
    """Walk both lists once: each received frame must be the next sent frame or a later one (frames
    in between were lost, which UDP allows); one equal to none ahead is altered or out of order."""
    where: dict[bytes, deque[int]] = defaultdict(deque)
    for i, f in enumerate(sent):
        where[f].append(i)
    nxt = matched = unmatched = missing = 0
    first_unmatched = None
    for k, f in enumerate(received):
        at = where.get(f)
        while at and at[0] < nxt:
            at.popleft()
        if not at:
            unmatched += 1
            first_unmatched = k if first_unmatched is None else first_unmatched
            continue
        i = at.popleft()
        missing += i - nxt
        nxt = i + 1
        matched += 1
    return InOrder(matched, unmatched, missing, len(sent) - nxt, first_unmatched)


def udp_drops(port: int, table: str) -> int | None:
    """The kernel's drop count of the UDP socket bound to ``port``, from /proc/net/udp's text."""
    for line in table.splitlines()[1:]:
        cols = line.split()
        if len(cols) >= 13 and cols[1].rsplit(":", 1)[-1].upper() == f"{port:04X}":
            return int(cols[-1])
    return None


def compare(original: list[Any], received: list[Seen], sysid: int,
            carriers: Callable[[Any], list[tuple[int, float]]]) -> dict[str, Any]:
    """Match what the ground station got to what the proxy received (same header), frame by frame."""
    orig = [m for m in original if key(m)[0] == sysid]
    got = [s.msg for s in received if key(s.msg)[0] == sysid]
    queue: dict[tuple[int, int, int, int], deque[Any]] = defaultdict(deque)
    for m in orig:
        queue[key(m)].append(m)
    untargeted_orig = [bytes(m.get_msgbuf()) for m in orig if m.get_type() not in TARGETED]
    untargeted_got = [bytes(m.get_msgbuf()) for m in got if m.get_type() not in TARGETED]
    # the ground station listens before the proxy starts and after it stops: the same list is expected,
    # less the frames the proxy read in the instant it was stopped and any its UDP socket dropped
    order = in_order(untargeted_orig, untargeted_got)
    per: dict[tuple[str, int], dict[str, Any]] = {}
    unmatched = 0
    twin_example: tuple[float, float] | None = None
    last_ds0: float | None = None
    last_true0: float | None = None  # rangefinder 0 as the vehicle sent it
    clearance: list[tuple[float, float, float]] = []  # ALTITUDE.bottom_clearance, true and lie of rangefinder 0
    no_reading = {"frames": 0, "made_valid": 0}
    limits: dict[int, tuple[float, float]] = {}  # DISTANCE_SENSOR id -> (min, max) m, as the vehicle sent them
    for m in got:
        q = queue.get(key(m))
        if not q:
            unmatched += 1
            continue
        o = q.popleft()
        if m.get_type() == "DISTANCE_SENSOR":
            limits[o.id] = (o.min_distance / 100.0, o.max_distance / 100.0)
        if (m.get_type() == "ALTITUDE" and math.isfinite(m.bottom_clearance) and last_true0 is not None
                and last_ds0 is not None):
            clearance.append((m.bottom_clearance, last_true0, last_ds0))
        for (idx, v_got), (_, v_orig) in zip(carriers(m), carriers(o), strict=True):
            # before the first DISTANCE_SENSOR of that id its limits are unknown: ArduPilot sends 0 for none
            lo, hi = limits.get(idx, (1e-9, float("inf")))
            row = per.setdefault((m.get_type(), idx), {"frames": 0, "changed": 0, "delta_m": [], "no_reading": 0})
            if not lo <= v_orig <= hi:  # no reading (on the ground: below min): must stay one
                row["no_reading"] += 1
                no_reading["frames"] += 1
                no_reading["made_valid"] += lo <= v_got <= hi
                continue
            row["frames"] += 1
            if abs(v_got - v_orig) > 1e-6:
                row["changed"] += 1
                row["delta_m"].append(v_got - v_orig)
            if m.get_type() == "DISTANCE_SENSOR" and idx == 0:
                last_ds0, last_true0 = v_got, v_orig
            if m.get_type() == "RANGEFINDER" and last_ds0 is not None and (
                    twin_example is None or v_got > twin_example[1]):
                twin_example = (last_ds0, v_got)
    return {
        "downlink_frames": len(orig), "received": len(got), "unmatched": unmatched,
        "untargeted_orig": len(untargeted_orig), "untargeted_got": len(untargeted_got), "order": order,
        "per": per, "twin_example": twin_example,
        "no_reading": no_reading, "clearance": clearance,
    }


# --- one run ----------------------------------------------------------------------------------


def profile_file(directory: Path, ap: Autopilot) -> Path:
    rules = [
        {"target": {"quantity": "rangefinder", "sensor_id": i},
         "kind": "bias", "offset": off, "note": f"rangefinder {i}: every message that carries it"}
        for i, off in enumerate(ap.offsets_m)
    ]
    p = directory / "bias-each-rangefinder.json"
    p.write_text(json.dumps({"name": "bias-each-rangefinder",
                             "description": f"one bias per {ap.name} SITL rangefinder", "rules": rules}))
    return p


def wait_for_text(path: Path, text: str, n: int, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if path.exists() and path.read_text(errors="replace").count(text) >= n:
            return True
        time.sleep(0.2)
    return False


def stop(p: subprocess.Popen[bytes] | None) -> None:
    if p is None or p.poll() is not None:
        return
    with_group = p.pid
    try:
        os.killpg(with_group, signal.SIGTERM)
    except ProcessLookupError:
        return
    try:
        p.wait(10)
    except subprocess.TimeoutExpired:
        os.killpg(with_group, signal.SIGKILL)
        p.wait()


# --- the checks: each judges what a run measured and returns the rows it prints -----------------


@dataclass(frozen=True)
class Row:
    """One printed line of a run, and whether the figure on it held (a line that only informs holds)."""

    text: str
    ok: bool = True


def judged(text: str, good: bool) -> Row:
    """A row that, failing, says so at its end."""
    return Row(text if good else f"{text}  FAIL", good)


def shown(rows: list[Row]) -> list[Row]:
    for row in rows:
        print(row.text)
    return rows


def check_parameters(fetched: dict[int, tuple[int, int, float]]) -> list[Row]:
    """Each vehicle's full parameter list through the proxy: sysid -> (received, count, seconds)."""
    return [judged(f"parameters, sysid {s}, through the proxy: {got} of {count} in {secs:.1f} s", got == count > 0)
            for s, (got, count, secs) in fetched.items()]  # fmt: skip


def check_mission(sent: int, equal: int, ack: str) -> list[Row]:
    """A mission uploaded to vehicle 1 through the proxy and read back."""
    return [judged(f"mission, sysid 1, through the proxy: {sent} waypoints uploaded ({ack}), "
                   f"{equal} of {sent} read back equal", equal == sent and ack == "MAV_MISSION_ACCEPTED")]


def check_flight(flight: dict[int, dict[str, Any]], flight_name: str) -> list[Row]:
    """What :func:`fly` saw of each vehicle: a take-off that reached its height, a landing that ended disarmed."""
    rows = []
    for s, f in flight.items():
        good = f.get("reached_m") is not None and f.get("landed_disarmed_s") is not None
        rows.append(judged(f"{flight_name} flight, sysid {s}: mode {f.get('mode')}, armed and take-off "
                           f"{f.get('takeoff')} {f.get('takeoff_after_s')} s after {flight_name}, reached "
                           f"{f.get('reached_m')} m {f.get('climb_s')} s later, land {f.get('land')}, landed and "
                           f"disarmed {f.get('landed_disarmed_s')} s after it", good))
    return rows


def check_rates(through: dict[str, float], direct: dict[str, float], seconds: float) -> list[Row]:
    """Message types and rates of vehicle 1 through the proxy against the direct link, over the same seconds
    (said, not judged: the two links are not asked for the same streams)."""
    only_proxy = sorted(set(through) - set(direct))
    only_direct = sorted(set(direct) - set(through))
    rows = [Row(f"message types, sysid 1, {seconds:.0f} s: {len(through)} through the proxy, {len(direct)} direct"
                f" (only through the proxy: {only_proxy or 'none'}; only direct: {only_direct or 'none'})"),
            Row("  type                       proxy Hz  direct Hz")]  # fmt: skip
    for t in sorted(set(through) | set(direct)):
        rows.append(Row(f"  {t:<26} {through.get(t, 0):8.2f}  {direct.get(t, 0):9.2f}"))
    return rows


def check_ground_frames(bad: int) -> list[Row]:
    """Every frame the ground station got parses (pymavlink's CRC and framing)."""
    return [Row(f"ground station: {bad} frames pymavlink rejected (bad CRC or framing)", bad == 0)]


def check_forwarding(s: int, c: dict[str, Any]) -> list[Row]:
    """Every downlink frame no rule targets arrived byte for byte and in order (:func:`compare`'s ``c``); the
    proxy may have read a few as it was stopped (at most 20), and frames lost on the way are judged by
    :func:`check_losses`."""
    o: InOrder = c["order"]
    exact = o.unmatched == 0 and o.tail <= 20
    fail = "" if exact else f"  FAIL, {o.unmatched} altered or out of order, the first at {o.first_unmatched}"
    return [Row(f"forwarding, sysid {s}: {o.matched} of {c['untargeted_got']} downlink frames no rule targets "
                f"arrived byte for byte and in order ({c['untargeted_orig']} received by the proxy, {o.tail} of "
                f"them as it was stopped, {o.missing} lost on the way){fail};"
                f" {c['downlink_frames']} downlink frames in all, {c['unmatched']} received without an original",
                exact)]  # fmt: skip


def check_attack(c: dict[str, Any], offsets_m: tuple[float, ...]) -> list[Row]:
    """Every reading of each attacked rangefinder rewritten, in every message that carries it."""
    rows = []
    twin = False
    for i, off in enumerate(offsets_m):
        for (mtype, idx), row in sorted(c["per"].items()):
            if idx != i:
                continue
            d = row["delta_m"]
            mean = sum(d) / len(d) if d else 0.0
            verdict = "rewritten" if row["changed"] == row["frames"] else (
                "TRUE VALUE LEFT ON THE WIRE" if row["changed"] == 0 else "partly rewritten")
            twin |= row["changed"] < row["frames"]
            rows.append(Row(f"  attack rangefinder {i} (+{off:g} m): {mtype:<16} {row['changed']:5d} of "
                            f"{row['frames']:5d} readings changed, mean change {mean:+.2f} m: {verdict} "
                            f"({row['no_reading']} frames with no reading left as they were)",
                            row["changed"] == row["frames"] > 0))
    if c["twin_example"]:
        lie, truth = c["twin_example"]
        rows.append(Row(f"  the ground station saw DISTANCE_SENSOR id 0 = {lie:.2f} m beside RANGEFINDER = "
                        f"{truth:.2f} m"))
    rows.append(Row(f"  every message carrying an attacked distance changed: {'yes' if not twin else 'NO'}"))
    return rows


def check_clearance(s: int, c: dict[str, Any], proxy_log: list[str]) -> list[Row]:
    """ALTITUDE.bottom_clearance is no rule's carrier (docs/profile.md): where it reveals the true distance, the
    proxy must have said so (``attack.true_copy``) when it applied the profile."""
    if not c["clearance"]:
        return []
    bc = c["clearance"]
    to_truth = statistics.median(abs(b - t) for b, t, _ in bc)
    to_lie = statistics.median(abs(b - lie) for b, _, lie in bc)
    rows = [Row(f"  ALTITUDE.bottom_clearance (the autopilot's fused height above ground, not rewritten): "
                f"{len(bc)} frames, median distance to rangefinder 0's true reading {to_truth:.2f} m, to the "
                f"attacked one {to_lie:.2f} m: "
                f"{'REVEALS THE TRUE DISTANCE' if to_truth < to_lie else 'follows the attacked reading'}")]
    if to_truth < to_lie:
        said = [ln for ln in proxy_log
                if " attack.true_copy " in ln and f"sysid={s} " in ln and "ALTITUDE.bottom_clearance" in ln]
        rows.append(Row("  the proxy said so when it applied the profile (attack.true_copy naming "
                        f"ALTITUDE.bottom_clearance): {'yes' if said else 'NO  FAIL'}", bool(said)))
    return rows


def check_no_reading(c: dict[str, Any]) -> list[Row]:
    """A frame with no reading (outside its sensor's min..max) must not be made to look valid by the bias."""
    nr = c["no_reading"]
    return [Row(f"  frames with no reading (outside min..max, e.g. on the ground): {nr['frames']}; "
                f"made to look valid by the bias: {nr['made_valid']}", nr["made_valid"] == 0)]


def check_losses(lost: int, drops: int | None, ground_kind: str) -> list[Row]:
    """UDP may lose frames; the proxy must not: every frame lost on the way must be one the ground station's own
    socket dropped (the kernel counts those; ``drops`` is None on a TCP or serial ground side, which lose none)."""
    if not (lost or drops):
        return []
    accounted = drops is not None and lost <= drops
    what = (f"{drops} datagrams dropped by the kernel (/proc/net/udp)" if drops is not None
            else f"a {ground_kind} link (nothing may be lost)")  # fmt: skip
    return [Row(f"ground station's side: {what}, {lost} frames lost on the way: "
                f"{'all accounted for' if accounted else 'NOT ACCOUNTED FOR  FAIL'}", accounted)]


def proxy_stats(proxy_log: list[str], sysids: list[int]) -> list[Row]:
    """The proxy's last stats line of each vehicle (said, not judged)."""
    rows = []
    for s in sysids:
        stats = [ln for ln in proxy_log if "proxy.stats" in ln and f"sysid={s} " in ln]
        if not stats:
            continue
        rows.append(Row(f"proxy's last stats line, sysid {s}: {stats[-1].split(' ', 1)[-1][:300]}"))
        bad = stats[-1].split(" bad=")[1].split()[0] if " bad=" in stats[-1] else "0"
        if bad != "0":
            rows.append(Row(f"  bad={bad} on a healthy link"))
    return rows


# --- the launcher and the run ------------------------------------------------------------------


class Stack:
    """The launcher of one run: the autopilot's ``n`` vehicles, this tree's ``secuav-proxy`` dialling each of them
    (recording, the bias profile in force), a ground station on the proxy's ground port and a direct link to
    vehicle 1 around the proxy. Leaving it (as a context manager) stops the proxy first (SIGTERM: it closes its
    recording), then the autopilot, and reads the ground socket's kernel drop count before closing it."""

    def __init__(self, n: int, work: Path, ap: Autopilot, ground_kind: str) -> None:
        self.n, self.work, self.ap = n, work, ap
        self.sysids = list(range(1, n + 1))
        self.ground = Ground(ground_kind, work)
        self.proxy_log = work / "proxy.log"
        self.sitl: subprocess.Popen[bytes] | None = None
        self.proxy: subprocess.Popen[bytes] | None = None
        self.gcs: Link | None = None
        self.direct: Link | None = None
        self.t_direct = self.t_end = 0.0  # the direct link joined; the run's measuring ended
        self.drops: int | None = None

    def start(self) -> list[Row]:
        """Launch everything and wait for every vehicle's HEARTBEAT through the proxy: the autopilot's version
        row, or a failing row that says what did not come up."""
        ap, n = self.ap, self.n
        self.sitl = ap.launch(n, self.work / "sitl-run.log")
        failed = ap.wait_ready(n)
        if failed:
            return [Row(f"FAIL: {failed}", False)]
        if self.ground.kind != "tcpin":
            self.gcs = Link("gcs", self.ground.connect()).start()
        cmd = [str(BIN / "secuav-proxy"), "--vehicles", str(n), "--ground", self.ground.proxy_url(),
               "--broker", "none", "--record", str(self.work / "record"),
               "--profile", str(profile_file(self.work, ap)), "--stats-interval", "5"]
        for url in ap.vehicle_urls(n):
            cmd += ["--vehicle", url]
        self.proxy = subprocess.Popen(cmd, stdout=self.proxy_log.open("wb"), stderr=subprocess.STDOUT,
                                      start_new_session=True)
        if self.gcs is None:
            self.gcs = Link("gcs", self.ground.connect()).start()  # tcpin: the proxy listens first
        for s in self.sysids:
            if self.gcs.wait(is_("HEARTBEAT", s), 60) is None:
                return [Row(f"FAIL: no HEARTBEAT from sysid {s} through the proxy; see {self.proxy_log}", False)]
        version = Row(f"{ap.name}: {ap.firmware}{autopilot_version(self.gcs, 1)}; {ap.build_text()}")
        self.direct = Link("direct", mavutil.mavlink_connection(ap.direct_url(), source_system=254,
                                                                dialect="ardupilotmega")).start()
        self.t_direct = time.time()
        return [version]

    def __enter__(self) -> Stack:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.t_end = time.time()
        time.sleep(1)
        if self.direct is not None:
            self.direct.close()
        stop(self.proxy)  # SIGTERM: the proxy closes its recording
        time.sleep(1.0)
        stop(self.sitl)
        if self.gcs is not None:
            self.drops = self.ground.drops()
            self.gcs.close()
        self.ground.close()


def run(n: int, work: Path, ap: Autopilot, ground_kind: str = "udp") -> tuple[bool, Path]:
    """One run: launch the stack and measure through it, stop it, then judge what it recorded; every check's rows
    printed as they come. True when every row held."""
    work.mkdir(parents=True, exist_ok=True)
    side = "" if ground_kind == "udp" else f", ground side {ground_kind}"
    print(f"\n=== {n} vehicle{'s' if n > 1 else ''}{side} ===")
    rows: list[Row] = []
    with Stack(n, work, ap, ground_kind) as stack:
        rows += shown(stack.start())
        if not all(r.ok for r in rows):
            return False, work
        gcs = stack.gcs
        assert gcs is not None and stack.direct is not None  # start() holds both when it held
        rows += shown(check_parameters({s: fetch_params(gcs, s) for s in stack.sysids}))
        home = gcs.wait(is_("GLOBAL_POSITION_INT", 1), 10)
        lat, lon = (home.lat / 1e7, home.lon / 1e7) if home else (-35.363261, 149.165230)
        rows += shown(check_mission(*mission_roundtrip(gcs, 1, (lat, lon), ap.home_item)))
        rows += shown(check_flight(fly(gcs, stack.sysids, ap), ap.flight_name))
    t0, t1 = stack.t_direct + 2, stack.t_end  # the same seconds on both links (the direct link joined after boot)
    rows += shown(check_rates(rates(gcs.msgs, 1, t0, t1), rates(stack.direct.msgs, 1, t0, t1), t1 - t0))
    rows += shown(check_ground_frames(gcs.bad))
    proxy_log = stack.proxy_log.read_text(errors="replace").splitlines()
    lost = 0
    for s in stack.sysids:
        c = compare(read_tlog(work / "record" / f"v{s}" / "original.tlog"), gcs.msgs, s, ap.carriers)
        lost += c["order"].missing
        for check in (check_forwarding(s, c), check_attack(c, ap.offsets_m), check_clearance(s, c, proxy_log),
                      check_no_reading(c)):
            rows += shown(check)
    rows += shown(check_losses(lost, stack.drops, ground_kind))
    rows += shown(proxy_stats(proxy_log, stack.sysids))
    return all(r.ok for r in rows), work


def secure_probe(work: Path, ap: Autopilot, seconds: float = 30.0) -> None:
    """The secure stage with a scenario whose sensor layout the autopilot does not send: does it say so?

    ``--scenario wall_hover`` expects forward rangefinders 0-4 and a downward 5; these SITLs send
    downward ones only (ArduPilot's ids 0, 1, 2 here, PX4 SIH's id 0). Reported, not failed: the
    stage cannot work here, and must say so (``secure.layout_mismatch``, docs/interfaces.md)
    rather than look busy (issue 27).
    """
    work.mkdir(parents=True, exist_ok=True)
    print(f"\n=== secure stage, --scenario wall_hover --secure secekf, 1 vehicle, {seconds:g} s ===")
    sitl = ap.launch(1, work / "sitl-run.log")
    proxy = None
    try:
        failed = ap.wait_ready(1)
        if failed:
            print(f"{failed}; skipped")
            return
        log = work / "proxy.log"
        proxy = subprocess.Popen([str(BIN / "secuav-proxy"), "--scenario", "wall_hover", "--secure", "secekf",
                                  "--vehicle", ap.vehicle_urls(1)[0], "--ground", f"udpout://127.0.0.1:{free_port()}",
                                  "--broker", "none", "--stats-interval", "5"],
                                 stdout=log.open("wb"), stderr=subprocess.STDOUT, start_new_session=True)
        time.sleep(seconds)
    finally:
        stop(proxy)
        stop(sitl)
    lines = (work / "proxy.log").read_text(errors="replace").splitlines()
    stats = [ln for ln in lines if "proxy.stats" in ln]
    warnings = [ln for ln in lines if " WARNING " in ln or " ERROR " in ln]
    rewritten = stats[-1].split(" rewritten=")[1].split()[0] if stats else "?"
    print(f"frames rewritten by the secure stage: {rewritten}; warnings or errors in the proxy's log: {len(warnings)}")
    for ln in warnings[:5]:
        print("  " + ln.split(" ", 1)[-1][:400])
    said = [ln for ln in lines if " secure.layout_mismatch " in ln]
    kept = [ln for ln in stats if "warnings=secure.layout_mismatch" in ln]
    if said:
        print(f"  the stage said so at once ({len(said)} secure.layout_mismatch event) and on {len(kept)} of "
              f"{len(stats)} stats lines")
    else:
        print("  the stage received downward DISTANCE_SENSOR ids where the scenario expects 0-4 (forward) "
              "and 5 (down), and said nothing: SILENTLY INERT")


def arguments(description: str) -> argparse.ArgumentParser:
    """The options both checks take; a check adds its own before parsing."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--vehicles", default="1,3", help="comma list of vehicle counts to run (default 1,3)")
    parser.add_argument("--keep", type=Path, help="keep logs and recordings in this directory")
    parser.add_argument("--tlog-out", type=Path, help="copy the 1-vehicle run's original.tlog here")
    parser.add_argument("--no-secure-probe", action="store_true", help="skip the secure stage's layout probe")
    parser.add_argument("--ground", choices=("udp", "tcpin", "serial"), default="udp",
                        help="the ground station's side of the proxy: udp (default), tcpin (the proxy listens "
                        "on TCP, the ground station dials it) or serial (a pty pair made by socat, as a radio)")
    return parser


def main(ap: Autopilot, args: argparse.Namespace) -> int:
    """Every run of ``args.vehicles``, then the secure probe; the exit status."""
    base = args.keep or Path(tempfile.mkdtemp(prefix=f"secuav-{ap.name.lower()}-"))
    all_ok = True
    for n in (int(x) for x in args.vehicles.split(",")):
        ok, work = run(n, base / f"n{n}", ap, args.ground)
        all_ok &= ok
        if n == 1 and args.tlog_out:
            shutil.copy(work / "record" / "v1" / "original.tlog", args.tlog_out)
            print(f"copied {work}/record/v1/original.tlog to {args.tlog_out}")
    if not args.no_secure_probe:
        secure_probe(base / "secure", ap)
    print(f"\nresult: {'every figure that should hold held' if all_ok else 'FAILED (see above)'}; logs in {base}")
    if not args.keep:
        shutil.rmtree(base, ignore_errors=True)
    return 0 if all_ok else 1
