"""The LIAS-CUHKSZ planar UWB decoder on small files written here in the dataset's own format
(no dataset file is bundled): it recovers the geometry, the per-link offsets and noise we put in,
names bad lines, and its output runs through ``secuav-eval --ranges``."""

from __future__ import annotations

import csv
import importlib.util
import math
import sys
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "datasets" / "lias_planar_uwb.py"


def _load():
    spec = importlib.util.spec_from_file_location("lias_planar_uwb", SCRIPT)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["lias_planar_uwb"] = mod
    spec.loader.exec_module(mod)
    return mod


lias = _load()
T0 = datetime(2022, 8, 15, 9, 42, 24, 766000)
OFFSETS = np.linspace(0.08, 0.3, 8)  # per anchor, the same for all tags


def _quat_flip_yaw(yaw: float) -> tuple[float, float, float, float]:
    """The dataset's body frame is z-down: a 180 deg turn about a horizontal axis at yaw/2."""
    return (0.0, math.cos(yaw / 2), math.sin(yaw / 2), 0.0)


def _write_run(folder: Path, run: str, seconds: float = 20.0, sigma: float = 0.03, seed: int = 0) -> None:
    """A trolley circling at 0.96 m height, 100 Hz UWB rows and 125 Hz motion capture, as the dataset stores them."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)

    def pose(t: float) -> tuple[np.ndarray, tuple[float, float, float, float]]:
        centre = np.array([1.5 * math.cos(0.3 * t), 1.0 * math.sin(0.3 * t), 0.96])
        return centre, _quat_flip_yaw(0.3 * t + 1.0)

    with (folder / f"motion_capture_dynamic_exp_{run}.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time", "x", "y", "z", "rotation", "", "", ""])
        for k in range(round(seconds * 125) + 50):
            t = -0.2 + k / 125
            c, q = pose(t)
            w.writerow([_stamp(t), *(f"{v:.9f}" for v in c), *(f"{v:.9f}" for v in q)])
    with (folder / f"UWB_dynamic_exp_{run}.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        for k in range(round(seconds * 100)):
            t = k / 100
            c, q = pose(t)
            rot = lias.rotation(np.array([q]))[0]
            cells = []
            for a in range(8):
                for tag in range(3):
                    p = c + rot @ (lias.TAG_OFFSETS_M[tag] * np.array([1.0, lias.BODY_Y_SIGN, 1.0]))
                    d = np.linalg.norm(p - lias.ANCHORS_M[a]) + OFFSETS[a] + rng.normal(0.0, sigma)
                    cells.append("" if (k == 7 and a == 2) else f"{d:.2f}")
            w.writerow([_stamp(t), *cells])


def _stamp(t: float) -> str:
    return (T0 + timedelta(seconds=t)).strftime("%Y-%m-%d %-H:%M:%S.%f")[:-3]


def test_decoder_recovers_geometry_offsets_and_noise(tmp_path: Path) -> None:
    _write_run(tmp_path, "fast")
    rec = lias.read_run(tmp_path, "fast")
    assert rec.ranges_m.shape == (2000, 8, 3) and math.isnan(rec.ranges_m[7, 2, 0])
    assert rec.t_mocap_s[0] == pytest.approx(-0.2, abs=1e-3)
    err = lias.range_errors(rec)
    # 0.01 m rounding adds 0.003 m; the offsets come back per link to well under a centimetre.
    assert np.nanmedian(err, axis=0) == pytest.approx(np.repeat(OFFSETS[:, None], 3, axis=1), abs=0.006)
    fitted = lias.fit_noise([lias.link_series(rec, lias.best_lag_s(rec, np.array([-0.1, 0.0, 0.1])))])
    assert fitted["offset_m"]["mean"] == pytest.approx(OFFSETS.mean(), abs=0.005)
    assert fitted["sigma_m"]["median"] == pytest.approx(math.hypot(0.03, 0.01 / math.sqrt(12)), rel=0.15)
    assert abs(fitted["acf"]["0.1"]) < 0.15  # white noise in, no correlation out
    assert fitted["gross_error_share"] == 0.0


def test_the_wrong_body_frame_reading_fits_worse(tmp_path: Path) -> None:
    _write_run(tmp_path, "mid")
    rec = lias.read_run(tmp_path, "mid")
    right = np.nanmedian(np.abs(lias.range_errors(rec) - OFFSETS[None, :, None]))
    lias.BODY_Y_SIGN = 1.0
    try:
        wrong = np.nanmedian(np.abs(lias.range_errors(rec) - OFFSETS[None, :, None]))
    finally:
        lias.BODY_Y_SIGN = -1.0
    assert wrong > 2 * right


def test_convert_writes_the_recorded_ranges_format(tmp_path: Path) -> None:
    _write_run(tmp_path / "src", "fast", seconds=5.0)
    assert (
        lias.main(
            ["convert", "--source", str(tmp_path / "src"), "--run", "fast", "--tag", "1", "--out", str(tmp_path / "o")]
        )
        == 0
    )
    rows = list(csv.DictReader((tmp_path / "o" / "ranges.csv").open()))
    assert rows[0].keys() == {"t_s", "sysid", "sensor_id", "range_m"} and len(rows) == 500 * 8
    assert {r["sensor_id"] for r in rows} == {str(10 + a) for a in range(8)}
    truth = list(csv.DictReader((tmp_path / "o" / "truth.csv").open()))
    first = truth[0]
    # NED: north = dataset y, east = dataset x, down = -z
    c = np.array([1.5 * math.cos(-0.06), 1.0 * math.sin(-0.06), 0.96])
    assert float(first["down_m"]) == pytest.approx(-0.96, abs=0.01)
    assert math.hypot(float(first["north_m"]) - c[1], float(first["east_m"]) - c[0]) < 0.25  # a tag, not the centre
    text = (tmp_path / "o" / "scenario.yaml").read_text()
    assert lias.COMMIT in text and "MIT" in text


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda rows: rows.__setitem__(3, rows[3].replace("2022-08-15", "15/08/2022")), r"line 4: time"),
        (lambda rows: rows.__setitem__(5, rows[5].replace(",", ",x", 1)), r"line 6: value 'x"),
        (lambda rows: rows.__setitem__(2, rows[2].rsplit(",", 1)[0]), r"line 3: 24 columns"),
    ],
)
def test_a_bad_line_is_named(tmp_path: Path, edit, message: str) -> None:
    _write_run(tmp_path, "fast", seconds=1.0)
    path = tmp_path / "UWB_dynamic_exp_fast.csv"
    rows = path.read_text().splitlines()
    edit(rows)
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(lias.DatasetError, match=message):
        lias.read_run(tmp_path, "fast")
    assert lias.main(["fit", "--source", str(tmp_path), "--runs", "fast"]) == 2
