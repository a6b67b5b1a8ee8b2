"""Sensor models and the vehicle's own state estimate.

All models read the TRUE state (physics) and add seeded noise; nothing here
ever feeds truth to the outside unaltered.

- Rangefinder: a ray from the centre of gravity along the mount direction,
  rotated by the true attitude, against the walls and the ground (z = 0);
  reading = true distance + N(0, noise_std); NaN when the nearest surface is
  outside [min_m, max_m] or the sample drops out (probability ``dropout_prob``).
- UWB anchor k (sensor id 10+k): 3-D distance to the anchor + N(0, std);
  NaN beyond ``max_m`` or on dropout.
- Inter-vehicle range to peer sysid n (sensor id 50+n): 3-D distance between
  the two true positions + N(0, std); NaN on dropout.
- Both radio ranges may instead carry what real UWB ranges show (``noise:`` in the
  scenario, :class:`secuav_common.scenario.RangeNoise`): heavy-tailed (Student-t)
  noise, NLOS excess paths and, per link (:class:`LinkNoise`), a constant offset, a
  time-correlated (Gauss-Markov) part, NLOS episodes and gross errors.
- GPS and the state estimate share one position error model, documented on
  :class:`PositionError`.

Each sensor samples on its own clock at ``rate_hz`` (first sample at t = 0).
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping

from flightsim.api import GpsFix, RangeReading, State
from flightsim.control.rotation import Vec3, quat_from_euler, rotate, wrap_pi
from flightsim.noise import GaussMarkov
from flightsim.world import World
from secuav_common import scenario as sc
from secuav_common.geo import ned_to_geodetic
from secuav_common.sensor_ids import (
    MOUNT_BODY,
    ORIENTATION,
    ORIENTATION_CUSTOM,
    SENSOR_TYPE,
    SENSOR_TYPE_UNKNOWN,
    anchor_sensor_id,
    peer_sensor_id,
)

PEER_MAX_M = 100.0
NAN = math.nan


class _Clock:
    """Fires at a fixed rate; ``due(t)`` is true once per period."""

    TOLERANCE_S = 1e-9

    def __init__(self, rate_hz: float) -> None:
        self.period_s = 1.0 / rate_hz
        self.next_t_s = 0.0

    def due(self, t_s: float) -> bool:
        # A small tolerance so float accumulation in t_s never skips a sample.
        if t_s + self.TOLERANCE_S < self.next_t_s:
            return False
        self.next_t_s += self.period_s
        if self.next_t_s <= t_s:  # fell behind (rate above the physics rate): resync
            self.next_t_s = t_s + self.period_s
        return True


class RangefinderModel:
    def __init__(self, cfg: sc.Rangefinder, world: World, rng: random.Random) -> None:
        self.cfg = cfg
        self.world = world
        self._rng = rng
        self._clock = _Clock(cfg.rate_hz)
        self._mount = MOUNT_BODY[cfg.orientation]

    @property
    def next_t_s(self) -> float:
        return self._clock.next_t_s

    def true_distance(self, truth: State) -> float:
        """Geometric distance along the beam to the nearest surface (inf if none)."""
        direction = rotate(truth.quat, self._mount)
        return self.world.raycast(truth.pos_ned_m, direction)[0]

    def sample(self, truth: State) -> RangeReading | None:
        if not self._clock.due(truth.t_s):
            return None
        cfg = self.cfg
        d = self.true_distance(truth)
        noise = self._rng.gauss(0.0, cfg.noise_std_m) if cfg.noise_std_m > 0 else 0.0
        dropped = cfg.dropout_prob > 0 and self._rng.random() < cfg.dropout_prob
        value = NAN if dropped or not cfg.min_m <= d <= cfg.max_m else max(0.0, d + noise)
        return RangeReading(
            sensor_id=cfg.id,
            t_s=truth.t_s,
            distance_m=value,
            min_m=cfg.min_m,
            max_m=cfg.max_m,
            sensor_type=SENSOR_TYPE[cfg.type],
            orientation=ORIENTATION[cfg.orientation],
            noise_std_m=cfg.noise_std_m,
        )


def radio_noise(rng: random.Random, std_m: float, extra: sc.RangeNoise | None) -> float:
    """The error of one radio range: Gaussian, or Student-t of the same std, plus an NLOS excess path."""
    if extra is None:  # the plain model draws exactly as it always has, so old seeds give old flights
        return rng.gauss(0.0, std_m) if std_m > 0 else 0.0
    noise = 0.0
    if std_m > 0:
        z = rng.gauss(0.0, 1.0)
        dof = extra.student_t_dof
        if dof is not None:  # t = z / sqrt(chi2_dof / dof), rescaled to unit variance
            z = z / math.sqrt(rng.gammavariate(dof / 2.0, 2.0) / dof) * math.sqrt((dof - 2.0) / dof)
        noise = std_m * z
    if extra.nlos_prob > 0 and rng.random() < extra.nlos_prob and extra.nlos_mean_m > 0:
        noise += rng.expovariate(1.0 / extra.nlos_mean_m)
    return noise


class LinkNoise:
    """The error process of one radio link (one anchor, or one peer), see :class:`~secuav_common.scenario.RangeNoise`.

    Without ``noise:``, or with only per-reading terms, each draw is :func:`radio_noise` and takes
    exactly the random numbers it always took. With stateful terms the link draws, once, its
    constant offset and the start of its Gauss-Markov part, then per reading: the Gauss-Markov step
    over the time since its last reading, the white remainder, an episode onset or end, a gross error.
    """

    def __init__(self, rng: random.Random, std_m: float, cfg: sc.RangeNoise | None) -> None:
        self._rng = rng
        self.std_m = std_m
        self.cfg = cfg
        self.stateful = cfg is not None and cfg.stateful
        self.offset_m = 0.0
        self._white_std = std_m
        self._gm: GaussMarkov | None = None
        self._last_t_s: float | None = None
        self._episode_end_s = -math.inf
        self._episode_bias_m = 0.0
        if self.stateful:
            assert cfg is not None
            spread = cfg.offset_std_m
            self.offset_m = rng.gauss(cfg.offset_mean_m, spread) if spread > 0 else cfg.offset_mean_m
            share = cfg.correlated_share
            self._white_std = std_m * math.sqrt(1.0 - share)
            if share > 0 and std_m > 0:
                self._gm = GaussMarkov(rng, std_m * math.sqrt(share), cfg.correlation_time_s)

    def draw(self, t_s: float) -> float:
        if not self.stateful:
            return radio_noise(self._rng, self.std_m, self.cfg)
        cfg, rng = self.cfg, self._rng
        assert cfg is not None
        dt = 0.0 if self._last_t_s is None else max(0.0, t_s - self._last_t_s)
        self._last_t_s = t_s
        noise = self.offset_m
        if self._gm is not None:
            noise += self._gm.step(dt) if dt > 0 else self._gm.value
        noise += radio_noise(rng, self._white_std, cfg)
        if cfg.nlos_episode_rate_hz > 0:
            if t_s >= self._episode_end_s and rng.random() < -math.expm1(-cfg.nlos_episode_rate_hz * dt):
                self._episode_end_s = t_s + rng.expovariate(1.0 / cfg.nlos_episode_mean_s)
                bias = cfg.nlos_episode_bias_m
                self._episode_bias_m = rng.expovariate(1.0 / bias) if bias > 0 else 0.0
            if t_s < self._episode_end_s:
                noise += self._episode_bias_m
        if cfg.outlier_prob > 0 and rng.random() < cfg.outlier_prob:
            noise += rng.gauss(0.0, cfg.outlier_std_m)
        return noise


class UwbModel:
    def __init__(self, cfg: sc.UwbRanging, anchors: Mapping[int, Vec3], rng: random.Random) -> None:
        self.cfg = cfg
        self.anchors = dict(sorted(anchors.items()))
        self._rng = rng
        self._clock = _Clock(cfg.rate_hz)
        self.links = {k: LinkNoise(rng, cfg.noise_std_m, cfg.noise) for k in self.anchors}

    @property
    def next_t_s(self) -> float:
        return self._clock.next_t_s

    def sample(self, truth: State) -> list[RangeReading]:
        if not self._clock.due(truth.t_s):
            return []
        cfg, rng = self.cfg, self._rng
        out = []
        for k, a in self.anchors.items():
            d = _dist(truth.pos_ned_m, a)
            noise = self.links[k].draw(truth.t_s)
            dropped = cfg.dropout_prob > 0 and rng.random() < cfg.dropout_prob
            value = NAN if dropped or d > cfg.max_m else max(0.0, d + noise)
            out.append(_range(anchor_sensor_id(k), truth.t_s, value, cfg.max_m, cfg.noise_std_m))
        return out


class PeerRangeModel:
    def __init__(self, cfg: sc.InterVehicleRanging, rng: random.Random) -> None:
        self.cfg = cfg
        self._rng = rng
        self._clock = _Clock(cfg.rate_hz)
        self.links = {n: LinkNoise(rng, cfg.noise_std_m, cfg.noise) for n in cfg.peers}

    @property
    def next_t_s(self) -> float:
        return self._clock.next_t_s

    def sample(self, truth: State, peers: Mapping[int, State]) -> list[RangeReading]:
        if not self._clock.due(truth.t_s):
            return []
        cfg, rng = self.cfg, self._rng
        out = []
        for sysid in cfg.peers:
            other = peers.get(sysid)
            noise = self.links[sysid].draw(truth.t_s)
            dropped = cfg.dropout_prob > 0 and rng.random() < cfg.dropout_prob
            value = NAN if other is None or dropped else max(0.0, _dist(truth.pos_ned_m, other.pos_ned_m) + noise)
            out.append(_range(peer_sensor_id(sysid), truth.t_s, value, PEER_MAX_M, cfg.noise_std_m))
        return out


class PositionError:
    """The position error shared by GPS fixes and the vehicle's estimate.

    Model (per axis, std ``s`` = the scenario's ``horizontal_std_m`` for north
    and east, ``vertical_std_m`` for down):

    - a slowly wandering bias, first-order Gauss-Markov with std ``0.8 s`` and
      correlation time ``BIAS_TAU_S`` (multipath, atmosphere);
    - plus white noise: std ``0.6 s`` on a GPS fix (so a fix errs by ``s`` in
      total), std ``0.3 s`` on the estimate (the filter smooths the white part
      but cannot see the bias, so the estimate follows it).
    """

    BIAS_TAU_S = 30.0
    BIAS_SHARE = 0.8
    GPS_WHITE_SHARE = 0.6
    ESTIMATE_WHITE_SHARE = 0.3

    def __init__(self, cfg: sc.Gps, rng: random.Random) -> None:
        self.std = (cfg.horizontal_std_m, cfg.horizontal_std_m, cfg.vertical_std_m)
        self._rng = rng
        self._bias = [GaussMarkov(rng, s * self.BIAS_SHARE, self.BIAS_TAU_S) for s in self.std]

    def step(self, dt_s: float) -> Vec3:
        b = self._bias
        return b[0].step(dt_s), b[1].step(dt_s), b[2].step(dt_s)

    @property
    def bias(self) -> Vec3:
        return self._bias[0].value, self._bias[1].value, self._bias[2].value

    def white(self, share: float) -> Vec3:
        g = self._rng.gauss
        s = self.std
        return g(0.0, s[0] * share), g(0.0, s[1] * share), g(0.0, s[2] * share)


class GpsModel:
    """GNSS fixes: true position + :class:`PositionError` (bias + GPS white noise)."""

    VEL_STD_M_S = 0.05

    def __init__(self, cfg: sc.Gps, home: sc.Home, error: PositionError, rng: random.Random) -> None:
        self.cfg = cfg
        self.home = home
        self.error = error
        self._rng = rng
        self._clock = _Clock(cfg.rate_hz)

    @property
    def next_t_s(self) -> float:
        return self._clock.next_t_s if self.cfg.enabled else math.inf

    def sample(self, truth: State) -> GpsFix | None:
        if not self.cfg.enabled or not self._clock.due(truth.t_s):
            return None
        b = self.error.bias
        w = self.error.white(PositionError.GPS_WHITE_SHARE)
        p = truth.pos_ned_m
        lat, lon, alt = ned_to_geodetic(self.home, p[0] + b[0] + w[0], p[1] + b[1] + w[1], p[2] + b[2] + w[2])
        g = self._rng.gauss
        s = self.VEL_STD_M_S
        v = truth.vel_ned_m_s
        return GpsFix(
            t_s=truth.t_s,
            lat_deg=lat,
            lon_deg=lon,
            alt_m=alt,
            vel_ned_m_s=(v[0] + g(0, s), v[1] + g(0, s), v[2] + g(0, s)),
            eph_m=max(self.cfg.horizontal_std_m, 0.01),
            epv_m=max(self.cfg.vertical_std_m, 0.01),
            satellites=self.cfg.satellites,
        )


class StateEstimator:
    """The vehicle's own estimate: truth + a documented error model, never raw truth.

    Position: truth + :class:`PositionError` bias + white noise (0.3 x the GPS std).
    Velocity: truth + white N(0, ``VEL_STD_M_S``). Acceleration: truth + white
    N(0, ``ACC_STD_M_S2``). Attitude: truth + white roll/pitch N(0, ``TILT_STD_RAD``),
    yaw N(0, ``YAW_STD_RAD``). Body rates: truth + white N(0, ``GYRO_STD_RAD_S``).
    When GPS is disabled the same model stands for whatever local positioning
    the vehicle uses (vision, UWB), so flight code need not special-case it.
    """

    VEL_STD_M_S = 0.03
    ACC_STD_M_S2 = 0.05
    TILT_STD_RAD = 0.002
    YAW_STD_RAD = 0.005
    GYRO_STD_RAD_S = 0.002

    def __init__(self, error: PositionError, rng: random.Random) -> None:
        self.error = error
        self._rng = rng
        self.state: State | None = None

    def update(self, truth: State, dt_s: float) -> State:
        b = self.error.step(dt_s)
        w = self.error.white(PositionError.ESTIMATE_WHITE_SHARE)
        g = self._rng.gauss
        p, v, a, e, r = truth.pos_ned_m, truth.vel_ned_m_s, truth.acc_ned_m_s2, truth.euler_rad, truth.rates_rad_s
        sv, sa, st, sy, sg = (
            self.VEL_STD_M_S,
            self.ACC_STD_M_S2,
            self.TILT_STD_RAD,
            self.YAW_STD_RAD,
            self.GYRO_STD_RAD_S,
        )
        euler = (e[0] + g(0, st), e[1] + g(0, st), wrap_pi(e[2] + g(0, sy)))
        self.state = State(
            t_s=truth.t_s,
            pos_ned_m=(p[0] + b[0] + w[0], p[1] + b[1] + w[1], p[2] + b[2] + w[2]),
            vel_ned_m_s=(v[0] + g(0, sv), v[1] + g(0, sv), v[2] + g(0, sv)),
            acc_ned_m_s2=(a[0] + g(0, sa), a[1] + g(0, sa), a[2] + g(0, sa)),
            quat=quat_from_euler(*euler),
            euler_rad=euler,
            rates_rad_s=(r[0] + g(0, sg), r[1] + g(0, sg), r[2] + g(0, sg)),
        )
        return self.state


def _dist(a: Vec3, b: Vec3) -> float:
    return math.sqrt((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2)


def _range(sensor_id: int, t_s: float, value: float, max_m: float, std: float) -> RangeReading:
    return RangeReading(
        sensor_id=sensor_id,
        t_s=t_s,
        distance_m=value,
        min_m=0.0,
        max_m=max_m,
        sensor_type=SENSOR_TYPE_UNKNOWN,
        orientation=ORIENTATION_CUSTOM,
        noise_std_m=std,
    )
