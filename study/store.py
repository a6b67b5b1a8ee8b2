"""The results of a study on disk: ``DIR/results.parquet``, a Parquet dataset written append-only.

Each batch of finished cells becomes one new file ``results.parquet/part-*.parquet``,
written under a hidden temporary name, synced, then renamed into place, so a
kill never leaves half a file and a written row is never rewritten. Any Parquet
reader takes the directory as one table (``pandas.read_parquet(DIR /
"results.parquet")``). A cell is done when it has a row for an estimator; rows
of a cell re-run with ``--retry-failed`` supersede the failed ones (:func:`load`
keeps the newest row per cell and estimator).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

RESULTS = "results.parquet"
STUDY_FILE = "study.json"

_S, _F, _I = pa.string(), pa.float64(), pa.int64()
SCHEMA = pa.schema([
    ("study", _S), ("cell", _S), ("scenario", _S), ("mode", _S), ("leg", _S),
    ("position", _S),  # JSON [north, east] in metres, or null for the scenario's own target
    ("noise_scale", _F),  # the flight's range noise over the stated (Study.noise_scales); null in older rows: 1
    ("recording", _S),  # the recording's name (Study.recording/recordings); null for flights and older rows
    ("attack", _S), ("attack_hash", _S), ("params", _S),  # params: JSON of this cell's parameter values
    ("seed", _I), ("estimator", _S),
    ("estimator_params", _S),  # JSON of the study's estimator_params grid point (null: the defaults)
    ("status", _S), ("error", _S),
    ("rmse_m", _F), ("mean_error_m", _F), ("p95_error_m", _F), ("max_error_m", _F),
    ("range_rmse_m", _F), ("range_max_error_m", _F), ("height_rmse_m", _F),
    ("estimate_fraction", _F), ("attacked_fraction", _F),
    ("valid_fraction", _F), ("valid_rmse_m", _F), ("valid_max_error_m", _F), ("nees_mean", _F),
    ("nis_mean", _F),  # the output filter's NIS per degree of freedom, over the steps claimed valid (1: consistent)
    # What the row scores: "own" (the method's own output) or "attributed" (a secure method's output with the
    # shared attribution on it: the +attribution row).
    ("output", _S),
    # Detection, one definition (study.metrics) for two claimants: own_* the method's own naming (null for a
    # method that claims none), attribution_* the shared attribution's (null but in +attribution rows).
    *((f"{who}_{figure}", _S if figure == "recall_by_sigma" else _F)
      for who in ("own", "attribution")
      for figure in ("recall", "precision", "false_naming", "alarm_fraction", "detection_delay_s",
                     "recall_by_sigma")),
    # JSON: what the calibration window did (estimators.noise.Calibrated.report: status, per link the readings
    # used, the offset and the scale); null without calibration_s
    ("calibration", _S),
    # How the estimator took the readings (evaluation.trial.TrialResult.processing): "sequential" or "aligned"
    # (a recording's readings each at its own time, with the window async_window_s) or "synchronous" (frames:
    # flights, and recordings with sync: true); null in older rows (framed)
    ("processing", _S), ("async_window_s", _F),
    ("step_time_us_median", _F), ("step_time_us_p99", _F),
    ("collided", pa.bool_()), ("min_distance_m", _F), ("flagged", _S),  # closed loop
    ("worker", _S), ("started_at", pa.timestamp("ms", tz="UTC")), ("wall_s", _F),
    # Provenance (study.provenance): the variant's estimator, where its code and the attack's came from, the
    # environment, and code_key, which decides whether a recorded row still stands for the code of today.
    ("estimator_name", _S), ("estimator_dist", _S), ("estimator_version", _S), ("estimator_code", _S),
    ("attack_code", _S), ("primitives", _S), ("code_key", _S),
    ("secuav_version", _S), ("secuav_commit", _S), ("secuav_dirty", pa.bool_()),
    ("python_version", _S), ("numpy_version", _S), ("scipy_version", _S),
])  # fmt: skip
COLUMNS = SCHEMA.names


def results_dir(out: Path | str) -> Path:
    return Path(out) / RESULTS


def _sync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class Writer:
    """Appends batches of rows as new part files; the only thing that writes ``DIR``."""

    def __init__(self, out: Path) -> None:
        self.dir = results_dir(out)
        self.dir.mkdir(parents=True, exist_ok=True)
        self._stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        self._seq = 0

    def write(self, rows: list[dict[str, Any]]) -> Path | None:
        if not rows:
            return None
        table = pa.Table.from_pylist([{c: r.get(c) for c in COLUMNS} for r in rows], schema=SCHEMA)
        self._seq += 1
        name = f"part-{self._stamp}-{os.getpid()}-{self._seq:06d}.parquet"
        tmp, final = self.dir / f".{name}.tmp", self.dir / name
        with open(tmp, "wb") as sink:
            pq.write_table(table, sink)
            sink.flush()
            os.fsync(sink.fileno())
        os.replace(tmp, final)
        _sync_dir(self.dir)
        return final


def load(out: Path | str) -> pd.DataFrame:
    """Every row of study directory ``out`` (a path or a string), the newest per (cell, estimator); an empty frame
    with the columns when there are none."""
    path = results_dir(out)
    if not path.is_dir() or not any(path.glob("part-*.parquet")):
        return pd.DataFrame({c: pd.Series(dtype=object) for c in COLUMNS})
    frame = ds.dataset(path, format="parquet", schema=SCHEMA).to_table().to_pandas()
    frame["noise_scale"] = frame["noise_scale"].fillna(1.0)  # rows written before the column existed
    frame = frame.sort_values("started_at", kind="stable")
    return frame.drop_duplicates(["cell", "estimator"], keep="last").reset_index(drop=True)


def done(out: Path | str, *, retry_failed: bool = False) -> dict[tuple[str, str], str | None]:
    """(cell, estimator) pairs already recorded, with the ``code_key`` they were computed with
    (with ``retry_failed``: only those that succeeded)."""
    frame = load(out)
    if retry_failed:
        frame = frame[frame["status"] == "ok"]
    keys = [None if k is None or k != k else str(k) for k in frame["code_key"]]  # NaN: a row from before provenance
    return dict(zip(zip(frame["cell"], frame["estimator"], strict=True), keys, strict=True))


def save_study(out: Path, definition: dict[str, Any]) -> None:
    """Remember which study the directory holds, so another one is not mixed into it."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / STUDY_FILE
    tmp = out / f".{STUDY_FILE}.tmp"
    tmp.write_text(json.dumps(definition, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def saved_study(out: Path | str) -> dict[str, Any] | None:
    path = Path(out) / STUDY_FILE
    return json.loads(path.read_text(encoding="utf-8")) if path.exists() else None


def as_json(value: Any) -> str | None:
    return None if value is None else json.dumps(value, sort_keys=True, separators=(",", ":"))
