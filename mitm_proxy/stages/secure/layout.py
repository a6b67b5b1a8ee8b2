"""Which readings feed the estimator, and what its output replaces, for one vehicle.

Built once per configuration from the scenario the simulator flies, so the
stage's per-frame work is dictionary lookups. The measurement model comes from
``estimators.scenario_models`` (the same one ``secuav-eval`` uses), which keeps
the proxy's numbers comparable with the offline evaluation:

- ``wall``: the vehicle's redundant rangefinder group (ReCaP's setting); the
  estimate is one distance, along the wall's normal when the vehicle's ATTITUDE
  projects each beam on it (``tilt.py``), and every sensor of the group is
  replaced by the range it implies along that sensor's beam.
- ``anchors``: UWB ranges to the scenario's anchors (seed test case 1); the
  estimate is a position, each anchor range is replaced by the 3-D distance
  from it to that anchor (``model.h``), and the position messages carry it.
  In 2-D the height is known: the downward rangefinder if the vehicle has one,
  else LOCAL_POSITION_NED's z, else the scenario's hold height.
  Inter-vehicle ranges (id 50+n) become the distance between this vehicle's
  secure position and peer n's, when peer n's link runs a secure stage on the
  same :class:`~mitm_proxy.stages.secure.stage.PeerBoard`; a reading far from it is flagged.
  VISION_POSITION_ESTIMATE frames travelling to the vehicle (external vision a companion feeds the
  autopilot) carry the secure position too, when the stage sits on the uplink: the anchors are then a
  second position source that outvotes a lying vision feed.

Substitution uses ``model.h(position, known)`` for every reading, so a reading
becomes exactly what the secure position implies.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

import estimators
from estimators import aligned
from estimators.aligned import ASYNC_PARAM
from estimators.models import MeasurementModel
from estimators.scenario_models import anchor_model, wall_group_model
from mavframe.codec import BY_NAME
from mavframe.layout import ATTITUDE, DISTANCE_SENSOR, GLOBAL_POSITION_INT, HOME_POSITION, LOCAL_POSITION_NED
from mitm_proxy.stages.secure.config import SecureConfig
from mitm_proxy.stages.secure.tilt import Geometry
from secuav_common.loading import InputError
from secuav_common.scenario import Home, Scenario, Vehicle, WallDistanceTarget
from secuav_common.sensor_ids import ORIENTATION, SensorKind, classify, peer_sensor_id

VISION_POSITION_ESTIMATE = BY_NAME["VISION_POSITION_ESTIMATE"].id  # 102: external vision fed to the autopilot


@dataclass(frozen=True, slots=True)
class Layout:
    """Index maps between wire sensor ids and the model's reading vector."""

    sysid: int
    group: str  # "wall" or "anchors"
    model: MeasurementModel
    index_of: dict[int, int]  # DISTANCE_SENSOR id -> index into z (and into model.h)
    sensor_ids: tuple[int, ...]  # index -> wire id
    height_sensor_id: int | None  # downward rangefinder giving the known height (2-D anchors)
    position_dims: int  # 0: no position output (wall); 2: north, east; 3: north, east, down
    peer_of: dict[int, int]  # inter-vehicle DISTANCE_SENSOR id -> peer sysid (anchors group only)
    peer_sigma_m: float  # noise std of the inter-vehicle ranges
    home: Home
    message_ids: frozenset[int]
    scenario: str = ""  # the scenario's name, for what the stage says when the stream does not fit
    orientation_of: dict[int, int] = dataclasses.field(default_factory=dict)  # wire id -> MAV_SENSOR_ORIENTATION
    anchor_ids: tuple[int, ...] = ()  # the UWB anchor ranges among sensor_ids (anchors group)
    tilt: Geometry | None = None  # wall group: beams and wall normal, to project readings with ATTITUDE (tilt.py)

    @property
    def p(self) -> int:
        return len(self.sensor_ids)


def resolve_group(config: SecureConfig, scenario: Scenario, sysid: int, source: str) -> str:
    """``auto`` picks the wall group for a wall-distance vehicle, else its UWB anchors."""
    vehicle = _vehicle(scenario, sysid, source)
    if config.group != "auto":
        return config.group
    if isinstance(vehicle.target, WallDistanceTarget):
        return "wall"
    if vehicle.sensors.uwb is not None:
        return "anchors"
    raise InputError(
        source, "group", "auto", f"vehicle {sysid} of scenario {scenario.name!r} has neither a wall group nor UWB"
    )


def build_layout(config: SecureConfig, scenario: Scenario, sysid: int, source: str = "<secure>") -> Layout:
    """Raise ``InputError`` naming the field when the scenario cannot support the request."""
    group = resolve_group(config, scenario, sysid, source)
    vehicle = _vehicle(scenario, sysid, source)
    try:
        model: MeasurementModel = (
            wall_group_model(scenario, sysid) if group == "wall" else anchor_model(scenario, sysid, config.dims)
        )
    except ValueError as exc:
        raise InputError(source, "group", group, str(exc)) from None
    if config.noise_std_m is not None:
        model = dataclasses.replace(model, sigma_m=np.full(model.p, config.noise_std_m))
    ids = tuple(int(i) for i in model.ids())
    height_id = None
    position_dims = 0
    peer_of: dict[int, int] = {}
    iv = vehicle.sensors.inter_vehicle
    wanted = {DISTANCE_SENSOR}
    if config.params.get("velocity_std_mps") is not None:
        wanted.add(LOCAL_POSITION_NED)  # the vehicle's own velocity: the filters' motion input
    if group == "anchors":
        position_dims = config.dims
        wanted |= {LOCAL_POSITION_NED, GLOBAL_POSITION_INT, HOME_POSITION, VISION_POSITION_ESTIMATE}
        if config.dims == 2:
            down = [r.id for r in vehicle.sensors.rangefinders if r.orientation == "down"]
            height_id = down[0] if down else None
        if iv is not None:
            peer_of = {peer_sensor_id(n): n for n in iv.peers}
    # How the scenario mounts the group's rangefinders (and the height laser): what their frames must say.
    mounts = {r.id: ORIENTATION[r.orientation] for r in vehicle.sensors.rangefinders}
    orientation_of = {sid: mounts[sid] for sid in (*ids, *(() if height_id is None else (height_id,))) if sid in mounts}
    tilt = None
    if group == "wall" and config.tilt and all(sid in mounts for sid in ids):
        tilt = Geometry.of([mounts[sid] for sid in ids], getattr(model, "normal_ned", None))
        if tilt is not None:
            wanted.add(ATTITUDE)
    return Layout(
        sysid=sysid,
        group=group,
        model=model,
        index_of={sid: i for i, sid in enumerate(ids)},
        sensor_ids=ids,
        height_sensor_id=height_id,
        position_dims=position_dims,
        peer_of=peer_of,
        peer_sigma_m=iv.noise_std_m if iv is not None else 0.1,
        home=scenario.world.home,
        message_ids=frozenset(wanted),
        scenario=scenario.name,
        orientation_of=orientation_of,
        anchor_ids=tuple(sid for sid in ids if classify(sid)[0] is SensorKind.ANCHOR) if group == "anchors" else (),
        tilt=tilt,
    )


def build_estimator(
    config: SecureConfig, layout: Layout, source: str = "<secure>"
) -> estimators.Estimator | aligned.AsyncEstimator:
    """The configured estimator on the layout's model; bad name or parameter -> ``InputError``."""
    name = config.estimator
    if not estimators.known(name):  # a built-in, a plugin's entry point, or package.module:Class
        raise InputError(source, "estimator", name, f"unknown estimator; choose one of {', '.join(estimators.names())}")
    params = dict(config.params)
    if config.asynchronous:
        params[ASYNC_PARAM] = config.max_age_s  # the window: the readings a step may use
    try:
        return aligned.create(name, layout.model, **params)
    except TypeError as exc:
        raise InputError(source, "params", config.params, f"not accepted by {name}: {exc}") from None
    except ValueError as exc:
        raise InputError(source, "params", config.params, str(exc)) from None


def _vehicle(scenario: Scenario, sysid: int, source: str) -> Vehicle:
    try:
        return scenario.vehicle(sysid)
    except KeyError as exc:
        raise InputError(source, "sysid", sysid, str(exc.args[0])) from None
