"""Stepping the estimator without holding up the frames that pass meanwhile.

Two ways, one shape (``submit`` a complete reading set, read the ``latest``
result, ``drain`` the results not yet published):

- :class:`ThreadStepper` (default): one dedicated worker thread and a mailbox
  of size one. ``submit`` never waits: a set that arrives while the previous
  one still waits for the worker replaces it and counts as a dropped step, so a
  slow estimator sheds load instead of queueing latency, and the forwarding path
  always substitutes the latest *finished* estimate. The estimators spend most
  of a step in small numpy calls, so the worker holds the GIL for much of it;
  the forwarding thread then waits at most the interpreter's switch interval
  (5 ms by default) — see ``benchmarks/secure_stage_bench.py`` for the figures.
- :class:`InlineStepper`: steps inside ``submit``, on the forwarding path.
  Deterministic (the tests use it to check accuracy frame by frame); the frame
  that completes a set waits one step (0.1-2 ms for the bench's estimators).
  A step longer than ``budget_s`` counts as an overrun.

The worker also computes what the estimate implies for every reading
(``model.h``), so the forwarding path only copies numbers.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np

from estimators import Estimate, Estimator
from estimators.models import Known, MeasurementModel

log = logging.getLogger(__name__)

MAX_UNPUBLISHED = 64  # results kept for publishing when nobody drains (no frames flowing)


@dataclass(frozen=True, slots=True)
class Job:
    """One reading set: ``z`` in metres (NaN = missing) at estimator time ``t_s``."""

    t_s: float
    z: np.ndarray
    known: Known
    sim_t_s: float | None  # the vehicle's clock (time_boot_ms) of the newest reading, to join with truth
    rx_s: float  # proxy monotonic time the set was complete


@dataclass(frozen=True, slots=True)
class StepResult:
    """An estimate and what it implies on the wire."""

    job: Job
    estimate: Estimate
    implied_m: np.ndarray  # model.h(position, known): the reading each sensor should show
    attacked_idx: frozenset[int]


def run_step(estimator: Estimator, model: MeasurementModel, job: Job) -> StepResult:
    est = estimator.step(job.t_s, job.z, job.known)
    if est.ok:
        implied = np.asarray(model.h(est.position_m, job.known), dtype=float).reshape(-1)
    else:
        implied = np.full(model.p, np.nan)
    return StepResult(job, est, implied, est.attacked)


class _Base:
    """Counters and the result hand-over shared by both steppers."""

    def __init__(self, estimator: Estimator, model: MeasurementModel) -> None:
        self.estimator = estimator
        self.model = model
        self.steps = 0
        self.dropped = 0
        self.overruns = 0
        self.errors = 0
        self.last_error: str | None = None
        self._latest: StepResult | None = None
        self._unpublished: deque[StepResult] = deque(maxlen=MAX_UNPUBLISHED)
        self._lock = threading.Lock()

    def latest(self) -> StepResult | None:
        return self._latest  # one attribute read: atomic under the GIL

    def drain(self) -> list[StepResult]:
        with self._lock:
            out = list(self._unpublished)
            self._unpublished.clear()
        return out

    def _step(self, job: Job) -> None:
        try:
            res = run_step(self.estimator, self.model, job)
        except Exception as exc:  # a numerical failure must not stop the stage; counted and logged once
            self.errors += 1
            if self.last_error is None:
                log.warning("secure estimator %s failed: %s", self.estimator.name, exc)
            self.last_error = f"{type(exc).__name__}: {exc}"
            return
        with self._lock:
            self.steps += 1
            self._latest = res
            self._unpublished.append(res)

    def close(self) -> None:
        pass


class InlineStepper(_Base):
    """Steps in the caller's thread (see module docstring)."""

    def __init__(self, estimator: Estimator, model: MeasurementModel, budget_s: float = 0.005) -> None:
        super().__init__(estimator, model)
        self.budget_s = budget_s

    def submit(self, job: Job) -> None:
        self._step(job)
        latest = self._latest
        if latest is not None and latest.job is job and latest.estimate.step_time_s > self.budget_s:
            self.overruns += 1

    @property
    def busy(self) -> bool:
        return False


class ThreadStepper(_Base):
    """One worker thread, mailbox of one, latest wins (see module docstring)."""

    def __init__(self, estimator: Estimator, model: MeasurementModel, name: str = "secure-step") -> None:
        super().__init__(estimator, model)
        self._cond = threading.Condition()
        self._mailbox: Job | None = None
        self._stepping = False
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, job: Job) -> None:
        with self._cond:
            if self._mailbox is not None:
                self.dropped += 1
            self._mailbox = job
            self._cond.notify()

    @property
    def busy(self) -> bool:
        return self._stepping or self._mailbox is not None

    def wait_idle(self, timeout_s: float = 5.0) -> bool:
        """Block until every submitted set is stepped (tests and shutdown only, never on the forwarding path)."""
        with self._cond:
            return self._cond.wait_for(lambda: not self.busy or self._closed, timeout_s)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._mailbox is not None or self._closed)
                if self._closed:
                    return
                job, self._mailbox = self._mailbox, None
                self._stepping = True
            try:
                self._step(job)  # type: ignore[arg-type]
            finally:
                with self._cond:
                    self._stepping = False
                    self._cond.notify_all()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=5.0)
