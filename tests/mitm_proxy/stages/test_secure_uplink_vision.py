"""The secure stage toward the vehicle with a second position source (issue 33, items 5 and 7): a companion feeds
the autopilot external vision (VISION_POSITION_ESTIMATE) and UWB anchor ranges; a rule toward the vehicle ramps
the vision's north away. On the uplink the anchors group writes its secure position into the vision frames, so
the autopilot receives the anchors' fix instead of the lie, while what the vehicle sends leaves byte for byte.

Sans I/O: one link's real pipeline (tap -> attack -> secure -> forward) with the real engine and estimator, fed
pymavlink frames on a simulated clock (the inline executor), in the bundled px4_vision scenario's geometry.
"""

from __future__ import annotations

import math
import random
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavframe.packet import Direction
from mitm_proxy.stages.secure.config import SecureConfig
from secuav_common.scenario import Scenario, load_scenario
from tests.support.uplink_bench import Run, UplinkBench

TRUE = (1.0, -2.0, -5.0)  # where the vehicle really is (NED, m)
UWB_STD_M, VISION_STD_M, RAMP_M_S = 0.10, 0.02, 0.5
RAMP = {"name": "vision-ramp", "rules": [{
    "target": {"message": "VISION_POSITION_ESTIMATE", "field": "x", "direction": "uplink"},
    "kind": "ramp", "rate_per_s": RAMP_M_S}]}  # fmt: skip
VPE = 102


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return load_scenario("px4_vision")


def fly(scenario: Scenario, secure: SecureConfig | None, seconds: float = 20.0, profile: dict | None = None) -> Run:
    """The companion (sysid 1, compid 197) sends vision at 30 Hz and the eight anchor ranges at 10 Hz toward the
    vehicle; the vehicle sends LOCAL_POSITION_NED and ATTITUDE toward the ground."""
    bench = UplinkBench(scenario, profile or RAMP, "ramp.yaml", secure)
    companion, vehicle, send, run = bench.companion, bench.vehicle, bench.send, bench.run
    anchors = scenario.anchor_positions([a.id for a in scenario.world.anchors])
    rng = random.Random(5)

    start_s = time.monotonic()  # the profile's activation clock started at install
    for k in range(int(seconds * 30)):
        t_s = start_s + k / 30
        usec = round(k / 30 * 1e6)
        x, y, z = (c + rng.gauss(0.0, VISION_STD_M) for c in TRUE)
        send(companion, mavlink.MAVLink_vision_position_estimate_message(usec, x, y, z, 0.0, 0.0, 0.0, [0.0] * 21),
             Direction.UPLINK, t_s)  # fmt: skip
        if k % 3 == 0:
            for a, pos in anchors.items():
                d = math.dist(TRUE, pos) + rng.gauss(0.0, UWB_STD_M)
                send(companion, mavlink.MAVLink_distance_sensor_message(usec // 1000, 0, 10000, round(d * 100), 0,
                                                                        10 + a, 100, 1),
                     Direction.UPLINK, t_s + 0.001)  # fmt: skip
            send(vehicle, mavlink.MAVLink_local_position_ned_message(usec // 1000, *TRUE, 0.0, 0.0, 0.0),
                 Direction.DOWNLINK, t_s + 0.002)  # fmt: skip
            send(vehicle, mavlink.MAVLink_attitude_message(usec // 1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
                 Direction.DOWNLINK, t_s + 0.003)  # fmt: skip
    return run


def vision_received(frames: list[bytes]) -> np.ndarray:
    """(time s, x, y, z) of each VISION_POSITION_ESTIMATE the autopilot got."""
    mav = mavlink.MAVLink(None)
    rows = []
    for raw in frames:
        msg = mav.parse_char(bytearray(raw))
        if msg.id == VPE:
            rows.append((msg.usec / 1e6, msg.x, msg.y, msg.z))
    return np.array(rows)


def test_without_the_stage_the_autopilot_gets_the_ramp(scenario: Scenario) -> None:
    got = vision_received(fly(scenario, None).up_out)
    late = got[got[:, 0] > 15.0]
    assert np.all(late[:, 1] - TRUE[0] > RAMP_M_S * 14.0)  # north ran away by the ramp
    assert np.all(np.abs(late[:, 2] - TRUE[1]) < 5 * VISION_STD_M)  # east untouched


def test_on_the_uplink_the_vision_frames_carry_the_anchors_secure_position(scenario: Scenario) -> None:
    cfg = SecureConfig(estimator="secekf", executor="inline", direction="uplink")
    run = fly(scenario, cfg)
    got = vision_received(run.up_out)
    assert len(run.up_out) == len(run.up_in)  # nothing dropped, nothing added
    late = got[got[:, 0] > 2.0]  # after the first anchor sets
    assert len(late) > 500
    err = np.hypot(late[:, 1] - TRUE[0], late[:, 2] - TRUE[1])
    assert err.max() < 0.3, err.max()  # the ramp (up to 10 m) is gone: the anchors' fix, within their noise
    assert np.all(np.abs(late[:, 3] - TRUE[2]) < 0.5)  # 3-D anchors: the height is theirs too
    assert run.down_out == run.down_in  # what the vehicle sends leaves byte for byte


def test_on_the_downlink_the_vision_fed_to_the_vehicle_is_left_alone(scenario: Scenario) -> None:
    cfg = SecureConfig(estimator="secekf", executor="inline")  # the default: the stage shields the ground
    run = fly(scenario, cfg)
    got = vision_received(run.up_out)
    late = got[got[:, 0] > 15.0]
    assert np.all(late[:, 1] - TRUE[0] > RAMP_M_S * 14.0)


def test_when_the_anchors_cannot_be_trusted_the_vision_frames_keep_the_last_trusted_position(
    scenario: Scenario,
) -> None:
    """Four of the eight anchor ranges lie too, from 5 s (more than secekf corrects): the estimate is degraded,
    and the autopilot is given the last position that was not, never the degraded one nor the ramped vision."""
    lying = [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": sid, "field": "current_distance",
                         "direction": "uplink"}, "kind": "bias", "offset": 1.5, "start_s": 5.0}
             for sid in (10, 11, 12, 13)]  # fmt: skip
    profile = {"name": "vision-and-anchors", "rules": [*RAMP["rules"], *lying]}
    stage_cfg = SecureConfig(estimator="secekf", executor="inline", direction="uplink")
    run = fly(scenario, stage_cfg, profile=profile)
    got = vision_received(run.up_out)
    mav = mavlink.MAVLink(None)
    sent = (mav.parse_char(bytearray(r)) for r in run.up_out[-200:])
    flagged = [m.signal_quality for m in sent if m.get_type() == "DISTANCE_SENSOR"]
    assert len(flagged) > 100 and np.mean(np.array(flagged) == 1) > 0.9  # the estimate is not to be trusted
    late = got[got[:, 0] > 8.0]
    err = np.hypot(late[:, 1] - TRUE[0], late[:, 2] - TRUE[1])
    assert err.max() < 0.3, err.max()  # the last trusted fix, not the 1.5 m lie nor the ramp (up to 10 m)
