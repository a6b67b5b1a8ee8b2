"""Named range-noise parameter sets fitted to public recorded data (``RangeNoise.preset``).

Each set is what ``scripts/datasets/<name>.py fit`` printed on the dataset named
beside it; docs/datasets.md gives the dataset's URL, commit and licence and how
each number was measured. Values are rounded to two significant figures.
"""

from __future__ import annotations

from typing import Any

PRESETS: dict[str, dict[str, Any]] = {
    # LIAS-CUHKSZ planar UWB dataset (Jiang et al., ICRA 2023), Planar_Dataset/Dynamic runs "fast" and
    # "mid", 48 anchor-tag links; github.com/LIAS-CUHKSZ/Efficient-Pose-Estimation-via-UWB-measurements
    # @ cabd39232cb8, MIT. Fitted by: python scripts/datasets/lias_planar_uwb.py fit --runs fast,mid
    # (noise_std_m itself, a field of the sensor, measured 0.069 m: median over links of 1.4826 MAD).
    "uwb-lias-planar": {
        "offset_mean_m": 0.17,
        "offset_std_m": 0.062,
        "correlated_share": 0.78,
        "correlation_time_s": 2.1,
        "student_t_dof": 6.2,
        "nlos_episode_rate_hz": 0.0033,
        "nlos_episode_mean_s": 0.34,
        "nlos_episode_bias_m": 0.32,
        "outlier_prob": 0.00022,
        "outlier_std_m": 2.0,
    },
}
