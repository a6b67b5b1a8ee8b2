"""The console's view of the fleet, fed by MQTT alone, and its requests to the proxies.

:class:`Fleet` is sans-I/O: :meth:`Fleet.on_message` takes each message the
console's MQTT session receives (``secuav/v<N>/...`` and the proxies' online
records) and keeps, per vehicle, the latest states and a bounded history of
samples for the page: truth, the position the ground is sent, the secure
estimate, and per sensor the reading as it came, as it left, what the secure
estimate implies and what it would be in truth. :class:`Session` is the MQTT
side: it connects (with backoff), announces the console on its retained
``secuav/console/<id>/online`` record (the proxies publish ``readings`` only
while a console is online), and sends requests, waiting for the proxy's own
acknowledgement on the retained ``.../state`` that carries the request id.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import time
import uuid
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from secuav_common.controlplane import switches
from secuav_common.controlplane.address import BrokerAddress
from secuav_common.controlplane.payloads import PayloadError, as_dict, decode
from secuav_common.controlplane.requests import Acks, AckTimeout
from secuav_common.controlplane.session import Client, LastWill, MqttError, messages
from secuav_common.controlplane.session import Session as MqttSession
from secuav_common.controlplane.topics import ANY, INSTANCES_ONLINE, console_topic, parse, vehicle_topic
from secuav_common.scenario import Scenario
from webconsole.world import secure_reading, true_reading

log = logging.getLogger("secuav-console")

__all__ = ["AckTimeout", "Fleet", "Session", "VehicleView", "leaves", "vehicle_switches"]
STREAMS = ("stats", "estimate", "truth", "readings")  # the vehicle streams the console reads
HISTORY = 8_000  # samples kept per vehicle: over two minutes at ~50 per second, what a page backfills
STALE_S = 3.0  # no stats for this long: the vehicle's proxy is gone or stuck (shown offline)
GONE_S = 30.0  # offline this long with no proxy claiming it: left off the fleet (its retained states linger)


@dataclass
class VehicleView:
    """What the console knows of one vehicle."""

    sysid: int
    states: dict[str, Any] = field(default_factory=dict)  # leaf -> latest body (attack/state, stats, ...)
    stats_at: float | None = None  # monotonic arrival of the latest stats
    rate_in: float | None = None  # downlink frames/s from two stats messages
    rate_out: float | None = None
    _last_counts: tuple[float, int, int] | None = None
    truth: list[float] | None = None  # latest true position, for the per-sensor truth
    estimate: dict[str, Any] | None = None
    samples: deque[dict[str, Any]] = field(default_factory=lambda: deque(maxlen=HISTORY))
    seq: int = 0

    def add(self, sample: dict[str, Any]) -> None:
        self.seq += 1
        sample["seq"] = self.seq
        self.samples.append(sample)

    def since(self, seq: int, not_before_t: float = 0.0) -> list[dict[str, Any]]:
        """Samples after ``seq`` (and not older than ``not_before_t``), oldest first."""
        if not self.samples or self.samples[-1]["seq"] <= seq:
            return []
        out = []
        for sample in reversed(self.samples):
            if sample["seq"] <= seq or sample["t"] < not_before_t:
                break
            out.append(sample)
        out.reverse()
        return out


def vehicle_switches() -> list[str]:
    """The kind of every declared vehicle switch (``attack``, ``attack/mode``, ``secure``, and any other
    module in secuav_common/controlplane/switches/), in the registry's order."""
    return [spec.kind for spec in switches.contracts() if spec.scope == "vehicle"]


def leaves() -> list[str]:
    """What the console reads of each vehicle: every vehicle switch's ``<kind>/state``, then the streams."""
    return [*(f"{kind}/state" for kind in vehicle_switches()), *STREAMS]


def _finite(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and math.isfinite(value) else None


def _vec(value: Any) -> list[float] | None:
    if isinstance(value, list | tuple) and value and all(_finite(v) is not None for v in value):
        return [float(v) for v in value]
    return None


class Fleet:
    """Every vehicle and proxy instance seen on the broker (see the module doc)."""

    def __init__(self, scenarios: Iterable[Scenario] = ()) -> None:
        self.scenarios = list(scenarios)
        self.vehicles: dict[int, VehicleView] = {}
        self.instances: dict[str, dict[str, Any]] = {}
        self.changed = asyncio.Event()

    def scenario_of(self, sysid: int) -> Scenario | None:
        return next((s for s in self.scenarios if any(v.sysid == sysid for v in s.vehicles)), None)

    def on_message(self, topic: str, body: Any, now: float | None = None) -> None:
        """One decoded MQTT message; anything not understood is ignored."""
        now = time.time() if now is None else now
        parsed = parse(topic)
        if parsed is None:
            return
        if parsed.scope == "proxy":
            if parsed.key is not None and parsed.leaf == "online" and parsed.verb is None and isinstance(body, dict):
                self.instances[parsed.key] = body
            return
        leaf = f"{parsed.leaf}/{parsed.verb}" if parsed.verb else parsed.leaf
        sysid = parsed.sysid
        if sysid is None or not 1 <= sysid <= 255 or not isinstance(body, dict):
            return
        is_switch = parsed.verb == "state" and switches.find("vehicle", parsed.leaf) is not None
        if not (is_switch or (parsed.verb is None and leaf in STREAMS)):
            return
        view = self.vehicles.get(sysid)
        if view is None:
            if leaf in ("truth", "readings", "estimate"):  # streams alone do not make a vehicle: a proxy does
                return
            view = self.vehicles[sysid] = VehicleView(sysid)
        handler = getattr(self, f"_on_{leaf.replace('/', '_')}", None)
        if handler is not None:
            handler(view, body, now)
        else:
            view.states[leaf] = body
        self.changed.set()

    def _on_stats(self, view: VehicleView, body: dict[str, Any], now: float) -> None:
        view.states["stats"] = body
        arrived = time.monotonic()
        down = body.get("downlink") or {}
        counts = (arrived, int(down.get("frames_in", 0) or 0), int(down.get("frames_out", 0) or 0))
        last = view._last_counts
        if last is not None and counts[0] - last[0] > 0.2 and counts[1] >= last[1]:
            dt = counts[0] - last[0]
            view.rate_in, view.rate_out = (counts[1] - last[1]) / dt, (counts[2] - last[2]) / dt
        view._last_counts = counts
        view.stats_at = arrived

    def _on_truth(self, view: VehicleView, body: dict[str, Any], now: float) -> None:
        pos = _vec(body.get("pos_ned_m"))
        if pos is not None and len(pos) == 3:
            view.truth = pos
            view.add({"t": now, "kind": "truth", "pos": pos})

    def _on_estimate(self, view: VehicleView, body: dict[str, Any], now: float) -> None:
        view.estimate = body
        attacked = [a for a in body.get("attacked") or [] if isinstance(a, int)]
        sample: dict[str, Any] = {"t": now, "kind": "estimate", "estimator": body.get("estimator"),
                                  "alarm": bool(body.get("alarm")), "valid": body.get("valid") is not False,
                                  "attacked": attacked}  # fmt: skip
        pos = _vec(body.get("position_ned_m"))
        if pos is not None:
            sample["pos"] = pos
        if (d := _finite(body.get("distance_m"))) is not None:
            sample["distance_m"] = d
        view.add(sample)

    def _on_readings(self, view: VehicleView, body: dict[str, Any], now: float) -> None:
        scenario = self.scenario_of(view.sysid)
        peers = {s: v.truth for s, v in self.vehicles.items() if v.truth is not None}
        height = -view.truth[2] if view.truth is not None else None
        sensors: dict[str, dict[str, Any]] = {}
        for key, reading in (body.get("sensors") or {}).items():
            if not (isinstance(reading, dict) and str(key).isdigit()):
                continue
            sensor = int(key)
            entry: dict[str, Any] = {"original_m": _finite(reading.get("original_m")),
                                     "forwarded_m": _finite(reading.get("forwarded_m")),
                                     "flagged": bool(reading.get("flagged"))}  # fmt: skip
            if (attacked := _finite(reading.get("attacked_m"))) is not None:
                entry["attacked_m"] = attacked
            if scenario is not None and view.truth is not None:
                entry["truth_m"] = true_reading(scenario, view.sysid, sensor, view.truth, peers)
            if view.estimate is not None and view.estimate.get("estimator"):
                entry["secure_m"] = secure_reading(scenario, sensor, view.estimate, height)
            sensors[key] = entry
        sample: dict[str, Any] = {"t": now, "kind": "readings", "sensors": sensors}
        position = body.get("position")
        if isinstance(position, dict):
            sample["ground_pos"] = _vec(position.get("forwarded_ned_m"))
            sample["original_pos"] = _vec(position.get("original_ned_m"))
        view.add(sample)

    # -- what the page and the API read ------------------------------------------------------------------

    def owners(self) -> dict[int, list[str]]:
        found: dict[int, list[str]] = {}
        for name, rec in self.instances.items():
            if rec.get("online"):
                for v in rec.get("vehicles", []):
                    if isinstance(v, int):
                        found.setdefault(v, []).append(name)
        return found

    def summary(self) -> list[dict[str, Any]]:
        """One row per vehicle: online, profile and the directions it changes, mode, estimator and the direction it
        sits on, rates, counters, latency, the warnings of
        the attack and secure states (what keeps them from working, e.g. a signed stream and no key), and
        ``switches``: the latest state of every declared vehicle switch by kind (None until one arrived),
        so a switch added in its own module shows without this code naming it."""
        owners = self.owners()
        now = time.monotonic()
        kinds = vehicle_switches()
        rows = []
        for sysid, view in sorted(self.vehicles.items()):
            age = None if view.stats_at is None else now - view.stats_at
            if not owners.get(sysid) and (age is None or age > GONE_S):
                continue  # its proxy stopped (or only retained states are left on the broker): gone
            attack = view.states.get("attack/state") or {}
            mode = (view.states.get("attack/mode/state") or {}).get("mode")
            secure = view.states.get("secure/state") or {}
            stats = view.states.get("stats") or {}
            down, up = stats.get("downlink") or {}, stats.get("uplink") or {}
            latency = stats.get("latency_ms") or {}
            fresh = age is not None and age < STALE_S
            rows.append({
                "sysid": sysid,
                "instances": owners.get(sysid, []),
                "online": bool(owners.get(sysid)) and fresh,
                "profile": attack.get("profile"), "hash": attack.get("hash"), "since": attack.get("since"),
                "directions": _strings(attack.get("directions")),  # downlink: toward the ground; uplink: the vehicle
                "secure_direction": secure.get("direction") if isinstance(secure.get("direction"), str) else None,
                "attack_ok": attack.get("ok", True), "attack_error": attack.get("error"),
                "mode": mode,
                "secure": secure.get("estimator"), "secure_available": secure.get("available", True) is not False,
                "secure_params": secure.get("params") or {},
                "frames_in_per_s": view.rate_in if fresh else None,
                "frames_out_per_s": view.rate_out if fresh else None,
                "rewritten": down.get("rewritten", 0) + up.get("rewritten", 0),
                "dropped": down.get("dropped", 0) + up.get("dropped", 0),
                "bad": down.get("bad_total", 0) + up.get("bad_total", 0),
                "latency_p50_ms": latency.get("p50"), "latency_p99_ms": latency.get("p99"),
                "flagged": sorted((view.estimate or {}).get("attacked") or []) if secure.get("estimator") else [],
                "warnings": _warnings(attack, secure),
                "switches": {kind: view.states.get(f"{kind}/state") for kind in kinds},
            })  # fmt: skip
        return rows


def _strings(value: Any) -> list[str]:
    """A list of strings from a state (an older proxy sends none: empty)."""
    return [v for v in value if isinstance(v, str)] if isinstance(value, list) else []


def _warnings(*states: dict[str, Any]) -> list[str]:
    """The ``warnings`` of the states, each a ``"code: text"`` string; anything else a proxy sent is skipped."""
    out: list[str] = []
    for st in states:
        found = st.get("warnings")
        if isinstance(found, list):
            out.extend(w for w in found if isinstance(w, str) and w not in out)
    return out


class Session:
    """The console's MQTT session: feeds the fleet, announces the console, sends requests."""

    def __init__(self, address: BrokerAddress, fleet: Fleet, url: str, *, username: str | None = None,
                 password: str | None = None, backoff_s: tuple[float, float] = (0.2, 5.0)) -> None:  # fmt: skip
        self.address = address
        self.fleet = fleet
        self.console_id = f"console-{uuid.uuid4().hex[:8]}"
        self.online_topic = console_topic(self.console_id)
        self.url = url
        self.since = time.time()
        self.acks = Acks("console-")
        self.refused = 0  # messages that did not fit their topic's model (skipped)
        self.mqtt = MqttSession(address, identifier=self.console_id, username=username, password=password,
                                will=LastWill(self.online_topic, self._record(False)), backoff_s=backoff_s,
                                log=log)  # fmt: skip
        self.connected = self.mqtt.connected

    def _record(self, online: bool) -> bytes:
        return json.dumps({"id": self.console_id, "online": online, "url": self.url, "since": self.since}).encode()

    async def run(self) -> None:
        """Connect, subscribe, receive; on broker trouble log once and retry with backoff, until cancelled."""
        await self.mqtt.run(self._serve)

    async def _serve(self, client: Client) -> None:
        await client.subscribe([(vehicle_topic(ANY, leaf), 0) for leaf in leaves()] + [(INSTANCES_ONLINE, 1)])
        await client.publish(self.online_topic, self._record(True), qos=1, retain=True)
        self.mqtt.mark_connected()
        async for topic, payload, _retained in messages(client):
            self._receive(topic, payload)

    def _receive(self, topic: str, payload: Any) -> None:
        raw = payload if isinstance(payload, bytes | bytearray) else b""
        try:
            body = as_dict(decode(topic, raw))
        except PayloadError:
            self.refused += 1
            return
        self.acks.feed(topic, body)
        self.fleet.on_message(topic, body)

    async def request(self, topic: str, body: dict[str, Any] | None, timeout_s: float = 5.0) -> dict[str, Any]:
        """Publish ``body`` (with a fresh request id first; None: a bare request) on ``topic``; the proxy's
        state for it, or :class:`AckTimeout`."""
        client = self.mqtt.current
        if client is None or not self.connected.is_set():
            raise AckTimeout(f"not connected to the broker at {self.address.url}")
        return await self.acks.request(client, topic, body, timeout_s)

    async def aclose(self) -> None:
        """Say offline while we can (a clean disconnect does not fire the will)."""
        client = self.mqtt.current
        if client is not None:
            with contextlib.suppress(MqttError, asyncio.TimeoutError):
                await asyncio.wait_for(client.publish(self.online_topic, self._record(False), qos=1, retain=True), 0.5)
