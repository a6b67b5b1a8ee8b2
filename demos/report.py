"""``report.json`` and the plots of a demo run (docs/interfaces.md#output-files)."""

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


# demo -> panels: (series key, y label, reference line or None)
PANELS: dict[str, list[tuple[str, str, float | None]]] = {
    "wall-hover": [("truth", "true distance to wall [m]", 2.5), ("seen", "distance the controller used [m]", 2.5)],
    "localise": [("error", "true distance from (2.5, 2.5) [m]", 0.0)],
    "formation": [("range", "true distance uav1-uav2 [m]", 3.0)],
    "height-hold": [  # on ArduCopter SITL: docs/ardupilot.md
        ("truth", "true height above ground [m] (SITL)", 5.0),
        ("seen", "height the controller used [m]", 5.0),
    ],
    "command-tamper": [  # docs/ardupilot.md: time from the takeoff command
        ("height", "true height above home [m]", 5.0),
        ("to_sent", "true distance to the waypoint sent [m]", 0.0),
    ],
}
XLABEL = {"command-tamper": "time from the takeoff command [s]"}
SURFACE = {"wall-hover": "wall", "height-hold": "ground"}  # the true-distance panel's zero line


def plot(out: Path, demo: str, results: list[dict[str, Any]]) -> Path:
    """Every case of the run on one figure, time from the attack onset (start of scoring)."""
    panels = PANELS[demo]
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 3.5 * len(panels)), sharex=True, squeeze=False)
    for ax, (key, label, ref) in zip(axes[:, 0], panels, strict=True):
        for r in results:
            series = r["series"].get(key) or []
            if series:
                t, v = zip(*((p[0], p[1]) for p in series), strict=True)
                ax.plot(t, v, label=r["case"].replace("_", ", "), linewidth=1.1)
        if ref is not None:
            ax.axhline(ref, color="k", linestyle="--", linewidth=0.8, label="target")
        if demo in SURFACE and key == "truth":
            ax.axhline(0.0, color="firebrick", linewidth=1.5, label=SURFACE[demo])
        ax.axvline(0.0, color="grey", linestyle=":", linewidth=0.8)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="best")
    axes[0, 0].set_title(f"SecUAV {demo}: attack and secure stage on/off")
    axes[-1, 0].set_xlabel(XLABEL.get(demo, "time from attack onset (start of scoring) [s]"))
    fig.tight_layout()
    path = out / f"{demo.replace('-', '_')}.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
