"""The secure stage on a real ArduCopter stream: the recorded SITL flight, attacked, behind ``ardupilot_height``.

ArduPilot grades none of its SITL rangefinders, so every DISTANCE_SENSOR it sends says
``signal_quality`` 0 (MAVLink's "unknown"); on the ground ``current_distance`` is below
``min_distance`` (no reading). The stage must take the first as readings and the second as
none, or it estimates nothing in front of ArduPilot. No SITL binary needed: the stream is
tests/data/ardupilot-copter-guided.tlog (tests/data/README.md).
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import estimators
from attack_profiles import library
from attack_profiles.engine import Engine
from mavframe import codec, tlog
from mavframe.packet import Direction, Packet
from mitm_proxy.stages.secure.collect import no_target
from mitm_proxy.stages.secure.config import SecureConfig
from mitm_proxy.stages.secure.layout import build_layout
from mitm_proxy.stages.secure.stage import FLAGGED_QUALITY, SecureStage
from secuav_common.scenario import Scenario, load_scenario

TLOG = Path(__file__).resolve().parents[2] / "data" / "ardupilot-copter-guided.tlog"
DS, RANGEFINDER = 132, 173


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return load_scenario("ardupilot_height")


def test_scenario_gives_the_secure_stage_the_three_downward_rangefinders_as_one_group(scenario: Scenario) -> None:
    layout = build_layout(SecureConfig(estimator="secekf"), scenario, 1)
    assert layout.group == "wall"
    assert layout.sensor_ids == (0, 1, 2)
    assert layout.model.normal_ned == (0.0, 0.0, -1.0)  # the distance grows as the vehicle climbs
    # Three readings of one quantity: one liar is outvoted, two are a majority no estimator can see through.
    assert layout.model.max_correctable == 1
    with pytest.raises(ValueError):
        estimators.create("secekf", layout.model, s=2)


@pytest.mark.parametrize(
    ("fields", "none"),
    [
        ({"current_distance": 500, "min_distance": 20, "max_distance": 4000, "signal_quality": 0}, False),  # ArduPilot
        ({"current_distance": 0, "min_distance": 20, "max_distance": 4000, "signal_quality": 0}, True),  # on the ground
        ({"current_distance": 4001, "min_distance": 10, "max_distance": 4000, "signal_quality": 0}, True),  # flightsim
        ({"current_distance": 5000, "min_distance": 10, "max_distance": 4000, "signal_quality": 100}, False),  # graded
    ],
)
def test_no_target_is_quality_unknown_and_out_of_range(fields: dict[str, Any], none: bool) -> None:
    assert no_target(fields) is none


def _flight(scenario: Scenario, engine: Engine | None) -> list[tuple[float, int, dict[str, Any], dict[str, Any]]]:
    """(time, msgid, fields as sent by the vehicle, fields as the ground gets them) of sysid 1's downlink."""
    stage = SecureStage(SecureConfig(estimator="secekf", executor="inline"), scenario, 1)
    out = []
    for entry in tlog.read(TLOG):
        h = entry.header
        if h.sysid != 1 or h.msgid not in (DS, RANGEFINDER):
            continue
        pkt = Packet(entry.raw, h, Direction.DOWNLINK, 0, entry.t_s)
        sent = dict(codec.decode(pkt))
        if engine is not None and h.msgid == DS:
            action = engine.process(entry.t_s, h.msgid, pkt.fields, Direction.DOWNLINK, h.sysid, h.compid)
            if action.fields:
                pkt.fields.update(action.fields)
                pkt.changed = True
        if h.msgid in stage.message_ids:
            stage.process(pkt, entry.t_s)
        out.append((entry.t_s, h.msgid, sent, dict(pkt.fields)))
    return out


def _hover(frames: list[tuple[float, int, dict[str, Any], dict[str, Any]]]) -> list[tuple[float, Any, Any]]:
    """DISTANCE_SENSOR frames in the air (above 3 m), with the true distance: RANGEFINDER's, sent beside them."""
    truth_m = np.nan
    rows = []
    for _t, msgid, sent, got in frames:
        if msgid == RANGEFINDER:
            truth_m = sent["distance"]
        elif sent["current_distance"] > 300:
            rows.append((truth_m, sent, got))
    return rows


def test_unattacked_arducopter_stream_is_estimated_and_nothing_is_flagged(scenario: Scenario) -> None:
    rows = _hover(_flight(scenario, None))
    assert len(rows) > 300
    errors = [abs(got["current_distance"] / 100 - truth) for truth, _sent, got in rows]
    changed = sum(got["current_distance"] != sent["current_distance"] for _truth, sent, got in rows)
    # The stage estimates from ArduPilot's quality-0 readings (it substitutes its own estimate)...
    assert changed > 0.5 * len(rows)
    assert np.median(errors) < 0.05
    # ...and the three agree, so none is judged attacked. What is flagged is the few sets the filter judged
    # degraded (all three marked) in the 2.5 m/s take-off, and after a 0.76 s stall of SITL's stream in it.
    flagged = [got for _truth, _sent, got in rows if got["signal_quality"] == FLAGGED_QUALITY]
    assert len(flagged) < 0.05 * len(rows)
    assert Counter(got["id"] for got in flagged) == Counter({0: len(flagged) // 3, 1: len(flagged) // 3,
                                                             2: len(flagged) // 3})  # fmt: skip


def test_one_ramped_rangefinder_of_three_is_named_and_outvoted(scenario: Scenario) -> None:
    entries = [e for e in tlog.read(TLOG) if e.header.msgid == DS and e.header.sysid == 1]
    airborne = next(e.t_s for e in entries if codec.decode(
        Packet(e.raw, e.header, Direction.DOWNLINK, 0, e.t_s))["current_distance"] > 300)  # fmt: skip
    engine = Engine(library.load("height-spoof-one", start_s=0.0, rate_per_s=1.0), seed=0, scenario=scenario)
    engine.activate(airborne)
    rows = _hover(_flight(scenario, engine))
    late = rows[len(rows) // 3 :]  # the ramp is metres long by then
    attacked = [(t, g) for t, _s, g in late if g["id"] == 2]
    honest = [(t, g) for t, _s, g in late if g["id"] != 2]
    assert np.mean([g["signal_quality"] == FLAGGED_QUALITY for _t, g in attacked]) > 0.9
    assert np.mean([g["signal_quality"] == FLAGGED_QUALITY for _t, g in honest]) < 0.05
    errors = [abs(g["current_distance"] / 100 - t) for t, g in honest]
    assert np.median(errors) < 0.1
