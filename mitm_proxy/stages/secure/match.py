"""Whether the DISTANCE_SENSOR stream a vehicle sends fits the layout the scenario gave the secure stage.

A stage whose sensors never arrive has nothing to estimate and rewrites
nothing, which looks exactly like a stage that found nothing to correct: in
front of ArduPilot SITL, ``--scenario wall_hover`` expects forward rangefinders
0-4, and the vehicle sent downward ids 0-2. :class:`LayoutCheck` watches each
DISTANCE_SENSOR frame of the vehicle (a dictionary lookup while nothing new
arrives) and says so:

- at once, when a group sensor arrives facing another way than the scenario
  mounts it (``orientation``, MAV_SENSOR_ORIENTATION: 0 forward, 25 down);
- ``grace_s`` after the vehicle's first DISTANCE_SENSOR frame, when group
  sensors were never seen: any of them for a wall group (each is one reading
  of the same distance), every anchor range for an anchors group (an anchor
  out of reach may stay silent; a vehicle that reports no anchor at all is
  not the scenario's).

The stage sits after the attack stage, so what it checks is what reaches it: a
profile that drops every frame of a group sensor from the start is named too
("never seen"), which is what the estimator then lives with.

The verdict is one line of text (:attr:`LayoutCheck.mismatch`, None while the
stream fits), which the stage logs once as ``secure.layout_mismatch`` and keeps
in its state and stats until matching readings arrive.
"""

from __future__ import annotations

from collections.abc import Iterable

from mitm_proxy.stages.secure.layout import Layout
from secuav_common.sensor_ids import ORIENTATION

GRACE_S = 3.0  # ArduPilot streams DISTANCE_SENSOR at 2-10 Hz, flightsim at 10-20 Hz: every sensor reports by then
CODE = "secure.layout_mismatch"
_NAMES = {v: k for k, v in ORIENTATION.items()}


def id_ranges(ids: Iterable[int]) -> str:
    """``0-4, 7``: sorted ids with runs folded."""
    runs: list[list[int]] = []
    for i in sorted(set(ids)):
        if runs and runs[-1][1] == i - 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def facing(orientation: int) -> str:
    name = _NAMES.get(orientation)
    return f"{name} ({orientation})" if name else f"orientation {orientation}"


def by_facing(table: dict[int, int]) -> str:
    """Sensor id -> orientation as ``0-2 down (25); 3 forward (0)``."""
    groups: dict[int, list[int]] = {}
    for sid, o in sorted(table.items()):
        groups.setdefault(o, []).append(sid)
    return "; ".join(f"{id_ranges(ids)} {facing(o)}" for o, ids in groups.items())


class LayoutCheck:
    """The layout's expectations against what arrives; see the module docstring."""

    def __init__(self, layout: Layout, grace_s: float = GRACE_S) -> None:
        self.layout = layout
        self.grace_s = grace_s
        self.seen: dict[int, int] = {}  # DISTANCE_SENSOR id -> its latest orientation (at most 256 entries)
        self.first_s: float | None = None
        self.mismatch: str | None = None
        self.fields: dict[str, str] = {}  # the mismatch's parts, for the structured log line
        self._late = False  # the grace period is over and was evaluated

    def take(self, sensor_id: int, orientation: int, now_s: float) -> bool:
        """One DISTANCE_SENSOR frame of the vehicle; True when :attr:`mismatch` changed."""
        if self.first_s is None:
            self.first_s = now_s
        if self.seen.get(sensor_id) != orientation:
            self.seen[sensor_id] = orientation
            return self._evaluate(now_s)
        if not self._late and now_s - self.first_s >= self.grace_s:
            return self._evaluate(now_s)
        return False

    def _evaluate(self, now_s: float) -> bool:
        late = self.first_s is not None and now_s - self.first_s >= self.grace_s
        self._late = late
        text = self._verdict(late)
        changed = text != self.mismatch
        self.mismatch = text
        return changed

    def _verdict(self, late: bool) -> str | None:
        lay = self.layout
        turned = sorted(i for i, want in lay.orientation_of.items() if i in self.seen and self.seen[i] != want)
        missing: list[int] = []
        if late:
            if lay.group == "anchors":
                missing = [] if any(i in self.seen for i in lay.anchor_ids) else list(lay.anchor_ids)
            else:
                missing = [i for i in lay.sensor_ids if i not in self.seen]
        if not turned and not missing:
            return None
        problems = []
        if turned:
            problems.append(f"facing another way: {id_ranges(turned)}")
        if missing:
            problems.append(f"never seen: {id_ranges(missing)}")
        self.fields = {"expected": self._expected(), "arrived": self.arrived(), "problem": ", ".join(problems)}
        f = self.fields
        return (f"{CODE}: scenario {lay.scenario!r} gives vehicle {lay.sysid} {f['expected']}, "
                f"but the DISTANCE_SENSOR frames reaching it are ids {f['arrived']} ({f['problem']}); "
                "the secure stage cannot estimate from readings it does not have: give --scenario one "
                "that describes this vehicle's rangefinders (docs/scenario.md)")  # fmt: skip

    def arrived(self) -> str:
        """The ids seen so far by orientation: ``0-2 down (25)``."""
        return by_facing(self.seen) or "none"

    def _expected(self) -> str:
        lay = self.layout
        mounted = by_facing(lay.orientation_of)
        if lay.group == "anchors":
            anchors = f"UWB anchor ranges (DISTANCE_SENSOR ids {id_ranges(lay.anchor_ids)})"
            return f"{anchors} and rangefinders {mounted}" if mounted else anchors
        return f"a wall group of DISTANCE_SENSOR ids {mounted}"
