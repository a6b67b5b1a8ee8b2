"""Decode the Hanyang outdoor UWB dataset's dynamic runs into SecUAV's recorded-ranges format, and fit their noise.

Dataset: "Comprehensive outdoor UWB dataset: Static and dynamic measurements in LOS/NLOS environments" (ADIP
laboratory, Hanyang University), https://github.com/cucudasluv/UWB-dataset (Apache-2.0, commit
``c12599812e556324eadc763e409ea8f51098dda6``; Zenodo DOI 10.5281/zenodo.15226105). Outdoors, a tag (Decawave
DWM1001, the ``/dwm1001/anchorN`` topics) moves at about 1 m/s up to 50 m from four anchors set up within a
5.2 x 1.7 m box, with an RTK-GNSS reference. Not bundled with SecUAV: this script downloads the files (where the
machine is online) or reads a local copy of the repository (``--source DIR``).

Per run, ``Dynamic_measurements/{LOS,NLOS}/Trajectory_{A,B}/Case_N/`` (cases 1, 2 on trajectory A; 3, 4 on B):

- ``A3.csv``, ``A5.csv``, ``A9.csv``, ``A12.csv``: one per anchor, ``rostopic echo -p`` CSV with the columns
  ``%time, field.stamp`` (ns), ``field.id``, ``field.x, field.y, field.z`` (the anchor's position, metres, the
  local frame), ``field.distanceFromTag`` (metres), ``field.rssi``, ``field.rssi_fp``. Each anchor is read at
  about 10 Hz on its own stamps: the four links are asynchronous.
- ``trajectory.csv``: ``timestamp`` (ns), ``x, y, z``, ``heading_degrees``: the RTK-GNSS reference at 8 Hz in the
  same frame.

Decoding choices, measured (``fit`` prints the figures, docs/datasets.md tabulates them):

- **Tag height.** The reference's z stays within -0.3..+0.5 m of the ground; the ranges fit best with the tag
  :data:`TAG_HEIGHT_M` = 1 m above it, as the authors' own scoring has it (``localization_error_analysis.py``
  compares against the reference z + 1). The truth is written at that constant height.
- **Reference glitches.** A reference point more than :data:`MAX_ABS_Z_M` from the ground (the authors' own
  filter) or reached from the last kept point faster than :data:`MAX_SPEED_MPS` is dropped (a few per run). The
  stretch out to 50 m along x is real, not a glitch: the ranges read 50 m there too.
- **Clock.** Anchor stamps (``field.stamp``) and the reference share the ROS clock; t = 0 is the first anchor
  stamp of the run. A range stamped t was measured where the reference was at t - :data:`CLOCK_LAG_S` (0.2 s;
  best lag 0.15-0.2 s in all eight runs, and it halves the residual spread), so the truth is written on the
  ranges' clock, its stamps shifted by that lag.

Anchors enter in the order A3, A5, A9, A12 as scenario anchors 0-3 (wire sensor ids 10-13). SecUAV's frame is
NED: north = y, east = x, down = -z of the dataset.

    python scripts/datasets/hanyang_outdoor_uwb.py convert --env LOS --case 1 --out out/hanyang-los-1
    python scripts/datasets/hanyang_outdoor_uwb.py convert --source DIR --env NLOS --case 3 --out out/hy-nlos-3
    python scripts/datasets/hanyang_outdoor_uwb.py fit --source DIR --cases LOS:1,LOS:2,NLOS:1
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared fitting module beside this script
from converter_cli import converter_parser, print_fit
from uwb_fit import sample_last

NAME = "Comprehensive outdoor UWB dataset (ADIP lab, Hanyang University), Dynamic_measurements"
REPO_URL = "https://github.com/cucudasluv/UWB-dataset"
COMMIT = "c12599812e556324eadc763e409ea8f51098dda6"
DOI = "10.5281/zenodo.15226105"
LICENCE = "Apache-2.0"
RAW_URL = f"https://raw.githubusercontent.com/cucudasluv/UWB-dataset/{COMMIT}"
FOLDER = "Dynamic_measurements"
ENVS = ("LOS", "NLOS")
TRAJECTORY = {1: "A", 2: "A", 3: "B", 4: "B"}
ANCHOR_IDS = (3, 5, 9, 12)  # the files A3, A5, A9, A12; scenario anchors 0..3 in this order
TAG_HEIGHT_M = 1.0  # the tag above the reference's ground height (the authors' scoring; fits best, see above)
MAX_ABS_Z_M = 0.5  # a reference point further from the ground is a glitch (the authors' own filter)
MAX_SPEED_MPS = 3.0  # a reference point reached faster than this from the last kept one is a glitch
CLOCK_LAG_S = 0.2  # ranges are stamped this late against the reference (measured, see above)
AREA_MARGIN_M = 5.0  # the site's area: the reference's extent and the anchors', widened by this, whole metres
TRUTH_GAP_S = 1.0  # no truth interpolated across a longer gap in the kept reference
RANGE_COLUMNS = ("field.stamp", "field.id", "field.x", "field.y", "field.z", "field.distanceFromTag")
TRAJECTORY_COLUMNS = ("timestamp", "x", "y", "z")


class DatasetError(ValueError):
    """A file of the dataset that does not parse: the message names the file, line and value."""


@dataclass(frozen=True)
class Anchor:
    """One anchor file: its id and fixed position, and its readings (seconds since the run's first stamp)."""

    anchor_id: int
    pos_m: np.ndarray  # (3,) dataset frame
    t_s: np.ndarray  # (N,)
    range_m: np.ndarray  # (N,)


@dataclass(frozen=True)
class Run:
    """One case decoded, on one clock: the four anchors and the reference with its glitches marked."""

    env: str
    case: int
    anchors: tuple[Anchor, ...]  # in ANCHOR_IDS order
    t_ref_s: np.ndarray  # (M,)
    xyz_ref_m: np.ndarray  # (M, 3) dataset frame, the reference antenna (z near the ground)
    kept: np.ndarray  # (M,) bool: not a glitch
    epoch_ns: int  # ROS time of t = 0

    @property
    def name(self) -> str:
        return f"{self.env}/Trajectory_{TRAJECTORY[self.case]}/Case_{self.case}"


def case_dir(root: Path, env: str, case: int) -> Path:
    return root / FOLDER / env / f"Trajectory_{TRAJECTORY[case]}" / f"Case_{case}"


def _rows(path: Path, needed: tuple[str, ...]) -> tuple[list[list[float]], list[int]]:
    """The needed columns of a headed CSV as floats, with their line numbers; a bad cell names file, line, value."""
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        header = [h.strip() for h in next(reader, [])]
        missing = [c for c in needed if c not in header]
        if missing:
            raise DatasetError(f"{path}: line 1: no column {missing[0]!r} (header {','.join(header)!r})")
        cols = [header.index(c) for c in needed]
        rows, lines = [], []
        for line, rec in enumerate(reader, start=2):
            if not rec:
                continue
            if len(rec) < len(header):
                raise DatasetError(f"{path}: line {line}: {len(rec)} columns, expected {len(header)}")
            try:
                rows.append([float(rec[c]) for c in cols])
            except ValueError:
                bad = next(rec[c] for c in cols if not _is_float(rec[c]))
                raise DatasetError(f"{path}: line {line}: value {bad!r} is not a number") from None
            lines.append(line)
    if not rows:
        raise DatasetError(f"{path}: no rows")
    return rows, lines


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_anchor(path: Path) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """(anchor id, position, stamps in ns as int64, ranges) of one anchor file, rows sorted by stamp."""
    # The stamps are 19-digit nanoseconds: parsed as text to int, not through float (which keeps ~256 ns).
    stamps = []
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        header = [h.strip() for h in next(reader, [])]
        col = header.index("field.stamp") if "field.stamp" in header else None
        for line, rec in enumerate(reader, start=2):
            if rec and col is not None:
                try:
                    stamps.append(int(rec[col]))
                except ValueError:
                    raise DatasetError(f"{path}: line {line}: stamp {rec[col]!r} is not integer nanoseconds") from None
    rows, lines = _rows(path, RANGE_COLUMNS)
    arr = np.array(rows)
    ids = np.unique(arr[:, 1])
    if ids.size != 1:
        values = ", ".join(f"{v:g}" for v in ids)
        raise DatasetError(f"{path}: field.id takes {ids.size} values ({values}), expected one")
    pos = arr[0, 2:5]
    moved = np.flatnonzero(np.any(arr[:, 2:5] != pos, axis=1))
    if moved.size:
        k = int(moved[0])
        raise DatasetError(f"{path}: line {lines[k]}: anchor position {arr[k, 2:5].tolist()} differs from the "
                           f"first row's {pos.tolist()}")  # fmt: skip
    t_ns = np.array(stamps, dtype=np.int64)
    order = np.argsort(t_ns, kind="stable")
    return int(ids[0]), pos, t_ns[order], arr[order, 5]


def read_trajectory(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(stamps in ns as float, (M, 3) x, y, z) of the reference, sorted by stamp."""
    arr = np.array(_rows(path, TRAJECTORY_COLUMNS)[0])
    order = np.argsort(arr[:, 0], kind="stable")
    return arr[order, 0], arr[order, 1:4]


def glitch_free(t_s: np.ndarray, xyz_m: np.ndarray) -> np.ndarray:
    """Which reference points to keep: near the ground and reached from the last kept point at a possible speed."""
    kept = np.abs(xyz_m[:, 2]) <= MAX_ABS_Z_M
    last = None
    for k in np.flatnonzero(kept):
        if last is not None:
            dt = t_s[k] - t_s[last]
            if dt <= 0 or np.hypot(*(xyz_m[k, :2] - xyz_m[last, :2])) > MAX_SPEED_MPS * dt:
                kept[k] = False
                continue
        last = k
    return kept


def read_run(root: Path, env: str, case: int) -> Run:
    folder = case_dir(root, env, case)
    raw = []
    for want in ANCHOR_IDS:
        path = folder / f"A{want}.csv"
        anchor_id, pos, t_ns, rng = read_anchor(path)
        if anchor_id != want:
            raise DatasetError(f"{path}: field.id is {anchor_id}, expected {want}")
        raw.append((anchor_id, pos, t_ns, rng))
    epoch = int(min(r[2][0] for r in raw))
    anchors = tuple(Anchor(a, pos, (t_ns - epoch) / 1e9, rng) for a, pos, t_ns, rng in raw)
    t_ref_ns, xyz = read_trajectory(folder / "trajectory.csv")
    t_ref = (t_ref_ns - epoch) / 1e9
    return Run(env, case, anchors, t_ref, xyz, glitch_free(t_ref, xyz), epoch)


def truth_xy(run: Run, t_s: np.ndarray) -> np.ndarray:
    """(N, 2) the reference's x, y interpolated at ``t_s`` over the kept points; NaN outside and across gaps."""
    t, xy = run.t_ref_s[run.kept], run.xyz_ref_m[run.kept, :2]
    out = np.column_stack([np.interp(t_s, t, xy[:, c], left=np.nan, right=np.nan) for c in range(2)])
    k = np.clip(np.searchsorted(t, t_s), 1, len(t) - 1)
    out[(t[k] - t[k - 1]) > TRUTH_GAP_S] = np.nan
    return out


def tag_height(run: Run, t_s: np.ndarray, mode: str) -> np.ndarray:
    """The tag's height under each reading of the choices ``fit`` compares (``fixed`` is what convert writes)."""
    if mode == "fixed":
        return np.full(t_s.shape, TAG_HEIGHT_M)
    z = np.interp(t_s, run.t_ref_s[run.kept], run.xyz_ref_m[run.kept, 2])
    return {"reference": z, "reference+1": z + TAG_HEIGHT_M}[mode]


def range_errors(run: Run, height: str = "fixed", lag_s: float = CLOCK_LAG_S) -> list[np.ndarray]:
    """Per anchor: measured minus true range at its readings' times (minus ``lag_s``); NaN without truth."""
    out = []
    for a in run.anchors:
        t = a.t_s - lag_s
        pos = np.column_stack([truth_xy(run, t), tag_height(run, t, height)])
        out.append(a.range_m - np.linalg.norm(pos - a.pos_m, axis=1))
    return out


def to_ned(xyz_m: np.ndarray) -> np.ndarray:
    """Dataset (x, y, z up) -> NED (north = y, east = x, down = -z)."""
    xyz = np.asarray(xyz_m, dtype=float)
    return np.stack([xyz[..., 1], xyz[..., 0], -xyz[..., 2]], axis=-1)


# ---------------------------------------------------------------- convert


def write_recording(run: Run, out: Path, sysid: int = 1, sigma_m: float = 0.1) -> dict[str, int]:
    """``ranges.csv`` (every reading at its own time), ``truth.csv`` and ``scenario.yaml``; returns row counts."""
    out.mkdir(parents=True, exist_ok=True)
    rows = sorted(
        (float(t), 10 + k, float(r)) for k, a in enumerate(run.anchors) for t, r in zip(a.t_s, a.range_m, strict=True)
    )
    with (out / "ranges.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "sensor_id", "range_m"])
        for t, sensor, r in rows:
            w.writerow([f"{t:.4f}", sysid, sensor, "" if not math.isfinite(r) or r < 0 else f"{r:.4f}"])
    truth = 0
    with (out / "truth.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "sysid", "north_m", "east_m", "down_m"])
        for t, p in zip(run.t_ref_s[run.kept] + CLOCK_LAG_S, run.xyz_ref_m[run.kept], strict=True):
            n, e, _ = to_ned(p)
            w.writerow([f"{t:.4f}", sysid, f"{n:.4f}", f"{e:.4f}", f"{-TAG_HEIGHT_M:.4f}"])
            truth += 1
    (out / "scenario.yaml").write_text(scenario_yaml(run, sysid, sigma_m))
    return {"ranges": len(rows), "truth": truth, "dropped_reference": int((~run.kept).sum())}


def scenario_yaml(run: Run, sysid: int, sigma_m: float) -> str:
    slug = f"hanyang-{run.env.lower()}-case{run.case}"
    last = max(float(a.t_s[-1]) for a in run.anchors)
    lines = [
        f"# Decoded by scripts/datasets/hanyang_outdoor_uwb.py from {NAME}, {run.name}.",
        f"# Source: {REPO_URL} at commit {COMMIT} ({LICENCE} licence; Zenodo DOI {DOI}).",
        "# Anchors 0-3 are the dataset's A3, A5, A9, A12 (wire sensor ids 10-13).",
        f"name: {slug}",
        "description: >-",
        f"  Recorded two-way UWB ranges (Decawave DWM1001) of a tag moving outdoors ({run.env}, trajectory",
        f"  {TRAJECTORY[run.case]}, case {run.case}) to four anchors, each read on its own stamps at about 10 Hz;",
        f"  RTK-GNSS truth, tag taken {TAG_HEIGHT_M:g} m above the reference.",
        f"  {NAME},",
        f"  {REPO_URL} @ {COMMIT[:12]}, {LICENCE}, doi:{DOI}.",
        f"duration_s: {last:.1f}",
        "world:",
        "  anchors:",
    ]
    for k, a in enumerate(run.anchors):
        p = to_ned(a.pos_m)
        lines.append(f"    - {{id: {k}, pos_ned_m: [{p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}]}}")
    lo, hi = area_ne(run)
    lines += [
        "  # The site: the tag ranges far outside the anchors' box, so the estimators' admissible box is stated.",
        f"  area: {{min_ne_m: [{lo[0]:.0f}, {lo[1]:.0f}], max_ne_m: [{hi[0]:.0f}, {hi[1]:.0f}]}}",
        "vehicles:",
        f"  - sysid: {sysid}",
        "    name: tag",
        "    start: {pos_ned_m: [0.0, 0.0, 0.0], yaw_deg: 0}",
        f"    target: {{kind: hold, pos_ned_m: [0.0, 0.0, {-TAG_HEIGHT_M:.4f}]}}",
        "    sensors:",
        f"      uwb: {{anchors: all, noise_std_m: {sigma_m:.3f}, rate_hz: 10}}",
        "      gps: {enabled: false}",
        "",
    ]
    return "\n".join(lines)


def area_ne(run: Run) -> tuple[np.ndarray, np.ndarray]:
    """(north, east) corners of the site: where the reference and the anchors lie, plus AREA_MARGIN_M."""
    points = to_ned(np.vstack([run.xyz_ref_m[run.kept], *(a.pos_m for a in run.anchors)]))[:, :2]
    return np.floor(points.min(axis=0) - AREA_MARGIN_M), np.ceil(points.max(axis=0) + AREA_MARGIN_M)


# ---------------------------------------------------------------- fit


def _spread(errors: list[np.ndarray]) -> tuple[float, float]:
    """(median, 1.4826 x MAD) of all readings' errors pooled over the anchors."""
    e = np.concatenate(errors)
    e = e[np.isfinite(e)]
    med = float(np.median(e))
    return med, float(1.4826 * np.median(np.abs(e - med)))


def best_lag_s(run: Run, lags_s: np.ndarray) -> float:
    """The clock offset (anchors minus reference) that makes the pooled residuals tightest."""
    return float(min(lags_s, key=lambda lag: _spread(range_errors(run, "fixed", lag))[1]))


def link_series(run: Run, lag_s: float, rate_hz: float = 10.0) -> np.ndarray:
    """(K, 4) errors per anchor on a ``rate_hz`` grid: each link's last reading at most 1.5 ticks old, else NaN."""
    errors = range_errors(run, "fixed", lag_s)
    start = min(float(a.t_s[0]) for a in run.anchors)
    end = max(float(a.t_s[-1]) for a in run.anchors)
    ticks = np.arange(start, end, 1.0 / rate_hz)
    return np.column_stack(
        [sample_last(a.t_s, e, ticks, 1.5 / rate_hz) for a, e in zip(run.anchors, errors, strict=True)]
    )


def describe(run: Run, lag_s: float = CLOCK_LAG_S) -> dict[str, object]:
    """What a run holds and how well each tag-height choice and clock lag fits it (convert: ``fixed``, 0.2 s)."""
    dist = np.linalg.norm(run.xyz_ref_m[run.kept, :2], axis=1)
    speed = np.linalg.norm(np.diff(run.xyz_ref_m[run.kept, :2], axis=0), axis=1) / np.diff(run.t_ref_s[run.kept])
    heights = {}
    for mode in ("fixed", "reference", "reference+1"):
        med, sig = _spread(range_errors(run, mode, lag_s))
        heights[mode] = {"median_m": round(med, 4), "mad_sigma_m": round(sig, 4)}
    return {
        "readings": {f"A{a.anchor_id}": int(a.t_s.size) for a in run.anchors},
        "rate_hz": {f"A{a.anchor_id}": round(float(1.0 / np.median(np.diff(a.t_s))), 2) for a in run.anchors},
        "duration_s": round(max(float(a.t_s[-1]) for a in run.anchors), 1),
        "reference_points": int(run.kept.size),
        "reference_dropped": int((~run.kept).sum()),
        "median_speed_mps": round(float(np.median(speed)), 2),
        "distance_from_origin_m": [round(float(dist.min()), 1), round(float(dist.max()), 1)],
        "tag_height_choices": heights,
        "mad_sigma_m_at_lag_s": {f"{lag:g}": round(_spread(range_errors(run, "fixed", lag))[1], 4)
                                 for lag in (0.0, 0.1, 0.2, 0.3)},
    }


# ---------------------------------------------------------------- cli


def fetch(root: Path, env: str, case: int) -> None:
    """Download one case's five files from the dataset's repository at the pinned commit."""
    folder = case_dir(root, env, case)
    folder.mkdir(parents=True, exist_ok=True)
    rel = folder.relative_to(root).as_posix()
    for name in [*(f"A{a}.csv" for a in ANCHOR_IDS), "trajectory.csv"]:
        target = folder / name
        if not target.exists():
            with urllib.request.urlopen(f"{RAW_URL}/{rel}/{name}", timeout=60) as resp:
                target.write_bytes(resp.read())


def _source(args: argparse.Namespace, env: str, case: int) -> Path:
    if args.source is not None:
        return args.source
    fetch(args.cache, env, case)
    return args.cache


def _cases(text: str) -> list[tuple[str, int]]:
    out = []
    for item in (s.strip() for s in text.split(",") if s.strip()):
        env, _, case = item.partition(":")
        if env not in ENVS or not case.isdigit() or int(case) not in TRAJECTORY:
            raise DatasetError(f"--cases: {item!r} is not ENV:CASE with ENV in {'/'.join(ENVS)} and CASE in 1-4")
        out.append((env, int(case)))
    return out


def main(argv: list[str] | None = None) -> int:
    p, conv, fit = converter_parser(
        __doc__.split("\n")[0], "a local copy of the repository (its root)", Path("out/datasets/hanyang-uwb")
    )
    conv.add_argument("--env", choices=ENVS, default="LOS")
    conv.add_argument("--case", type=int, choices=sorted(TRAJECTORY), default=1)
    conv.add_argument("--sigma", type=float, default=0.1, help="the noise std the scenario states (m)")
    conv.add_argument("--out", type=Path, required=True)
    fit.add_argument("--cases", default="LOS:1,LOS:2,LOS:3,LOS:4", help="comma-separated ENV:CASE")
    args = p.parse_args(argv)
    try:
        if args.cmd == "convert":
            run = read_run(_source(args, args.env, args.case), args.env, args.case)
            counts = write_recording(run, args.out, sigma_m=args.sigma)
            print(f"wrote {args.out}/ranges.csv ({counts['ranges']} rows), truth.csv ({counts['truth']}; "
                  f"{counts['dropped_reference']} reference glitches dropped), scenario.yaml")  # fmt: skip
            return 0
        series, runs = [], {}
        for env, case in _cases(args.cases):
            run = read_run(_source(args, env, case), env, case)
            lag = best_lag_s(run, np.round(np.arange(-0.3, 0.301, 0.05), 3))
            runs[run.name] = {**describe(run, lag), "clock_lag_s": lag}
            series.append(link_series(run, lag))
        result = {"dataset": NAME, "url": REPO_URL, "commit": COMMIT, "licence": LICENCE, "doi": DOI, "runs": runs}
        return print_fit(result, series)
    except (DatasetError, OSError) as err:
        print(f"hanyang_outdoor_uwb: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
