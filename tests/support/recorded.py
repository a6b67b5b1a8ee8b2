"""Synthetic recorded ranges for the evaluation tests: anchors8 ranges with per-link offsets, written as
docs/recorded-ranges.md says (``write_ranges``)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from secuav_common.scenario import load_scenario

SIGMA = 0.1
OFFSETS = np.array([0.10, 0.20, 0.05, 0.15, 0.25, 0.0, 0.12, 0.30])  # per anchor link, read long by this


def path_at(t: np.ndarray) -> np.ndarray:
    return np.column_stack([2.5 + np.cos(0.2 * t), 2.5 + np.sin(0.2 * t), np.full(t.shape, -2.5)])


def write_ranges(folder: Path, seconds: float, poll_hz: float, round_robin: bool) -> tuple[Path, Path]:
    """anchors8 ranges with per-link offsets. ``round_robin``: one anchor per poll (each link at poll_hz / 8, as a
    tag that polls the anchors one at a time); else every anchor at every poll."""
    anchors = load_scenario("anchors8").anchor_positions()
    rng = np.random.default_rng(3)
    t = np.arange(0.0, seconds, 1.0 / poll_hz)
    pos = path_at(t)
    ranges, truth = folder / "ranges.csv", folder / "truth.csv"
    with ranges.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "sensor_id", "range_m"])
        for k, tk in enumerate(t):
            for a in [k % 8] if round_robin else sorted(anchors):
                value = float(np.linalg.norm(pos[k] - np.array(anchors[a]))) + OFFSETS[a] + rng.normal(0.0, SIGMA)
                w.writerow([f"{tk:.3f}", 1, 10 + a, f"{value:.4f}"])
    with truth.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "north_m", "east_m", "down_m"])
        for tk, p in zip(t, pos, strict=True):
            w.writerow([f"{tk:.3f}", 1, *(f"{v:.4f}" for v in p)])
    return ranges, truth


def write_polled(folder: Path, t: np.ndarray, pos: np.ndarray, sigma: float, seed: int,
                 t_format: str = ".4f") -> tuple[Path, Path]:  # fmt: skip
    """``ranges.csv`` and ``truth.csv`` of a tag that polls anchors8's eight anchors one at a time (reading k from
    anchor k mod 8, so each link at a poll rate / 8 and no two readings at one time), at positions ``pos[k]``
    (NED, one row per time of ``t``), with Gaussian noise ``sigma`` drawn from ``seed``."""
    anchors = load_scenario("anchors8").anchor_positions()
    rng = np.random.default_rng(seed)
    ranges, truth = folder / "ranges.csv", folder / "truth.csv"
    with ranges.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sensor_id", "range_m"])
        for k, tk in enumerate(t):
            a = k % 8
            reading = np.linalg.norm(pos[k] - anchors[a]) + rng.normal(0, sigma)
            w.writerow([f"{tk:{t_format}}", 10 + a, f"{reading:.4f}"])
    with truth.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "north_m", "east_m", "down_m"])
        for tk, pk in zip(t, pos, strict=True):
            w.writerow([f"{tk:{t_format}}", 1, *(f"{v:.4f}" for v in pk)])
    return ranges, truth
