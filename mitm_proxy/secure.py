"""The secure stage: feed the passing ranges to a secure estimator, substitute its output.

Pipeline step 3 of DESIGN.md (tap -> attack -> secure -> forward). The stage
sees the readings *after* the attack stage, as the ground side would, and:

1. collects the configured group's DISTANCE_SENSOR readings (the wall group,
   or the UWB anchor ranges) into a reading vector, NaN where a sensor is
   silent, reports "no target" (``signal_quality`` 0) or is older than
   ``max_age_s``;
2. steps the estimator when every sensor has reported since the last step
   (or ``max_wait_s`` after the first one did, so a dropped sensor cannot stall
   it), or at ``rate_hz`` if configured; on the forwarding path while steps are
   cheap, in a worker thread that sheds sets when they are not
   (:mod:`mitm_proxy.secure_worker` says why, with the figures);
3. rewrites what passes with the latest finished estimate: each group reading
   becomes what the secure estimate implies for it (the secure distance; the
   range from the secure position to that anchor); LOCAL_POSITION_NED and
   GLOBAL_POSITION_INT carry the secure position (lat/lon via the vehicle's
   HOME_POSITION, else the scenario's home); sensors judged attacked get
   ``signal_quality`` 1. When the estimate is degraded (the estimator's alarm,
   confirmed by the readings: more sensors disagree than it can correct), so
   not to be trusted:
   every reading of the group is marked invalid, LOCAL_POSITION_NED carries
   NaN (MAVLink's "unknown") and GLOBAL_POSITION_INT keeps the last position
   that was not degraded, so a ground controller holds instead of steering
   on a confident wrong answer;
4. publishes each estimate through ``publish(sysid, payload)`` (the control
   plane sends it to ``secuav/v<sysid>/estimate``).

The estimator's clock is the proxy's monotonic clock, not the frames'
``time_boot_ms``: an attacker who delays or replays frames cannot make the
filter run backwards. The vehicle's time of the newest reading still rides
along in each published estimate (``sim_t_s``) to join with truth.

Until the first estimate exists, frames pass unchanged. Frames of other
vehicles, of the uplink, and of sensors outside the group pass untouched.
:class:`SecureSlot` is the one door for changing the configuration at runtime
(``secure/set``); a rejected request keeps the running estimator.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from mavframe import codec
from mavframe.packet import Direction, Packet
from mitm_proxy.secure_config import OFF, SecureConfig, config_from_payload
from mitm_proxy.secure_layout import (
    DISTANCE_SENSOR,
    GLOBAL_POSITION_INT,
    HOME_POSITION,
    LOCAL_POSITION_NED,
    Layout,
    build_estimator,
    build_layout,
)
from mitm_proxy.secure_worker import Job, Stepper, StepResult
from secuav_common.geo import ned_to_geodetic
from secuav_common.loading import InputError
from secuav_common.scenario import Home, Scenario

__all__ = ["FLAGGED_QUALITY", "PeerBoard", "SecureConfig", "SecureSlot", "SecureStage", "make_slots"]

log = logging.getLogger(__name__)

Publish = Callable[[int, dict[str, Any]], None]
FLAGGED_QUALITY = 1  # DISTANCE_SENSOR.signal_quality: 1 = "invalid" (0 = unknown/no target, 100 = best)
NO_TARGET_QUALITY = 0
UINT16_TOP = 65534  # 65535 means "unknown" in several MAVLink fields
NOTE = "secure"


class PeerBoard:
    """The latest secure position of each vehicle, shared by the secure stages of one proxy.

    Each stage posts its own estimate and reads its peers', so an
    inter-vehicle range can be checked against, and replaced by, the distance
    between two secure positions. All access is from the event loop's thread.
    """

    def __init__(self, max_age_s: float = 1.0) -> None:
        self.max_age_s = max_age_s
        self._pos: dict[int, tuple[np.ndarray, float]] = {}

    def post(self, sysid: int, pos_ned_m: np.ndarray, now_s: float) -> None:
        self._pos[sysid] = (pos_ned_m, now_s)

    def get(self, sysid: int, now_s: float) -> np.ndarray | None:
        entry = self._pos.get(sysid)
        if entry is None or now_s - entry[1] > self.max_age_s:
            return None
        return entry[0]


@dataclass(slots=True)
class _Counters:
    frames_seen: int = 0
    substituted_frames: int = 0
    flagged_frames: int = 0
    readings: int = 0
    sets_complete: int = 0
    sets_timed_out: int = 0
    decode_errors: int = 0
    published: int = 0


class SecureStage:
    """Stage protocol of :mod:`mitm_proxy.pipeline`; see the module docstring."""

    name = "secure"

    def __init__(
        self,
        config: SecureConfig,
        scenario: Scenario,
        sysid: int,
        publish: Publish | None = None,
        source: str = "<secure>",
        peers: PeerBoard | None = None,
    ) -> None:
        self.scenario = scenario
        self.sysid = sysid
        self.publish = publish
        self.peers = peers if peers is not None else PeerBoard()
        self._peer_flagged: set[int] = set()  # inter-vehicle sensor ids judged attacked, latest frame each
        self._last_valid: StepResult | None = None  # the newest estimate without the alarm
        self.config = OFF
        self.layout: Layout | None = None
        self._stepper: Stepper | None = None
        self._ids: frozenset[int] = frozenset()
        self.counters = _Counters()
        self._home = scenario.world.home
        self.reconfigure(config, source)

    # -- configuration ------------------------------------------------------------------------------

    def reconfigure(self, config: SecureConfig, source: str = "<secure>") -> None:
        """Build everything for ``config`` first; install it with single assignments (between two frames).

        Raises ``InputError`` (and keeps the running configuration) when the
        scenario or the estimator refuses it.
        """
        if not config.enabled:
            old, self._stepper = self._stepper, None
            self.config, self.layout, self._ids = config, None, frozenset()
            if old is not None:
                old.close()
            return
        layout = build_layout(config, self.scenario, self.sysid, source)
        estimator = build_estimator(config, layout, source)
        stepper = Stepper(estimator, layout.model, config.executor, config.step_budget_s, name=f"secure-v{self.sysid}")
        old = self._stepper
        self._reset_readings(layout)
        self.config, self.layout, self._stepper = config, layout, stepper
        self._ids = layout.message_ids
        if old is not None:
            old.close()

    def _reset_readings(self, layout: Layout) -> None:
        p = layout.p
        self._z = np.full(p, np.nan)
        self._rx = np.full(p, -math.inf)  # proxy time of each sensor's latest reading
        self._fresh = np.zeros(p, dtype=bool)  # reported since the last step
        self._pending_since: float | None = None
        self._last_submit_s = -math.inf
        self._sim_t_s: float | None = None
        self._height_m: float | None = None  # known NED z (2-D anchors)
        self._peer_flagged = set()
        self._last_valid = None
        self._height_rx = -math.inf
        self._velocity: np.ndarray | None = None
        self._velocity_rx = -math.inf

    def close(self) -> None:
        """Stop the worker thread (the proxy calls this on shutdown)."""
        if self._stepper is not None:
            self._stepper.close()

    # -- the Stage protocol -------------------------------------------------------------------------

    @property
    def active(self) -> bool:
        return self._stepper is not None

    @property
    def message_ids(self) -> frozenset[int]:
        return self._ids

    def process(self, pkt: Packet, now_s: float) -> list[Packet]:
        layout = self.layout
        if layout is None or pkt.direction is not Direction.DOWNLINK or pkt.header.sysid != self.sysid:
            return [pkt]
        self.counters.frames_seen += 1
        try:
            fields = codec.decode(pkt)
        except codec.DecodeError:
            self.counters.decode_errors += 1
            return [pkt]
        msgid = pkt.header.msgid
        if msgid == LOCAL_POSITION_NED:  # the vehicle's own velocity: the filters' motion input, if configured
            vel = [fields.get(k) for k in ("vx", "vy", "vz")]
            if all(isinstance(v, float) and math.isfinite(v) for v in vel):
                self._velocity, self._velocity_rx = np.array(vel, dtype=float), now_s
        if msgid == DISTANCE_SENSOR:
            self._take_reading(layout, fields, now_s)
        elif msgid == LOCAL_POSITION_NED and layout.height_sensor_id is None:
            z = fields.get("z")
            if isinstance(z, float) and math.isfinite(z):
                self._height_m, self._height_rx = z, now_s
        elif msgid == HOME_POSITION:
            self._take_home(fields)
            return [pkt]
        self.poll(now_s)
        self._substitute(layout, pkt, fields, now_s)
        return [pkt]

    # -- collecting --------------------------------------------------------------------------------

    def _take_reading(self, layout: Layout, fields: dict[str, Any], now_s: float) -> None:
        sid = fields.get("id")
        quality = fields.get("signal_quality", 100)
        distance_m = fields.get("current_distance", 0) / 100.0
        valid = quality != NO_TARGET_QUALITY
        if sid == layout.height_sensor_id and valid:
            self._height_m, self._height_rx = -distance_m, now_s
        i = layout.index_of.get(sid)  # type: ignore[arg-type]
        if i is None:
            return
        self.counters.readings += 1
        self._z[i] = distance_m if valid else math.nan
        self._rx[i] = now_s
        self._fresh[i] = True
        boot_ms = fields.get("time_boot_ms")
        if isinstance(boot_ms, int):
            self._sim_t_s = boot_ms / 1000.0 if self._sim_t_s is None else max(self._sim_t_s, boot_ms / 1000.0)
        if self._pending_since is None:
            self._pending_since = now_s

    def _take_home(self, fields: dict[str, Any]) -> None:
        lat, lon, alt = fields.get("latitude"), fields.get("longitude"), fields.get("altitude")
        if isinstance(lat, int) and isinstance(lon, int) and isinstance(alt, int) and (lat or lon):
            # Out-of-range coordinates (a garbage attack): keep the last good home.
            with contextlib.suppress(ValueError):
                self._home = Home(lat_deg=lat / 1e7, lon_deg=lon / 1e7, alt_m=alt / 1000.0)

    def poll(self, now_s: float) -> None:
        """Step if a set is due, publish finished estimates. Also safe to call from a timer when no frames flow."""
        stepper = self._stepper
        if stepper is None or self.layout is None:
            return
        cfg = self.config
        if self._pending_since is not None:
            if cfg.rate_hz is not None:
                due = now_s - self._last_submit_s >= 1.0 / cfg.rate_hz - 1e-6  # not lost to float rounding
            elif np.all(self._fresh | (now_s - self._rx > cfg.max_age_s)):  # a silent sensor is not waited for
                due = True
                self.counters.sets_complete += 1
            else:
                due = now_s - self._pending_since >= cfg.max_wait_s
                if due:
                    self.counters.sets_timed_out += 1
            if due:
                self._submit(stepper, now_s)
        done = stepper.drain()
        if done and self.layout.position_dims:
            last = done[-1]
            if last.estimate.ok:
                self.peers.post(self.sysid, np.array(_position_ned(self.layout, last)), now_s)
        if self.publish is not None:
            for res in done:
                self._publish(res)

    def _submit(self, stepper: Stepper, now_s: float) -> None:
        z = np.where(now_s - self._rx <= self.config.max_age_s, self._z, np.nan)
        known: float | None = None
        if self.layout is not None and self.layout.position_dims == 2:
            fresh_height = self._height_m is not None and now_s - self._height_rx <= 2.0
            known = self._height_m if fresh_height else None  # None: the model's hold height
        velocity = self._velocity if now_s - self._velocity_rx <= 0.5 else None
        job = Job(t_s=now_s, z=z, known=known, sim_t_s=self._sim_t_s, rx_s=now_s, velocity=velocity)
        self._fresh[:] = False
        self._pending_since = None
        self._last_submit_s = now_s
        stepper.submit(job)

    # -- substituting ------------------------------------------------------------------------------

    def _substitute(self, layout: Layout, pkt: Packet, fields: dict[str, Any], now_s: float) -> None:
        stepper = self._stepper
        res = stepper.latest() if stepper is not None else None
        if res is None or not res.estimate.ok:
            return
        degraded = not res.estimate.valid
        if not degraded:
            self._last_valid = res
        msgid = pkt.header.msgid
        changed = False
        if msgid == DISTANCE_SENSOR:
            i = layout.index_of.get(fields.get("id"))  # type: ignore[arg-type]
            if i is None:
                if fields.get("id") in layout.peer_of:
                    changed = self._substitute_peer_range(layout, res, fields, now_s)
                    self._note_change(pkt, changed)
                return
            implied = res.implied_m[i]
            if math.isfinite(implied):
                cm = min(max(round(implied * 100.0), 0), UINT16_TOP)
                changed |= _set(fields, "current_distance", cm)
            if i in res.attacked_idx or degraded:
                changed |= _set(fields, "signal_quality", FLAGGED_QUALITY)
                self.counters.flagged_frames += 1
        elif msgid == LOCAL_POSITION_NED and layout.position_dims:
            pos = (math.nan,) * 3 if degraded else _position_ned(layout, res)
            changed |= _set(fields, "x", pos[0])
            changed |= _set(fields, "y", pos[1])
            if layout.position_dims == 3:
                changed |= _set(fields, "z", pos[2])
        elif msgid == GLOBAL_POSITION_INT and layout.position_dims:
            if degraded and self._last_valid is None:
                return  # nothing trustworthy to say yet: the frame passes as it came
            pos = _position_ned(layout, self._last_valid if degraded else res)
            lat, lon, alt = ned_to_geodetic(self._home, pos[0], pos[1], pos[2] if math.isfinite(pos[2]) else 0.0)
            changed |= _set(fields, "lat", _int32(lat * 1e7))
            changed |= _set(fields, "lon", _int32(lon * 1e7))
            if layout.position_dims == 3:
                # A home altitude from a garbled HOME_POSITION can be absurd; the field stays encodable.
                changed |= _set(fields, "alt", _int32(alt * 1000.0))
                changed |= _set(fields, "relative_alt", _int32(-pos[2] * 1000.0))
        self._note_change(pkt, changed)

    def _substitute_peer_range(self, layout: Layout, res: StepResult, fields: dict[str, Any], now_s: float) -> bool:
        """Range to peer n: the distance between the two secure positions; flagged when the reading is far off."""
        sid = fields["id"]
        peer = self.peers.get(layout.peer_of[sid], now_s)
        own = np.array(_position_ned(layout, res))
        if peer is None or not np.all(np.isfinite(own)) or not np.all(np.isfinite(peer)):
            return False
        implied = float(np.linalg.norm(own - peer))
        changed = False
        if fields.get("signal_quality") != NO_TARGET_QUALITY:
            if abs(fields.get("current_distance", 0) / 100.0 - implied) > self.config.peer_gate_m:
                self._peer_flagged.add(sid)
            else:
                self._peer_flagged.discard(sid)
        if sid in self._peer_flagged:
            changed |= _set(fields, "signal_quality", FLAGGED_QUALITY)
            self.counters.flagged_frames += 1
        changed |= _set(fields, "current_distance", min(max(round(implied * 100.0), 0), UINT16_TOP))
        return changed

    def _note_change(self, pkt: Packet, changed: bool) -> None:
        if changed:
            pkt.changed = True
            pkt.notes.append(f"{NOTE}:{self.config.estimator}")
            self.counters.substituted_frames += 1

    # -- reporting ---------------------------------------------------------------------------------

    def _publish(self, res: StepResult) -> None:
        layout = self.layout
        if layout is None or self.publish is None:
            return
        est = res.estimate
        payload: dict[str, Any] = {
            "sysid": self.sysid,
            "estimator": self.config.estimator,
            "group": layout.group,
            "sim_t_s": res.job.sim_t_s,
            "rx_s": res.job.rx_s,
            "time_s": time.time(),
            "ok": est.ok,
            "alarm": est.alarm,
            "valid": est.valid,
            "attacked": sorted([*(layout.sensor_ids[i] for i in res.attacked_idx), *self._peer_flagged]),
            "used": sorted(layout.sensor_ids[i] for i in est.used),
            "step_time_s": est.step_time_s,
            "readings_m": [_num(v) for v in res.job.z],
            "sensor_ids": list(layout.sensor_ids),
        }
        if layout.position_dims:
            payload["position_ned_m"] = [_num(v) for v in _position_ned(layout, res)]
        else:
            payload["distance_m"] = _num(est.position_m[0])
        try:
            self.publish(self.sysid, payload)
            self.counters.published += 1
        except Exception as exc:  # the control plane's trouble must not stop forwarding
            log.warning("publishing the estimate of vehicle %d failed: %s", self.sysid, exc)

    def stats(self) -> dict[str, Any]:
        """Counters for ``secuav/v<sysid>/stats`` and the logs."""
        c = self.counters
        st = self._stepper
        res = st.latest() if st is not None else None
        flagged = (
            []
            if res is None or self.layout is None
            else sorted([*(self.layout.sensor_ids[i] for i in res.attacked_idx), *self._peer_flagged])
        )
        return {
            "active": self.active,
            "estimator": self.config.estimator,
            "group": None if self.layout is None else self.layout.group,
            "executor": self.config.executor,
            "threaded": None if st is None else st.threaded,
            "executor_switches": 0 if st is None else st.switches,
            "step_time_ewma_s": None if st is None else st.step_ewma_s,
            "steps": 0 if st is None else st.steps,
            "dropped_steps": 0 if st is None else st.dropped,
            "overruns": 0 if st is None else st.overruns,
            "step_errors": 0 if st is None else st.errors,
            "last_step_time_s": None if res is None else res.estimate.step_time_s,
            "sets_complete": c.sets_complete,
            "sets_timed_out": c.sets_timed_out,
            "readings": c.readings,
            "frames_seen": c.frames_seen,
            "substituted_frames": c.substituted_frames,
            "flagged_frames": c.flagged_frames,
            "flagged_sensors": flagged,
            "alarm": None if res is None else res.estimate.alarm,
            "decode_errors": c.decode_errors,
            "published": c.published,
        }

    def wait_idle(self, timeout_s: float = 5.0) -> bool:
        """Block until submitted sets are stepped (tests, shutdown; never on the forwarding path)."""
        st = self._stepper
        return st.wait_idle(timeout_s) if st is not None else True


def _position_ned(layout: Layout, res: StepResult) -> tuple[float, float, float]:
    pos = res.estimate.position_m
    if layout.position_dims == 3:
        return float(pos[0]), float(pos[1]), float(pos[2])
    known = res.job.known
    down = float(known) if isinstance(known, float) else float(getattr(layout.model, "vehicle_z_ned_m", math.nan))
    return float(pos[0]), float(pos[1]), down


def _set(fields: dict[str, Any], name: str, value: Any) -> bool:
    if fields.get(name) == value:
        return False
    fields[name] = value
    return True


def _int32(v: float) -> int:
    """``v`` rounded and held inside MAVLink's int32 range."""
    return min(max(round(v), -(2**31)), 2**31 - 1)


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


@dataclass(frozen=True, slots=True)
class SecureState:
    """What ``secuav/v<sysid>/secure/state`` carries (retained)."""

    sysid: int
    ok: bool
    estimator: str | None
    params: dict[str, Any]
    group: str | None
    request_id: str | None
    error: str | None
    since: float | None

    def to_json(self) -> dict[str, Any]:
        return {
            "sysid": self.sysid,
            "ok": self.ok,
            "estimator": self.estimator,
            "params": dict(self.params),
            "group": self.group,
            "request_id": self.request_id,
            "error": self.error,
            "since": self.since,
        }


class SecureSlot:
    """The secure stage of one link and the one door for changing it (``--secure``, config, MQTT)."""

    def __init__(
        self,
        sysid: int,
        scenario: Scenario,
        config: SecureConfig | None = None,
        publish: Publish | None = None,
        peers: PeerBoard | None = None,
    ) -> None:
        """``config`` is the starting configuration (``--secure``, config file); ``InputError`` if unusable.

        Give every slot of one proxy the same ``peers`` board, so inter-vehicle
        ranges can be checked against the peers' secure positions.
        """
        self.sysid = sysid
        self.stage = SecureStage(config or OFF, scenario, sysid, publish, source="--secure", peers=peers)
        self._state = self._accepted(None)

    @property
    def state(self) -> dict[str, Any]:
        return self._state.to_json()

    def offer(self, config: SecureConfig, request_id: str | None = None, source: str = "<secure>") -> dict[str, Any]:
        try:
            self.stage.reconfigure(config, source)
        except InputError as exc:
            return self.reject(str(exc), request_id)
        self._state = self._accepted(request_id)
        return self.state

    def offer_payload(self, payload: Any, request_id: str | None = None, source: str = "<mqtt>") -> dict[str, Any]:
        """Decoded JSON of ``secure/set``: ``null``/``"off"``, a name, or ``{"estimator": ..., "params": {...}}``."""
        if request_id is None and isinstance(payload, dict) and isinstance(payload.get("request_id"), str):
            request_id = payload["request_id"]
        try:
            config = config_from_payload(payload, source, base=self.stage.config)
        except InputError as exc:
            return self.reject(str(exc), request_id)
        return self.offer(config, request_id, source)

    def reject(self, error: str, request_id: str | None = None) -> dict[str, Any]:
        """A request refused (bad JSON, oversized, invalid): the running estimator stays."""
        s = self._state
        self._state = SecureState(s.sysid, False, s.estimator, s.params, s.group, request_id, error, s.since)
        return self.state

    def _accepted(self, request_id: str | None) -> SecureState:
        cfg = self.stage.config
        group = None if self.stage.layout is None else self.stage.layout.group
        return SecureState(self.sysid, True, cfg.estimator, dict(cfg.params), group, request_id, None, time.time())

    def close(self) -> None:
        self.stage.close()


def make_slots(
    scenario: Scenario,
    sysids: list[int],
    config: SecureConfig | str | None = None,
    publish: Publish | None = None,
    source: str = "--secure",
) -> dict[int, SecureSlot]:
    """One slot per link, all on one :class:`PeerBoard`; what the proxy app builds at start.

    ``config`` may be an estimator name (``--secure NAME``), ``"off"``/None, or a
    full :class:`SecureConfig` (the config file). ``InputError`` names the
    source and field when a vehicle cannot run it (no wall group and no UWB).
    """
    if not isinstance(config, SecureConfig):
        config = config_from_payload(config, source)
    board = PeerBoard()
    slots: dict[int, SecureSlot] = {}
    try:
        for sysid in sysids:
            slots[sysid] = SecureSlot(sysid, scenario, config, publish, peers=board)
    except InputError:
        for slot in slots.values():
            slot.close()
        raise
    return slots
