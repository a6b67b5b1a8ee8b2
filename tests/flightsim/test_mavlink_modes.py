"""PX4's mode numbers as flightsim speaks them, and as scripts/sitl/check_px4.py asks a real PX4 for them."""

from __future__ import annotations

import pytest

from flightsim.api import FlightMode
from flightsim.mavlink.modes import MAIN_AUTO, SUB_LAND, SUB_LOITER, custom_mode, decode_custom_mode, main_sub


def test_hold_and_land_as_px4_numbers_them() -> None:
    assert main_sub(FlightMode.HOLD) == (MAIN_AUTO, SUB_LOITER) == (4, 3)
    assert main_sub(FlightMode.LAND) == (MAIN_AUTO, SUB_LAND) == (4, 6)
    # PX4 v1.17 SIH on the ground in Hold sent HEARTBEAT.custom_mode 50593792 (docs/px4.md)
    assert custom_mode(FlightMode.HOLD) == 50593792


@pytest.mark.parametrize("mode", list(FlightMode))
def test_every_mode_packs_and_decodes_back(mode: FlightMode) -> None:
    main, sub = main_sub(mode)
    assert custom_mode(mode) == main << 16 | sub << 24
    assert decode_custom_mode(custom_mode(mode)) == mode
