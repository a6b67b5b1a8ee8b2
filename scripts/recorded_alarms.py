"""False alarms, honest links named, bias recall and ramp naming of the calibrated estimators on recorded ranges.

    python scripts/datasets/lias_planar_uwb.py convert --run mid --tag 0 --out out/lias-mid-0
    .venv/bin/python scripts/recorded_alarms.py out/lias-mid-0 out/lias-fast-0 [--fixed-offsets]

The documented protocol of docs/recorded-ranges.md: framed at 10 Hz, ``--dims 2``, calibrated on the first 20 s,
scored from 21 s; attacks from 30 s on the profile clock (time since the first frame), added to the recorded
readings as ``secuav-eval --attack`` does: +1.5 m on links 11 and 14 (``anchors-constant``) and 0.1 m/s on the
same links (``anchors-ramp``). Per estimator and recording it prints, on the clean run, the share of scored steps
naming a link (every link is honest there) and with an alarm, and the same as events (runs of consecutive steps)
per run and per hour; under the bias, the share of attacked steps naming both attacked links and the RMSE; under
the ramp, how large it was when first named on each link (the larger of the two).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from estimators import noise
from evaluation.recorded import load_recording
from evaluation.trial import _inputs
from secuav_common.scenario import load_scenario

LINKS = (1, 4)  # indices of sensor ids 11 and 14
ONSET_S = 30.0


def _events(flags: np.ndarray) -> int:
    return int(np.sum(flags[1:] & ~flags[:-1]) + (flags[0] if flags.size else 0))


def run(inp, name: str, attack: str | None, params: dict, ramp_mps: float = 0.1) -> dict[str, float]:
    model, s1 = inp.model, inp.s1
    t = s1.t_s - s1.t_s[0]
    added = np.zeros_like(inp.z)
    on = t >= ONSET_S
    for link in LINKS:
        if attack == "bias":
            added[on, link] = 1.5
        elif attack == "ramp":
            added[on, link] = ramp_mps * (t[on] - ONSET_S)
    z = inp.z + added
    est = noise.create(name, model, calibration_s=20.0, **params)
    n = len(t)
    named = np.zeros(z.shape, dtype=bool)
    alarm = np.zeros(n, dtype=bool)
    err = np.full(n, np.nan)
    for k in range(n):
        out = est.step(float(s1.t_s[k]), z[k], float(inp.known[k, 0]))
        named[k, list(out.attacked)] = True
        alarm[k] = out.alarm
        err[k] = float(np.linalg.norm(out.position_m[:2] - s1.truth_ned_m[k, :2]))
    scored = t >= 21.0
    res = {"rmse": float(np.sqrt(np.nanmean(err[scored] ** 2))), "max": float(np.nanmax(err[scored]))}
    if attack is None:
        honest, al = named[scored].any(axis=1), alarm[scored]
        hours = float(t[scored][-1] - t[scored][0]) / 3600.0
        res.update(named=float(honest.mean()), alarm=float(al.mean()), named_run=_events(honest),
                   alarm_run=_events(al), named_h=_events(honest) / hours, alarm_h=_events(al) / hours)  # fmt: skip
    elif attack == "bias":
        hit = scored & on
        res["recall"] = float(named[hit][:, list(LINKS)].all(axis=1).mean())
    else:
        first = [np.flatnonzero(on & named[:, link]) for link in LINKS]
        res["ramp_m"] = max(float(ramp_mps * (t[f[0]] - ONSET_S)) if f.size else np.inf for f in first)
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("recordings", nargs="+", type=Path, help="folders written by lias_planar_uwb.py convert")
    ap.add_argument("--estimators", default="secekf,secopt,recap,rarse,l1")
    ap.add_argument("--fixed-offsets", action="store_true", help="the window's offsets for the whole run")
    ap.add_argument("--ramp-mps", type=float, default=0.1, help="the ramp's rate (m/s)")
    args = ap.parse_args(argv)
    params = {noise.TRACK_PARAM: False} if args.fixed_offsets else {}
    print("| recording | estimator | clean RMSE / max [m] | honest link named: per step, per run, per hour "
          "| alarms: per step, per run, per hour | +1.5 m on 11, 14: both named on attacked steps, RMSE [m] "
          f"| {args.ramp_mps:g} m/s ramp on 11, 14: named at [m] |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for folder in args.recordings:
        scenario = load_scenario(folder / "scenario.yaml")
        rec = load_recording(scenario, ranges=folder / "ranges.csv", truth=folder / "truth.csv", rate_hz=10.0)
        inp = _inputs(scenario, rec.streams, None, 2)
        for name in args.estimators.split(","):
            c, b, r = (run(inp, name, a, dict(params), args.ramp_mps) for a in (None, "bias", "ramp"))
            print(f"| {folder.name} | {name} | {c['rmse']:.3f} / {c['max']:.2f} "
                  f"| {c['named']:.3f}, {c['named_run']}, {c['named_h']:.0f}/h "
                  f"| {c['alarm']:.3f}, {c['alarm_run']}, {c['alarm_h']:.0f}/h "
                  f"| {b['recall']:.3f}, {b['rmse']:.3f} | {r['ramp_m']:.2f} |", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
