"""Noise fitting shared by the dataset decoders in this folder (``lias_planar_uwb.py``, ``hanyang_outdoor_uwb.py``).

Both hand :func:`fit_noise` per-link range errors (measured minus true range) on a regular grid and get the
numbers docs/datasets.md tabulates: per-link offsets, a robust noise scale, time correlation, heavy tails, NLOS
episodes and gross errors. The decoders import it from beside themselves (they are scripts, not a package).
"""

from __future__ import annotations

import math

import numpy as np

GROSS_M = 1.0  # a reading this far from its link's median error is a gross error, not noise


def sample_last(t_s: np.ndarray, values: np.ndarray, ticks_s: np.ndarray, max_age_s: float = math.inf) -> np.ndarray:
    """``values`` (rows at the sorted stamps ``t_s``) at each tick: the last row at or before it, NaN where there
    is none or it is older than ``max_age_s`` (a link that polls at its own times, resampled onto one grid)."""
    idx = np.searchsorted(t_s, ticks_s + 1e-9, side="right") - 1
    out = np.asarray(values, dtype=float)[np.maximum(idx, 0)].copy()
    stale = (idx < 0) | (ticks_s - t_s[np.maximum(idx, 0)] > max_age_s)
    out[stale] = np.nan
    return out


def fit_noise(series: list[np.ndarray], rate_hz: float = 10.0) -> dict[str, object]:
    """Noise parameters from per-link error series (each (K, L), one per run): see docs/datasets.md."""
    offsets, sigmas, acf_lags = [], [], {}
    z_all, gross, total, gross_values = [], 0, 0, []
    episodes, episode_len, episode_excess, link_time_s = 0, [], [], 0.0
    lags = (1, 2, 5, 10, 20, 50)
    for e in series:
        med = np.nanmedian(e, axis=0)
        r = e - med
        mad = 1.4826 * np.nanmedian(np.abs(r), axis=0)
        offsets += med.tolist()
        sigmas += mad.tolist()
        bad = np.abs(r) > GROSS_M
        gross += int(bad.sum())
        gross_values += r[bad].tolist()
        total += int(np.isfinite(r).sum())
        core = np.where(bad, np.nan, r)
        z_all.append((core / mad)[np.isfinite(core)])
        for lag in lags:
            for c in range(r.shape[1]):
                x = core[:, c] - np.nanmean(core[:, c])
                a, b = x[:-lag], x[lag:]
                ok = np.isfinite(a) & np.isfinite(b)
                acf_lags.setdefault(lag, []).append(
                    float(np.sum(a[ok] * b[ok]) / np.sqrt(np.sum(a[ok] ** 2) * np.sum(b[ok] ** 2)))
                )
        # NLOS-like episodes: runs of at least 0.3 s above +3 sigma of the link
        for c in range(r.shape[1]):
            above = np.nan_to_num(core[:, c] / mad[c], nan=0.0) > 3.0
            link_time_s += r.shape[0] / rate_hz
            k = 0
            while k < above.size:
                if above[k]:
                    j = k
                    while j < above.size and above[j]:
                        j += 1
                    if j - k >= round(0.3 * rate_hz):
                        episodes += 1
                        episode_len.append((j - k) / rate_hz)
                        episode_excess.append(float(np.nanmean(core[k:j, c])))
                    k = j
                else:
                    k += 1
    z = np.concatenate(z_all)
    acf = {f"{lag / rate_hz:.1f}": float(np.median(v)) for lag, v in sorted(acf_lags.items())}
    # ACF(lag) ~ share * exp(-lag / tau) for lags >= 1 tick: a least-squares line through log ACF.
    x = np.array([lag / rate_hz for lag in lags])
    y = np.log(np.clip([acf[f"{v:.1f}"] for v in x], 1e-3, None))
    slope, intercept = np.polyfit(x, y, 1)
    kurt = float(np.mean(z**4) / np.mean(z**2) ** 2)
    dof = 4.0 + 6.0 / (kurt - 3.0) if kurt > 3.0 else None  # Student-t: kurtosis 3 + 6 / (dof - 4)
    return {
        "links": len(offsets),
        "offset_m": {
            "mean": float(np.mean(offsets)),
            "std": float(np.std(offsets)),
            "min": float(np.min(offsets)),
            "max": float(np.max(offsets)),
        },
        "sigma_m": {"median": float(np.median(sigmas)), "min": float(np.min(sigmas)), "max": float(np.max(sigmas))},
        "acf": acf,
        "correlated_share": float(min(1.0, math.exp(intercept))),
        "correlation_time_s": float(-1.0 / slope) if slope < 0 else None,
        "kurtosis": kurt,
        "student_t_dof": dof,
        "tail_share_beyond_3_sigma": float(np.mean(np.abs(z) > 3.0)),
        "tail_share_beyond_5_sigma": float(np.mean(np.abs(z) > 5.0)),
        "gross_error_share": gross / max(total, 1),
        "gross_error_rms_m": float(np.sqrt(np.mean(np.square(gross_values)))) if gross_values else None,
        "gross_error_range_m": [float(min(gross_values)), float(max(gross_values))] if gross_values else None,
        "nlos_episode_rate_hz": episodes / max(link_time_s, 1e-9),
        "nlos_episode_mean_s": float(np.mean(episode_len)) if episode_len else None,
        "nlos_episode_excess_m": float(np.mean(episode_excess)) if episode_excess else None,
    }
