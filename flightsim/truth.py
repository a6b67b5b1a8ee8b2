"""Ground truth out of the simulator: MQTT ``secuav/v<sysid>/truth`` and a CSV file.

Evaluation only (estimators never read it). Every sample carries sim time so
it can be joined with estimates and recorded MAVLink. The MQTT publisher is
the control plane's session (:mod:`secuav_common.controlplane.session`): TLS
for an ``mqtts://`` address or a CA file, and it reconnects by itself: if the
broker goes away the simulation keeps flying, samples meanwhile are dropped,
and publishing resumes when it is back.
"""

from __future__ import annotations

import asyncio
import contextlib
import csv
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

from flightsim.api import State
from secuav_common.controlplane.address import BrokerAddress
from secuav_common.controlplane.payloads import Truth
from secuav_common.controlplane.topics import vehicle_topic

if TYPE_CHECKING:
    from secuav_common.controlplane.session import Client, Session

log = logging.getLogger(__name__)
QUEUE_MAX = 2000
RECONNECT_S = 1.0
CSV_COLUMNS = (
    "t_s", "sysid", "north_m", "east_m", "down_m", "vn_m_s", "ve_m_s", "vd_m_s",
    "roll_rad", "pitch_rad", "yaw_rad", "qw", "qx", "qy", "qz", "collided",
)  # fmt: skip


@dataclass(frozen=True, slots=True)
class TruthSample:
    sysid: int
    state: State
    collided: bool

    def as_json(self) -> str:
        s = self.state
        message = Truth(
            t_s=round(s.t_s, 6),
            sysid=self.sysid,
            pos_ned_m=[round(c, 5) for c in s.pos_ned_m],
            vel_ned_m_s=[round(c, 5) for c in s.vel_ned_m_s],
            euler_rad=[round(c, 6) for c in s.euler_rad],
            quat=[round(c, 7) for c in s.quat],
            collided=self.collided,
        )
        return json.dumps(message.model_dump())

    def as_row(self) -> list[object]:
        s = self.state
        return [
            f"{s.t_s:.4f}", self.sysid,
            *(f"{c:.5f}" for c in s.pos_ned_m), *(f"{c:.5f}" for c in s.vel_ned_m_s),
            *(f"{c:.6f}" for c in s.euler_rad), *(f"{c:.7f}" for c in s.quat), int(self.collided),
        ]  # fmt: skip


def truth_topic(sysid: int) -> str:
    return vehicle_topic(sysid, "truth")


class CsvTruth:
    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self._file: IO[str] = path.open("w", newline="")
        self._writer = csv.writer(self._file)
        self._writer.writerow(CSV_COLUMNS)

    def write(self, sample: TruthSample) -> None:
        self._writer.writerow(sample.as_row())

    def close(self) -> None:
        self._file.close()


class MqttTruth:
    """Publishes samples from a bounded queue in a background task."""

    def __init__(self, address: BrokerAddress, tls_ca: str | None = None) -> None:
        self.address = address
        self.tls_ca = tls_ca
        self._queue: asyncio.Queue[TruthSample] = asyncio.Queue(QUEUE_MAX)
        self._task: asyncio.Task[None] | None = None
        self.session: Session | None = None
        self.published = 0
        self.dropped = 0

    @property
    def connected(self) -> bool:
        return self.session is not None and self.session.connected.is_set()

    def start(self) -> None:
        # Imported here: runs without a broker never load the MQTT stack.
        from secuav_common.controlplane.session import Session

        self.session = Session(self.address, tls_ca=self.tls_ca, backoff_s=(RECONNECT_S, RECONNECT_S), log=log)
        self._task = asyncio.create_task(self.session.run(self._serve, on_down=self._discard), name="truth-mqtt")

    def publish(self, sample: TruthSample) -> None:
        if not self.connected:
            self.dropped += 1
            return
        try:
            self._queue.put_nowait(sample)
        except asyncio.QueueFull:
            self.dropped += 1

    async def _serve(self, client: Client) -> None:
        assert self.session is not None
        self.session.mark_connected()
        log.info("truth.mqtt_connected", extra={"url": self.address.url})
        while True:
            sample = await self._queue.get()
            await client.publish(truth_topic(sample.sysid), sample.as_json(), qos=0)
            self.published += 1

    def _discard(self) -> None:
        """The session ended: what waited for it is stale by the time it is back."""
        while not self._queue.empty():
            self._queue.get_nowait()
            self.dropped += 1

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await asyncio.wait_for(self._task, timeout=1.0)
