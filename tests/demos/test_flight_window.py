"""A flight of several vehicles is scored where all of them hold: their holds end together, and a window
without ground truth is refused with the reason rather than scored as NaN."""

from __future__ import annotations

from pathlib import Path

import pytest

from demos.controllers.common import HoldClock
from demos.flight import check_window
from demos.scoring import Window


def test_a_hold_counts_from_its_own_start_without_a_file() -> None:
    clock = HoldClock(12.0, None, now=100.0)
    assert clock.running(111.9) and not clock.running(112.0)


def test_holds_that_began_apart_end_together_counted_from_the_file(tmp_path: Path) -> None:
    go = tmp_path / "all-holding"
    early, late = HoldClock(12.0, str(go), now=100.0), HoldClock(12.0, str(go), now=113.0)
    assert early.running(113.0) and late.running(113.0)  # uav1 held 13 s before uav2 did: it has not landed
    go.write_text("113.5\n")
    assert early.running(113.5) and late.running(113.5)  # both start counting here
    assert early.running(125.4) and late.running(125.4)
    assert not early.running(125.5) and not late.running(125.5)


def test_a_window_without_truth_is_refused_with_the_reason(tmp_path: Path) -> None:
    window = Window(start_s=186.9, end_s=187.4, hold_s=183.9)
    truth = {1: [(186.0, {}), (187.0, {})], 2: [(186.0, {}), (188.0, {})]}
    with pytest.raises(RuntimeError, match=r"no ground truth of vehicle 2 in the scored window: it ran 0\.50 s"):
        check_window(window, truth, tmp_path)
    check_window(window, {1: truth[1]}, tmp_path)
