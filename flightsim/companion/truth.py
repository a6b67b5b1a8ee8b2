"""Where ``secuav-feed`` takes the true state from: flightsim's truth topic, a SITL's own truth, a recording.

Each source is an async iterator of :class:`flightsim.api.State` (local NED from the scenario's home):

- :class:`MqttTruth`: ``secuav/v<sysid>/truth`` as ``secuav-sim --broker`` publishes it (its ``t_s`` is sim time);
- :class:`MavlinkTruth`: a simulator's ground truth over MAVLink, never the autopilot's belief: ArduPilot
  SITL's SIM_STATE (#108) or PX4 SIH's HIL_STATE_QUATERNION (#115), asked for with SET_MESSAGE_INTERVAL
  until it comes; stamped on arrival (seconds since the source opened). ArduPilot's SIMSTATE (#164)
  carries no altitude, so it is not used;
- :class:`TlogTruth`: the same messages from a ``.tlog``, replayed at the recorded pace (``speed``); a
  recording without them (a proxy's recording of flightsim) falls back to LOCAL_POSITION_NED with
  ATTITUDE, the autopilot's estimate, which is what the vehicle flew by.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator
from pathlib import Path

from pydantic import ValidationError
from pymavlink.dialects.v20 import ardupilotmega as apm

from flightsim.api import State
from flightsim.control.rotation import euler_from_quat, quat_from_euler
from flightsim.mavlink.udp import UdpLink
from mavframe.tlog import read as read_tlog
from secuav_common.controlplane.address import BrokerAddress
from secuav_common.controlplane.payloads import Truth
from secuav_common.controlplane.topics import vehicle_topic
from secuav_common.geo import geodetic_to_ned
from secuav_common.scenario import Home
from secuav_common.urls import Endpoint

log = logging.getLogger(__name__)
ZERO = (0.0, 0.0, 0.0)
TRUTH_MESSAGES = (apm.MAVLINK_MSG_ID_SIM_STATE, apm.MAVLINK_MSG_ID_HIL_STATE_QUATERNION)
ASK_PERIOD_S = 2.0
QUEUE_MAX = 64


def state(t_s: float, pos: tuple[float, float, float], vel: tuple[float, float, float],
          quat: tuple[float, float, float, float], rates: tuple[float, float, float] = ZERO) -> State:  # fmt: skip
    return State(t_s, pos, vel, ZERO, quat, euler_from_quat(quat), rates)


class TruthDecoder:
    """MAVLink truth messages of one system -> State; keeps the last ATTITUDE for LOCAL_POSITION_NED."""

    def __init__(self, home: Home, sysid: int, estimate_fallback: bool = False) -> None:
        self.home = home
        self.sysid = sysid
        self.estimate_fallback = estimate_fallback
        self._quat: tuple[float, float, float, float] | None = None
        self.truth_seen = False

    def decode(self, msg: apm.MAVLink_message, t_s: float) -> State | None:
        if msg.get_srcSystem() != self.sysid:
            return None
        kind = msg.get_type()
        if kind == "SIM_STATE":
            self.truth_seen = True
            lat = msg.lat_int / 1e7 if getattr(msg, "lat_int", 0) else msg.lat  # lat_int since 2021, degrees before
            lon = msg.lon_int / 1e7 if getattr(msg, "lon_int", 0) else msg.lon
            pos = geodetic_to_ned(self.home, lat, lon, msg.alt)
            return state(t_s, pos, (msg.vn, msg.ve, msg.vd), (msg.q1, msg.q2, msg.q3, msg.q4),
                         (msg.xgyro, msg.ygyro, msg.zgyro))  # fmt: skip
        if kind == "HIL_STATE_QUATERNION":
            self.truth_seen = True
            pos = geodetic_to_ned(self.home, msg.lat / 1e7, msg.lon / 1e7, msg.alt / 1000.0)
            q = tuple(msg.attitude_quaternion)
            return state(t_s, pos, (msg.vx / 100, msg.vy / 100, msg.vz / 100), q,  # type: ignore[arg-type]
                         (msg.rollspeed, msg.pitchspeed, msg.yawspeed))  # fmt: skip
        if not self.estimate_fallback or self.truth_seen:
            return None
        if kind == "ATTITUDE":
            self._quat = quat_from_euler(msg.roll, msg.pitch, msg.yaw)
        elif kind == "LOCAL_POSITION_NED" and self._quat is not None:
            return state(t_s, (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz), self._quat)
        return None


class MqttTruth:
    """``secuav/v<sysid>/truth`` from the broker; reconnects by itself (the control plane's session)."""

    def __init__(self, address: BrokerAddress, sysid: int, tls_ca: str | None = None) -> None:
        self.address, self.sysid, self.tls_ca = address, sysid, tls_ca
        self.bad = 0  # payloads that are not a truth sample

    async def states(self) -> AsyncIterator[State]:
        from secuav_common.controlplane.session import Client, Session

        queue: asyncio.Queue[State] = asyncio.Queue(QUEUE_MAX)
        session = Session(self.address, tls_ca=self.tls_ca, backoff_s=(0.5, 2.0), log=log)
        topic = vehicle_topic(self.sysid, "truth")

        async def serve(client: Client) -> None:
            await client.subscribe(topic, qos=0)
            session.mark_connected()
            async for m in client.messages:
                try:
                    t = Truth.model_validate_json(bytes(m.payload))  # type: ignore[arg-type]
                except ValidationError:
                    self.bad += 1
                    continue
                if queue.full():  # a slow consumer wants the newest state, not a backlog
                    queue.get_nowait()
                quat = tuple(t.quat) if t.quat and len(t.quat) == 4 else quat_from_euler(*(t.euler_rad or ZERO))
                vel = tuple(t.vel_ned_m_s) if t.vel_ned_m_s and len(t.vel_ned_m_s) == 3 else ZERO
                stamp = t.t_s if t.t_s is not None else time.monotonic()
                queue.put_nowait(state(stamp, tuple(t.pos_ned_m), vel, quat))  # type: ignore[arg-type]

        task = asyncio.create_task(session.run(serve), name="feed-truth-mqtt")
        try:
            while True:
                yield await queue.get()
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task


class MavlinkTruth:
    """A simulator's truth over MAVLink: ``udpin://``, ``udpout://`` or ``tcp://`` (SITL's serial ports)."""

    def __init__(self, endpoint: Endpoint, home: Home, sysid: int) -> None:
        if endpoint.mode not in ("udpin", "udpout", "tcp"):
            raise ValueError(f"--truth {endpoint}: a MAVLink truth source is udpin://, udpout:// or tcp://HOST:PORT")
        self.endpoint, self.home, self.sysid = endpoint, home, sysid
        self.decoder = TruthDecoder(home, sysid)

    async def states(self) -> AsyncIterator[State]:
        queue: asyncio.Queue[State] = asyncio.Queue(QUEUE_MAX)
        parser = apm.MAVLink(None)
        ask = apm.MAVLink(None, srcSystem=255, srcComponent=apm.MAV_COMP_ID_PERIPHERAL)
        t0 = time.monotonic()

        def on_bytes(data: bytes, now: float) -> None:
            try:
                msgs = parser.parse_buffer(data) or []
            except apm.MAVError:
                return  # a corrupt frame: pymavlink resynchronises on the next call
            for msg in msgs:
                s = self.decoder.decode(msg, now - t0)
                if s is not None:
                    if queue.full():
                        queue.get_nowait()
                    queue.put_nowait(s)

        def requests() -> bytes:
            out = b""
            for msg_id in TRUTH_MESSAGES:
                cmd = ask.command_long_encode(self.sysid, 1, apm.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, 50_000,
                                              0, 0, 0, 0, 0)  # fmt: skip
                out += cmd.pack(ask)
            return out

        send, close = await self._open(on_bytes)
        try:
            while True:
                if not self.decoder.truth_seen:
                    send(requests())  # 20 Hz of each, until one comes (SITL may still be booting)
                try:
                    yield await asyncio.wait_for(queue.get(), ASK_PERIOD_S)
                except TimeoutError:
                    continue
        finally:
            close()

    async def _open(self, on_bytes: object) -> tuple[object, object]:
        ep = self.endpoint
        callback = on_bytes  # type: ignore[assignment]
        if ep.mode == "tcp":
            reader, writer = await asyncio.open_connection(ep.host, ep.port)

            async def pump() -> None:
                while data := await reader.read(4096):
                    callback(data, time.monotonic())  # type: ignore[operator]

            task = asyncio.create_task(pump(), name="feed-truth-tcp")

            def send_tcp(data: bytes) -> None:
                writer.write(data)

            def close_tcp() -> None:
                task.cancel()
                writer.close()

            return send_tcp, close_tcp
        link = await UdpLink(ep, callback).open()  # type: ignore[arg-type]

        def send_udp(data: bytes) -> None:
            link.send(data)
            link.flush()

        return send_udp, link.close


class TlogTruth:
    """Truth (or, failing that, the estimate) from a recording, at ``speed`` x its pace (0: at once)."""

    def __init__(self, path: Path, home: Home, sysid: int, speed: float = 1.0) -> None:
        self.path, self.speed = path, speed
        self.decoder = TruthDecoder(home, sysid, estimate_fallback=True)
        self.skipped = 0

    async def states(self) -> AsyncIterator[State]:
        reader = read_tlog(self.path)
        parser = apm.MAVLink(None)
        t_first: float | None = None
        wall0 = time.monotonic()
        for entry in reader:
            try:
                msg = parser.decode(bytearray(entry.raw))
            except Exception:  # pymavlink raises several types on a frame it refuses
                self.skipped += 1
                continue
            if t_first is None:
                t_first = entry.t_s
            t = entry.t_s - t_first
            s = self.decoder.decode(msg, t)
            if s is None:
                continue
            if self.speed > 0:
                await asyncio.sleep(max(0.0, wall0 + t / self.speed - time.monotonic()))
            else:
                await asyncio.sleep(0)
            yield s
        self.skipped += reader.skipped
