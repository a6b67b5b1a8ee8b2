"""``milp``: the l0 problem as a mixed-integer linear program on the linearised model.

Paper: M. Pajic, I. Lee, G. J. Pappas, "Attack-resilient state estimation for
noisy dynamical systems", IEEE TCNS 2017 (its l0 estimator as an MILP; the
ICCPS'14 paper has the bounded-noise setting). Solved with SciPy's
``scipy.optimize.milp`` (the HiGHS branch and bound).

Model: any ``MeasurementModel``, linearised at the current guess. Attacker: at
most ``s`` sensors, the same over a window of ``T`` steps, arbitrary values;
noise bounded by ``k_sigma`` standard deviations (the bounded-noise setting).

Equations. For each step t of the window, around the guess ``g_t``:
``y_t = z_t - h(g_t) ~ H_t dx_t + e_t + v_t``, with ``|v_i,t| <= k sigma_i``.
A binary ``b_i`` per sensor says "sensor i is attacked" over the whole window;
``|e_i,t| <= M b_i`` and ``sum_i b_i <= s``. The program
``min  sum_i b_i + eps * sum_t,i |v_i,t| / sigma_i`` (``|v|`` via slack
variables ``u >= +-v``) finds the fewest attacked sensors that explain the
readings within the noise bound, and among those the smallest noise. The
current step's ``g + dx`` is the estimate; the guess is moved there and the
program solved again (``passes``), because the ranges are not linear.
Infeasible (HiGHS proved it): no set of s sensors explains the readings; the
estimate is raised as an alarm (degraded) at the last guess. A solve that hits
``time_limit_s`` is not that proof: with a feasible incumbent (at most s
attacked explain the readings, fewest not proven) its answer is used; without
one the step is marked not valid *without* an alarm, at the last guess.
``status_counts`` counts each outcome (optimal, infeasible, timeout with and
without an incumbent), so a run can report its timeouts apart from its alarms. Attacked: sensors with ``b_i = 1``
that fail the tests of ``attribution.py``. A missing reading drops its rows.
RECON: the window with free per-step positions (no dynamics), the objective's
noise term and the re-linearisation are ours. Defaults: T = 5, k = 3, M = 100 m (capped at twice the largest
innovation in the window plus 1 m, which keeps the relaxation tight), one pass.

Asynchronous readings (``async_window_s``, estimators.aligned; the default on recorded ranges and in the secure
stage): the program is written on one vector per step, the window's readings brought to the step's time
(window alignment); its noise box is the readings' stated noise, the alignment's own error (module
``estimators.aligned``) is not in it.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, milp

from estimators.base import TUNED_ON_BUNDLED, Estimate, Estimator
from estimators.models import Known, MeasurementModel
from estimators.subsets import secure_snapshot


class Milp(Estimator):
    name = "milp"
    tuned_on = TUNED_ON_BUNDLED
    secure = True

    def __init__(
        self,
        model: MeasurementModel,
        *,
        window: int = 5,
        k_sigma: float = 3.0,
        big_m: float = 100.0,
        passes: int = 1,
        eps: float = 1e-3,
        time_limit_s: float = 1.0,
        **params,
    ) -> None:
        self.window, self.k_sigma, self.big_m, self.passes, self.eps = int(window), k_sigma, big_m, int(passes), eps
        self.time_limit_s = float(time_limit_s)
        self.status_counts = {"optimal": 0, "infeasible": 0, "timeout_incumbent": 0, "timeout_none": 0, "other": 0}
        super().__init__(model, **params)

    def _reset(self, x0: np.ndarray | None, P0: np.ndarray) -> None:
        self.pos = None if x0 is None else x0[: self.model.d].copy()
        self.hist: deque[tuple[np.ndarray, Known, np.ndarray]] = deque(maxlen=self.window)  # (z, known, guess)

    def _step(self, t_s: float, dt_s: float, z: np.ndarray, known: Known) -> Estimate:
        model = self.model
        avail = ~np.isnan(z)
        if self.pos is None:
            if avail.sum() < model.min_sensors:
                return self._estimate(t_s, None, alarm=False)
            # The first guess: the one-step l0 decoder (a fit on all readings may sit metres off under attack).
            self.pos = secure_snapshot(model, z, self.s, self.chi, None, known, 20).pos
        guess = self.pos.copy()
        self.hist.append((z, known, guess))
        result, status = None, "optimal"
        for _ in range(self.passes):
            result, status = self._solve()
            if result is None:
                break
            dx_now, b = result
            guess = model.clip(guess + dx_now)
            self.hist[-1] = (z, known, guess)
        if result is None:
            if status == "infeasible":
                return self._estimate(t_s, self.pos, alarm=True, used=avail)
            # Out of time (or the solver failed) before any answer: nothing is proven, neither an attack beyond s
            # nor an explanation within it. Not an alarm; not an estimate to trust either.
            est = self._estimate(t_s, self.pos, alarm=False, used=np.zeros_like(avail))
            object.__setattr__(est, "valid", False)
            return est
        self.pos = guess
        jac = model.jac(guess, known)
        cov = _covariance(jac[avail & ~b], model.sigma_m[avail & ~b], model.d)
        return self._estimate(t_s, self.pos, cov=cov, used=avail & ~b)

    def _solve(self) -> tuple[tuple[np.ndarray, np.ndarray] | None, str]:
        """The program over the window: ((current step's dx, attacked mask) or None, the outcome counted in
        ``status_counts``)."""
        model = self.model
        p, d, steps = model.p, model.d, len(self.hist)
        per = d + 2 * p  # per step: dx (d), e (p), u (p); the p binaries b come first
        n = p + steps * per
        eye = np.eye(p)
        # A big-M no larger than needed keeps the relaxation tight (HiGHS then branches far less):
        # an attack never has to exceed the largest innovation in the window plus the room dx has.
        innovations = np.concatenate([np.abs(z - model.h(g, kn)) for z, kn, g in self.hist])
        spread = float(innovations[~np.isnan(innovations)].max(initial=0.0))
        big_m = min(self.big_m, 2.0 * spread + 1.0)
        blocks, lo, hi = [], [], []
        var_lo, var_hi = np.full(n, -np.inf), np.full(n, np.inf)
        var_lo[:p], var_hi[:p] = 0.0, 1.0
        for t, (z, known, guess) in enumerate(self.hist):
            hx, jac = model.h_jac(guess, known)
            have = ~np.isnan(z)
            y = (z - hx)[have]
            k = int(have.sum())
            base = p + t * per
            # v = y - H dx - e, |v| <= u:  H dx + e + u >= y  and  H dx + e - u <= y
            fit = np.zeros((2 * k, n))
            for half, sign in ((slice(0, k), 1.0), (slice(k, 2 * k), -1.0)):
                fit[half, base : base + d] = jac[have]
                fit[half, base + d : base + d + p] = eye[have]
                fit[half, base + d + p : base + per] = sign * eye[have]
            lo += [*y, *np.full(k, -np.inf)]
            hi += [*np.full(k, np.inf), *y]
            # |e| <= M b:  e - M b <= 0  and  e + M b >= 0
            cap = np.zeros((2 * k, n))
            cap[:k, base + d : base + d + p] = eye[have]
            cap[:k, :p] = -big_m * eye[have]
            cap[k:, base + d : base + d + p] = eye[have]
            cap[k:, :p] = big_m * eye[have]
            lo += [*np.full(k, -np.inf), *np.zeros(k)]
            hi += [*np.zeros(k), *np.full(k, np.inf)]
            blocks += [fit, cap]
            var_lo[base + d + p : base + per] = 0.0
            var_hi[base + d + p : base + per] = np.where(have, self.k_sigma * model.sigma_m, 0.0)  # bounded noise
        groups = model.tolerance_groups(self.s)
        budget = np.zeros((len(groups), n))
        for row, (idx, _) in enumerate(groups):
            budget[row, list(idx)] = 1.0  # at most the group's tolerance attacked
        cost = np.zeros(n)
        cost[:p] = 1.0
        for t in range(steps):
            base = p + t * per
            cost[base + d + p : base + per] = self.eps / model.sigma_m
        integrality = np.zeros(n)
        integrality[:p] = 1
        caps = [float(k) for _, k in groups]
        constraints = [LinearConstraint(np.vstack(blocks), lo, hi), LinearConstraint(budget, 0.0, caps)]
        res = milp(cost, constraints=constraints, integrality=integrality, bounds=Bounds(var_lo, var_hi),
                   options={"time_limit": self.time_limit_s})  # fmt: skip
        # scipy.optimize.milp: 0 optimal, 1 iteration or time limit, 2 infeasible, 3 unbounded, 4 other.
        if res.status == 0:
            status = "optimal"
        elif res.status == 2:
            status = "infeasible"
        elif res.status == 1:
            status = "timeout_incumbent" if res.x is not None else "timeout_none"
        else:
            status = "other"
        self.status_counts[status] += 1
        if res.x is None or status in ("infeasible", "other"):
            return None, status
        last = p + (steps - 1) * per
        return (res.x[last : last + d], res.x[:p] > 0.5), status


def _covariance(jac: np.ndarray, sigma: np.ndarray, d: int) -> np.ndarray:
    info = (jac / sigma[:, None] ** 2).T @ jac + 1e-9 * np.eye(d)
    return np.linalg.inv(info)
