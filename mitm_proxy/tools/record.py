"""Record a MAVLink stream to a .tlog, optionally through an attack, so ``secuav-eval --tlog`` has logs to read.

    secuav-record --listen udpin://127.0.0.1:14560 --out flight.tlog \\
        [--attack type-a --scenario anchors8 [--param K=V] [--seed S]] [--duration S] [--idle-stop S]

Listens where a vehicle sends (``secuav-sim --mavlink udpout://127.0.0.1:PORT``
sends vehicle i to PORT + i: give one ``--listen`` per vehicle) and writes
every frame as QGroundControl and MAVProxy do: an 8-byte big-endian wall-clock
timestamp in microseconds, then the frame's bytes. With ``--attack`` the
frames a profile targets go through the proxy's own pipeline and attack stage
(re-packed with their original sysid, compid and sequence number, dropped or
held back), so a log carries an attack exactly as a proxy recording would.
The profile's activation clock runs on the vehicle's boot time
(``time_boot_ms``), not the wall clock, so a simulator run faster than real
time is attacked at the same sim seconds as at 1x.

``--takeoff`` makes the recorder a minimal ground station: on each vehicle's
first HEARTBEAT it sends arm (MAV_CMD_COMPONENT_ARM_DISARM) and take off
(MAV_CMD_NAV_TAKEOFF, all-NaN: the vehicle's MIS_TAKEOFF_ALT) back to the
address the vehicle sends from, so a simulator run headless records a flight,
not a parked vehicle. (Those two commands are not written to the log.)

Stops on SIGINT/SIGTERM, after ``--duration`` seconds, or ``--idle-stop``
seconds after the last datagram (the simulator finished). Prints one summary
line (frames in, written, rewritten, dropped, delayed, and the ``directions`` the
profile changes: ``downlink`` toward the ground, ``uplink`` toward the vehicle).
The recorder hears only what the vehicle sends: a rule toward the vehicle changes
nothing here, and the recorder says so at start. What the proxy would warn about
(``attack.true_copy``, once the vehicle sends a message that keeps the attacked
value true) is logged as the proxy logs it, on stderr.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import heapq
import json
import math
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from pymavlink.dialects.v20 import common as mavlink

from attack_profiles import Engine
from attack_profiles.directions import UPLINK, directions_of, rule_directions
from attack_profiles.profile import Profile
from attack_profiles.resolve import resolve_profile
from mavframe import codec, tlog
from mavframe.frames import split
from mavframe.packet import Direction, Header, Packet
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from secuav_common.loading import InputError, parse_params
from secuav_common.logs import add_common_flags, setup_logging
from secuav_common.scenario import load_scenario, resolve_scenario_path
from secuav_common.urls import Endpoint, parse_endpoint

# Messages that carry the vehicle's boot clock: the recorder's time base for delayed frames.
_BOOT_CLOCKED = frozenset(mid for mid, cls in mavlink.mavlink_map.items() if "time_boot_ms" in cls.fieldnames)


@dataclass
class Counts:
    frames_in: int = 0
    written: int = 0
    rewritten: int = 0
    dropped: int = 0
    delayed: int = 0
    bad: int = 0


@dataclass
class TlogWriter:
    """Frames to a .tlog, the attack (if any) applied on the way; delayed frames wait on the vehicle clock.

    The attack runs through the proxy's own pipeline (attack stage, re-pack with the original header), one
    per vehicle, fed with the vehicle's clock: a recording carries exactly what the proxy would forward.
    """

    out: IO[bytes]
    engine: Engine | None = None
    bad: int = 0
    _written: int = 0
    _frames_in: int = 0
    _pipes: dict[int, Pipeline] = field(default_factory=dict)
    _vehicle_s: dict[int, float] = field(default_factory=dict)
    _held: list[tuple[float, int, bytes]] = field(default_factory=list)
    _order: int = 0

    @property
    def counts(self) -> Counts:
        stats = [p.stats[Direction.DOWNLINK] for p in self._pipes.values()]
        return Counts(self._frames_in, self._written, sum(s.rewritten for s in stats), sum(s.dropped for s in stats),
                      sum(s.delayed for s in stats), self.bad)  # fmt: skip

    def _write(self, frame: bytes) -> None:
        self.out.write(tlog.stamp(time.time()) + frame)
        self._written += 1

    def _pipeline(self, sysid: int) -> Pipeline | None:
        if self.engine is None:
            return None
        pipe = self._pipes.get(sysid)
        if pipe is None:
            slot = AttackSlot(sysid)
            AttackSwitch(slot).install(self.engine)  # the caller's engine and clock, shared by the vehicles
            pipe = self._pipes[sysid] = Pipeline(len(self._pipes), [AttackStage(slot)], stats=LinkStats(sysid))
        return pipe

    def feed(self, datagram: bytes) -> list[tuple[Header, bytes]]:
        """The frames of one datagram as received (returned); bytes that are no valid frame are counted in ``bad``."""
        found = split(datagram)
        self.bad += len(found.bad)
        for header, raw in found.frames:
            self._feed_frame(header, raw)
        return found.frames

    def _feed_frame(self, header: Header, raw: bytes) -> None:
        self._frames_in += 1
        sysid = header.sysid
        if header.msgid in _BOOT_CLOCKED:
            fields = codec.decode(Packet(raw, header, Direction.DOWNLINK, 0, 0.0))
            self._vehicle_s[sysid] = fields["time_boot_ms"] * 1e-3
        now_s = self._vehicle_s.get(sysid, 0.0)
        self._release(now_s)
        pipe = self._pipeline(sysid)
        if pipe is None:
            self._write(raw)
            return
        for out in pipe.feed(raw, Direction.DOWNLINK, now_s):
            if out.release_s > now_s:
                self._order += 1
                heapq.heappush(self._held, (out.release_s, self._order, out.data))
            else:
                self._write(out.data)

    def _release(self, now_s: float) -> None:
        while self._held and self._held[0][0] <= now_s:
            self._write(heapq.heappop(self._held)[2])

    def close(self) -> None:
        """Frames still held back leave at the end, in release order."""
        self._release(float("inf"))
        self.out.flush()


GCS_SYSID, GCS_COMPID = 255, 190  # what QGroundControl uses


class _Listener(asyncio.DatagramProtocol):
    """One bound UDP port; each datagram is split on its own, as the proxy does."""

    def __init__(self, writer: TlogWriter, seen: asyncio.Event, takeoff: bool = False) -> None:
        self.writer = writer
        self.seen = seen
        self.last_rx = time.monotonic()
        self.takeoff = takeoff
        self.commanded: set[int] = set()
        self.gcs = mavlink.MAVLink(None, srcSystem=GCS_SYSID, srcComponent=GCS_COMPID)
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.last_rx = time.monotonic()
        self.seen.set()
        frames = self.writer.feed(data)
        if self.takeoff:
            for header, _ in frames:
                if header.msgid == mavlink.MAVLINK_MSG_ID_HEARTBEAT and header.sysid not in self.commanded:
                    self._arm_and_take_off(header.sysid, header.compid, addr)

    def _arm_and_take_off(self, sysid: int, compid: int, addr: tuple[str, int]) -> None:
        if self.transport is None:
            return
        self.commanded.add(sysid)
        nan = math.nan
        arm = self.gcs.command_long_encode(sysid, compid, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        up = self.gcs.command_long_encode(sysid, compid, mavlink.MAV_CMD_NAV_TAKEOFF, 0, *([nan] * 7))
        for cmd in (arm, up):
            self.transport.sendto(bytes(cmd.pack(self.gcs)), addr)


async def record(
    listen: list[Endpoint],
    out: Path,
    engine: Engine | None = None,
    duration_s: float | None = None,
    idle_stop_s: float | None = None,
    on_bound: Callable[[list[tuple[str, int]]], None] | None = None,
    takeoff: bool = False,
) -> Counts:
    """Record until stopped (signal, duration, or idle after the first datagram).

    ``on_bound`` receives the bound addresses (port 0 in a URL picks a free port).
    """
    for ep in listen:
        if ep.mode != "udpin":
            raise InputError("--listen", "", str(ep), "the recorder listens: use udpin://HOST:PORT")
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    seen = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    out.parent.mkdir(parents=True, exist_ok=True)
    transports = []
    with out.open("wb") as fh:
        writer = TlogWriter(fh, engine)
        listeners = []
        try:
            for ep in listen:
                lis = _Listener(writer, seen, takeoff)
                transport, _ = await loop.create_datagram_endpoint(lambda lis=lis: lis, local_addr=ep.address)
                transports.append(transport)
                listeners.append(lis)
            if on_bound is not None:
                on_bound([t.get_extra_info("sockname")[:2] for t in transports])
            started = time.monotonic()
            while not stop.is_set():
                await asyncio.sleep(0.05)
                now = time.monotonic()
                if duration_s is not None and now - started >= duration_s:
                    break
                if idle_stop_s is not None and seen.is_set() and now - max(x.last_rx for x in listeners) >= idle_stop_s:
                    break
        finally:
            for t in transports:
                t.close()
            writer.close()
            for sig in (signal.SIGINT, signal.SIGTERM):
                with contextlib.suppress(NotImplementedError, RuntimeError):
                    loop.remove_signal_handler(sig)
    return writer.counts


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="secuav-record", description=__doc__.split("\n")[0])
    p.add_argument("--listen", action="append", required=True, metavar="URL", help="udpin://HOST:PORT (repeatable)")
    p.add_argument("--out", required=True, type=Path, help=".tlog file to write")
    p.add_argument("--attack", default="none", help="profile file, library name, or 'none' (default)")
    p.add_argument("--param", action="append", default=[], metavar="K=V", help="library profile parameter")
    p.add_argument("--scenario", default=None, help="scenario (checks the profile's sensor ids; coordinated spoof)")
    p.add_argument("--seed", type=int, default=0, help="seed of the attack's random primitives")
    p.add_argument("--duration", type=float, default=None, help="stop after S seconds (wall clock)")
    p.add_argument("--idle-stop", type=float, default=None, help="stop S seconds after the last datagram")
    p.add_argument("--takeoff", action="store_true", help="arm and take off each vehicle on its first heartbeat")
    p.add_argument("-q", "--quiet", action="store_true", help="no summary line")
    add_common_flags(p, log_flags=False)
    return p


def _engine(args: argparse.Namespace) -> Engine | None:
    params = parse_params(args.param)
    profile: Profile | None = None if args.attack == "none" else resolve_profile(args.attack, params, "--attack")
    if profile is None:
        return None
    scenario = None if args.scenario is None else load_scenario(resolve_scenario_path(args.scenario))
    return Engine(profile, seed=args.seed, scenario=scenario)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        listen = []
        for url in args.listen:
            try:
                listen.append(parse_endpoint(url))
            except ValueError as err:
                raise InputError("--listen", "", url, str(err)) from None
        engine = _engine(args)
        directions = [] if engine is None else directions_of(engine.profile)
        if engine is not None and UPLINK in directions:
            rules = [f"rules[{i}]" for i, r in enumerate(engine.profile.rules) if UPLINK in rule_directions(r)]
            print(f"record: {', '.join(rules)} of {engine.profile.name} change frames toward the vehicle; the "
                  "recorder hears only what the vehicle sends, so they change nothing here", file=sys.stderr)
        setup_logging(0, True, noisy=())  # the attack stage's warnings as the proxy writes them, not bare names
        counts = asyncio.run(record(listen, args.out, engine, args.duration, args.idle_stop, takeoff=args.takeoff))
    except InputError as err:
        print(f"record: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"record: {err}", file=sys.stderr)
        return 1
    if not args.quiet:
        print(json.dumps({"out": str(args.out), **counts.__dict__, "directions": directions}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
