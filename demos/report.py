"""``report.json`` and the plots of a demo run (docs/interfaces.md#output-files)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only; no display on a server or in CI
import matplotlib.pyplot as plt
from matplotlib.figure import Figure


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
    "rangefinder-feed": [  # the autopilot holds on its own estimate: docs/ardupilot.md
        ("truth", "true height above ground [m]", 5.0),
        ("seen", "the autopilot's own altitude [m]", 5.0),
    ],
    "vision": [  # on PX4 SIH: docs/px4.md
        ("drift", "true distance from the hold point [m] (SIH)", 0.0),
        ("estimate_error", "PX4's position estimate minus truth [m]", 0.0),
    ],
    "command-tamper": [  # docs/ardupilot.md: time from the takeoff command
        ("height", "true height above home [m]", 5.0),
        ("to_sent", "true distance to the waypoint sent [m]", 0.0),
    ],
}
XLABEL = {"command-tamper": "time from the takeoff command [s]"}
# the true-distance panel's zero line
SURFACE = {"wall-hover": "wall", "height-hold": "ground", "rangefinder-feed": "ground"}
SURFACE_COLOUR = "firebrick"
# One colour per case, none of them the surface's red: secure on is blue (attacked) or green (clean).
CASE_COLOURS = {
    "attack-off_secure-off": "tab:gray", "attack-off_secure-on": "tab:green",
    "attack-on_secure-off": "tab:orange", "attack-on_secure-on": "tab:blue",
}  # fmt: skip
CAPTION = {
    "wall-hover": "x: the vehicle touched the wall (the simulator's contact flag). The controller flies on the mean "
    "of its five forward sensors; with two of them ramped away (the default attack, wall-spoof-two) it keeps "
    "that mean at 2.5 m while closing on the wall. The step in the lower panel at about 29-34 s after the onset: "
    "the vehicle touches the wall, below the radar's 0.3 m minimum, so the radar stops reporting (the mean jumps up), "
    "then the spoofed sonar passes its 7 m maximum and drops out too (the mean falls back).",
}


def plot(out: Path, demo: str, results: list[dict[str, Any]]) -> Path:
    """Every case of the run on one figure, time from the attack onset (start of scoring)."""
    fig = figure(demo, results)
    path = out / f"{demo.replace('-', '_')}.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def figure(demo: str, results: list[dict[str, Any]]) -> Figure:
    """The figure :func:`plot` saves: a panel per series, a line per case, an x where a case collided."""
    panels = PANELS[demo]
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 3.5 * len(panels)), sharex=True, squeeze=False)
    for ax, (key, label, ref) in zip(axes[:, 0], panels, strict=True):
        marked = False
        for r in results:
            series = r["series"].get(key) or []
            if not series:
                continue
            colour = CASE_COLOURS.get(r["case"])
            t, v = zip(*((p[0], p[1]) for p in series), strict=True)
            ax.plot(t, v, label=r["case"].replace("_", ", "), linewidth=1.1, color=colour)
            hit = r.get("collided_at_s")
            if key == "truth" and hit is not None:  # where the true line meets the surface
                y = min(series, key=lambda p: abs(p[0] - hit))[1]
                ax.plot([hit], [y], marker="X", markersize=11, color=colour or "k", markeredgecolor="k",
                        linestyle="none", label=None if marked else "collision", zorder=5)  # fmt: skip
                marked = True
        if ref is not None:
            ax.axhline(ref, color="k", linestyle="--", linewidth=0.8, label="target")
        if demo in SURFACE and key == "truth":
            ax.axhline(0.0, color=SURFACE_COLOUR, linewidth=1.5, label=SURFACE[demo])
        ax.axvline(0.0, color="grey", linestyle=":", linewidth=0.8)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="best")
    axes[0, 0].set_title(f"SecUAV {demo}: attack and secure stage on/off")
    axes[-1, 0].set_xlabel(XLABEL.get(demo, "time from attack onset (start of scoring) [s]"))
    if demo in CAPTION:
        fig.text(0.01, 0.005, CAPTION[demo], fontsize=7.5, wrap=True, va="bottom")
        fig.tight_layout(rect=(0, 0.07, 1, 1))
    else:
        fig.tight_layout()
    return fig
