"""Vehicles and ground stations as plain loopback UDP sockets speaking real MAVLink (frames packed by pymavlink),
for tests that run the real proxy in-process."""

from __future__ import annotations

import asyncio
import socket

from pymavlink.dialects.v20 import common as mavlink2

from mavframe.frames import split


def packer(sysid: int, compid: int = 1) -> mavlink2.MAVLink:
    return mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)


def heartbeat(mav: mavlink2.MAVLink) -> bytes:
    return mav.heartbeat_encode(2, 12, 0, 0, 3).pack(mav)


def command(mav: mavlink2.MAVLink, target: int) -> bytes:
    return mav.command_long_encode(target, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav)


def distance(mav: mavlink2.MAVLink, cm: int, sensor_id: int = 0) -> bytes:
    return mav.distance_sensor_encode(1000, 10, 4000, cm, 0, sensor_id, 0, 0).pack(mav)


class Peer:
    """A vehicle or ground station: a loopback UDP socket."""

    def __init__(self, port: int | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port or 0))
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]

    def send(self, data: bytes, port: int) -> None:
        self.sock.sendto(data, ("127.0.0.1", port))

    def reply(self, data: bytes, addr: tuple[str, int]) -> None:
        self.sock.sendto(data, addr)

    async def frames(self, quiet_s: float = 0.3) -> tuple[list[bytes], tuple[str, int] | None]:
        """Every frame received until nothing arrives for ``quiet_s``; and the last sender."""
        loop = asyncio.get_running_loop()
        out: list[bytes] = []
        sender = None
        while True:
            try:
                data, sender = await asyncio.wait_for(loop.sock_recvfrom(self.sock, 65535), quiet_s)
            except TimeoutError:
                return out, sender
            out.extend(f for _h, f in split(data).frames)

    async def take(self, count: int, bound_s: float = 20.0) -> tuple[list[bytes], tuple[str, int] | None]:
        """The first ``count`` frames to arrive, however slowly a loaded machine delivers them, and the last
        sender. ``bound_s`` only bounds a failure: when fewer arrive, what did is returned for the assertion."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + bound_s
        out: list[bytes] = []
        sender = None
        while len(out) < count:
            try:
                data, sender = await asyncio.wait_for(loop.sock_recvfrom(self.sock, 65535), deadline - loop.time())
            except TimeoutError:
                break
            out.extend(f for _h, f in split(data).frames)
        return out, sender

    def close(self) -> None:
        self.sock.close()
