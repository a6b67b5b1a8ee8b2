"""The proxy process: links, control plane and the periodic stats line.

Each link's pipeline is tap -> attack -> secure -> forward (mitm_proxy/README.md). The
attack stage is always there (``--attack bypass`` skips it; with no profile
it costs nothing); the secure stage is there when a scenario says what the
sensors are (``--scenario``), off until ``--secure NAME`` or ``secure/set``.

``async with Proxy(config) as proxy: await stop.wait()`` is the whole daemon
(:func:`serve` adds the signal handling). Entering opens every socket first, so
a port that is taken fails before anything else starts; leaving closes the
sockets, cancels held-back frames, closes the recordings and says goodbye on
the control plane, within a second.

The control plane is optional and never on the forwarding path: if the broker
is down or restarts, frames keep flowing and the control plane reconnects on
its own (``ControlPlane.run``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import socket
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from attack_profiles.directions import check_no_uplink, describe
from attack_profiles.resolve import resolve_profile
from mavframe.signing import Signer
from mitm_proxy.config import ProxyConfig
from mitm_proxy.control.attack import AttackSwitch
from mitm_proxy.control.link import LinkParts, SwitchHost
from mitm_proxy.control.mode import ModeSwitch
from mitm_proxy.control.secure import SecureSwitch
from mitm_proxy.control.switches import Controls, build_controls, default_instance
from mitm_proxy.core.pipeline import Pipeline, Stage
from mitm_proxy.core.readings import ReadingsTap
from mitm_proxy.core.recorder import Recorder
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.net.endpoints import DEFAULT_TAKEOVER_S, BaseEndpoint
from mitm_proxy.net.factory import make_endpoint
from mitm_proxy.net.link import GroundRouter, Link
from mitm_proxy.stages.attack import AttackStage
from mitm_proxy.stages.attack_slot import AttackSlot
from mitm_proxy.stages.secure.config import OFF, SecureConfig, config_from_payload
from secuav_common.broker import redact
from secuav_common.controlplane.topics import vehicle_topic
from secuav_common.loading import InputError
from secuav_common.scenario import Scenario, load_scenario
from secuav_common.urls import Endpoint

if TYPE_CHECKING:  # imported when used: numpy/scipy (secure) and MQTT (control) stay out of start-up
    from mitm_proxy.control.plane import ControlPlane
    from mitm_proxy.control.reload import ProfileWatcher

log = logging.getLogger("secuav-proxy")
# Where the secure stage reads and substitutes, as proxy.ready says it.
WORDS_ON = {"downlink": "toward the ground", "uplink": "toward the vehicle", "both": "both directions"}
VEHICLE_TAKEOVER_S = 1.0  # a new vehicle source port is followed after this much silence from the old one
STOP_BUDGET_S = 0.8  # what the control plane may take to say goodbye
READINGS_PERIOD_S = 0.1  # secuav/v<N>/readings while a console watches


class Proxy:
    """The daemon as an async context manager; ``vehicles`` and ``links`` are keyed/ordered by vehicle."""

    def __init__(self, config: ProxyConfig) -> None:
        self.config = config
        self.instance = config.instance or default_instance()
        self.scenario: Scenario | None = load_scenario(config.scenario) if config.scenario else None
        self.signer: Signer | None = Signer.from_file(config.signing_key) if config.signing_key else None
        initial = resolve_profile(config.profile) if config.profile else None  # a file or a library name
        if initial is not None and config.no_uplink_attacks:  # one line, before any slot logs a refusal
            check_no_uplink(initial, initial.source)
        sysids = [link.sysid for link in config.links]
        secure: dict[int, SecureSwitch] = {}
        if self.scenario is not None:  # the estimators' models come from the scenario
            from mitm_proxy.stages.secure.stage import make_stages  # numpy/scipy estimators: only when they can run

            stages = make_stages(self.scenario, sysids, self._secure_config(), self._publish_estimate, "secure")
            secure = {sysid: SecureSwitch(stage) for sysid, stage in stages.items()}
        elif config_from_payload(config.secure, "secure").enabled:
            raise InputError("secure", "estimator", config.secure, "the secure stage needs --scenario")
        self.vehicles: dict[int, LinkParts] = {}
        for sysid in sysids:
            slot = AttackSlot(sysid, self.scenario, config.seed, forbid_uplink=config.no_uplink_attacks)
            slot.announce = False  # the start profile's notes are said once the proxy runs (see __aenter__)
            attack = AttackSwitch(slot)
            if initial is not None:
                state = attack.offer(initial, request_id="--profile")
                if not state.ok:  # the error names the file already
                    raise ValueError(state.error or f"{config.profile}: rejected")
            stage = AttackStage(slot)
            mode = ModeSwitch(sysid, stage)
            mode.set(config.attack == "on", source="--attack")
            self.vehicles[sysid] = LinkParts(sysid, stage, attack, mode, LinkStats(sysid), secure.get(sysid))
        self.endpoints: dict[Endpoint, BaseEndpoint] = {}
        self.links: list[Link] = []
        self.routers: list[GroundRouter] = []
        self.recorders: list[Recorder] = []
        self.taps: dict[int, ReadingsTap] = {}  # sysid -> the readings tap, while a console watches
        self.control: ControlPlane | None = None  # when a broker is configured
        self._stack = contextlib.AsyncExitStack()
        self._tasks: list[asyncio.Task[Any]] = []
        self._readings_task: asyncio.Task[None] | None = None

    def _secure_config(self) -> SecureConfig:
        """``--secure`` / ``secure:`` (and ``--secure-direction``), checked against the scenario by ``make_stages``."""
        cfg = config_from_payload(self.config.secure, "secure")
        if self.config.secure_direction is not None:
            cfg = cfg.model_copy(update={"direction": self.config.secure_direction})
        return cfg if cfg.enabled else OFF.model_copy(update={"direction": cfg.direction})

    @property
    def slots(self) -> dict[int, AttackSwitch]:
        """sysid -> the link's attack switch (its profile, and the verdict on the last request)."""
        return {s: v.attack for s, v in self.vehicles.items()}

    @property
    def stages(self) -> dict[int, AttackStage]:
        return {s: v.stage for s, v in self.vehicles.items()}

    @property
    def secure(self) -> dict[int, SecureSwitch]:
        """sysid -> the link's secure switch (empty without a scenario)."""
        return {s: v.secure for s, v in self.vehicles.items() if v.secure is not None}

    def _publish_estimate(self, sysid: int, payload: dict[str, Any]) -> None:
        if self.control is not None:
            self.control.publish_nowait(vehicle_topic(sysid, "estimate"), payload)

    # -- life cycle --------------------------------------------------------------
    async def __aenter__(self) -> Proxy:
        try:
            await self._open_links()
            self._tasks.append(asyncio.create_task(self._print_stats(), name="stats"))
            self._start_reload()
            await self._start_control()
        except BaseException:
            await self._close()
            raise
        log.info("proxy.ready", extra={
            "links": " ".join(f"v{ln.sysid}:{ln.vehicle.endpoint}->{','.join(str(g.endpoint) for g in ln.grounds)}"
                              for ln in self.links),
            "attack": self.config.attack, "profile": self.slots[self.links[0].sysid].state.profile or "none",
            "changes": describe(self.slots[self.links[0].sysid].slot.directions),
            "uplink_attacks": "forbidden" if self.config.no_uplink_attacks else "allowed",
            "secure": next((s.stage.config.estimator for s in self.secure.values() if s.stage.config.estimator), "off")
            if self.secure else "unavailable (no --scenario)",
            "secure_on": next((WORDS_ON[s.stage.config.direction] for s in self.secure.values()), "-"),
            "broker": redact(self.config.broker_url), "instance": self.instance, "record": self.config.record or "off",
            "signing": "on" if self.signer else "off",
        })  # fmt: skip
        for parts in self.vehicles.values():  # the start profile's notes, now that the log says them
            parts.stage.slot.announce = True
            parts.stage.slot.say_notes()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self._close()

    async def _open_links(self) -> None:
        for link_cfg in self.config.links:
            for ep in (link_cfg.vehicle_endpoint, *link_cfg.ground_endpoints):
                if ep not in self.endpoints:
                    role = "vehicle" if ep == link_cfg.vehicle_endpoint else "ground"
                    # A vehicle streams tens of frames a second: a second of silence means it restarted.
                    takeover = VEHICLE_TAKEOVER_S if role == "vehicle" else DEFAULT_TAKEOVER_S
                    opened = make_endpoint(ep, f"{role}:{ep.port}", role, takeover)
                    self.endpoints[ep] = opened
                    await opened.open()
        users: dict[Endpoint, list[Link]] = {}
        for i, link_cfg in enumerate(self.config.links):
            sysid = link_cfg.sysid
            recorder = None
            if self.config.record is not None:
                recorder = Recorder(Path(self.config.record) / f"v{sysid}", i)
                self.recorders.append(recorder)
            parts = self.vehicles[sysid]
            if recorder is not None:  # profiles.json: the profile in force now, then each change
                _note_profile(recorder, parts.stage.slot)
                parts.stage.slot.on_install.append(lambda slot, rec=recorder: _note_profile(rec, slot))
            stages: list[Stage] = [parts.stage]  # tap -> attack -> secure -> forward
            if parts.secure is not None:
                stages.append(parts.secure.stage)
            signer = None if self.signer is None else self.signer.for_link()  # replay state per link
            pipeline = Pipeline(i, stages, stats=parts.stats, observers=[recorder] if recorder else (), signer=signer)
            parts.stage.slot.unkeyed = pipeline.unkeyed_signed  # a profile writing frames where it cannot: refused
            grounds = [self.endpoints[ep] for ep in link_cfg.ground_endpoints]
            link = Link(i, sysid, pipeline, parts.stats, self.endpoints[link_cfg.vehicle_endpoint], grounds)
            self.links.append(link)
            for ep in link_cfg.ground_endpoints:
                users.setdefault(ep, []).append(link)
        self.routers = [GroundRouter(self.endpoints[ep], links) for ep, links in users.items()]

    def build_controls(self) -> Controls:
        """Every declared runtime switch of this process (``secuav_common/controlplane/switches/``), each
        built or found by its own factory from the links' parts and the endpoints."""
        endpoints = {ep.name: ep for ep in self.endpoints.values()}
        return build_controls(SwitchHost(self.instance, self.vehicles, endpoints))

    def _describe(self) -> dict[str, Any]:
        """What the online record adds: where this proxy runs and what it connects."""
        links = {f"v{ln.sysid}": {"vehicle": str(ln.vehicle.endpoint), "ground": [str(g.endpoint) for g in ln.grounds]}
                 for ln in self.links}  # fmt: skip
        return {"pid": os.getpid(), "host": socket.gethostname(), "links": links}

    def _watch(self, consoles: int) -> None:
        """A console watches: give each pipeline a readings tap and publish it at 10 Hz; none: take them away."""
        for link in self.links:
            tap = self.taps.pop(link.sysid, None)
            if tap is not None:
                link.pipeline.detach(tap)
            if consoles:
                tap = self.taps[link.sysid] = ReadingsTap(link.sysid, after=link.pipeline.stages[0].name)
                link.pipeline.attach(tap)
        if consoles and self._readings_task is None:
            self._readings_task = asyncio.create_task(self._publish_readings(), name="readings")
            self._tasks.append(self._readings_task)
        elif not consoles and self._readings_task is not None:
            self._readings_task.cancel()
            self._tasks.remove(self._readings_task)
            self._readings_task = None

    async def _publish_readings(self) -> None:
        while True:
            await asyncio.sleep(READINGS_PERIOD_S)
            for link in self.links:
                tap = self.taps.get(link.sysid)
                payload = tap.take() if tap is not None else None
                if payload is not None and self.control is not None:
                    self.control.publish_nowait(vehicle_topic(link.sysid, "readings"), payload)

    async def _start_control(self) -> None:
        cfg = self.config
        if cfg.broker == "none":
            return
        from mitm_proxy.control.plane import ControlPlane
        from secuav_common.broker import EmbeddedBroker, parse_broker_url
        from secuav_common.ports import MQTT_PORT

        if cfg.broker == "embedded":
            embedded = EmbeddedBroker(port=cfg.broker_port or MQTT_PORT, process=True, username=cfg.broker_username,
                                      password=cfg.broker_password)  # fmt: skip
            broker = await self._stack.enter_async_context(embedded)  # in its own process: off the forwarding loop
            url = broker.address.url
        else:
            url = cfg.broker_url
        parse_broker_url(url)
        ca = str(cfg.broker_tls_ca) if cfg.broker_tls_ca else None
        plane = ControlPlane(url, self.build_controls(), stats=self.stats_snapshot, describe=self._describe,
                             on_watchers=self._watch, username=cfg.broker_username, password=cfg.broker_password,
                             tls_ca=ca)  # fmt: skip
        self.control = plane
        await self._stack.enter_async_context(plane)  # it connects, reconnects and publishes in its own task

    def _start_reload(self) -> None:
        """A ``--profile`` file is watched and re-offered when it changes (a library name is not)."""
        profile = self.config.profile
        if profile is None or not Path(profile).exists():
            return
        from mitm_proxy.control.reload import ProfileWatcher

        watcher = ProfileWatcher(Path(profile), self.slots)
        self._tasks.append(asyncio.create_task(_run_watcher(watcher), name="reload"))

    async def _close(self) -> None:
        for task in self._tasks:
            task.cancel()
        if self._tasks:
            await asyncio.wait(self._tasks, timeout=STOP_BUDGET_S)
        self._tasks.clear()
        try:
            await asyncio.wait_for(self._stack.aclose(), timeout=STOP_BUDGET_S)
        except (TimeoutError, Exception) as exc:  # the broker may be gone; never hang the shutdown on it
            log.warning("proxy.control_close", extra={"error": repr(exc)})
        for link in self.links:
            link.close()
        for ep in self.endpoints.values():
            ep.close()
        for rec in self.recorders:
            rec.close()
        self.recorders.clear()
        for parts in self.vehicles.values():
            if parts.secure is not None:
                parts.secure.close()

    # -- what the control plane and the log show ------------------------------------
    def stats_snapshot(self) -> dict[int, dict[str, Any]]:
        out: dict[int, dict[str, Any]] = {}
        for link in self.links:
            snap = link.stats.snapshot()
            parts = self.vehicles[link.sysid]
            snap["attack"] = "on" if parts.stage.enabled else "bypass"
            snap["pending_delayed"] = link.pending
            snap["pipeline_errors"] = link.pipeline_errors
            snap["endpoints"] = {ep.name: ep.snapshot() for ep in (link.vehicle, *link.grounds)}
            secure = parts.secure
            warnings = parts.stage.slot.warnings
            if secure is not None:
                counters = asdict(secure.stage.counters)
                counters["readings"] = counters.pop("readings_taken")  # the snapshot's key (docs/interfaces.md)
                snap["secure"] = {"estimator": secure.stage.config.estimator, **counters, **secure.stage.clock_stats()}
                warnings = [*warnings, *secure.stage.warnings]
            snap["warnings"] = warnings  # what keeps the attack or the secure stage from working, "code: text"
            out[link.sysid] = snap
        return out

    async def _print_stats(self) -> None:
        while True:
            await asyncio.sleep(self.config.stats_interval_s)
            for sysid, snap in self.stats_snapshot().items():
                line = stats_line(sysid, snap)  # a link whose stages cannot work says so at warning level
                log.log(logging.WARNING if "warnings" in line else logging.INFO, "proxy.stats", extra=line)


def _note_profile(recorder: Recorder, slot: AttackSlot) -> None:
    """The recording's profiles.json learns the profile in force and which way it changes frames."""
    engine = slot.engine
    recorder.profile(None if engine is None else engine.profile.name, slot.hash, slot.directions)


def stats_line(sysid: int, snap: dict[str, Any]) -> dict[str, Any]:
    """The fields of one link's periodic log line; ``warnings`` (their codes) only while there are some."""
    down, up, lat = snap["downlink"], snap["uplink"], snap["latency_ms"]
    faults: dict[str, int] = {}
    for ep in snap["endpoints"].values():
        for kind, n in ep["faults"].items():
            faults[kind] = faults.get(kind, 0) + n
    line: dict[str, Any] = {
        "sysid": sysid,
        "down": f"{down['frames_in']}/{down['frames_out']}",
        "up": f"{up['frames_in']}/{up['frames_out']}",
        "rewritten": down["rewritten"] + up["rewritten"],
        "dropped": down["dropped"] + up["dropped"],
        "injected": down["injected"] + up["injected"],
        "bad": down["bad_total"] + up["bad_total"],
        "p50_ms": _ms(lat["p50"]),
        "p99_ms": _ms(lat["p99"]),
        "faults": ",".join(f"{k}={v}" for k, v in sorted(faults.items())) or "none",
    }
    muted = [name for name, ep in snap["endpoints"].items() if ep.get("muted")]
    if muted:  # ground ports nobody listens on, sent only a probe now and then (mitm_proxy/net/endpoints.py)
        line["muted"] = ",".join(muted)
    warnings = snap.get("warnings")
    if warnings:  # said on every line until it is fixed; the full text is in the state and the first warning
        line["warnings"] = ",".join(dict.fromkeys(w.split(":", 1)[0] for w in warnings))
    return line


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


async def _run_watcher(watcher: ProfileWatcher) -> None:
    async with watcher:
        await watcher.run()


async def serve(proxy: Proxy, stop: asyncio.Event | None = None,
                on_ready: Callable[[Proxy], None] | None = None) -> int:  # fmt: skip
    """Run ``proxy`` until SIGINT/SIGTERM (or ``stop``); returns the exit code."""
    stop = stop or asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    async with proxy:
        if on_ready is not None:
            on_ready(proxy)
        await stop.wait()
        log.info("proxy.stop", extra={"frames": sum(s["downlink"]["frames_in"] + s["uplink"]["frames_in"]
                                                    for s in proxy.stats_snapshot().values())})  # fmt: skip
    return 0
