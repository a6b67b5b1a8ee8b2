"""Run all vehicles of a scenario in one process, each on its own MAVLink socket.

One asyncio loop owns the clock: every tick it advances the simulation by
``TICK_STEPS`` physics steps, then lets each vehicle's PX4 personality send
what is due. Datagrams are handled as they arrive, between ticks, so a
command is acknowledged within one tick (20 ms) at 1x.

Clock: ``speed`` 1.0 is the wall clock (MAVSDK's timers are wall clock),
``speed`` X runs X times faster, ``speed`` 0 as fast as the CPU allows. Sim
time is a step count times ``dt_s``: the same seed gives the same flight
whatever the speed, given the same commands.
"""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from flightsim.mavlink import Px4Personality, UdpLink
from flightsim.mavlink.tcp import TcpServerLink
from flightsim.simulation import Simulation
from flightsim.truth import CsvTruth, MqttTruth, TruthSample
from secuav_common.controlplane.address import BrokerAddress
from secuav_common.scenario import Scenario
from secuav_common.urls import Endpoint

log = logging.getLogger(__name__)

TICK_STEPS = 4  # 200 Hz physics / 4 = 50 Hz MAVLink ticks, PX4's position-controller rate
MAX_LAG_S = 0.5  # further behind the wall clock than this (CPU starved): skip ahead instead of bursting
STATUS_PERIOD_S = 10.0
FAST_YIELD_TICKS = 5  # in as-fast-as-possible mode, let the sockets breathe this often


@dataclass(slots=True)
class RunConfig:
    scenario: Scenario
    endpoints: list[Endpoint]  # one per vehicle, in scenario order
    seed: int | None = None
    speed: float = 1.0  # 0 = as fast as possible
    duration_s: float | None = None  # sim seconds; None = until stopped
    broker: BrokerAddress | None = None
    truth_csv: Path | None = None
    truth_hz: float = 20.0
    gcs: Endpoint | None = None  # every vehicle also streams here (udpout), e.g. QGroundControl on 14550
    broker_tls_ca: Path | None = None  # CA file of a TLS broker (a private CA); mqtts:// alone uses the system's


@dataclass(slots=True)
class VehicleLink:
    sysid: int
    link: UdpLink | TcpServerLink
    personality: Px4Personality


@dataclass(slots=True)
class RunSummary:
    sim_t_s: float = 0.0
    wall_s: float = 0.0
    ticks: int = 0
    frames_sent: dict[int, int] = field(default_factory=dict)
    frames_received: dict[int, int] = field(default_factory=dict)
    malformed: dict[int, int] = field(default_factory=dict)
    crashed: list[int] = field(default_factory=list)

    @property
    def real_time_factor(self) -> float:
        return self.sim_t_s / self.wall_s if self.wall_s > 0 else 0.0


class SimRunner:
    """``async with SimRunner(config) as runner: await runner.run(stop_event)``."""

    def __init__(self, config: RunConfig) -> None:
        if len(config.endpoints) != len(config.scenario.vehicles):
            raise ValueError("one MAVLink endpoint per vehicle is needed")
        self.config = config
        self.sim = Simulation(config.scenario, seed=config.seed)
        self.vehicles: list[VehicleLink] = []
        self._csv: CsvTruth | None = None
        self._mqtt: MqttTruth | None = None
        # Truth is sampled on ticks (50 Hz); a rate that does not divide it (20 Hz) keeps its average
        # by stepping a due time instead of publishing every round(50 / rate) ticks.
        self._truth_period_s = 1.0 / config.truth_hz
        self._next_truth_t_s = 0.0
        self.summary = RunSummary()

    async def __aenter__(self) -> SimRunner:
        try:
            for cfg, endpoint in zip(self.config.scenario.vehicles, self.config.endpoints, strict=True):
                vehicle = self.sim.vehicles[cfg.sysid]
                holder: list[Px4Personality] = []
                also = (self.config.gcs.address,) if self.config.gcs is not None else ()

                def receive(data: bytes, now: float, h: list[Px4Personality] = holder) -> None:
                    h[0].receive(data, now)

                link: UdpLink | TcpServerLink
                if endpoint.mode == "tcpin":
                    link = TcpServerLink(endpoint, receive)
                else:
                    link = UdpLink(endpoint, receive, also)
                personality = Px4Personality(vehicle, link.send)
                holder.append(personality)
                # Answers (COMMAND_ACK, PARAM_VALUE) leave right away, not at the next tick.
                link.on_after_receive = link.flush
                await link.open()
                self.vehicles.append(VehicleLink(cfg.sysid, link, personality))
                host, port = link.local_address
                log.info(
                    "vehicle.ready", extra={"sysid": cfg.sysid, "mavlink": str(endpoint), "local": f"{host}:{port}"}
                )
        except BaseException:
            await self._close()
            raise
        if self.config.truth_csv is not None:
            self._csv = CsvTruth(self.config.truth_csv)
        if self.config.broker is not None:
            ca = self.config.broker_tls_ca
            self._mqtt = MqttTruth(self.config.broker, tls_ca=None if ca is None else str(ca))
            self._mqtt.start()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self._close()

    async def _close(self) -> None:
        for v in self.vehicles:
            v.link.close()
        if self._csv is not None:
            self._csv.close()
            self._csv = None
        if self._mqtt is not None:
            await self._mqtt.close()
            self._mqtt = None

    # -- the clock ---------------------------------------------------------------------------
    def tick(self, now_wall_s: float) -> None:
        """Advance the simulation one tick and let every vehicle talk."""
        sim = self.sim
        for _ in range(TICK_STEPS):
            sim.step()
        t = sim.t_s
        for v in self.vehicles:
            v.personality.tick(t, now_wall_s)
            v.link.flush()
        self.summary.ticks += 1
        if t + 1e-9 >= self._next_truth_t_s and (self._csv or self._mqtt):
            self._next_truth_t_s = max(self._next_truth_t_s + self._truth_period_s, t)
            self._publish_truth()

    def _publish_truth(self) -> None:
        for sysid, vehicle in self.sim.vehicles.items():
            sample = TruthSample(sysid, vehicle.truth, vehicle.crashed)
            if self._csv is not None:
                self._csv.write(sample)
            if self._mqtt is not None:
                self._mqtt.publish(sample)

    async def run(self, stop: asyncio.Event) -> RunSummary:
        """Tick until ``stop`` is set or the duration is reached."""
        cfg = self.config
        tick_sim_s = self.sim.dt_s * TICK_STEPS
        end_s = cfg.duration_s if cfg.duration_s is not None else float("inf")
        wall0 = time.monotonic()
        sim0 = self.sim.t_s
        next_status = wall0 + STATUS_PERIOD_S
        while not stop.is_set() and self.sim.t_s + 1e-9 < end_s:
            now = time.monotonic()
            if cfg.speed <= 0:
                for _ in range(FAST_YIELD_TICKS):
                    self.tick(now)
                    if self.sim.t_s + 1e-9 >= end_s:
                        break
                await asyncio.sleep(0)
            else:
                target = sim0 + (now - wall0) * cfg.speed
                if target - self.sim.t_s > MAX_LAG_S * cfg.speed:
                    log.warning("clock.behind", extra={"lag_s": round(target - self.sim.t_s, 3)})
                    wall0 = now - (self.sim.t_s - sim0) / cfg.speed
                    target = self.sim.t_s
                while self.sim.t_s + tick_sim_s <= target + 1e-9 and self.sim.t_s + 1e-9 < end_s:
                    self.tick(now)
                next_tick_wall = wall0 + (self.sim.t_s + tick_sim_s - sim0) / cfg.speed
                await _wait(next_tick_wall - time.monotonic())
            if now >= next_status:
                next_status = now + STATUS_PERIOD_S
                self._log_status(now - wall0)
        self.summary.wall_s = time.monotonic() - wall0
        self.summary.sim_t_s = self.sim.t_s - sim0
        for v in self.vehicles:
            st = v.personality.stats
            self.summary.frames_sent[v.sysid] = st.tx_frames
            self.summary.frames_received[v.sysid] = st.rx_frames
            self.summary.malformed[v.sysid] = st.rx_malformed
            if v.personality.vehicle.crashed:
                self.summary.crashed.append(v.sysid)
        return self.summary

    def _log_status(self, wall_s: float) -> None:
        parts = []
        for v in self.vehicles:
            veh = v.personality.vehicle
            alt = -veh.estimate.pos_ned_m[2]
            state = "crashed" if veh.crashed else ("armed" if veh.armed else "disarmed")
            parts.append(f"v{v.sysid}:{veh.mode.value}/{state}/alt={alt:.1f}m")
        log.info("sim.status", extra={"t_s": round(self.sim.t_s, 1), "rtf": round(self.sim.t_s / wall_s, 2)
                                      if wall_s > 0 else 0.0, "vehicles": " ".join(parts)})  # fmt: skip


async def _wait(seconds: float) -> None:
    """Sleep until the next tick is due; a stop request is seen within one tick (20 ms)."""
    await asyncio.sleep(max(0.0, seconds))
