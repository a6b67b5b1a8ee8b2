"""Measurement models: what a vector of readings z says about a position.

Every model maps a position ``pos`` (shape ``(..., d)``, broadcast over any
leading axes so one call serves a whole bank of subset estimators) to the p
noise-free readings ``h(pos)`` and their Jacobian ``jac(pos)`` (``(..., p, d)``).
Readings are ``z = h(pos) + v + e``: ``v`` Gaussian with std ``sigma_m[i]``,
``e`` the attack (zero on honest sensors). A missing reading is NaN.

Some models need a quantity that is known each step but is not estimated (the
vehicle's height from its downward laser in the 2-D anchor model). It travels
as ``known`` (a float or an array); ``default_known`` is used when the caller
gives none.

``max_correctable`` is the largest number of attacked sensors for which the
state can still be recovered from one snapshot (2s-sparse observability):
deleting any 2s sensors must leave readings that pin the position down. For
anchor ranges that is decided from the geometry over the flight region
(``region_m``): each model's ``support()`` hands its anchors and boxes to the geometry of
``estimators.observability``, not only by counting sensors.

``honest_subsets(s)`` lists the hypotheses the subset estimators weigh ("these
readings are honest"): every way of leaving ``s`` readings out, or, for a model
made of groups that each must survive on its own (the formation: each vehicle's
anchors), ``s`` out of each group.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from estimators import observability as geometry
from estimators.observability import Box, Mirror, Support

Known = float | np.ndarray | None


Groups = tuple[tuple[tuple[int, ...], int], ...]  # (reading indices, how many of them may be left out)


@lru_cache(maxsize=64)
def leave_out_masks(p: int, groups: Groups) -> np.ndarray:
    """Every subset that leaves out exactly k readings of each group (k its tolerance: any k liars are covered by some
    row); a group no larger than its tolerance (the single inter-vehicle range) is tried both with and without each
    reading. Readings in no group are always kept. Read-only ``(n, p)`` boolean array."""
    per_group = []
    for idx, k in groups:
        sizes = [k] if len(idx) > k else range(len(idx) + 1)
        per_group.append([c for size in sizes for c in itertools.combinations(idx, size)])
    rows = list(itertools.product(*per_group))
    out = np.ones((len(rows), p), dtype=bool)
    for j, dropped in enumerate(rows):
        for idx in dropped:
            out[j, list(idx)] = False
    out.setflags(write=False)
    return out


def subset_count(groups: Groups) -> int:
    """How many rows :func:`leave_out_masks` would have, without building them (C(24, 10) rows take seconds)."""
    return math.prod(math.comb(len(idx), k) if len(idx) > k else 2 ** len(idx) for idx, k in groups)


def _as_sigma(sigma_m: float | np.ndarray | list[float], p: int) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(sigma_m, dtype=float), (p,)).copy()
    if np.any(arr <= 0):
        raise ValueError("every noise std must be positive")
    return arr


@dataclass(frozen=True, eq=False)
class MeasurementModel:
    """Base of all models; subclasses fill in ``h`` and ``jac``."""

    sigma_m: np.ndarray
    sensor_ids: tuple[int, ...] = ()
    bounds_m: tuple[np.ndarray, np.ndarray] | None = None
    # Where the vehicle flies (a box in the model's coordinates), for the observability check; None: see
    # each anchor model's flight_region().
    region_m: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def p(self) -> int:
        return int(self.sigma_m.shape[0])

    @property
    def d(self) -> int:
        raise NotImplementedError

    @property
    def min_sensors(self) -> int:
        """Fewest clean readings that pin the position down (without mirror ambiguity)."""
        return self.d

    @property
    def max_correctable(self) -> int:
        """The largest s the layout supports over its flight region (``observability.support``)."""
        return self.support().s_max

    @property
    def count_bound(self) -> int:
        """What counting sensors alone allows: ``(p - min_sensors) // 2``."""
        return max(0, (self.p - self.min_sensors) // 2)

    def support(self) -> Support:
        """Why ``max_correctable`` is what it is: the count bound and the geometry (cached: the layout is fixed)."""
        cached = self.__dict__.get("_support_cache")
        if cached is None:
            cached = self._support()
            object.__setattr__(self, "_support_cache", cached)
        return cached

    def _support(self) -> Support:
        """The layout's answer (:meth:`support` caches it); a model without geometry has its count bound."""
        return geometry.count_only(self.count_bound)

    def mirrors(self, min_size: int, tol_m: float | None = None) -> list[Mirror]:
        """Every line or plane of the layout holding at least ``min_size`` readings, wherever its mirror falls
        (``observability.mirrors``). None for a model that is not single-vehicle anchor ranges."""
        return []

    @property
    def default_known(self) -> Known:
        return None

    def tolerance_groups(self, s: int) -> Groups:
        """Who may lie: by default any ``s`` of the p readings."""
        return ((tuple(range(self.p)), s),)

    def within_tolerance(self, left_out: np.ndarray, s: int) -> bool:
        """Whether leaving out the readings marked in ``left_out`` stays within tolerance ``s`` in every group."""
        return all(int(left_out[list(idx)].sum()) <= min(k, len(idx)) for idx, k in self.tolerance_groups(s))

    def honest_subsets(self, s: int) -> np.ndarray:
        """The subset hypotheses for tolerance ``s`` (module docstring), ``(n, p)`` bool."""
        if not 0 <= s < self.p:
            raise ValueError(f"tolerance s={s} outside 0..{self.p - 1}")
        return leave_out_masks(self.p, self.tolerance_groups(s))

    def subset_count(self, s: int) -> int:
        """``honest_subsets(s).shape[0]``, counted rather than built."""
        if not 0 <= s < self.p:
            raise ValueError(f"tolerance s={s} outside 0..{self.p - 1}")
        return subset_count(self.tolerance_groups(s))

    def h(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        raise NotImplementedError

    def jac(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        raise NotImplementedError

    def h_jac(self, pos: np.ndarray, known: Known = None) -> tuple[np.ndarray, np.ndarray]:
        """``(h(pos), jac(pos))`` in one pass (the hot path of every solver)."""
        return self.h(pos, known), self.jac(pos, known)

    def minimal_fixes(self, z: np.ndarray, masks: np.ndarray, known: Known = None) -> np.ndarray | None:
        """Closed-form fixes from minimal reading sets, where the model has one (else None: use Gauss-Newton)."""
        return None

    def initial_pos(self) -> np.ndarray:
        """Starting point for Gauss-Newton when nothing better is known."""
        return np.zeros(self.d)

    def initial_guess(self, z: np.ndarray, known: Known = None) -> np.ndarray:
        """Starting point for a cold start given this step's readings (default: :meth:`initial_pos`)."""
        return self.initial_pos()

    def state_velocity(self, velocity_ned_m_s: np.ndarray) -> np.ndarray | None:
        """The rate of the model's position state given the vehicle's own NED velocity (the motion input).

        Positions in north, east (and down): the first ``d`` components; a model whose state is not a
        position (a distance to a wall) projects. None when the velocity cannot be read.
        """
        vel = np.asarray(velocity_ned_m_s, dtype=float).reshape(-1)[: self.d]
        return vel if vel.shape[0] == self.d and np.isfinite(vel).all() else None

    def axis_noise(self, q_mps2: float) -> tuple[float, ...]:
        """The white-acceleration std of the constant-velocity model per axis (default: ``q_mps2`` on each)."""
        return (float(q_mps2),) * self.d

    def clip(self, pos: np.ndarray) -> np.ndarray:
        """Project onto the admissible box (rejects mirror solutions outside the area)."""
        if self.bounds_m is None:
            return pos
        return np.minimum(np.maximum(pos, self.bounds_m[0]), self.bounds_m[1])  # np.clip's wrapper costs more

    def ids(self) -> tuple[int, ...]:
        return self.sensor_ids or tuple(range(self.p))


def _anchor_box(anchors_xy: np.ndarray, margin_frac: float) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = anchors_xy.min(axis=0), anchors_xy.max(axis=0)
    margin = margin_frac * max(float(np.max(hi - lo)), 1.0)
    return lo - margin, hi + margin


@dataclass(frozen=True, eq=False)
class AnchorRanges2D(MeasurementModel):
    """UWB ranges to p anchors; horizontal position (north, east) estimated, height known.

    ``r_i = sqrt(||p - a_i||^2 + (z - z_i)^2)`` with ``p`` in R^2, ``a_i`` the
    anchor's (north, east), ``z`` the vehicle's NED down coordinate (``known``,
    from the downward laser), ``z_i`` the anchor's. Seed test case 1.
    """

    anchors_ned_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    vehicle_z_ned_m: float = -2.5

    @classmethod
    def build(
        cls,
        anchors_ned_m: np.ndarray | list[list[float]],
        sigma_m: float | np.ndarray = 0.1,
        vehicle_z_ned_m: float = -2.5,
        sensor_ids: tuple[int, ...] = (),
        margin_frac: float = 0.2,
        region_m: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> AnchorRanges2D:
        anchors = np.asarray(anchors_ned_m, dtype=float).reshape(-1, 3)
        return cls(
            sigma_m=_as_sigma(sigma_m, anchors.shape[0]),
            sensor_ids=tuple(sensor_ids),
            bounds_m=_anchor_box(anchors[:, :2], margin_frac),
            region_m=region_m,
            anchors_ned_m=anchors,
            vehicle_z_ned_m=float(vehicle_z_ned_m),
        )

    @property
    def d(self) -> int:
        return 2

    @property
    def min_sensors(self) -> int:
        return 3  # two circles leave a mirror pair

    @property
    def default_known(self) -> Known:
        return self.vehicle_z_ned_m

    def _dz2(self, known: Known) -> np.ndarray:
        z = self.vehicle_z_ned_m if known is None else known if isinstance(known, float) else float(np.ravel(known)[0])
        cached = self.__dict__.get("_dz2_cache")
        if cached is not None and cached[0] == z:
            return cached[1]
        dz = z - self.anchors_ned_m[:, 2]
        # Frozen dataclass: the cache bypasses __setattr__ (the height changes rarely between steps).
        object.__setattr__(self, "_dz2_cache", (z, dz * dz + 1e-12))
        return self.__dict__["_dz2_cache"][1]

    def h(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        diff = pos[..., None, :] - self.anchors_ned_m[:, :2]
        return np.sqrt(np.einsum("...i,...i->...", diff, diff) + self._dz2(known))

    def jac(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        return self.h_jac(pos, known)[1]

    def h_jac(self, pos: np.ndarray, known: Known = None) -> tuple[np.ndarray, np.ndarray]:
        diff = pos[..., None, :] - self.anchors_ned_m[:, :2]
        r = np.sqrt(np.einsum("...i,...i->...", diff, diff) + self._dz2(known))
        return r, diff / r[..., None]

    def minimal_fixes(self, z: np.ndarray, masks: np.ndarray, known: Known = None) -> np.ndarray | None:
        """Closed-form fix from each 3-anchor mask: difference squared horizontal ranges (linear in pos).

        ``2 (a_l - a_i)^T pos = rho_i^2 - rho_l^2 - |a_i|^2 + |a_l|^2`` for the pairs (i, l), (j, l),
        with ``rho^2 = r^2 - dz^2`` the horizontal range squared. Collinear triples give garbage that
        the caller's consensus rejects. None if a mask does not hold exactly three readings.
        """
        geometry = self._triples(masks)
        if geometry is None:
            return None
        idx, inv = geometry
        rho2 = z * z - self._dz2(known)
        rho2 = np.where(np.isnan(rho2), 0.0, rho2)
        rhs_base = rho2 - self._norm2
        rhs = rhs_base[idx[:, :2]] - rhs_base[idx[:, 2:3]]
        return self.clip(np.einsum("jab,jb->ja", inv, rhs))

    def _triples(self, masks: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Anchor indices and inverse 2x2 systems per 3-anchor mask (cached: geometry is fixed)."""
        key = masks.tobytes()
        cache = self.__dict__.setdefault("_triples_cache", {})
        if key not in cache:
            if masks.shape[1] != self.p or np.any(masks.sum(axis=1) != 3):
                cache[key] = None
            else:
                idx = np.nonzero(masks)[1].reshape(-1, 3)
                a = self.anchors_ned_m[:, :2]
                mat = 2.0 * np.stack([a[idx[:, 2]] - a[idx[:, 0]], a[idx[:, 2]] - a[idx[:, 1]]], axis=1)
                det = mat[:, 0, 0] * mat[:, 1, 1] - mat[:, 0, 1] * mat[:, 1, 0]
                det = np.where(np.abs(det) < 1e-9, 1e-9, det)  # collinear: garbage the consensus rejects
                # Adjugate of [[a, b], [c, d]] is [[d, -b], [-c, a]] (mat is not symmetric).
                adj = np.empty_like(mat)
                adj[:, 0, 0], adj[:, 0, 1] = mat[:, 1, 1], -mat[:, 0, 1]
                adj[:, 1, 0], adj[:, 1, 1] = -mat[:, 1, 0], mat[:, 0, 0]
                inv = adj / det[:, None, None]
                object.__setattr__(self, "_norm2", np.einsum("pi,pi->p", a, a))
                cache[key] = (idx, inv)
        return cache[key]

    def initial_pos(self) -> np.ndarray:
        return self.anchors_ned_m[:, :2].mean(axis=0)

    def flight_region(self) -> Box:
        """Where the vehicle flies, for the layout check: ``region_m``, else the anchors' horizontal box."""
        return geometry.plane_region(self.anchors_ned_m) if self.region_m is None else geometry.as_box(self.region_m)

    def _support(self) -> Support:
        """The plane case (``observability``): anchors on one line whose mirror reaches the box."""
        if self.bounds_m is None:
            return super()._support()
        tol, sep = geometry.tolerances(self.sigma_m)
        sets = geometry.degenerate(self.anchors_ned_m[:, :2], self.flight_region(), geometry.as_box(self.bounds_m),
                                   tol, sep)  # fmt: skip
        return geometry.largest(self.p, self.count_bound, sets, self.ids())

    def mirrors(self, min_size: int, tol_m: float | None = None) -> list[Mirror]:
        tol = geometry.tolerances(self.sigma_m, tol_m)[0]
        return geometry.mirrors(self.anchors_ned_m[:, :2], tol, min_size, (0, 1), self.p)


@dataclass(frozen=True, eq=False)
class AnchorRanges3D(MeasurementModel):
    """UWB ranges to p anchors; full NED position estimated: ``r_i = ||p - a_i||``.

    Anchors in one plane leave a mirror solution across that plane; the box
    (``bounds_m``) and the starting point (``start_above_m`` above the anchors,
    where vehicles fly) pick the physical side.
    """

    anchors_ned_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    start_above_m: float = 1.5

    @classmethod
    def build(
        cls,
        anchors_ned_m: np.ndarray | list[list[float]],
        sigma_m: float | np.ndarray = 0.1,
        sensor_ids: tuple[int, ...] = (),
        margin_frac: float = 0.2,
        ceiling_m: float = 30.0,
        start_above_m: float = 1.5,
        region_m: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> AnchorRanges3D:
        anchors = np.asarray(anchors_ned_m, dtype=float).reshape(-1, 3)
        lo_xy, hi_xy = _anchor_box(anchors[:, :2], margin_frac)
        # Vehicles fly above the lowest anchor (NED: smaller z); a coplanar
        # anchor layout cannot tell above from below, so the box does.
        z_hi = float(anchors[:, 2].max()) - 0.05 if np.ptp(anchors[:, 2]) < 0.5 else float(anchors[:, 2].max()) + 1.0
        lo = np.array([lo_xy[0], lo_xy[1], float(anchors[:, 2].min()) - ceiling_m])
        hi = np.array([hi_xy[0], hi_xy[1], z_hi])
        return cls(
            sigma_m=_as_sigma(sigma_m, anchors.shape[0]),
            sensor_ids=tuple(sensor_ids),
            bounds_m=(lo, hi),
            region_m=region_m,
            anchors_ned_m=anchors,
            start_above_m=start_above_m,
        )

    @property
    def d(self) -> int:
        return 3

    @property
    def min_sensors(self) -> int:
        return 4

    def h(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        diff = pos[..., None, :] - self.anchors_ned_m
        return np.sqrt(np.einsum("...ij,...ij->...i", diff, diff))

    def jac(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        return self.h_jac(pos, known)[1]

    def h_jac(self, pos: np.ndarray, known: Known = None) -> tuple[np.ndarray, np.ndarray]:
        diff = pos[..., None, :] - self.anchors_ned_m
        r = np.sqrt(np.einsum("...ij,...ij->...i", diff, diff))
        return r, diff / np.maximum(r, 1e-9)[..., None]

    def initial_pos(self) -> np.ndarray:
        c = self.anchors_ned_m.mean(axis=0)
        return c - np.array([0.0, 0.0, self.start_above_m])

    def flight_region(self) -> Box:
        """Where the vehicle flies, for the layout check: ``region_m``, else over the anchors from the box's top
        down to ``start_above_m`` above the highest anchor (``observability.space_region``)."""
        if self.region_m is not None:
            return geometry.as_box(self.region_m)
        return geometry.space_region(self.anchors_ned_m, self.bounds_m, self.start_above_m)

    def _support(self) -> Support:
        """The space case (``observability``): anchors on one plane whose mirror reaches the box, or on one line."""
        if self.bounds_m is None:
            return super()._support()
        tol, sep = geometry.tolerances(self.sigma_m)
        sets = geometry.degenerate(self.anchors_ned_m, self.flight_region(), geometry.as_box(self.bounds_m), tol, sep)
        return geometry.largest(self.p, self.count_bound, sets, self.ids())

    def mirrors(self, min_size: int, tol_m: float | None = None) -> list[Mirror]:
        tol = geometry.tolerances(self.sigma_m, tol_m)[0]
        return geometry.mirrors(self.anchors_ned_m, tol, min_size, (0, 1, 2), self.p)


@dataclass(frozen=True, eq=False)
class AnchorRangesHeight(AnchorRanges3D):
    """UWB ranges to p anchors and the downward laser: full NED position estimated, the laser one more reading.

    Readings: ``r_i = ||pos - a_i||`` for the p anchors, then the laser's
    distance to flat ground, ``ground_down_m - pos_down`` (a level vehicle; the
    laser's std should allow for the tilt, ``scenario_models.anchor_model``
    does). In the 2-D model the laser's height is a known input, so a spoofed
    laser moves every range model with no test able to catch it; here it is a
    sensor like the ranges, which a secure estimator can outvote and name.
    ``max_correctable`` counts the laser: (p + 1 - 4) // 2 (2 for 8 anchors).

    The limit of coplanar anchors: the ranges alone cannot tell a position from
    its mirror image across the anchor plane. At the hover height (2.5 m over
    anchors on 1 m posts) the mirror is underground, outside the box, and the
    laser is one reading among nine. Below twice the anchors' height the mirror
    lies above the ground and only the laser says which side the vehicle is on:
    there (take-off, landing) a spoofed laser moves the height to the mirror and
    no estimator on this layout can tell. Anchors at two heights remove it.
    """

    ground_down_m: float = 0.0
    # A take-off climbs at ~1.5 m/s within half a second: the vertical axis moves faster than a hover's q.
    vertical_q_mps2: float = 3.0

    @classmethod
    def build_with_laser(
        cls,
        anchors_ned_m: np.ndarray | list[list[float]],
        sigma_m: float | np.ndarray = 0.1,
        laser_sigma_m: float = 0.03,
        sensor_ids: tuple[int, ...] = (),
        ground_down_m: float = 0.0,
        margin_frac: float = 0.2,
        ceiling_m: float = 30.0,
        region_m: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> AnchorRangesHeight:
        base = AnchorRanges3D.build(anchors_ned_m, sigma_m, margin_frac=margin_frac, ceiling_m=ceiling_m)
        lo, hi = base.bounds_m if base.bounds_m is not None else (None, None)
        # The laser tells above the anchors from below them (on the ground, before take-off), so the box
        # reaches down to the ground instead of stopping at the anchor plane as ranges alone must.
        return cls(
            sigma_m=np.append(base.sigma_m, float(laser_sigma_m)),
            sensor_ids=tuple(sensor_ids),
            bounds_m=None if lo is None or hi is None else (lo, np.array([hi[0], hi[1], ground_down_m])),
            region_m=region_m,
            anchors_ned_m=base.anchors_ned_m,
            start_above_m=base.start_above_m,
            ground_down_m=float(ground_down_m),
        )

    @property
    def n_anchors(self) -> int:
        return int(self.anchors_ned_m.shape[0])

    def initial_pos(self) -> np.ndarray:
        """On the ground amid the anchors: where a vehicle starts, and where its laser has no reading yet
        (below its minimum range), so ranges alone must pick the ground-side mirror."""
        c = self.anchors_ned_m.mean(axis=0)
        return np.array([c[0], c[1], self.ground_down_m - 0.1])

    def initial_guess(self, z: np.ndarray, known: Known = None) -> np.ndarray:
        """Amid the anchors at the laser's height when it has a reading (the ranges' two mirror images lie
        either side of the anchor plane: the laser says which), else on the ground (:meth:`initial_pos`)."""
        start = self.initial_pos()
        laser = float(z[self.n_anchors]) if z.shape[0] > self.n_anchors else float("nan")
        if np.isfinite(laser):
            start[2] = self.ground_down_m - laser
        return start

    def axis_noise(self, q_mps2: float) -> tuple[float, ...]:
        """Horizontal ``q_mps2``; vertical at least ``vertical_q_mps2`` (the filters must follow a take-off, or
        they leave the laser out while the ranges, blind to height at the anchor plane, pick the wrong side)."""
        return (float(q_mps2), float(q_mps2), max(float(q_mps2), self.vertical_q_mps2))

    def _support(self) -> Support:
        """Without the laser the space case; with it, the plane case on the anchors seen from above."""
        if self.bounds_m is None:
            return geometry.count_only(self.count_bound)
        tol, sep = geometry.tolerances(self.sigma_m)
        region, box = self.flight_region(), geometry.as_box(self.bounds_m)
        sets = geometry.degenerate(self.anchors_ned_m, region, box, tol, sep)
        flat = geometry.degenerate(self.anchors_ned_m[:, :2], geometry.horizontal(region), geometry.horizontal(box),
                                   tol, sep)  # fmt: skip
        for members, why in flat:
            above = why.replace("on one line", "on one line seen from above")
            sets.append(((*members, self.n_anchors), "the laser and " + above))
        return geometry.largest(self.p, self.count_bound, sets, self.ids())

    def mirrors(self, min_size: int, tol_m: float | None = None) -> list[Mirror]:
        """The anchors' planes, then their lines seen from above with the laser (which fixes the height)."""
        tol = geometry.tolerances(self.sigma_m, tol_m)[0]
        level = geometry.mirrors(self.anchors_ned_m[:, :2], tol, min_size, (0, 1), self.p, extra=(self.n_anchors,))
        return [*super().mirrors(min_size, tol_m), *level]

    def h(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        ranges = super().h(pos, known)
        return np.concatenate([ranges, (self.ground_down_m - pos[..., 2])[..., None]], axis=-1)

    def jac(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        return self.h_jac(pos, known)[1]

    def h_jac(self, pos: np.ndarray, known: Known = None) -> tuple[np.ndarray, np.ndarray]:
        ranges, jac = super().h_jac(pos, known)
        laser_row = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (*pos.shape[:-1], 1, 3))
        h = np.concatenate([ranges, (self.ground_down_m - pos[..., 2])[..., None]], axis=-1)
        return h, np.concatenate([jac, laser_row], axis=-2)


@dataclass(frozen=True, eq=False)
class ScalarGroup(MeasurementModel):
    """A redundant group of m sensors measuring one scalar ``d`` (ReCaP's setting).

    ``z_i = d + v_i + e_i``; the wall distance measured by lasers, sonar,
    infrared and radar at once. The "position" is the scalar itself. With
    ``normal_ned`` (the unit normal of the wall, pointing to the side the
    vehicle flies on) the motion input is the vehicle's velocity along it,
    the rate of the distance; without it the group has no motion input.
    """

    normal_ned: tuple[float, float, float] | None = None

    @classmethod
    def build(
        cls,
        sigma_m: float | np.ndarray | list[float],
        m: int | None = None,
        sensor_ids: tuple[int, ...] = (),
        normal_ned: tuple[float, float, float] | None = None,
    ) -> ScalarGroup:
        count = m if m is not None else len(np.atleast_1d(sigma_m))
        unit = None
        if normal_ned is not None:
            n = np.asarray(normal_ned, dtype=float)
            if n.shape != (3,) or not np.isfinite(n).all() or np.linalg.norm(n) == 0:
                raise ValueError(f"normal_ned={normal_ned}: expected a non-zero vector of 3 numbers")
            unit = tuple(float(c) for c in n / np.linalg.norm(n))
        return cls(sigma_m=_as_sigma(sigma_m, count), sensor_ids=tuple(sensor_ids), normal_ned=unit)

    def state_velocity(self, velocity_ned_m_s: np.ndarray) -> np.ndarray | None:
        vel = np.asarray(velocity_ned_m_s, dtype=float).reshape(-1)
        if self.normal_ned is None or vel.shape[0] != 3 or not np.isfinite(vel).all():
            return None
        return np.array([float(np.dot(vel, self.normal_ned))])

    @property
    def d(self) -> int:
        return 1

    def h(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        return np.repeat(pos, self.p, axis=-1)

    def jac(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        return np.ones((*pos.shape[:-1], self.p, 1))

    def initial_pos(self) -> np.ndarray:
        return np.zeros(1)


@dataclass(frozen=True, eq=False)
class LinearModel(MeasurementModel):
    """Linear readings ``y = C x`` (Fawzi et al.'s setting, one output per row)."""

    C: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    _min_sensors: int = 0

    @classmethod
    def build(cls, C: np.ndarray, sigma_m: float | np.ndarray = 0.1, sensor_ids: tuple[int, ...] = ()) -> LinearModel:
        mat = np.atleast_2d(np.asarray(C, dtype=float))
        return cls(
            sigma_m=_as_sigma(sigma_m, mat.shape[0]),
            sensor_ids=tuple(sensor_ids),
            C=mat,
            _min_sensors=_min_rows_for_rank(mat),
        )

    @property
    def d(self) -> int:
        return int(self.C.shape[1])

    @property
    def min_sensors(self) -> int:
        return self._min_sensors

    def _support(self) -> Support:
        """Exact sparse-observability index (``observability.linear_correctable``): the largest s with full column
        rank after removing any 2s rows."""
        best, failing = geometry.linear_correctable(self.C)
        count = max(0, (self.p - self.d) // 2)
        reason = f"rows {', '.join(map(str, failing))} alone do not have full column rank" if failing else ""
        return Support(best, count, (failing,) if failing else (), reason)

    def h(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        return pos @ self.C.T

    def jac(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        return np.broadcast_to(self.C, (*pos.shape[:-1], *self.C.shape))


def _min_rows_for_rank(C: np.ndarray) -> int:
    """Fewest rows such that EVERY choice of that many rows has full column rank (else p + 1)."""
    p, n = C.shape
    for k in range(n, p + 1):
        if all(np.linalg.matrix_rank(C[list(rows)]) == n for rows in itertools.combinations(range(p), k)):
            return k
    return p + 1


@dataclass(frozen=True, eq=False)
class TwoVehicleRanges(MeasurementModel):
    """Two vehicles (seed test case 2): each one's anchor ranges plus the range between them.

    Position ``[n1, e1, n2, e2]`` (2-D, heights known: ``known = (z1, z2)``).
    Readings: ``p`` ranges of vehicle 1, then ``p`` of vehicle 2, then the
    inter-vehicle range ``sqrt(||p1 - p2||^2 + (z1 - z2)^2)``.
    """

    anchors_ned_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    vehicle_z_ned_m: tuple[float, float] = (-2.5, -2.5)

    @classmethod
    def build(
        cls,
        anchors_ned_m: np.ndarray | list[list[float]],
        sigma_m: float | np.ndarray = 0.1,
        vehicle_z_ned_m: tuple[float, float] = (-2.5, -2.5),
        sensor_ids: tuple[int, ...] = (),
        margin_frac: float = 0.2,
        region_m: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> TwoVehicleRanges:
        anchors = np.asarray(anchors_ned_m, dtype=float).reshape(-1, 3)
        lo, hi = _anchor_box(anchors[:, :2], margin_frac)
        return cls(
            sigma_m=_as_sigma(sigma_m, 2 * anchors.shape[0] + 1),
            sensor_ids=tuple(sensor_ids),
            bounds_m=(np.tile(lo, 2), np.tile(hi, 2)),
            region_m=region_m,
            anchors_ned_m=anchors,
            vehicle_z_ned_m=(float(vehicle_z_ned_m[0]), float(vehicle_z_ned_m[1])),
        )

    @property
    def d(self) -> int:
        return 4

    @property
    def n_anchors(self) -> int:
        return int(self.anchors_ned_m.shape[0])

    @property
    def min_sensors(self) -> int:
        return 6

    def tolerance_groups(self, s: int) -> Groups:
        """Each vehicle its own tolerance: ``s`` of its anchor links may lie, and so may the inter-vehicle
        range; not ``s`` over all readings, which would let two lying links of one vehicle use up the other's."""
        q = self.n_anchors
        return ((tuple(range(q)), s), (tuple(range(q, 2 * q)), s), ((2 * q,), min(s, 1)))

    @property
    def default_known(self) -> Known:
        return np.asarray(self.vehicle_z_ned_m)

    def _z(self, known: Known) -> tuple[float, float]:
        if known is None:
            return self.vehicle_z_ned_m
        arr = np.asarray(known, dtype=float).reshape(-1)
        return float(arr[0]), float(arr[1])

    def _parts(self, pos: np.ndarray, known: Known) -> tuple[np.ndarray, ...]:
        z1, z2 = self._z(known)
        a_xy, a_z = self.anchors_ned_m[:, :2], self.anchors_ned_m[:, 2]
        d1 = pos[..., None, 0:2] - a_xy
        d2 = pos[..., None, 2:4] - a_xy
        r1 = np.sqrt(np.einsum("...ij,...ij->...i", d1, d1) + (z1 - a_z) ** 2)
        r2 = np.sqrt(np.einsum("...ij,...ij->...i", d2, d2) + (z2 - a_z) ** 2)
        d12 = pos[..., 0:2] - pos[..., 2:4]
        r12 = np.sqrt(np.einsum("...i,...i->...", d12, d12) + (z1 - z2) ** 2)
        return d1, d2, d12, r1, r2, r12

    def h(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        _, _, _, r1, r2, r12 = self._parts(pos, known)
        return np.concatenate([r1, r2, r12[..., None]], axis=-1)

    def jac(self, pos: np.ndarray, known: Known = None) -> np.ndarray:
        d1, d2, d12, r1, r2, r12 = self._parts(pos, known)
        q = self.n_anchors
        out = np.zeros((*pos.shape[:-1], 2 * q + 1, 4))
        out[..., :q, 0:2] = d1 / np.maximum(r1, 1e-9)[..., None]
        out[..., q : 2 * q, 2:4] = d2 / np.maximum(r2, 1e-9)[..., None]
        g = d12 / np.maximum(r12, 1e-9)[..., None]
        out[..., 2 * q, 0:2] = g
        out[..., 2 * q, 2:4] = -g
        return out

    def initial_pos(self) -> np.ndarray:
        return np.tile(self.anchors_ned_m[:, :2].mean(axis=0), 2)

    def flight_region(self) -> Box:
        """Where the vehicles fly, for the layout check: ``region_m``, else the anchors' horizontal box."""
        return geometry.plane_region(self.anchors_ned_m) if self.region_m is None else geometry.as_box(self.region_m)

    def _support(self) -> Support:
        """Per vehicle (its own tolerance group): the plane case on its anchors, judged on its half of the box (the
        inter-vehicle range is not counted: conservative)."""
        if self.bounds_m is None:
            return super()._support()
        tol, sep = geometry.tolerances(self.sigma_m)
        q = self.n_anchors
        region, box = geometry.horizontal(self.flight_region()), geometry.horizontal(geometry.as_box(self.bounds_m))
        sets = geometry.degenerate(self.anchors_ned_m[:, :2], region, box, tol, sep)
        return geometry.largest(q, max(0, (q - 3) // 2), sets, self.ids()[:q])
