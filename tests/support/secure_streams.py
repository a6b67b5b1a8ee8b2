"""Synthetic telemetry streams for the secure-stage tests, as real MAVLink frames.

A vehicle holding still (plus a slow sway, so a frozen estimate would show)
sends what flightsim sends: DISTANCE_SENSOR per sensor at its rate (wall group,
UWB anchors, downward laser), LOCAL_POSITION_NED, GLOBAL_POSITION_INT and
HOME_POSITION, packed by pymavlink; with ``attitude`` also ATTITUDE, and each wall
rangefinder then reads along its tilted beam (flightsim's own rotation code). An optional real attack_profiles Engine
rewrites the frames on the way, exactly as the proxy's attack stage does
(Action.fields merged, frames re-packed by pymavlink), so the secure stage sees
attacked wire bytes. tests/mitm_proxy/stages/test_secure_support.py checks the generator itself.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from attack_profiles.engine import Engine
from flightsim.control.rotation import quat_from_euler, rotate
from mavframe import codec
from mavframe.packet import Direction, Header, Packet
from mitm_proxy.stages.secure.stage import SecureStage
from secuav_common.geo import ned_to_geodetic
from secuav_common.scenario import KeepRangeTarget, Scenario, WallDistanceTarget
from secuav_common.sensor_ids import MOUNT_BODY, ORIENTATION, SENSOR_TYPE

Attitude = Callable[[float], tuple[float, float, float]]  # time s -> roll, pitch, yaw (rad)

V2_HEADER = struct.Struct("<BBBBBBBHB")


def packet_of(raw: bytes, now_s: float, direction: Direction = Direction.DOWNLINK) -> Packet:
    """Peek a MAVLink 2 frame's header the way the frame layer does."""
    _stx, plen, iflags, _cflags, seq, sysid, compid, lo, hi = V2_HEADER.unpack_from(raw)
    header = Header(2, lo | hi << 16, sysid, compid, seq, plen, iflags, bool(iflags & 1))
    return Packet(raw, header, direction, 0, now_s)


def wire_fields(pkt: Packet) -> dict[str, Any]:
    """What the ground side would decode from the bytes the pipeline sends (real codec + pymavlink)."""
    data = codec.encode(pkt)
    mav = mavlink.MAVLink(None)
    msg = mav.parse_char(bytearray(data))
    assert msg is not None, "the re-packed frame must parse"
    return msg.to_dict()


@dataclass
class Frame:
    """One frame of the stream with the truth it was made from."""

    t_s: float
    raw: bytes  # after the attack, if any
    clean: dict[str, Any]  # fields before the attack
    attacked: dict[str, Any]  # fields after the attack
    truth: dict[str, float] = field(default_factory=dict)


class StreamMaker:
    """Frames of one vehicle of ``scenario`` hovering at its target; ``engine`` attacks them."""

    def __init__(
        self,
        scenario: Scenario,
        sysid: int = 1,
        *,
        engine: Engine | None = None,
        seed: int = 0,
        sway_m: float = 0.05,
        peers: dict[int, StreamMaker] | None = None,
        attitude: Attitude | None = None,
    ) -> None:
        self.sc = scenario
        self.veh = scenario.vehicle(sysid)
        self.sysid = sysid
        self.engine = engine
        self.rng = np.random.default_rng(seed)
        self.sway_m = sway_m
        self.peers = peers or {}  # sysid -> the peer's maker, for inter-vehicle ranges
        self.attitude = attitude
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.mav.robust_parsing = True
        if engine is not None:
            engine.activate(0.0)
        tgt = self.veh.target
        if isinstance(tgt, WallDistanceTarget):
            wall = scenario.wall(tgt.wall)
            n = np.asarray(wall.normal_ned)
            self.hold = np.asarray(wall.point_ned_m) + n * tgt.distance_m
            self.hold[2] = -tgt.altitude_m
        elif isinstance(tgt, KeepRangeTarget):
            start = self.veh.start.pos_ned_m
            self.hold = np.array([start[0], start[1], -tgt.altitude_m])
        else:
            self.hold = np.asarray(tgt.pos_ned_m, dtype=float)  # type: ignore[union-attr]

    def truth(self, t_s: float) -> np.ndarray:
        a = self.sway_m
        return self.hold + np.array([a * math.sin(0.5 * t_s), a * math.cos(0.3 * t_s), 0.0])

    def velocity(self, t_s: float) -> np.ndarray:
        """The rate of :meth:`truth`, which LOCAL_POSITION_NED's vx, vy, vz carry (the autopilot's own estimate)."""
        a = self.sway_m
        return np.array([0.5 * a * math.cos(0.5 * t_s), -0.3 * a * math.sin(0.3 * t_s), 0.0])

    def wall_distance(self, pos: np.ndarray) -> float:
        tgt = self.veh.target
        assert isinstance(tgt, WallDistanceTarget)
        wall = self.sc.wall(tgt.wall)
        return float((pos - np.asarray(wall.point_ned_m)) @ np.asarray(wall.normal_ned))

    def beam_range(self, pos: np.ndarray, t_s: float, orientation: str) -> float:
        """What a wall rangefinder reads along its beam at the attitude of ``t_s`` (level without ``attitude``)."""
        d = self.wall_distance(pos)
        if self.attitude is None:
            return d
        tgt = self.veh.target
        assert isinstance(tgt, WallDistanceTarget)
        beam = rotate(quat_from_euler(*self.attitude(t_s)), MOUNT_BODY[orientation])
        return d / float(np.dot(beam, -np.asarray(self.sc.wall(tgt.wall).normal_ned)))

    def _pack(self, msg: mavlink.MAVLink_message) -> bytes:
        return bytes(msg.pack(self.mav))

    def _attack(self, t_s: float, msg: mavlink.MAVLink_message) -> tuple[bytes, dict[str, Any], dict[str, Any]]:
        clean = msg.to_dict()
        clean.pop("mavpackettype", None)
        if self.engine is None or msg.get_msgId() not in self.engine.message_ids:
            return self._pack(msg), clean, clean
        action = self.engine.process(t_s, msg.get_msgId(), clean, Direction.DOWNLINK, self.sysid, 1)
        if action.drop:
            return b"", clean, {}
        if not action.fields:
            return self._pack(msg), clean, clean
        attacked = {**clean, **action.fields}
        cls = type(msg)
        return self._pack(cls(**{k: attacked[k] for k in cls.fieldnames})), clean, attacked

    def frames(self, duration_s: float, dt_s: float = 0.05) -> Iterator[Frame]:
        """20 Hz ticks: every sensor due at a tick sends; position at 20/10 Hz; home at 0.5 Hz."""
        anchors = self.sc.anchor_positions()
        sensors = self.veh.sensors
        for k in range(round(duration_s / dt_s)):
            t = k * dt_s
            ms = round(t * 1000)
            pos = self.truth(t)
            msgs: list[tuple[mavlink.MAVLink_message, dict[str, float]]] = []
            if k % 40 == 0:
                h = self.sc.world.home
                msgs.append(
                    (
                        self.mav.home_position_encode(
                            round(h.lat_deg * 1e7),
                            round(h.lon_deg * 1e7),
                            round(h.alt_m * 1000),
                            0,
                            0,
                            0,
                            (1, 0, 0, 0),
                            0,
                            0,
                            0,
                            round(t * 1e6),
                        ),
                        {},
                    )
                )
            if self.attitude is not None:
                msgs.append((self.mav.attitude_encode(ms, *self.attitude(t), 0.0, 0.0, 0.0), {}))
            for r in sensors.rangefinders:
                if k % max(1, round(1 / (r.rate_hz * dt_s))):
                    continue
                if r.orientation == "down":
                    true_m = -pos[2]
                elif isinstance(self.veh.target, WallDistanceTarget):
                    true_m = self.beam_range(pos, t, r.orientation)
                else:
                    continue
                meas = true_m + r.noise_std_m * self.rng.standard_normal()
                msgs.append(
                    (
                        self._range(
                            ms,
                            r.min_m,
                            r.max_m,
                            meas,
                            SENSOR_TYPE[r.type],
                            r.id,
                            ORIENTATION[r.orientation],
                            r.noise_std_m,
                        ),
                        {"range_m": true_m},
                    )
                )
            uwb = sensors.uwb
            if uwb is not None and k % max(1, round(1 / (uwb.rate_hz * dt_s))) == 0:
                for a, apos in sorted(anchors.items()):
                    true_m = float(np.linalg.norm(pos - np.asarray(apos)))
                    meas = true_m + uwb.noise_std_m * self.rng.standard_normal()
                    msgs.append(
                        (self._range(ms, 0.0, uwb.max_m, meas, 4, 10 + a, 100, uwb.noise_std_m), {"range_m": true_m})
                    )
            iv = sensors.inter_vehicle
            if iv is not None and k % max(1, round(1 / (iv.rate_hz * dt_s))) == 0:
                for n, peer in sorted(self.peers.items()):
                    true_m = float(np.linalg.norm(pos - peer.truth(t)))
                    meas = true_m + iv.noise_std_m * self.rng.standard_normal()
                    msgs.append(
                        (self._range(ms, 0.0, 100.0, meas, 4, 50 + n, 100, iv.noise_std_m), {"range_m": true_m})
                    )
            gps = 0.05 * self.rng.standard_normal(3)
            own = pos + gps  # the autopilot's own (GPS) estimate
            msgs.append((self.mav.local_position_ned_encode(ms, *own, *self.velocity(t)), {"n": pos[0], "e": pos[1]}))
            if k % 2 == 0:
                lat, lon, alt = ned_to_geodetic(self.sc.world.home, *own)
                msgs.append(
                    (
                        self.mav.global_position_int_encode(
                            ms, round(lat * 1e7), round(lon * 1e7), round(alt * 1000), round(-own[2] * 1000), 0, 0, 0, 0
                        ),
                        {"n": pos[0], "e": pos[1]},
                    )
                )
            for msg, truth in msgs:
                raw, clean, attacked = self._attack(t, msg)
                if raw:
                    yield Frame(t, raw, clean, attacked, truth)

    def _range(
        self, ms: int, lo: float, hi: float, meas: float, kind: int, sid: int, orient: int, std: float
    ) -> mavlink.MAVLink_message:
        cm = max(0, min(65534, round(meas * 100)))
        cov = min(254, round((std * 100) ** 2))
        return self.mav.distance_sensor_encode(
            ms, round(lo * 100), round(hi * 100), cm, kind, sid, orient, cov, signal_quality=100
        )


@dataclass
class Out:
    frame: Frame
    msgid: int
    fields: dict[str, Any]  # as the ground side decodes them
    changed: bool
    raw_out: bytes


def run(stage: SecureStage, maker: StreamMaker, duration_s: float) -> list[Out]:
    """The maker's frames through the stage as the pipeline hands them over; what the ground side decodes."""
    outs = []
    for fr in maker.frames(duration_s):
        pkt = packet_of(fr.raw, fr.t_s)
        if stage.active and pkt.header.msgid in stage.message_ids:
            res = stage.process(pkt, fr.t_s)
            assert len(res) == 1 and res[0] is pkt
        outs.append(Out(fr, pkt.header.msgid, wire_fields(pkt), pkt.changed, fr.raw if not pkt.changed else b""))
    return outs
