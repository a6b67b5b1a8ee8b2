"""How many attacked readings an anchor layout can correct over its flight region, from the geometry.

Correcting any ``s`` attacked readings from one snapshot needs every ``p - 2s``
readings to pin the position down (2s-sparse observability): two positions
whose readings differ in at most ``2s`` places cannot be told apart when ``s``
of them lie (each explanation blames ``s``). Counting sensors
(``(p - min_sensors) // 2``) is necessary, not sufficient: four collinear
anchors of eight in the plane measure the same ranges to a position and to its
mirror image across their line, so with two more liars both explanations need
two, a tie no estimator can break from the readings.

For range readings the condition is geometric and exact. The readings of a set
K of anchors leave the position ambiguous inside the admissible box B
(``model.bounds_m``, where an estimator accepts an answer) exactly when the
anchors do not span the space the position lives in:

- plane (north, east; height known): the anchors of K lie on one line. The
  readings then fit the position and its mirror across that line; it is an
  ambiguity when the mirror of some position of the flight region R lies in B.
- space (north, east, down): the anchors lie on one plane (the mirror across
  it, judged as above) or on one line (a circle of positions: always).
- anchors and the downward laser: with the laser in K the height is known and
  the rest is the plane case on the anchors' horizontal projections; without it,
  the space case (coplanar anchors: the mirror across their plane, e.g. under
  the hover height during take-off, which R may exclude).

So a set fails iff it lies inside one *degenerate set* (the readings of a line
or plane whose mirror reaches B from R), and the largest ``s`` is the largest
one within the count bound for which ``p - 2s`` exceeds the largest degenerate
set. "On a line" allows ``tol_m`` (default half the smallest range noise std:
an anchor that far off the line tells the mirror by at most one std). Whether a
mirror reaches B is judged on a grid of R (``GRID`` points per axis) and
counts only mirrors more than ``sep_m`` (default four noise stds) from their
original, strictly inside B. The two-vehicle model applies the plane case to
each vehicle's anchors (the inter-vehicle range is not counted: conservative).

This module is geometry over arrays (anchor positions, boxes, noise stds) and knows no model: each
measurement model's ``support()`` and ``mirrors()`` (``estimators.models``) hand it their anchors, boxes
and reading indices.

``LinearModel`` keeps its exact combinatorial test: :func:`linear_correctable`
(every set of ``p - 2s`` sensors must observe the state; with dynamics ``A``,
sensor i contributes its observability block ``c_i, c_i A, ..., c_i A^(n-1)``, as
in the s-sparse observability of Shoukry et al.'s Imhotep-SMT; sensors declared
safe are never among the removed).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

GRID = 7  # sample points per axis of the flight region


@dataclass(frozen=True)
class Support:
    """The answer: the largest correctable ``s`` and, when the geometry lowers it, why."""

    s_max: int
    count_bound: int  # (p - min_sensors) // 2, what counting sensors alone allows
    degenerate: tuple[tuple[int, ...], ...]  # reading sets (indices into z) whose readings leave a mirror in B
    reason: str  # one line naming the largest degenerate set, "" when the geometry does not lower s

    def explain(self, s: int) -> str:
        """One line saying why ``s`` is refused (call for s > s_max)."""
        why = self.reason or f"counting sensors allows at most {self.count_bound}"
        return f"s={s} exceeds the largest number of attacked readings this layout can correct, {self.s_max}: {why}"


Box = tuple[np.ndarray, np.ndarray]


def count_only(count_bound: int) -> Support:
    """What counting sensors alone allows (a model whose geometry adds nothing)."""
    return Support(count_bound, count_bound, (), "")


def tolerances(sigma_m: np.ndarray, tol_m: float | None = None, sep_m: float | None = None) -> tuple[float, float]:
    """``(tol_m, sep_m)``: "on a line" within half the smallest noise std, a mirror counted beyond four of the
    largest (module docstring), unless given."""
    tol = 0.5 * float(np.min(sigma_m)) if tol_m is None else float(tol_m)
    sep = 4.0 * float(np.max(sigma_m)) if sep_m is None else float(sep_m)
    return tol, sep


def as_box(box: Box) -> Box:
    return np.asarray(box[0], float), np.asarray(box[1], float)


def horizontal(box: Box) -> Box:
    """The (north, east) part of a box."""
    return box[0][:2], box[1][:2]


def plane_region(anchors_ned_m: np.ndarray) -> Box:
    """The anchors' horizontal box: where a vehicle of a plane model flies unless told otherwise."""
    return anchors_ned_m[:, :2].min(axis=0), anchors_ned_m[:, :2].max(axis=0)


def space_region(anchors_ned_m: np.ndarray, bounds_m: Box | None, start_above_m: float) -> Box:
    """The anchors' horizontal box and the admissible heights down to ``start_above_m`` above the highest anchor
    (where vehicles hover; lower, during take-off and landing, coplanar anchors leave a mirror the box cannot
    exclude)."""
    lo_xy, hi_xy = plane_region(anchors_ned_m)
    top = float(bounds_m[0][2]) if bounds_m is not None else float(anchors_ned_m[:, 2].min()) - 30.0
    low = float(anchors_ned_m[:, 2].min()) - float(start_above_m)
    return np.array([lo_xy[0], lo_xy[1], top]), np.array([hi_xy[0], hi_xy[1], max(top, low)])


def _grid(region: Box) -> np.ndarray:
    lo, hi = region
    axes = [np.linspace(lo[i], hi[i], GRID) if hi[i] > lo[i] else np.array([lo[i]]) for i in range(lo.shape[0])]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, lo.shape[0])


def _inside(points: np.ndarray, box: Box, margin: float) -> np.ndarray:
    return np.all((points > box[0] + margin) & (points < box[1] - margin), axis=-1)


def _mirror_reaches(
    points: np.ndarray, origin: np.ndarray, normal: np.ndarray, box: Box, sep_m: float, margin: float
) -> bool:
    """Whether the mirror across the hyperplane (origin, unit normal) of some sample point lands strictly in the box,
    more than ``sep_m`` from the point."""
    off = (points - origin) @ normal
    mirrored = points - 2.0 * off[:, None] * normal
    return bool(np.any((np.abs(2.0 * off) > sep_m) & _inside(mirrored, box, margin)))


def flats(pts: np.ndarray, tol_m: float) -> list[tuple[tuple[int, ...], np.ndarray, np.ndarray | None]]:
    """Maximal sets of points within ``tol_m`` of a hyperplane through d of them (a line in 2-D, a plane in 3-D):
    (indices, origin, unit normal); in 3-D also the sets on one line (normal None: a circle of solutions)."""
    n, d = pts.shape
    out: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray | None]] = {}
    for pair in itertools.combinations(range(n), 2):  # lines
        a, b = pts[pair[0]], pts[pair[1]]
        u = b - a
        if np.linalg.norm(u) < tol_m:
            continue
        u = u / np.linalg.norm(u)
        rel = pts - a
        dist = np.linalg.norm(rel - np.outer(rel @ u, u), axis=1)
        members = tuple(int(i) for i in np.flatnonzero(dist <= tol_m))
        if d == 2:
            out.setdefault(members, (a, np.array([-u[1], u[0]])))
        else:
            out.setdefault(members, (a, None))
    if d == 3:
        for triple in itertools.combinations(range(n), 3):
            a, b, c = pts[list(triple)]
            normal = np.cross(b - a, c - a)
            if np.linalg.norm(normal) < tol_m * max(np.linalg.norm(b - a), np.linalg.norm(c - a), 1e-9):
                continue  # collinear triple: a line, above
            normal = normal / np.linalg.norm(normal)
            members = tuple(int(i) for i in np.flatnonzero(np.abs((pts - a) @ normal) <= tol_m))
            out.setdefault(members, (a, normal))
    return [(k, v[0], v[1]) for k, v in out.items()]


def degenerate(
    pts: np.ndarray, region: Box, box: Box, tol_m: float, sep_m: float
) -> list[tuple[tuple[int, ...], str]]:
    """Degenerate anchor sets of a plane or space layout, with what makes each one ambiguous."""
    samples = _grid(region)
    found = []
    for members, origin, normal in flats(pts, tol_m):
        if normal is None:
            found.append((members, "anchors on one line (a circle of positions fits their ranges)"))
        elif _mirror_reaches(samples, origin, normal, box, sep_m, tol_m):
            what = "line" if pts.shape[1] == 2 else "plane"
            found.append((members, f"anchors on one {what}: the mirror image across it of positions in the flight "
                                   f"region lies inside the admissible box"))  # fmt: skip
    return found


def largest(p: int, count_bound: int, sets: list[tuple[tuple[int, ...], str]], ids: tuple[int, ...]) -> Support:
    """The largest ``s`` within ``count_bound`` for which ``p - 2s`` readings exceed every degenerate set."""
    biggest = max(sets, key=lambda item: len(item[0]), default=((), ""))
    s_max = count_bound
    while s_max > 0 and p - 2 * s_max <= len(biggest[0]):
        s_max -= 1
    reason = ""
    if s_max < count_bound:
        names = ", ".join(str(ids[i]) for i in biggest[0])
        keep = p - 2 * (s_max + 1)
        reason = f"readings {names} are {biggest[1]}, and {p} - 2 x {s_max + 1} = {keep} readings could be them"
    return Support(s_max, count_bound, tuple(m for m, _ in sets), reason)


def linear_correctable(
    C: np.ndarray, A: np.ndarray | None = None, safe: tuple[int, ...] = ()
) -> tuple[int, tuple[int, ...]]:
    """The largest s such that every set of sensors left after removing any 2s of the unsafe ones observes the
    state, and the first set that does not observe it at s + 1 (empty when none fails).

    One output row per sensor; ``A`` (n x n) adds the dynamics: sensor i is then seen through its block
    ``[c_i; c_i A; ...; c_i A^(n-1)]`` (a window of n steps). Exact: every subset is checked.
    """
    mat = np.atleast_2d(np.asarray(C, dtype=float))
    p, n = mat.shape
    blocks = [mat[i : i + 1] for i in range(p)]
    if A is not None:
        powers = [np.linalg.matrix_power(np.asarray(A, dtype=float), k) for k in range(n)]
        blocks = [np.vstack([row @ pk for pk in powers]) for row in blocks]
    unsafe = [i for i in range(p) if i not in set(safe)]
    best, failing = 0, ()
    for s in range(1, len(unsafe) // 2 + 1):
        for removed in itertools.combinations(unsafe, 2 * s):
            kept = [i for i in range(p) if i not in removed]
            if not kept or np.linalg.matrix_rank(np.vstack([blocks[i] for i in kept])) < n:
                failing = tuple(kept)
                break
        if failing:
            break
        best = s
    return best, failing


@dataclass(frozen=True)
class Mirror:
    """A degenerate set and the reflection that keeps its readings: the other place a tie can put the vehicle."""

    members: np.ndarray  # (p,) bool: the readings that measure the same to a position and to its mirror
    origin: np.ndarray  # a point of the line or plane, in the axes it reflects
    normal: np.ndarray  # its unit normal, in those axes
    axes: tuple[int, ...]  # which position coordinates it reflects (the horizontal ones when the laser is in)

    def reflect(self, pos: np.ndarray) -> np.ndarray:
        out = np.array(pos, dtype=float)
        sub = out[list(self.axes)]
        out[list(self.axes)] = sub - 2.0 * float((sub - self.origin) @ self.normal) * self.normal
        return out


def mirrors(pts: np.ndarray, tol_m: float, min_size: int, axes: tuple[int, ...],
            p: int, extra: tuple[int, ...] = ()) -> list[Mirror]:  # fmt: skip
    """Every line (2-D points) or plane (3-D) of the anchors ``pts`` holding at least ``min_size`` of the ``p``
    readings (its anchors' plus ``extra``, the laser), wherever its mirror falls (the run-time tie check:
    :meth:`estimators.base.Estimator._tie`). ``axes``: which position coordinates the points stand for."""
    found: list[Mirror] = []
    for members, origin, normal in flats(pts, tol_m):
        held = (*members, *extra)
        if normal is not None and len(held) >= min_size:
            mask = np.zeros(p, dtype=bool)
            mask[list(held)] = True
            found.append(Mirror(mask, origin, normal, axes))
    return found
