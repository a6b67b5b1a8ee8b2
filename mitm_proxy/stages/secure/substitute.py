"""What the ground gets instead: the frames of the group and the position messages, rewritten from the estimate.

Each group reading becomes what the secure estimate implies for it (the secure
distance; the range from the secure position to that anchor), and a sensor
judged attacked gets ``signal_quality`` 1 ("invalid"). LOCAL_POSITION_NED and
GLOBAL_POSITION_INT carry the secure position, and so does VISION_POSITION_ESTIMATE
(x, y, and z in 3-D) when it travels to the vehicle on a stage that sits on the uplink. A degraded estimate (the
estimator's alarm, confirmed by the readings) is not to be trusted: every
reading of the group is marked invalid, LOCAL_POSITION_NED carries NaN
(MAVLink's "unknown") and GLOBAL_POSITION_INT keeps the last position that was
not degraded, so a ground controller holds instead of steering on a confident
wrong answer. A range to a peer vehicle becomes the distance between the two
secure positions, flagged when the reading is farther from it than ``peer_gate_m``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mavframe.layout import DISTANCE_SENSOR, GLOBAL_POSITION_INT, LOCAL_POSITION_NED
from mitm_proxy.stages.secure.collect import NO_TARGET_QUALITY, no_target
from mitm_proxy.stages.secure.geodesy import HomeTracker, position_ned
from mitm_proxy.stages.secure.layout import VISION_POSITION_ESTIMATE, Layout
from mitm_proxy.stages.secure.peers import PeerBoard
from mitm_proxy.stages.secure.report import Counters
from mitm_proxy.stages.secure.worker import StepResult
from secuav_common.sensor_ids import QUALITY_INVALID

FLAGGED_QUALITY = QUALITY_INVALID  # what a reading judged attacked is sent with
UINT16_TOP = 65534  # 65535 means "unknown" in several MAVLink fields


def _set(fields: dict[str, Any], name: str, value: Any) -> bool:
    if fields.get(name) == value:
        return False
    fields[name] = value
    return True


def _cm(distance_m: float) -> int:
    return min(max(round(distance_m * 100.0), 0), UINT16_TOP)


class Substitution:
    """Rewrites one vehicle's frames from its latest estimate; remembers what it must across frames."""

    def __init__(self, sysid: int, peers: PeerBoard, home: HomeTracker, counters: Counters) -> None:
        self.sysid = sysid
        self.peers = peers
        self.home = home
        self.counters = counters
        self.peer_flagged: set[int] = set()  # inter-vehicle sensor ids judged attacked, latest frame each
        self.last_valid: StepResult | None = None  # the newest estimate without the alarm

    def reset(self) -> None:
        self.peer_flagged = set()
        self.last_valid = None

    def apply(self, layout: Layout, res: StepResult, msgid: int, fields: dict[str, Any], now_s: float,
              peer_gate_m: float, tilt: np.ndarray | None = None) -> bool:  # fmt: skip
        """Rewrite ``fields`` (decoded from a frame of ``msgid``); True when anything changed.

        ``tilt``: the wall group's projection factors at the current attitude (else the step's): a reading
        becomes the estimate divided by its sensor's factor, the range along its beam (tilt.py)."""
        degraded = not res.estimate.valid
        if not degraded:
            self.last_valid = res
        if msgid == DISTANCE_SENSOR:
            i = layout.index_of.get(fields.get("id"))  # type: ignore[arg-type]
            if i is None:
                return fields.get("id") in layout.peer_of and self._peer_range(layout, res, fields, now_s, peer_gate_m)
            changed = False
            implied = res.implied_m[i]
            factors = tilt if tilt is not None else res.job.tilt
            if factors is not None:
                implied = implied / factors[i]  # NaN past 60 degrees: the reading's value is left as it came
            if math.isfinite(implied) and not no_target(fields):  # "nothing in range" stays that, never a value
                changed |= _set(fields, "current_distance", _cm(implied))
            if i in res.attacked_idx or degraded:
                changed |= _set(fields, "signal_quality", FLAGGED_QUALITY)
                self.counters.flagged_frames += 1
            return changed
        if msgid == LOCAL_POSITION_NED and layout.position_dims:
            pos = (math.nan,) * 3 if degraded else position_ned(layout, res)
            changed = _set(fields, "x", pos[0]) | _set(fields, "y", pos[1])
            if layout.position_dims == 3:
                changed |= _set(fields, "z", pos[2])
            return changed
        if msgid == GLOBAL_POSITION_INT and layout.position_dims:
            if degraded and self.last_valid is None:
                return False  # nothing trustworthy to say yet: the frame passes as it came
            source = self.last_valid if degraded and self.last_valid is not None else res
            lat, lon, alt, relative_alt = self.home.global_int(position_ned(layout, source))
            changed = _set(fields, "lat", lat) | _set(fields, "lon", lon)
            if layout.position_dims == 3:
                # A home altitude from a garbled HOME_POSITION can be absurd; the field stays encodable.
                changed |= _set(fields, "alt", alt) | _set(fields, "relative_alt", relative_alt)
            return changed
        if msgid == VISION_POSITION_ESTIMATE and layout.position_dims:
            # External vision on its way to the autopilot: its position becomes the anchors' secure one. When
            # degraded, the last position that was not, so the autopilot holds rather than follows a bad fix.
            source = self.last_valid if degraded else res
            if source is None:
                return False
            pos = position_ned(layout, source)
            if not all(math.isfinite(c) for c in pos[: layout.position_dims]):
                return False
            changed = _set(fields, "x", pos[0]) | _set(fields, "y", pos[1])
            if layout.position_dims == 3:
                changed |= _set(fields, "z", pos[2])
            return changed
        return False

    def _peer_range(self, layout: Layout, res: StepResult, fields: dict[str, Any], now_s: float,
                    peer_gate_m: float) -> bool:  # fmt: skip
        """Range to peer n: the distance between the two secure positions; flagged when the reading is far off."""
        sid = fields["id"]
        peer = self.peers.get(layout.peer_of[sid], now_s)
        own = np.array(position_ned(layout, res))
        if peer is None or not np.all(np.isfinite(own)) or not np.all(np.isfinite(peer)):
            return False
        implied = float(np.linalg.norm(own - peer))
        changed = False
        if fields.get("signal_quality") != NO_TARGET_QUALITY:
            if abs(fields.get("current_distance", 0) / 100.0 - implied) > peer_gate_m:
                self.peer_flagged.add(sid)
            else:
                self.peer_flagged.discard(sid)
        if sid in self.peer_flagged:
            changed |= _set(fields, "signal_quality", FLAGGED_QUALITY)
            self.counters.flagged_frames += 1
        changed |= _set(fields, "current_distance", _cm(implied))
        return changed
