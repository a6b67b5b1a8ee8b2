"""The secure stage: feed the passing ranges to a secure estimator, substitute its output.

Pipeline step 3 of mitm_proxy/README.md (tap -> attack -> secure -> forward). The stage
sees the readings *after* the attack stage, as the ground side would, and:

1. collects the configured group's DISTANCE_SENSOR readings (the wall group,
   or the UWB anchor ranges) into a reading vector, NaN where a sensor is
   silent, reports "no target" (``signal_quality`` 0 and a distance outside
   its limits: ``collect.no_target``) or is older than ``max_age_s``;
2. steps the estimator when every sensor has reported since the last step
   (or ``max_wait_s`` after the first one did, so a dropped sensor cannot stall
   it), or at ``rate_hz`` if configured; on the forwarding path while steps are
   cheap, in a worker thread that sheds sets when they are not
   (:mod:`mitm_proxy.stages.secure.worker` says why, with the figures);
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
filter run backwards. Each reading is placed on that clock at the time the
vehicle stamped it (``reading_time: stamp``, the default: its ``time_boot_ms``
mapped per sender by :mod:`mitm_proxy.stages.secure.stamps`, never later than
its arrival), so link jitter, batching and replays do not misplace it; the
stats say how many readings were timed so, how many had no stamp (timed at
arrival) and how often a sender's clock was re-anchored. The vehicle's time of
the newest reading still rides along in each published estimate (``sim_t_s``)
to join with truth.

When the vehicle's DISTANCE_SENSOR ids or orientations do not fit the layout
(:mod:`mitm_proxy.stages.secure.match`), the stage logs ``secure.layout_mismatch``
once and keeps the warning in :attr:`SecureStage.warnings` (the ``secure/state``
and the stats) until matching readings arrive; when the vehicle signs its frames
and the proxy has no key, the pipeline hands the stage nothing and it says
``secure.signed_no_key`` the same way.

Direction (``direction`` in the configuration, ``--secure-direction``): by default
the stage reads and rewrites what the vehicle sends (downlink), shielding the
ground. With ``uplink`` it reads the group's readings from the frames travelling
to the vehicle (a companion's MAVLink rangefinders, UWB ranges fed to the
autopilot) and substitutes the secure estimate in those frames, so the
autopilot's own estimator receives it (the anchors group also writes its
secure position into the VISION_POSITION_ESTIMATE frames a companion feeds
the autopilot: a second source standing in for a vision feed that may lie);
``both`` does both, for a group whose
sensors travel different ways (some fed to the autopilot, some its own): a
DISTANCE_SENSOR id once seen travelling to the vehicle is read from the uplink
only, its downlink frames being the autopilot's echo of what it was given
(rewritten, so the ground sees the secure value too, never read). The vehicle's
own state (ATTITUDE for the beams' tilt, LOCAL_POSITION_NED's velocity and
height, HOME_POSITION) is read from the downlink whatever the direction, and
downlink frames are never changed unless the direction includes it. On the
uplink a frame counts whatever its sysid (a companion may use its own): the
link's uplink goes to this vehicle.

Until the first estimate exists, frames pass unchanged. Frames of other
vehicles, of a direction the stage does not sit on, and of sensors outside the
group pass untouched.
:meth:`SecureStage.reconfigure` is the one door for changing the configuration at runtime (the proxy's
``secure`` switch, :mod:`mitm_proxy.control.secure`, calls it); a rejected configuration keeps the running
estimator.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from mavframe import codec
from mavframe.packet import Direction, Header, Packet
from mitm_proxy.stages.secure.collect import Readings
from mitm_proxy.stages.secure.config import OFF, SecureConfig, config_from_payload
from mitm_proxy.stages.secure.geodesy import HomeTracker, position_ned
from mitm_proxy.stages.secure.layout import (
    ATTITUDE,
    DISTANCE_SENSOR,
    HOME_POSITION,
    LOCAL_POSITION_NED,
    VISION_POSITION_ESTIMATE,
    Layout,
    build_estimator,
    build_layout,
)
from mitm_proxy.stages.secure.match import LayoutCheck
from mitm_proxy.stages.secure.peers import PeerBoard
from mitm_proxy.stages.secure.report import Counters, estimate_payload, stage_stats
from mitm_proxy.stages.secure.stamps import StampClock
from mitm_proxy.stages.secure.substitute import FLAGGED_QUALITY, Substitution
from mitm_proxy.stages.secure.worker import Stepper, StepResult
from secuav_common.loading import InputError
from secuav_common.scenario import Scenario

__all__ = ["FLAGGED_QUALITY", "PeerBoard", "SecureConfig", "SecureStage", "make_stages"]

log = logging.getLogger(__name__)

Publish = Callable[[int, dict[str, Any]], None]
NOTE = "secure"
_DIRECTIONS = {
    "downlink": frozenset((Direction.DOWNLINK,)),
    "uplink": frozenset((Direction.UPLINK,)),
    "both": frozenset((Direction.DOWNLINK, Direction.UPLINK)),
}


class SecureStage:
    """Stage protocol of :mod:`mitm_proxy.core.pipeline`; see the module docstring.

    The stage orchestrates its parts: :class:`~mitm_proxy.stages.secure.collect.Readings` collects
    and says when a step is due, the :class:`~mitm_proxy.stages.secure.worker.Stepper` steps,
    :class:`~mitm_proxy.stages.secure.substitute.Substitution` rewrites what passes (with
    :mod:`~mitm_proxy.stages.secure.geodesy`), :mod:`~mitm_proxy.stages.secure.report` shapes what
    is published and counted.
    """

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
        self.config = OFF
        self.layout: Layout | None = None
        self.readings: Readings | None = None
        self._stepper: Stepper | None = None
        self._ids: frozenset[int] = frozenset()
        self.check: LayoutCheck | None = None
        self.signed_warning: str | None = None
        self.counters = Counters()
        self._directions: frozenset[Direction] = _DIRECTIONS["downlink"]
        self._fed: set[int] = set()  # DISTANCE_SENSOR ids seen travelling to the vehicle (direction both)
        self.substitution = Substitution(sysid, self.peers, HomeTracker(scenario.world.home), self.counters)
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
            self.check, self.signed_warning = None, None
            if old is not None:
                old.close()
            return
        layout = build_layout(config, self.scenario, self.sysid, source)
        estimator = build_estimator(config, layout, source)
        stepper = Stepper(estimator, layout.model, config.executor, config.step_budget_s, name=f"secure-v{self.sysid}")
        old = self._stepper
        self.readings = Readings(layout, StampClock(config.reading_time, name=f"secure-v{self.sysid}"))
        self.check, self.signed_warning = LayoutCheck(layout), None
        self.substitution.reset()
        self.config, self.layout, self._stepper = config, layout, stepper
        self._directions, self._fed = _DIRECTIONS[config.direction], set()
        self._ids = layout.message_ids
        if old is not None:
            old.close()

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
        layout, readings = self.layout, self.readings
        if layout is None or readings is None:
            return [pkt]
        downlink = pkt.direction is Direction.DOWNLINK
        mine = pkt.direction in self._directions  # the group is read and rewritten here
        if not (mine or downlink) or (downlink and pkt.header.sysid != self.sysid):
            return [pkt]
        msgid = pkt.header.msgid
        echo = downlink and not mine and msgid == DISTANCE_SENSOR  # the autopilot's echo of what it was fed
        # its state is what it says, not what it is told; external vision fed to it is rewritten, never read
        told = not downlink and msgid not in (DISTANCE_SENSOR, VISION_POSITION_ESTIMATE)
        if echo or told:
            return [pkt]
        self.counters.frames_seen += 1
        try:
            fields = codec.decode(pkt)
        except codec.DecodeError:
            self.counters.decode_errors += 1
            return [pkt]
        if msgid == LOCAL_POSITION_NED:  # the vehicle's own velocity: the filters' motion input, if configured
            readings.take_velocity(fields, now_s)
        elif msgid == ATTITUDE:  # the wall group's beams, projected on the wall's normal (tilt.py)
            readings.take_attitude(fields, now_s)
            return [pkt]
        if msgid == DISTANCE_SENSOR:
            sid = fields.get("id")
            if not downlink:
                self._fed.add(sid)  # type: ignore[arg-type]  # a uint8: at most 256 ids
            if not (downlink and sid in self._fed):  # on both, the autopilot's echo of a fed id is not a reading
                self._check_layout(fields, now_s)
                if readings.take_range(layout, fields, now_s, (pkt.header.sysid, pkt.header.compid)):
                    self.counters.readings_taken += 1
        elif msgid == LOCAL_POSITION_NED and layout.height_sensor_id is None:
            z = fields.get("z")
            if isinstance(z, float) and math.isfinite(z):
                readings.take_height(z, now_s)
        elif msgid == HOME_POSITION:
            self.substitution.home.take(fields)
            return [pkt]
        self.poll(now_s)
        if not mine:  # read for the vehicle's state only: the frame leaves as it came
            return [pkt]
        return self._substitute(pkt, fields, msgid, now_s)

    def _substitute(self, pkt: Packet, fields: dict[str, Any], msgid: int, now_s: float) -> list[Packet]:
        """Rewrite a frame of the stage's direction from the latest finished estimate."""
        layout, readings = self.layout, self.readings
        assert layout is not None and readings is not None
        stepper = self._stepper
        res = stepper.latest() if stepper is not None else None
        if res is not None and res.estimate.ok:
            tilt_now = readings.tilt_factors(now_s) if msgid == DISTANCE_SENSOR else None
            changed = self.substitution.apply(layout, res, msgid, fields, now_s, self.config.peer_gate_m, tilt_now)
            if changed:
                pkt.changed = True
                pkt.notes.append(f"{NOTE}:{self.config.estimator}")
                self.counters.substituted_frames += 1
        return [pkt]

    def signed_untouched(self, header: Header) -> None:
        """The pipeline left a signed frame this stage wanted alone (no key): the stage cannot read it."""
        if header.sysid != self.sysid:
            return
        self.counters.signed_untouched += 1
        if self.signed_warning is None and self.layout is not None:
            self.signed_warning = (
                f"secure.signed_no_key: vehicle {self.sysid} signs its frames and this proxy has no signing key, "
                "so the secure stage reads and rewrites none of them: start secuav-proxy with --signing-key FILE "
                "(docs/interfaces.md)")

    def _check_layout(self, fields: dict[str, Any], now_s: float) -> None:
        check, sid, orientation = self.check, fields.get("id"), fields.get("orientation")
        if check is None or not isinstance(sid, int) or not isinstance(orientation, int):
            return
        was = check.mismatch
        if check.take(sid, orientation, now_s):
            if was is None:
                log.warning("secure.layout_mismatch", extra={"sysid": self.sysid, "scenario": check.layout.scenario,
                                                             "group": check.layout.group, **check.fields})  # fmt: skip
            elif check.mismatch is None:
                log.info("secure.layout_match", extra={"sysid": self.sysid, "arrived": check.arrived()})

    @property
    def warnings(self) -> list[str]:
        """What keeps the stage from doing its work now (``secure/state``, the stats); empty while it can."""
        check = self.check
        return [w for w in (None if check is None else check.mismatch, self.signed_warning) if w is not None]

    # -- stepping ----------------------------------------------------------------------------------

    def poll(self, now_s: float) -> None:
        """Step if a set is due, publish finished estimates. Also safe to call from a timer when no frames flow."""
        stepper, layout, readings = self._stepper, self.layout, self.readings
        if stepper is None or layout is None or readings is None:
            return
        due = readings.due(self.config, now_s)
        if due is not None:
            if due == "complete":
                self.counters.sets_complete += 1
            elif due == "timed_out":
                self.counters.sets_timed_out += 1
            stepper.submit(readings.job(self.config, layout, now_s))
        done = stepper.drain()
        if done and layout.position_dims:
            last = done[-1]
            if last.estimate.ok:
                self.peers.post(self.sysid, np.array(position_ned(layout, last)), now_s)
        if self.publish is not None:
            for res in done:
                self._publish(layout, res)

    # -- reporting ---------------------------------------------------------------------------------

    def _publish(self, layout: Layout, res: StepResult) -> None:
        if self.publish is None:
            return
        payload = estimate_payload(self.sysid, self.config.estimator, layout, res, self.substitution.peer_flagged)
        try:
            self.publish(self.sysid, payload)
            self.counters.published += 1
        except Exception as exc:  # the control plane's trouble must not stop forwarding
            log.warning("publishing the estimate of vehicle %d failed: %s", self.sysid, exc)

    def stats(self) -> dict[str, Any]:
        """Counters for ``secuav/v<sysid>/stats`` and the logs."""
        return {**stage_stats(self.active, self.config.estimator, self.config.executor, self.layout, self._stepper,
                              self.counters, self.substitution.peer_flagged), **self.clock_stats(),
                "warnings": self.warnings}  # fmt: skip

    def clock_stats(self) -> dict[str, Any]:
        """How readings are timed and what the senders' clocks did (stamps.py); in the stats and the proxy's
        ``secuav/v<sysid>/stats``."""
        clock = self.readings.clock if self.readings is not None else StampClock(self.config.reading_time)
        return clock.stats()

    def wait_idle(self, timeout_s: float = 5.0) -> bool:
        """Block until submitted sets are stepped (tests, shutdown; never on the forwarding path)."""
        st = self._stepper
        return st.wait_idle(timeout_s) if st is not None else True


def make_stages(
    scenario: Scenario,
    sysids: list[int],
    config: SecureConfig | str | None = None,
    publish: Publish | None = None,
    source: str = "--secure",
) -> dict[int, SecureStage]:
    """One stage per link, all on one :class:`PeerBoard`; what the proxy app builds at start.

    ``config`` may be an estimator name (``--secure NAME``), ``"off"``/None, or a
    full :class:`SecureConfig` (the config file). ``InputError`` names the
    source and field when a vehicle cannot run it (no wall group and no UWB).
    """
    if not isinstance(config, SecureConfig):
        config = config_from_payload(config, source)
    board = PeerBoard()
    stages: dict[int, SecureStage] = {}
    try:
        for sysid in sysids:
            stages[sysid] = SecureStage(config, scenario, sysid, publish, source="--secure", peers=board)
    except InputError:
        for stage in stages.values():
            stage.close()
        raise
    return stages
