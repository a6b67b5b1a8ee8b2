"""``report.json`` and the plots of a demo run (DESIGN.md, "Evaluation output")."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only; no display on a server or in CI
import matplotlib.pyplot as plt


def write_report(out: Path, demo: str, settings: dict[str, Any], results: list[dict[str, Any]]) -> Path:
    """Figures without the long series go to ``report.json``; the series stay in each case's folder."""
    out.mkdir(parents=True, exist_ok=True)
    for r in results:
        (out / r["case"]).mkdir(parents=True, exist_ok=True)
        (out / r["case"] / "series.json").write_text(json.dumps(r["series"]), encoding="utf-8")
    cases = {r["case"]: {k: v for k, v in r.items() if k != "series"} for r in results}
    path = out / "report.json"
    path.write_text(json.dumps({"demo": demo, "settings": settings, "cases": cases}, indent=2), encoding="utf-8")
    return path


def plot_wall_hover(out: Path, results: list[dict[str, Any]]) -> Path:
    """True distance to the wall and what the controller saw, every case on one figure."""
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for r in results:
        label = r["case"].replace("_", ", ")
        t, d = zip(*r["series"]["truth"], strict=True) if r["series"]["truth"] else ((), ())
        top.plot(t, d, label=label, linewidth=1.2)
        if r["series"]["seen"]:
            ts, ds = zip(*r["series"]["seen"], strict=True)
            bottom.plot(ts, ds, label=label, linewidth=1.0)
    target = results[0]["target_distance_m"] if results else 2.5
    for ax in (top, bottom):
        ax.axhline(target, color="k", linestyle="--", linewidth=0.8, label="target")
        ax.axvline(0.0, color="grey", linestyle=":", linewidth=0.8)
        ax.grid(True, alpha=0.3)
    top.axhline(0.0, color="firebrick", linewidth=1.5, label="wall")
    top.set_ylabel("true distance to wall [m]")
    bottom.set_ylabel("distance the controller used [m]")
    bottom.set_xlabel("time from attack onset (start of scoring) [s]")
    top.legend(fontsize=8, loc="best")
    top.set_title("SecUAV wall hover (seed Fig. A.5): attack and secure stage on/off")
    fig.tight_layout()
    path = out / "wall_hover.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
