"""Default UDP port plan (mirrors PX4 SITL so stock tools work unchanged)."""

from __future__ import annotations

LOOPBACK = "127.0.0.1"
PROXY_VEHICLE_BASE = 14560  # vehicle i sends to the proxy here (+i)
GROUND_API_BASE = 14540  # MAVSDK / offboard API, vehicle i at +i
GCS_PORT = 14550  # QGroundControl, MAVProxy
MQTT_PORT = 1883


def vehicle_index(sysid: int) -> int:
    """Vehicle i has sysid i + 1."""
    return sysid - 1


def proxy_vehicle_url(index: int) -> str:
    return f"udpout://{LOOPBACK}:{PROXY_VEHICLE_BASE + index}"


def api_url(index: int) -> str:
    return f"udpout://{LOOPBACK}:{GROUND_API_BASE + index}"


def gcs_url() -> str:
    return f"udpout://{LOOPBACK}:{GCS_PORT}"
