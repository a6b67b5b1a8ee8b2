"""Counters and the latency histogram: quantiles within a bin of the exact ones, constant memory."""

from __future__ import annotations

import json
import random

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mavframe.packet import Direction
from mitm_proxy.core.stats import LatencyHistogram, LinkStats


def test_snapshot_is_json_with_both_directions_and_latency() -> None:
    stats = LinkStats(sysid=3)
    stats[Direction.DOWNLINK].frames_in += 5
    stats[Direction.UPLINK].add_bad("garbage")
    stats[Direction.UPLINK].add_bad("garbage")
    stats[Direction.UPLINK].add_bad("bad_crc")
    snap = json.loads(json.dumps(stats.snapshot()))
    assert snap["sysid"] == 3
    assert snap["downlink"]["frames_in"] == 5
    assert snap["uplink"]["bad"] == {"garbage": 2, "bad_crc": 1} and snap["uplink"]["bad_total"] == 3
    assert snap["latency_ms"] == {"count": 0, "p50": None, "p99": None, "max": None}


def test_latency_quantiles_match_numpy_within_a_bin() -> None:
    rng = random.Random(1)
    xs = [rng.lognormvariate(-7.5, 0.6) for _ in range(20000)]  # ~0.5 ms median
    stats = LinkStats()
    for x in xs:
        stats.latency(x)
    snap = stats.snapshot()["latency_ms"]
    for q, key in ((0.5, "p50"), (0.99, "p99")):
        exact = float(np.quantile(xs, q)) * 1e3
        assert exact <= snap[key] <= exact * 1.025, (key, exact, snap[key])
    assert snap["count"] == 20000 and snap["max"] == max(xs) * 1e3


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.0, 1000.0, allow_nan=False), min_size=1, max_size=200), st.floats(0.01, 1.0))
def test_quantile_never_below_the_exact_and_never_above_the_max(xs: list[float], q: float) -> None:
    h = LatencyHistogram()
    for x in xs:
        h.add(x)
    got = h.quantile(q)
    assert got is not None
    exact = sorted(xs)[max(1, int(np.ceil(q * len(xs)))) - 1]
    assert got <= max(max(xs), h.LO_S)
    assert got >= exact * (1 - 1e-9)
    assert got <= max(exact * 1.02, h.LO_S) or got == max(xs)


def test_memory_is_constant_and_reset_works() -> None:
    h = LatencyHistogram()
    n_bins = len(h._counts)
    for i in range(100000):
        h.add(i * 1e-5)
    h.add(float("nan"))  # ignored
    assert len(h._counts) == n_bins and h.count == 100000
    h.reset()
    assert h.count == 0 and h.quantile(0.5) is None


def test_boot_text_is_shown_but_not_counted_as_bad() -> None:
    """ArduPilot SITL's "Init ArduCopter ..." lines on its serial link are not an attack on the link."""
    stats = LinkStats(1)
    stats[Direction.DOWNLINK].add_bad("text", 3)
    stats[Direction.DOWNLINK].add_bad("bad_crc")
    snap = stats.snapshot()
    assert snap["downlink"]["bad"] == {"text": 3, "bad_crc": 1} and snap["downlink"]["bad_total"] == 1
