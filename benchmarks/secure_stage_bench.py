"""What the secure stage adds to the proxy's forwarding path, and what its estimator costs.

One run, side by side, through the real Pipeline (frame splitter, stages, codec):

- baseline: the pipeline without the secure stage;
- inline: the estimator steps on the forwarding path (the frame completing a set waits);
- thread: the estimator steps in its worker thread, frames use the latest finished estimate;
- auto: inline while the smoothed step time is under the budget (2 ms), else the thread.

The stream is anchors8's telemetry in real time (8 UWB ranges at 10 Hz, a height
laser at 20 Hz, LOCAL_POSITION_NED 20 Hz, GLOBAL_POSITION_INT 10 Hz) padded with
ATTITUDE frames to ``--rate`` frames/s, one frame per datagram, each fed at its
scheduled time. Latency (see :func:`run`) is measured on the frames the stage
substitutes; "added" is against the baseline of the same run. The estimator's
share of one core is the sum of its step times over the wall time. Usage:
``python benchmarks/secure_stage_bench.py [--rate 2000] [--seconds 3] [--rounds 3]
[--estimator secekf] [--params JSON]``.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from mavframe.packet import Direction
from mitm_proxy.core.pipeline import Pipeline
from mitm_proxy.core.stats import LinkStats
from mitm_proxy.stages.secure.stage import SecureConfig, SecureStage
from secuav_common.geo import ned_to_geodetic
from secuav_common.scenario import load_scenario

TARGETED = {132, 32, 33}


def make_stream(rate_hz: float, seconds: float, seed: int = 0) -> list[tuple[float, bytes, bool]]:
    """(arrival time, datagram, is a frame the stage rewrites) in arrival order."""
    sc = load_scenario("anchors8")
    anchors = sc.anchor_positions()
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    rng = np.random.default_rng(seed)
    hold = np.array([2.5, 2.5, -2.5])
    out: list[tuple[float, bytes, bool]] = []
    tick_s = 0.05
    for k in range(round(seconds / tick_s)):
        t = k * tick_s
        ms = round(t * 1000)
        pos = hold + 0.05 * np.array([math.sin(0.5 * t), math.cos(0.3 * t), 0.0])
        msgs = [
            (mav.distance_sensor_encode(ms, 5, 4000, round(-pos[2] * 100), 0, 0, 25, 4, signal_quality=100), False),
            (mav.local_position_ned_encode(ms, *pos, 0.0, 0.0, 0.0), True),
        ]
        if k % 2 == 0:
            for a, apos in sorted(anchors.items()):
                r = float(np.linalg.norm(pos - np.asarray(apos))) + 0.1 * rng.standard_normal()
                msgs.append((mav.distance_sensor_encode(ms, 0, 10000, round(r * 100), 4, 10 + a, 100, 100), True))
            lat, lon, alt = ned_to_geodetic(sc.world.home, *pos)
            gpi = mav.global_position_int_encode(
                ms, round(lat * 1e7), round(lon * 1e7), round(alt * 1e3), 2500, 0, 0, 0, 0
            )
            msgs.append((gpi, True))
        pad = max(0, round(rate_hz * tick_s) - len(msgs))
        msgs += [(mav.attitude_encode(ms, 0.01, 0.02, 0.03, 0.0, 0.0, 0.0), False) for _ in range(pad)]
        step = tick_s / len(msgs)
        out += [(t + i * step, bytes(m.pack(mav)), sub) for i, (m, sub) in enumerate(msgs)]
    return out


def run(stream: list[tuple[float, bytes, bool]], stage: SecureStage | None) -> tuple[np.ndarray, float, float]:
    """Latencies (s) of the targeted frames, CPU seconds of the process, wall seconds.

    A frame's latency is the time it spent queued behind the previous frame
    (``ready - due``, where ready is when the previous one was done) plus its
    own ``feed`` time. The time our pacing thread overslept after ``ready`` is
    the OS scheduler's, not the stage's, and is left out: on a shared 2-core
    machine it would otherwise dominate every variant's p99 alike.
    """
    pipe = Pipeline(0, [stage] if stage is not None else [], stats=LinkStats(1))
    lat: list[float] = []
    cpu0, wall0 = time.process_time(), time.perf_counter()
    done = wall0
    for t_s, dgram, targeted in stream:
        due = wall0 + t_s
        while (now := time.perf_counter()) < due:
            if due - now > 0.0002:
                time.sleep(due - now - 0.0001)  # sleeping hands the GIL to a worker thread, as epoll would
        ready = max(due, done)
        start = time.perf_counter()
        pipe.feed(dgram, Direction.DOWNLINK, due)
        done = time.perf_counter()
        if targeted:
            lat.append((ready - due) + (done - start))
    return np.array(lat), time.process_time() - cpu0, time.perf_counter() - wall0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=2000.0, help="frames per second (default 2000)")
    ap.add_argument("--seconds", type=float, default=3.0, help="length of one run (default 3)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds; medians are printed (default 3)")
    ap.add_argument("--estimator", default="secekf")
    ap.add_argument("--params", default="{}", help="estimator parameters as JSON, e.g. '{\"n_irls\": 1500}'")
    args = ap.parse_args()
    params = json.loads(args.params)
    sc = load_scenario("anchors8")
    stream = make_stream(args.rate, args.seconds)
    print(f"secure stage: anchors8, {args.estimator} {params or ''}, {len(stream) / args.seconds:.0f} frames/s,"
          f" {args.rounds} x {args.seconds:.0f} s, medians over rounds")  # fmt: skip
    variants = ("baseline", "inline", "thread", "auto")
    rows: dict[str, list[dict[str, float]]] = {v: [] for v in variants}
    for _ in range(args.rounds):
        for v in variants:
            steps: list[float] = []
            stage = None
            if v != "baseline":
                cfg = SecureConfig(estimator=args.estimator, params=params, executor=v)
                stage = SecureStage(cfg, sc, 1, publish=lambda _s, p, steps=steps: steps.append(p["step_time_s"]))
            try:
                lat, cpu, wall = run(stream, stage)
                st: dict = {}
                if stage is not None:
                    stage.wait_idle()
                    stage.poll(time.perf_counter())
                    st = stage.stats()
            finally:
                if stage is not None:
                    stage.close()
            p50, p99 = np.percentile(lat, [50, 99]) * 1e3
            rows[v].append({
                "p50": p50, "p99": p99, "max": lat.max() * 1e3, "cpu": cpu,
                "steps": st.get("steps", 0), "drop": st.get("dropped_steps", 0),
                "step": float(np.median(steps)) * 1e3 if steps else math.nan, "share": sum(steps) / wall,
                "switches": st.get("executor_switches", 0),
            })  # fmt: skip
    med = {v: {k: float(np.median([r[k] for r in rs])) for k in rs[0]} for v, rs in rows.items()}
    base = med["baseline"]
    print(f"{'variant':10s} {'p50 ms':>8s} {'p99 ms':>8s} {'max ms':>8s} {'+p99 ms':>8s} {'steps':>6s} {'drop':>5s}"
          f" {'step ms':>8s} {'est core':>8s} {'cpu x':>6s}")  # fmt: skip
    for v in variants:
        m = med[v]
        extra = "" if v == "baseline" else f"{m['p99'] - base['p99']:8.3f}"
        steps_txt = "" if v == "baseline" else f"{m['steps']:6.0f} {m['drop']:5.0f} {m['step']:8.3f} {m['share']:8.1%}"
        print(f"{v:10s} {m['p50']:8.3f} {m['p99']:8.3f} {m['max']:8.3f} {extra:>8s} {steps_txt:>30s}"
              f" {m['cpu'] / base['cpu']:6.2f}")  # fmt: skip
    print("latency: queued behind the previous frame + own feed() time, substituted frames; +p99: over the baseline;")
    print("est core: estimator step time / wall time; cpu x: process CPU time relative to the baseline run")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
