"""An attacker who knows the defence: it runs the estimator under attack on what it injects, and never lets a step
be caught.

A man in the middle sees every reading, so it can run an exact copy of the
defender's estimator (same algorithm, same parameters, same past). It picks a
set of links and a direction ``u`` in the horizontal plane and makes those links
report the ranges of a fake position ``x_seen + delta u`` (``x_seen`` the
vehicle's own estimate, as it reads on LOCAL_POSITION_NED; each reading keeps
its own noise, only the geometric difference is added). Every step it tries, in
order, ``delta`` grown by ``g dt``, ``delta`` held, ``delta`` shrunk by ``g dt``
and no attack at all, on a copy of the estimator, and commits the first that the
copy accepts: no attacked link named, no alarm, the estimate valid. The growth
``g`` rises by a quarter after a step committed growing (up to ``MAX_RATE_MPS``)
and halves after one that could not grow: the cheapest version is the slow
three-link ramp, which this finds and speeds up to whatever the tests let pass.

:func:`search` tries every link set and direction it is given and keeps, per
estimator, the one with the largest error on the steps the defence claimed
valid (the damage). The undefended EKF is run on the very readings that attack
produced (paired), since it has no test to stay under.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

import estimators
from estimators.base import Estimator
from estimators.models import MeasurementModel

START_RATE_MPS = 0.02
MAX_RATE_MPS = 1.0


@dataclass(frozen=True, eq=False)
class AdaptiveRun:
    """One attack against one estimator: its errors and the paired EKF's, and what the attacker injected."""

    name: str
    links: tuple[int, ...]  # indices into z
    direction_deg: float
    err_m: np.ndarray  # (T,) horizontal error of the defended estimate (NaN where it had none)
    valid: np.ndarray  # (T,) claimed valid
    ekf_err_m: np.ndarray  # (T,) the plain EKF on the same readings
    delta_m: np.ndarray  # (T,) the fake position's offset the attacker committed

    @property
    def damage_m(self) -> float:
        """The largest error the defence claimed valid during the attack (0 when it claimed nothing)."""
        hit = self.valid & np.isfinite(self.err_m) & (self.delta_m > 0)
        return float(self.err_m[hit].max(initial=0.0))


def _accepted(out: estimators.Estimate, links: np.ndarray) -> bool:
    return out.ok and out.valid and not out.alarm and not (set(out.attacked) & set(links.tolist()))


def attack(
    model: MeasurementModel,
    name: str,
    t_s: np.ndarray,
    z: np.ndarray,
    truth_xy_m: np.ndarray,
    seen_ned_m: np.ndarray,
    links: Sequence[int],
    direction_deg: float,
    start_s: float,
    params: dict[str, Any] | None = None,
    velocity: np.ndarray | None = None,
) -> AdaptiveRun:
    """Attack ``name`` adaptively on the clean readings ``z`` (T, p) (module docstring)."""
    est: Estimator = estimators.create(name, model, **(params or {}))
    ekf = estimators.create("ekf", model)
    memo = {id(model): model}  # the copies share the (read-only) model and its caches
    idx = np.asarray(links, dtype=int)
    u = np.array([np.cos(np.radians(direction_deg)), np.sin(np.radians(direction_deg))])
    n = z.shape[0]
    err, ekf_err, valid, deltas = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, bool), np.zeros(n)
    delta, rate = 0.0, START_RATE_MPS
    d = model.d
    for k in range(n):
        dt = 0.0 if k == 0 else float(t_s[k] - t_s[k - 1])
        vel = None if velocity is None else velocity[k]

        def spoofed(step_delta: float, k: int = k) -> np.ndarray:
            out = z[k].copy()
            if step_delta > 0.0:
                here = seen_ned_m[k, :d].copy()
                fake = here.copy()
                fake[:2] = fake[:2] + step_delta * u
                out[idx] = z[k, idx] + (model.h(fake) - model.h(here))[idx]
            return out

        candidates = [delta + rate * dt, delta, max(delta - rate * dt, 0.0), 0.0] if t_s[k] >= start_s else [0.0]
        chosen = candidates[-1]
        for cand in candidates[:-1]:
            probe = copy.deepcopy(est, memo)
            if _accepted(probe.step(float(t_s[k]), spoofed(cand), velocity=vel), idx):
                chosen = cand
                break
        grew = chosen > delta
        if t_s[k] >= start_s:
            rate = min(rate * 1.25, MAX_RATE_MPS) if grew else max(rate / 2.0, 1e-3)
        delta = chosen
        zk = spoofed(delta)
        out = est.step(float(t_s[k]), zk, velocity=vel)
        ref = ekf.step(float(t_s[k]), zk)
        deltas[k] = delta
        valid[k] = out.ok and out.valid
        if out.ok:
            err[k] = float(np.linalg.norm(out.position_m[:2] - truth_xy_m[k]))
        if ref.ok:
            ekf_err[k] = float(np.linalg.norm(ref.position_m[:2] - truth_xy_m[k]))
    return AdaptiveRun(name, tuple(int(i) for i in idx), float(direction_deg), err, valid, ekf_err, deltas)


def search(
    model: MeasurementModel,
    name: str,
    t_s: np.ndarray,
    z: np.ndarray,
    truth_xy_m: np.ndarray,
    seen_ned_m: np.ndarray,
    link_sets: Sequence[Sequence[int]],
    directions_deg: Sequence[float],
    start_s: float,
    params: dict[str, Any] | None = None,
    velocity: np.ndarray | None = None,
) -> AdaptiveRun:
    """Every link set x direction; the run with the largest damage (ties: the first)."""
    best: AdaptiveRun | None = None
    for links in link_sets:
        for direction in directions_deg:
            run = attack(model, name, t_s, z, truth_xy_m, seen_ned_m, links, direction, start_s, params, velocity)
            if best is None or run.damage_m > best.damage_m:
                best = run
    assert best is not None
    return best
