"""The scenario schema: world, vehicles and their sensors.

Shared by flightsim (what to simulate), attack_profiles (which sensor ids
exist, where anchors are), estimators' evaluation and the proxy's secure stage
(measurement models). Frame: local NED in metres, origin = home, so a vehicle
2.5 m above ground has ``z = -2.5``.

Sensor ids on the wire follow docs/interfaces.md (see :mod:`secuav_common.sensor_ids`):
rangefinders 0-9, UWB anchor k -> 10+k, peer sysid n -> 50+n.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from secuav_common import plugins
from secuav_common.loading import InputError, load_model, parse_document, validate
from secuav_common.sensor_ids import MAX_ANCHORS, MAX_PEER_SYSID, MAX_RANGEFINDERS

Vec3 = tuple[float, float, float]
Probability = Annotated[float, Field(ge=0.0, le=1.0)]
PositiveFloat = Annotated[float, Field(gt=0.0)]
NonNegFloat = Annotated[float, Field(ge=0.0)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Home(_Strict):
    """Geodetic position of the NED origin (PX4 SITL's default site)."""

    lat_deg: float = Field(47.397742, ge=-90, le=90)
    lon_deg: float = Field(8.545594, ge=-180, le=180)
    alt_m: float = Field(488.0, description="altitude above mean sea level")


class Wall(_Strict):
    """An infinite vertical or tilted plane the vehicle must not cross."""

    name: str
    point_ned_m: Vec3 = Field(description="any point on the plane")
    normal_ned: Vec3 = Field(description="normal pointing into the free side (where vehicles fly)")

    @field_validator("normal_ned")
    @classmethod
    def _unit_normal(cls, v: Vec3) -> Vec3:
        norm = math.sqrt(sum(c * c for c in v))
        if norm < 1e-9:
            raise ValueError("normal must not be zero")
        return (v[0] / norm, v[1] / norm, v[2] / norm)


class Anchor(_Strict):
    """A UWB anchor at a known position; ranges to it go out as sensor id 10+id."""

    id: int = Field(ge=0, lt=MAX_ANCHORS)
    pos_ned_m: Vec3


class Area(_Strict):
    """Where the vehicles may be, horizontally (north, east metres): the box estimators clip a fix to."""

    min_ne_m: tuple[float, float]
    max_ne_m: tuple[float, float]

    @model_validator(mode="after")
    def _ordered(self) -> Area:
        if not all(lo < hi for lo, hi in zip(self.min_ne_m, self.max_ne_m, strict=True)):
            raise ValueError(f"area: min_ne_m {list(self.min_ne_m)} must lie below max_ne_m {list(self.max_ne_m)}")
        return self


class World(_Strict):
    home: Home = Field(default_factory=Home)
    walls: list[Wall] = []
    anchors: list[Anchor] = []
    # None: the anchors' box plus 20 % (estimators.models). A site where vehicles range far outside the anchors
    # (a recorded outdoor run, docs/recorded-ranges.md) states its own.
    area: Area | None = None

    @model_validator(mode="after")
    def _unique(self) -> World:
        _require_unique([a.id for a in self.anchors], "anchors", "id")
        _require_unique([w.name for w in self.walls], "walls", "name")
        return self


RangefinderType = Literal["laser", "ultrasound", "infrared", "radar"]
Orientation = Literal["forward", "backward", "left", "right", "up", "down"]


class Rangefinder(_Strict):
    """A 1-D range sensor rigidly mounted on the body, ray-cast against walls and ground."""

    id: int = Field(ge=0, lt=MAX_RANGEFINDERS)
    type: RangefinderType = "laser"
    orientation: Orientation = "forward"
    min_m: NonNegFloat = 0.1
    max_m: PositiveFloat = 40.0
    noise_std_m: NonNegFloat = 0.02
    rate_hz: PositiveFloat = 20.0
    dropout_prob: Probability = 0.0

    @model_validator(mode="after")
    def _limits(self) -> Rangefinder:
        if self.max_m <= self.min_m:
            raise ValueError(f"max_m ({self.max_m}) must exceed min_m ({self.min_m})")
        return self


class RangeNoise(_Strict):
    """Radio range noise beyond white Gaussian; off by default (without ``noise:`` a range is truth +
    N(0, ``noise_std_m``), and a scenario using only ``nlos_prob``, ``nlos_mean_m`` and ``student_t_dof``
    draws the numbers it always did). A reading's error is the sum of: its link's constant offset, drawn
    once per link and run from N(``offset_mean_m``, ``offset_std_m``); noise of std ``noise_std_m`` (the
    sensor's field) whose share ``correlated_share`` of the variance is a first-order Gauss-Markov process
    with correlation time ``correlation_time_s`` and the rest white (Student-t with ``student_t_dof``
    degrees of freedom when set, rescaled to keep its variance); a non-line-of-sight excess path, per
    reading with probability ``nlos_prob`` (exponential, mean ``nlos_mean_m``), and in episodes that start
    at ``nlos_episode_rate_hz`` per link, last an exponential time of mean ``nlos_episode_mean_s`` and read
    long by an exponential bias of mean ``nlos_episode_bias_m``; and with probability ``outlier_prob`` a
    gross error N(0, ``outlier_std_m``). ``preset`` fills the fields not given from a set fitted to real
    recorded ranges (``uwb-lias-planar``: docs/datasets.md gives the dataset, its licence and the fit).

    Real two-way UWB ranges read long by about 0.1-0.3 m per link (antenna delay left after
    calibration), their errors are correlated over seconds (multipath changes with the geometry), and
    bodies in the way add NLOS excess paths; the per-link state lives in ``flightsim.sensors.LinkNoise``.
    """

    preset: Literal["uwb-lias-planar"] | None = Field(
        None, description="fill the fields not given from a fitted parameter set (docs/datasets.md)"
    )
    nlos_prob: Probability = Field(0.0, description="share of readings with an NLOS excess path")
    nlos_mean_m: NonNegFloat = Field(0.3, description="mean of that excess path (exponential)")
    student_t_dof: float | None = Field(None, gt=2.0, description="None: Gaussian; > 2 for a finite variance")
    offset_mean_m: float = Field(0.0, ge=-10.0, le=10.0, description="mean of the per-link constant offsets")
    offset_std_m: NonNegFloat = Field(0.0, description="spread of the per-link constant offsets across links")
    correlated_share: Probability = Field(0.0, description="share of the noise variance that is Gauss-Markov")
    correlation_time_s: PositiveFloat = Field(1.0, description="correlation time of the Gauss-Markov part")
    nlos_episode_rate_hz: NonNegFloat = Field(0.0, description="NLOS episode onsets per second per link")
    nlos_episode_mean_s: PositiveFloat = Field(0.5, description="mean NLOS episode duration (exponential)")
    nlos_episode_bias_m: NonNegFloat = Field(0.3, description="mean excess range during an episode")
    outlier_prob: Probability = Field(0.0, description="share of readings with a gross error")
    outlier_std_m: NonNegFloat = Field(2.0, description="std of a gross error")

    @model_validator(mode="before")
    @classmethod
    def _fill_preset(cls, data: object) -> object:
        if isinstance(data, dict) and data.get("preset") is not None:
            from secuav_common.noise_presets import PRESETS

            base = PRESETS.get(data["preset"])
            if base is not None:  # an unknown name is refused by the Literal above
                return {**base, **data}
        return data

    @property
    def stateful(self) -> bool:
        """True when a link carries state (offset, correlated part, episodes, outliers) beyond per-reading draws."""
        return bool(
            self.offset_mean_m or self.offset_std_m or self.correlated_share or self.nlos_episode_rate_hz
            or self.outlier_prob
        )


class UwbRanging(_Strict):
    """Two-way ranging to anchors of the world (3-D distances)."""

    anchors: list[int] | Literal["all"] = "all"
    noise_std_m: NonNegFloat = 0.10
    noise: RangeNoise | None = None
    rate_hz: PositiveFloat = 10.0
    dropout_prob: Probability = 0.0
    max_m: PositiveFloat = 100.0


class InterVehicleRanging(_Strict):
    """Ranges to other vehicles of the scenario, by their sysid."""

    peers: list[int]
    noise_std_m: NonNegFloat = 0.10
    noise: RangeNoise | None = None
    rate_hz: PositiveFloat = 10.0
    dropout_prob: Probability = 0.0


class Gps(_Strict):
    """GNSS receiver; also sets the noise of the vehicle's own position estimate."""

    enabled: bool = True
    horizontal_std_m: NonNegFloat = 0.05
    vertical_std_m: NonNegFloat = 0.08
    rate_hz: PositiveFloat = 10.0
    satellites: int = Field(12, ge=0, le=40)


class Sensors(_Strict):
    rangefinders: list[Rangefinder] = []
    uwb: UwbRanging | None = None
    inter_vehicle: InterVehicleRanging | None = None
    gps: Gps = Field(default_factory=Gps)

    @model_validator(mode="after")
    def _unique(self) -> Sensors:
        _require_unique([r.id for r in self.rangefinders], "rangefinders", "id")
        return self


# Source components a companion's feed may come from (MAV_COMPONENT): a peripheral, an onboard computer,
# a visual-inertial odometry unit; secuav-feed uses the first.
COMPANION_COMPIDS = (158, 191, 197)


class ExternalRangefinder(Rangefinder):
    """A rangefinder the autopilot reads over MAVLink (DISTANCE_SENSOR from a companion, as PX4's MAVLink
    distance sensor or ArduPilot's ``RNGFNDx_TYPE 10``). Its reading fixes the vehicle's position along the
    normal of ``surface``: ``ground`` (a downward beam: the height the vehicle holds) or a wall of
    ``world.walls`` (a beam toward it: the wall distance)."""

    surface: str = Field("ground", description="'ground' or the name of a wall in world.walls")

    @model_validator(mode="after")
    def _ground_is_below(self) -> ExternalRangefinder:
        if self.surface == "ground" and self.orientation != "down":
            raise ValueError(f"orientation {self.orientation!r}: a rangefinder measuring the ground must face down")
        return self


class ExternalVision(_Strict):
    """External position in the local NED frame (motion capture, VIO), as VISION_POSITION_ESTIMATE or ODOMETRY."""

    message: Literal["vision_position_estimate", "odometry"] = Field(
        "vision_position_estimate", description="what secuav-feed sends; the vehicle takes either"
    )
    noise_std_m: NonNegFloat = 0.02
    rate_hz: PositiveFloat = 30.0
    dropout_prob: Probability = 0.0


class ExternalInputs(_Strict):
    """Readings the vehicle's own estimator takes over MAVLink from a companion computer, so an attack on
    their way to the vehicle (an uplink rule) moves the vehicle itself. ``secuav-feed`` reads the same block
    to know what to send (docs/cli.md#secuav-feed); the bundled ``companion_feed`` scenario is an example. A
    downward rangefinder (DISTANCE_SENSOR, ids 0-9) replaces the height, as PX4's ``EKF2_HGT_REF`` range or
    ArduPilot's ``EK3_SRC1_POSZ 2``; one toward a wall, the position along the wall's normal; vision
    (VISION_POSITION_ESTIMATE or ODOMETRY in a local NED frame, as ``EKF2_EV_CTRL`` or ``EK3_SRC1_POSXY 6``)
    or UWB anchor ranges (DISTANCE_SENSOR id 10+k, a least-squares fix) replace the position. What the
    vehicle takes it re-reports as its own DISTANCE_SENSOR, as PX4 streams a MAVLink rangefinder. A source
    silent for ``timeout_s`` is dropped with a warning (STATUSTEXT) and its part of the estimate falls back
    to the vehicle's own (GPS); it is taken again, with an info text, when it comes back. Frames from other
    systems or components, undeclared ids, and a rangefinder facing another way than declared are ignored
    (counted as ``external_ignored``)."""

    source_sysid: int | None = Field(
        None, ge=1, le=255, description="the feed's MAVLink system id; default the vehicle's own (an onboard companion)"
    )
    source_compids: list[int] = Field(
        list(COMPANION_COMPIDS), min_length=1, description="component ids the feed may send from"
    )
    rangefinders: list[ExternalRangefinder] = []
    uwb: UwbRanging | None = Field(None, description="anchor ranges (DISTANCE_SENSOR id 10+k) for a position fix")
    vision: ExternalVision | None = Field(None, description="true, or the vision source's settings")
    timeout_s: PositiveFloat = Field(0.5, description="a source older than this is dropped")

    @field_validator("vision", mode="before")
    @classmethod
    def _vision_flag(cls, v: object) -> object:
        if v is True:
            return {}
        return None if v is False else v

    @field_validator("source_compids")
    @classmethod
    def _compids(cls, v: list[int]) -> list[int]:
        for i, c in enumerate(v):
            if not 1 <= c <= 255:
                raise ValueError(f"[{i}]: component id {c} outside 1..255")
        return v

    @model_validator(mode="after")
    def _unique(self) -> ExternalInputs:
        _require_unique([r.id for r in self.rangefinders], "rangefinders", "id")
        return self


class StartPose(_Strict):
    pos_ned_m: Vec3 = (0.0, 0.0, 0.0)
    yaw_deg: float = Field(0.0, ge=-360, le=360)


class HoldTarget(_Strict):
    """Hold a position (anchors8: the area's centre)."""

    kind: Literal["hold"] = "hold"
    pos_ned_m: Vec3


class WallDistanceTarget(_Strict):
    """Hold a distance from a wall, measured by a rangefinder group (wall_hover)."""

    kind: Literal["wall_distance"] = "wall_distance"
    wall: str
    distance_m: PositiveFloat = 2.5
    altitude_m: PositiveFloat = 2.5
    sensor_ids: list[int] = Field(description="the redundant rangefinder group that measures it")


class KeepRangeTarget(_Strict):
    """Keep a distance from another vehicle (formation)."""

    kind: Literal["keep_range"] = "keep_range"
    peer: int
    distance_m: PositiveFloat
    altitude_m: PositiveFloat = 2.5


Target = Annotated[HoldTarget | WallDistanceTarget | KeepRangeTarget, Field(discriminator="kind")]


class Vehicle(_Strict):
    sysid: int = Field(ge=1, le=MAX_PEER_SYSID)
    name: str = ""
    model: str = "F450"
    start: StartPose = Field(default_factory=StartPose)
    sensors: Sensors = Field(default_factory=Sensors)
    target: Target | None = None
    external: ExternalInputs | None = Field(
        None, description="readings the autopilot fuses from a companion over MAVLink (secuav-feed)"
    )

    @property
    def all_rangefinders(self) -> list[Rangefinder]:
        """Every rangefinder whose DISTANCE_SENSOR this vehicle's link carries: its own, then a companion's
        (``external``; they travel to the vehicle and it re-reports them). Ids never collide (validated)."""
        return [*self.sensors.rangefinders, *(self.external.rangefinders if self.external else [])]

    @property
    def uwb_ranging(self) -> UwbRanging | None:
        """The anchor ranging on this vehicle's link: its own (``sensors.uwb``) or a companion's (``external.uwb``)."""
        return self.sensors.uwb or (self.external.uwb if self.external else None)


ScenarioKind = Literal["wall", "formation", "anchors"]


class Scenario(_Strict):
    name: str
    description: str = ""
    seed: int = 0
    duration_s: PositiveFloat = 60.0
    world: World = Field(default_factory=World)
    vehicles: list[Vehicle] = Field(min_length=1)

    @model_validator(mode="after")
    def _cross_refs(self) -> Scenario:
        _require_unique([v.sysid for v in self.vehicles], "vehicles", "sysid")
        anchor_ids = {a.id for a in self.world.anchors}
        sysids = {v.sysid for v in self.vehicles}
        walls = {w.name for w in self.world.walls}
        for i, veh in enumerate(self.vehicles):
            where = f"vehicles[{i}].sensors"
            uwb = veh.sensors.uwb
            if uwb is not None and uwb.anchors != "all":
                for j, k in enumerate(uwb.anchors):
                    if k not in anchor_ids:
                        raise ValueError(f"{where}.uwb.anchors[{j}]: no anchor with id {k} in world.anchors")
            if uwb is not None and not anchor_ids:
                raise ValueError(f"{where}.uwb: world.anchors is empty")
            iv = veh.sensors.inter_vehicle
            if iv is not None:
                for j, peer in enumerate(iv.peers):
                    if peer not in sysids or peer == veh.sysid:
                        raise ValueError(f"{where}.inter_vehicle.peers[{j}]: {peer} is not another vehicle's sysid")
            ext = veh.external
            if ext is not None:
                _check_external(ext, veh, f"vehicles[{i}].external", walls, anchor_ids)
            tgt = veh.target
            if isinstance(tgt, WallDistanceTarget):
                if tgt.wall not in walls:
                    raise ValueError(f"vehicles[{i}].target.wall: no wall named {tgt.wall!r}")
                ids = {r.id for r in veh.sensors.rangefinders} | {r.id for r in (ext.rangefinders if ext else [])}
                for j, sid in enumerate(tgt.sensor_ids):
                    if sid not in ids:
                        raise ValueError(f"vehicles[{i}].target.sensor_ids[{j}]: no rangefinder with id {sid}")
            if isinstance(tgt, KeepRangeTarget) and (tgt.peer not in sysids or tgt.peer == veh.sysid):
                raise ValueError(f"vehicles[{i}].target.peer: {tgt.peer} is not another vehicle's sysid")
        return self

    def vehicle(self, sysid: int) -> Vehicle:
        for veh in self.vehicles:
            if veh.sysid == sysid:
                return veh
        raise KeyError(f"scenario {self.name!r} has no vehicle with sysid {sysid}")

    def anchor_positions(self, ids: list[int] | Literal["all"] = "all") -> dict[int, Vec3]:
        """Anchor id -> NED position, for the ids given (or all)."""
        table = {a.id: a.pos_ned_m for a in self.world.anchors}
        return table if ids == "all" else {k: table[k] for k in ids}

    @property
    def kind(self) -> ScenarioKind:
        """What the scenario is, for whoever picks its measurement model or its test case (one answer for the
        evaluation, the studies and the demos): ``"wall"``, the first vehicle holds a distance from a wall by a
        rangefinder group and has no UWB; ``"formation"``, the first two vehicles range to anchors and to each
        other (seed test case 2); else ``"anchors"``, the first vehicle's anchor ranges (seed test case 1)."""
        first = self.vehicles[0]
        if first.sensors.uwb is None and isinstance(first.target, WallDistanceTarget):
            return "wall"
        pair = self.vehicles[:2]
        if len(pair) == 2 and all(v.sensors.uwb is not None and v.sensors.inter_vehicle is not None for v in pair):
            return "formation"
        return "anchors"

    def wall(self, name: str) -> Wall:
        for wall in self.world.walls:
            if wall.name == name:
                return wall
        raise KeyError(f"scenario {self.name!r} has no wall named {name!r}")


def with_noise_scale(scenario: Scenario, scale: float) -> Scenario:
    """``scenario`` with the noise std of every range sensor (rangefinders, UWB, inter-vehicle ranges) times
    ``scale``: the flight of a noise-mismatch study, whose estimators are told the scenario's own stds."""
    if not (scale > 0 and math.isfinite(scale)):
        raise ValueError(f"noise scale {scale}: must be a positive number")
    vehicles = []
    for v in scenario.vehicles:
        s = v.sensors
        update: dict[str, Any] = {
            "rangefinders": [r.model_copy(update={"noise_std_m": r.noise_std_m * scale}) for r in s.rangefinders]
        }
        for name in ("uwb", "inter_vehicle"):
            radio = getattr(s, name)
            if radio is not None:
                update[name] = radio.model_copy(update={"noise_std_m": radio.noise_std_m * scale})
        vehicles.append(v.model_copy(update={"sensors": s.model_copy(update=update)}))
    return scenario.model_copy(update={"vehicles": vehicles})


def _check_external(ext: ExternalInputs, veh: Vehicle, where: str, walls: set[str], anchor_ids: set[int]) -> None:
    """The external block against the world and the vehicle's own sensors: the vehicle re-reports what it
    fuses as DISTANCE_SENSOR, so an id may not be both its own sensor's and the feed's."""
    own = {r.id for r in veh.sensors.rangefinders}
    for j, rf in enumerate(ext.rangefinders):
        if rf.surface != "ground" and rf.surface not in walls:
            raise ValueError(f"{where}.rangefinders[{j}].surface: no wall named {rf.surface!r} (nor 'ground')")
        if rf.id in own:
            raise ValueError(f"{where}.rangefinders[{j}].id: {rf.id} is already the vehicle's own rangefinder")
    if ext.uwb is not None:
        if veh.sensors.uwb is not None:
            raise ValueError(f"{where}.uwb: the vehicle already ranges the anchors itself (sensors.uwb)")
        if not anchor_ids:
            raise ValueError(f"{where}.uwb: world.anchors is empty")
        if ext.uwb.anchors != "all":
            for j, k in enumerate(ext.uwb.anchors):
                if k not in anchor_ids:
                    raise ValueError(f"{where}.uwb.anchors[{j}]: no anchor with id {k} in world.anchors")


def _require_unique(values: list[object], where: str, field: str) -> None:
    seen: set[object] = set()
    for i, v in enumerate(values):
        if v in seen:
            raise ValueError(f"{where}[{i}].{field}: duplicate value {v!r}")
        seen.add(v)


SCENARIO_DIR = Path(__file__).resolve().parent / "scenarios"  # packaged; ./scenarios links here
DEFAULT_SCENARIO = SCENARIO_DIR / "wall_hover.yaml"


def resolve_scenario_path(name_or_path: str | Path) -> Path:
    """Accept a path, or a bare name of a bundled scenario (``anchors8``) or of a plugin's (docs/plugins.md).

    A bare name that is neither raises ``InputError`` listing the names there are (as a profile name does).
    """
    path = Path(name_or_path)
    if path.exists() or path.suffix or "/" in str(name_or_path):
        return path
    bundled = SCENARIO_DIR / f"{name_or_path}.yaml"
    if bundled.is_file():
        return bundled
    found = plugins.yaml_catalogue(plugins.SCENARIOS).get(str(name_or_path))
    if found is None:
        names = ", ".join(scenario_names())
        raise InputError("scenario", "", str(name_or_path), f"no such file or scenario name (scenarios: {names})")
    return found[0]


def scenario_names(with_plugins: bool = True) -> list[str]:
    """Bundled scenario names, sorted, then (``with_plugins``) the installed plugins' that are not bundled."""
    bundled = sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))
    extra = sorted(set(plugins.yaml_catalogue(plugins.SCENARIOS)) - set(bundled)) if with_plugins else []
    return bundled + extra


def load_scenario(name_or_path: str | Path = DEFAULT_SCENARIO) -> Scenario:
    """Load and validate a scenario; raises ``InputError`` naming file, field and value."""
    return load_model(Scenario, resolve_scenario_path(name_or_path))


def parse_scenario(text: str, source: str = "<scenario>") -> Scenario:
    return validate(Scenario, parse_document(text, source), source)
