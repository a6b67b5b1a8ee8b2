"""Decode the LIAS-CUHKSZ planar UWB dataset into SecUAV's recorded-ranges format, and fit its noise.

Dataset: "Efficient Planar Pose Estimation via UWB Measurements" (Jiang et al., ICRA 2023), folder
``Planar_Dataset/Dynamic`` of https://github.com/LIAS-CUHKSZ/Efficient-Pose-Estimation-via-UWB-measurements
(MIT licence, commit ``cabd39232cb855d3c1160ed16692034f4d41a092``). A trolley carrying three UWB tags
moves among eight two-way-ranging anchors while a motion-capture system tracks it. The data are not
bundled with SecUAV: this script downloads them (where the machine is online) or reads a local copy.

Two CSV files per run (``fast``, ``mid``, ``slow``):

- ``UWB_dynamic_exp_<run>.csv``: no header; column 1 a wall-clock stamp ``YYYY-MM-DD H:MM:SS.fff``,
  columns 2-25 the ranges in metres, anchor-major (a0-t0, a0-t1, a0-t2, a1-t0, ...).
- ``motion_capture_dynamic_exp_<run>.csv``: one header line, then the stamp, the rigid body's
  centroid x, y, z (metres) and its attitude quaternion (w, x, y, z).

The tags sit at fixed offsets in the body frame (``TAG_OFFSETS_M``, from the dataset's README); the
motion-capture body frame has z pointing down, so the README's y offsets enter with their sign
flipped (:data:`BODY_Y_SIGN`; measured: the median absolute range residual is 0.046 m this way
against 0.15-0.25 m for the other readings of the frame). SecUAV's frame is NED: north = y,
east = x, down = -z of the dataset (a proper rotation of its right-handed, z-up frame).

    python scripts/datasets/lias_planar_uwb.py convert --run fast --tag 0 --out out/lias-fast
    python scripts/datasets/lias_planar_uwb.py convert --source DIR --run mid --out out/lias-mid
    python scripts/datasets/lias_planar_uwb.py fit --source DIR --runs fast,mid

``convert`` writes ``ranges.csv`` and ``truth.csv`` (docs/recorded-ranges.md) and ``scenario.yaml``
(the anchors, the vehicle as sysid 1, the dataset's provenance in its description), ready for
``secuav-eval --scenario OUT/scenario.yaml --ranges OUT/ranges.csv --truth OUT/truth.csv``.
``fit`` prints the noise parameters of every anchor-tag link as JSON (what the ``uwb-lias-planar``
noise preset holds, see docs/datasets.md).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import urllib.request
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared fitting module beside this script
from converter_cli import converter_parser, print_fit
from uwb_fit import fit_noise as fit_noise  # the fit, also from this module (as its tests call it)
from uwb_fit import sample_last

NAME = "LIAS-CUHKSZ planar UWB dataset (Jiang et al., ICRA 2023), Planar_Dataset/Dynamic"
REPO_URL = "https://github.com/LIAS-CUHKSZ/Efficient-Pose-Estimation-via-UWB-measurements"
COMMIT = "cabd39232cb855d3c1160ed16692034f4d41a092"
LICENCE = "MIT"
RAW_URL = f"https://raw.githubusercontent.com/LIAS-CUHKSZ/Efficient-Pose-Estimation-via-UWB-measurements/{COMMIT}"
FOLDER = "Planar_Dataset/Dynamic"
RUNS = ("fast", "mid", "slow")

# Anchor positions in the dataset's frame (x, y, z metres), from its README.
ANCHORS_M = np.array(
    [
        [-3.4203, 3.0053, 1.0442],
        [0.0016, 3.0110, 1.0446],
        [3.6056, 2.9795, 1.0463],
        [3.6011, -0.0008, 1.0422],
        [3.5674, -3.0087, 1.0443],
        [-0.0072, -2.9652, 1.0444],
        [-3.4673, -2.9587, 1.0445],
        [-3.4858, -0.0098, 1.0457],
    ]
)
# The three tags in the rigid body's frame (x, y, z metres), from its README.
TAG_OFFSETS_M = np.array([[-0.0689, -0.1423, 0.0011], [-0.0750, 0.1402, 0.0016], [0.2034, 0.1451, -0.0008]])
BODY_Y_SIGN = -1.0
N_TAGS = 3
N_ANCHORS = 8
STAMP = "%Y-%m-%d %H:%M:%S.%f"


class DatasetError(ValueError):
    """A file of the dataset that does not parse: the message names the file, line and value."""


@dataclass(frozen=True)
class Recording:
    """One run, decoded: UWB rows and motion capture, on one clock (seconds since the first UWB row)."""

    t_uwb_s: np.ndarray  # (N,)
    ranges_m: np.ndarray  # (N, 8, 3) anchor x tag; NaN = empty cell
    t_mocap_s: np.ndarray  # (M,)
    centroid_m: np.ndarray  # (M, 3) dataset frame
    quat_wxyz: np.ndarray  # (M, 4)
    epoch_s: float  # wall-clock time of t = 0 (POSIX seconds, the stamps' local time read as UTC)


def _stamp(text: str, path: Path, line: int) -> float:
    try:
        # Read as UTC whatever this machine's zone: only differences are used, and no zone shifts them.
        return datetime.strptime(text.strip(), STAMP).replace(tzinfo=UTC).timestamp()
    except ValueError:
        raise DatasetError(f"{path}: line {line}: time {text!r} is not {STAMP}") from None


def _floats(cells: list[str], path: Path, line: int) -> list[float]:
    out = []
    for c in cells:
        c = c.strip()
        if not c:
            out.append(math.nan)
            continue
        try:
            out.append(float(c))
        except ValueError:
            raise DatasetError(f"{path}: line {line}: value {c!r} is not a number") from None
    return out


def read_uwb(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(stamps, (N, 8, 3) ranges) of a UWB file; an empty cell is NaN."""
    stamps, rows = [], []
    with path.open(newline="") as fh:
        for line, rec in enumerate(csv.reader(fh), start=1):
            if not rec:
                continue
            if len(rec) != 1 + N_ANCHORS * N_TAGS:
                raise DatasetError(f"{path}: line {line}: {len(rec)} columns, expected {1 + N_ANCHORS * N_TAGS}")
            stamps.append(_stamp(rec[0], path, line))
            rows.append(_floats(rec[1:], path, line))
    if not rows:
        raise DatasetError(f"{path}: no UWB rows")
    return np.array(stamps), np.array(rows).reshape(-1, N_ANCHORS, N_TAGS)


def read_mocap(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(stamps, (M, 3) centroid, (M, 4) quaternion w, x, y, z) of a motion-capture file."""
    stamps, rows = [], []
    with path.open(newline="") as fh:
        for line, rec in enumerate(csv.reader(fh), start=1):
            if not rec or (line == 1 and rec[0].strip().lower() == "time"):
                continue
            if len(rec) < 8:
                raise DatasetError(f"{path}: line {line}: {len(rec)} columns, expected 8")
            stamps.append(_stamp(rec[0], path, line))
            rows.append(_floats(rec[1:8], path, line))
    if not rows:
        raise DatasetError(f"{path}: no motion-capture rows")
    arr = np.array(rows)
    return np.array(stamps), arr[:, :3], arr[:, 3:7]


def read_run(folder: Path, run: str) -> Recording:
    t_u, ranges = read_uwb(folder / f"UWB_dynamic_exp_{run}.csv")
    t_m, centroid, quat = read_mocap(folder / f"motion_capture_dynamic_exp_{run}.csv")
    t0 = float(t_u[0])
    return Recording(t_u - t0, ranges, t_m - t0, centroid, quat, t0)


def rotation(quat_wxyz: np.ndarray) -> np.ndarray:
    """(M, 3, 3) body-to-world rotations of unit quaternions (w, x, y, z)."""
    q = quat_wxyz / np.linalg.norm(quat_wxyz, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=1,
    )


def tag_positions(rec: Recording, tag: int) -> np.ndarray:
    """(M, 3) the tag's position in the dataset frame at the motion-capture stamps."""
    offset = TAG_OFFSETS_M[tag] * np.array([1.0, BODY_Y_SIGN, 1.0])
    return rec.centroid_m + np.einsum("nij,j->ni", rotation(rec.quat_wxyz), offset)


def at_uwb_times(rec: Recording, pos_m: np.ndarray, lag_s: float = 0.0) -> np.ndarray:
    """Positions interpolated at the UWB stamps (minus ``lag_s``); NaN outside the capture."""
    t = rec.t_uwb_s - lag_s
    return np.column_stack([np.interp(t, rec.t_mocap_s, pos_m[:, c], left=np.nan, right=np.nan) for c in range(3)])


def range_errors(rec: Recording, lag_s: float = 0.0) -> np.ndarray:
    """(N, 8, 3) measured minus true range per anchor and tag."""
    out = np.full(rec.ranges_m.shape, np.nan)
    for tag in range(N_TAGS):
        pos = at_uwb_times(rec, tag_positions(rec, tag), lag_s)
        for a in range(N_ANCHORS):
            out[:, a, tag] = rec.ranges_m[:, a, tag] - np.linalg.norm(pos - ANCHORS_M[a], axis=1)
    return out


def to_ned(xyz_m: np.ndarray) -> np.ndarray:
    """Dataset (x, y, z up) -> NED (north = y, east = x, down = -z)."""
    xyz = np.asarray(xyz_m, dtype=float)
    return np.stack([xyz[..., 1], xyz[..., 0], -xyz[..., 2]], axis=-1)


# ---------------------------------------------------------------- convert


def write_recording(rec: Recording, tag: int, out: Path, run: str, sysid: int = 1) -> dict[str, int]:
    """``ranges.csv``, ``truth.csv`` and ``scenario.yaml`` for one tag as the vehicle; returns row counts."""
    out.mkdir(parents=True, exist_ok=True)
    n_ranges = 0
    with (out / "ranges.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "sensor_id", "range_m"])
        for k, t in enumerate(rec.t_uwb_s):
            for a in range(N_ANCHORS):
                value = rec.ranges_m[k, a, tag]
                w.writerow([f"{t:.3f}", sysid, 10 + a, "" if math.isnan(value) else f"{value:.3f}"])
                n_ranges += 1
    ned = to_ned(tag_positions(rec, tag))
    with (out / "truth.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "north_m", "east_m", "down_m"])
        for t, p in zip(rec.t_mocap_s, ned, strict=True):
            if np.isfinite(p).all():
                w.writerow([f"{t:.4f}", sysid, f"{p[0]:.4f}", f"{p[1]:.4f}", f"{p[2]:.4f}"])
    (out / "scenario.yaml").write_text(scenario_yaml(rec, tag, run, sysid, float(np.nanmedian(ned[:, 2]))))
    return {"ranges": n_ranges, "truth": int(np.isfinite(ned).all(axis=1).sum())}


def scenario_yaml(rec: Recording, tag: int, run: str, sysid: int, down_m: float) -> str:
    anchors = to_ned(ANCHORS_M)
    lines = [
        f"# Decoded by scripts/datasets/lias_planar_uwb.py from {NAME}, run {run!r}, tag {tag}.",
        f"# Source: {REPO_URL} at commit {COMMIT} ({LICENCE} licence).",
        f"name: lias-planar-{run}-tag{tag}",
        "description: >-",
        f"  Recorded two-way UWB ranges of tag {tag} ({run} run) to eight anchors, motion-capture truth;",
        f"  {NAME}, {REPO_URL} @ {COMMIT[:12]}, {LICENCE}.",
        f"duration_s: {float(rec.t_uwb_s[-1]):.1f}",
        "world:",
        "  anchors:",
    ]
    for a, p in enumerate(anchors):
        lines.append(f"    - {{id: {a}, pos_ned_m: [{p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}]}}")
    lines += [
        "vehicles:",
        f"  - sysid: {sysid}",
        f"    name: tag{tag}",
        "    start: {pos_ned_m: [0.0, 0.0, 0.0], yaw_deg: 0}",
        f"    target: {{kind: hold, pos_ned_m: [0.0, 0.0, {down_m:.4f}]}}",
        "    sensors:",
        "      uwb: {anchors: all, noise_std_m: 0.07, rate_hz: 100, noise: {preset: uwb-lias-planar}}",
        "      gps: {enabled: false}",
        "",
    ]
    return "\n".join(lines)


# ---------------------------------------------------------------- fit


def best_lag_s(rec: Recording, lags_s: np.ndarray) -> float:
    """The clock offset (UWB minus motion capture) that makes the residuals tightest (median |r - median|)."""

    def spread(lag: float) -> float:
        e = range_errors(rec, lag)
        return float(np.nanmean(np.nanmedian(np.abs(e - np.nanmedian(e, axis=0)), axis=0)))

    return float(min(lags_s, key=spread))


def link_series(rec: Recording, lag_s: float, rate_hz: float = 10.0) -> np.ndarray:
    """(K, 24) errors per link resampled at ``rate_hz`` (the last UWB row at or before each tick)."""
    e = range_errors(rec, lag_s).reshape(len(rec.t_uwb_s), -1)
    return sample_last(rec.t_uwb_s, e, np.arange(rec.t_uwb_s[0], rec.t_uwb_s[-1], 1.0 / rate_hz))


# ---------------------------------------------------------------- cli


def fetch(folder: Path, run: str) -> None:
    """Download one run's two files from the dataset's repository at the pinned commit."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in (f"UWB_dynamic_exp_{run}.csv", f"motion_capture_dynamic_exp_{run}.csv"):
        target = folder / name
        if not target.exists():
            with urllib.request.urlopen(f"{RAW_URL}/{FOLDER}/{name}", timeout=60) as resp:
                target.write_bytes(resp.read())


def _source(args: argparse.Namespace, run: str) -> Path:
    if args.source is not None:
        return args.source
    fetch(args.cache, run)
    return args.cache


def main(argv: list[str] | None = None) -> int:
    p, conv, fit = converter_parser(
        __doc__.split("\n")[0], "a local copy of Planar_Dataset/Dynamic", Path("out/datasets/lias-planar")
    )
    conv.add_argument("--run", choices=RUNS, default="fast")
    conv.add_argument("--tag", type=int, choices=range(N_TAGS), default=0)
    conv.add_argument("--out", type=Path, required=True)
    fit.add_argument("--runs", default="fast,mid", help="comma-separated runs")
    args = p.parse_args(argv)
    try:
        if args.cmd == "convert":
            rec = read_run(_source(args, args.run), args.run)
            counts = write_recording(rec, args.tag, args.out, args.run)
            print(
                f"wrote {args.out}/ranges.csv ({counts['ranges']} rows), truth.csv ({counts['truth']}), scenario.yaml"
            )
            return 0
        series, lags = [], {}
        for run in [r.strip() for r in args.runs.split(",") if r.strip()]:
            rec = read_run(_source(args, run), run)
            lags[run] = best_lag_s(rec, np.round(np.arange(-0.3, 0.301, 0.02), 3))
            series.append(link_series(rec, lags[run]))
        result = {"dataset": NAME, "url": REPO_URL, "commit": COMMIT, "licence": LICENCE, "clock_lag_s": lags}
        return print_fit(result, series)
    except (DatasetError, OSError) as err:
        print(f"lias_planar_uwb: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
