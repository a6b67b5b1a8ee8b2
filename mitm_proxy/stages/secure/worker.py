"""Stepping the estimator without holding up the frames that pass meanwhile.

One :class:`Stepper`, three modes (``submit`` a reading set, read the
``latest`` finished result, ``drain`` the results not yet published):

- ``inline``: the step runs inside ``submit``, on the forwarding path; the frame
  that completes a set waits one step. Deterministic (the accuracy tests use it).
- ``thread``: one dedicated worker thread with a mailbox of one. ``submit`` never
  waits: a set that arrives while the previous one still waits for the worker
  replaces it and counts as a dropped step, so a slow estimator sheds load
  instead of queueing latency, and frames carry the latest *finished* estimate.
- ``auto`` (the default): inline while steps are cheap, the worker thread once
  the smoothed step cost (CPU time of the stepping thread, so a busy machine
  that preempts a cheap step does not count as a costly estimator) exceeds
  ``budget_s``, back inline when it falls under half of it.

Why auto, from ``benchmarks/secure_stage_bench.py`` (2 k frames/s through the
real pipeline on the 2-core bench machine): the bench's estimators step in
0.1-2 ms, mostly in small numpy calls that hold the GIL, so a worker thread does
not run beside the forwarding thread but takes turns with it; every handover
costs a thread wake-up and the frames arriving meanwhile wait for the GIL.
Measured (anchors8, secekf, 0.36 ms steps at 10 Hz, medians of 5 rounds, a
loaded machine): added p99 of a substituted frame +0.3 to +0.7 ms inline/auto,
+2.1 ms with the thread. Only a step much longer than a frame interval is
worth moving off the path, which is what the budget decides.

The worker also computes what the estimate implies for every reading
(``model.h``), so the forwarding path only copies numbers.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Literal

import numpy as np

from estimators import Estimate, Estimator
from estimators.aligned import AsyncEstimator
from estimators.models import Known, MeasurementModel

log = logging.getLogger(__name__)

Mode = Literal["auto", "inline", "thread"]
MAX_UNPUBLISHED = 64  # results kept for publishing when nobody drains (no frames flowing)
EWMA_GAIN = 0.2  # weight of the newest step time in the smoothed figure


@dataclass(frozen=True, slots=True)
class Job:
    """One reading set: ``z`` in metres (NaN = missing) at estimator time ``t_s``."""

    t_s: float
    z: np.ndarray
    known: Known
    sim_t_s: float | None  # the vehicle's clock (time_boot_ms) of the newest reading, to join with truth
    rx_s: float  # proxy monotonic time the set was submitted
    velocity: np.ndarray | None = None  # the vehicle's own NED velocity (LOCAL_POSITION_NED), the motion input
    times: np.ndarray | None = None  # per reading, the estimator time it arrived (asynchronous processing)
    tilt: np.ndarray | None = None  # per reading, the factor that projected it on the wall's normal (tilt.py)


@dataclass(frozen=True, slots=True)
class StepResult:
    """An estimate and what it implies on the wire."""

    job: Job
    estimate: Estimate
    implied_m: np.ndarray  # model.h(position, known): the reading each sensor should show
    attacked_idx: frozenset[int]


def run_step(estimator: Estimator | AsyncEstimator, model: MeasurementModel, job: Job) -> StepResult:
    if isinstance(estimator, AsyncEstimator):  # each reading at its own time, brought to the step's (aligned.py)
        est = estimator.step(job.t_s, job.z, job.known, velocity=job.velocity, times=job.times)
    else:
        est = estimator.step(job.t_s, job.z, job.known, velocity=job.velocity)
    if est.ok:
        implied = np.asarray(model.h(est.position_m, job.known), dtype=float).reshape(-1)
    else:
        implied = np.full(model.p, np.nan)
    return StepResult(job, est, implied, est.attacked)


class Stepper:
    """Runs one estimator in the configured mode; see the module docstring."""

    def __init__(
        self,
        estimator: Estimator | AsyncEstimator,
        model: MeasurementModel,
        mode: Mode = "auto",
        budget_s: float = 0.002,
        name: str = "secure-step",
    ) -> None:
        self.estimator = estimator
        self.model = model
        self.mode = mode
        self.budget_s = budget_s
        self.name = name
        self.steps = 0
        self.dropped = 0
        self.overruns = 0  # inline steps longer than the budget
        self.switches = 0  # auto: moves between inline and the thread
        self.errors = 0
        self.last_error: str | None = None
        self.step_ewma_s: float | None = None
        self._latest: StepResult | None = None
        self._unpublished: deque[StepResult] = deque(maxlen=MAX_UNPUBLISHED)
        self._lock = threading.Lock()
        self._cond = threading.Condition()
        self._mailbox: Job | None = None
        self._stepping = False
        self._closed = False
        self._thread: threading.Thread | None = None
        self._threaded = mode == "thread"
        if self._threaded:
            self._start_thread()

    # -- for the forwarding path ----------------------------------------------------------------------

    @property
    def threaded(self) -> bool:
        """True while steps run in the worker thread."""
        return self._threaded

    def submit(self, job: Job) -> None:
        if self._threaded and self.mode == "auto" and self._calm() and not self.busy:
            self._threaded = False  # steps became cheap again: back on the path
            self.switches += 1
        if not self._threaded:
            self._step(job)
            if self.step_ewma_s is not None and self.step_ewma_s > self.budget_s:
                self.overruns += 1
                if self.mode == "auto":
                    self._threaded = True
                    self.switches += 1
                    self._start_thread()
            return
        with self._cond:
            if self._mailbox is not None:
                self.dropped += 1
            self._mailbox = job
            self._cond.notify()

    def latest(self) -> StepResult | None:
        return self._latest  # one attribute read: atomic under the GIL

    def drain(self) -> list[StepResult]:
        with self._lock:
            out = list(self._unpublished)
            self._unpublished.clear()
        return out

    @property
    def busy(self) -> bool:
        return self._stepping or self._mailbox is not None

    def wait_idle(self, timeout_s: float = 5.0) -> bool:
        """Block until every submitted set is stepped (tests and shutdown only, never on the forwarding path)."""
        with self._cond:
            return self._cond.wait_for(lambda: not self.busy or self._closed, timeout_s)

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        t = self._thread
        if t is not None and threading.current_thread() is not t:
            t.join(timeout=5.0)

    # -- internals --------------------------------------------------------------------------------------

    def _calm(self) -> bool:
        return self.step_ewma_s is not None and self.step_ewma_s < self.budget_s / 2

    def _step(self, job: Job) -> None:
        cpu0 = time.thread_time()
        try:
            res = run_step(self.estimator, self.model, job)
        except Exception as exc:  # a numerical failure must not stop the stage; counted, logged once
            self.errors += 1
            if self.last_error is None:
                log.warning("secure estimator %s failed: %s", self.estimator.name, exc)
            self.last_error = f"{type(exc).__name__}: {exc}"
            return
        # What the step costs, in this thread's CPU time: a step preempted by another process is not a costly
        # step, and moving it to the thread would only add hand-overs (module docstring).
        dt = time.thread_time() - cpu0
        self.step_ewma_s = dt if self.step_ewma_s is None else self.step_ewma_s + EWMA_GAIN * (dt - self.step_ewma_s)
        with self._lock:
            self.steps += 1
            self._latest = res
            self._unpublished.append(res)

    def _start_thread(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
            self._thread.start()

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
