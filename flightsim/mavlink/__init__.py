"""PX4 personality over MAVLink 2 for a simulated vehicle.

The protocol core (:class:`~flightsim.mavlink.personality.Px4Personality`) is
sans-I/O: it takes received datagrams and the passing of sim time, and hands
encoded frames to a ``send`` callback. :mod:`flightsim.mavlink.udp` is the thin
asyncio edge that owns the socket. Each protocol (telemetry streams, commands,
parameters, missions, offboard) lives in its own small module.
"""

from flightsim.mavlink.personality import Px4Personality
from flightsim.mavlink.udp import UdpLink

__all__ = ["Px4Personality", "UdpLink"]
