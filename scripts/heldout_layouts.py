"""Write the held-out studies of issue 26: random anchor layouts nobody tuned on.

    .venv/bin/python scripts/heldout_layouts.py --layouts 3 --draw-seed 2026   # writes studies/heldout-*.yaml
    secuav-study run studies/heldout-1.yaml --out out/heldout-1
    .venv/bin/python scripts/paired_table.py out/heldout-1 --metric rmse_m valid_max_error_m

Each layout: eight anchors drawn uniformly over an 8 x 8 m area (at least 1.5 m apart) at heights
drawn from 0.5, 1 and 2.5 m, a vehicle holding, at 2.5 m, the point half way from the anchors'
centroid to a random point of their box; the
attacked links, the offsets and the onset (0 s: before the filters converge, 8 s: after) drawn
too. Everything is drawn once from ``--draw-seed`` and frozen in the files (so the files, not the
script, are the protocol); the flight seeds are 200-204, disjoint from the 0-19 the settings were
chosen on. The estimators run with their defaults, ``s`` from the layout's geometry
(``estimators/observability.py``); a layout supporting s = 0 is drawn again.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import yaml

from estimators.scenario_models import anchor_model
from secuav_common.scenario import parse_scenario

ROOT = Path(__file__).resolve().parent.parent
HEIGHTS_M = (0.5, 1.0, 2.5)
SEEDS = [200, 201, 202, 203, 204]


def _layout(rng: np.random.Generator) -> np.ndarray:
    while True:
        xy = rng.uniform(0.0, 8.0, size=(8, 2))
        gaps = np.linalg.norm(xy[:, None] - xy[None], axis=-1) + 10 * np.eye(8)
        if gaps.min() >= 1.5:
            return np.column_stack([xy, -rng.choice(HEIGHTS_M, size=8)])


def _inside(anchors: np.ndarray, rng: np.random.Generator) -> tuple[float, float]:
    lo, hi = anchors[:, :2].min(axis=0), anchors[:, :2].max(axis=0)
    mid = anchors[:, :2].mean(axis=0)
    point = mid + 0.5 * (rng.uniform(lo, hi) - mid)  # half way from the centroid toward a random point
    return round(float(point[0]), 2), round(float(point[1]), 2)


def scenario_doc(name: str, anchors: np.ndarray, hold: tuple[float, float]) -> dict:
    return {
        "name": name,
        "description": f"Held-out random layout {name} (scripts/heldout_layouts.py).",
        "seed": 2,
        "duration_s": 30,
        "world": {"anchors": [{"id": i, "pos_ned_m": [round(float(c), 2) for c in a]} for i, a in enumerate(anchors)]},
        "vehicles": [{
            "sysid": 1, "name": "uav1",
            "start": {"pos_ned_m": [hold[0], hold[1], 0.0], "yaw_deg": 0},
            "target": {"kind": "hold", "pos_ned_m": [hold[0], hold[1], -2.5]},
            "sensors": {
                "rangefinders": [{"id": 0, "type": "laser", "orientation": "down", "min_m": 0.05, "max_m": 40,
                                  "noise_std_m": 0.02, "rate_hz": 20}],
                "uwb": {"anchors": "all", "noise_std_m": 0.10, "rate_hz": 10},
                "gps": {"horizontal_std_m": 0.05, "vertical_std_m": 0.08, "rate_hz": 10},
            },
        }],
    }  # fmt: skip


def study_doc(k: int, scenario_file: str, rng: np.random.Generator) -> dict:
    links = [int(10 + i) for i in rng.choice(8, size=3, replace=False)]
    onsets = [0.0, 8.0]
    return {
        "name": f"heldout-{k}",
        "description": "Issue 26 held-out protocol: a random layout, attacked links and onsets, seeds 200-204.",
        "mode": "offline",
        "scenario": scenario_file,
        "duration_s": 30,
        "legs": ["hover", "moving"],
        "estimators": ["ekf", "secekf", "secopt", "recap", "rarse"],
        "seeds": SEEDS,
        "attacks": [
            "none",
            {"profile": "type-a", "params": {"links": [links[:2]], "offset_m": [round(float(rng.uniform(0.3, 1.5)), 2)],
                                              "start_s": onsets}},
            {"profile": "anchors-relay", "params": {"links": [list(links)], "excess_m": [0.3, 0.5],
                                                    "start_s": list(onsets)}},
            {"profile": "anchors-ramp", "params": {"links": [list(links)], "rate_per_s": [0.01], "start_s": [5.0]}},
        ],
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--layouts", type=int, default=3)
    ap.add_argument("--draw-seed", type=int, default=2026)
    ap.add_argument("--out", type=Path, default=ROOT / "studies")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.draw_seed)
    (args.out / "scenarios").mkdir(parents=True, exist_ok=True)
    k = 0
    while k < args.layouts:
        anchors = _layout(rng)
        name = f"heldout{k + 1}"
        doc = scenario_doc(name, anchors, _inside(anchors, rng))
        text = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=110)
        support = anchor_model(parse_scenario(text, name)).support()
        if support.s_max == 0:
            continue
        k += 1
        header = f"# Drawn by scripts/heldout_layouts.py --draw-seed {args.draw_seed}; s_max = {support.s_max}.\n"
        (args.out / "scenarios" / f"{name}.yaml").write_text(header + text)
        study = study_doc(k, f"scenarios/{name}.yaml", rng)
        dumped = yaml.safe_dump(study, sort_keys=False, default_flow_style=None, width=110)
        (args.out / f"heldout-{k}.yaml").write_text(header + dumped)
        print(f"studies/heldout-{k}.yaml: s_max {support.s_max} {support.reason}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
