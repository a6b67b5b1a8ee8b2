"""The formation demo (seed test case 2, live): uav2 keeps 3 m from uav1 among eight anchors.

uav1 holds (4, 4) by trilateration; uav2 fixes itself the same way and keeps
its distance using the inter-vehicle range (id 51). The default attack ramps two
anchor links and the inter-vehicle range of uav2. Scored from truth: the error
of the true distance between the two from 3 m, and each vehicle's position error.
"""

from __future__ import annotations

from typing import Any

from demos.catalog import SCENARIO_OF_DEMO
from demos.flight import Case, Controller, Options, fly
from demos.localise import hold_point
from demos.scoring import position_metrics, range_metrics
from secuav_common.scenario import load_scenario

SCENARIO = SCENARIO_OF_DEMO["formation"]
CONTROLLER = "demos.controllers.localise"
LEADER = (4.0, 4.0)
KEEP_M = 3.0
DEFAULT_ATTACK = "anchors-ramp"
DEFAULT_PARAMS: dict[str, Any] = {"links": [11, 14, 51]}
DEFAULT_SECURE = "secekf"
AUTOPILOTS = ("flightsim",)  # the vehicles it flies: secuav-sim's


async def run_case(case: Case, opts: Options) -> dict[str, Any]:
    name = opts.scenario or SCENARIO
    lead, keep_m, start = LEADER, KEEP_M, "1.0,1.0"
    if opts.scenario is not None:  # a scenario of the formation's shape (demos.catalog.demo_for checked it)
        scenario = load_scenario(name)
        lead = hold_point(scenario, 1)
        second = next(v for v in scenario.vehicles if v.sysid == 2)
        keep_m = float(second.target.distance_m)  # type: ignore[union-attr]
        start = f"{second.start.pos_ned_m[0]},{second.start.pos_ned_m[1]}"
    where = f"{lead[0]},{lead[1]}"
    follow = ("--peer-range", "51", "--peer-at", where, "--keep", str(keep_m), "--target", start)
    controllers = [
        Controller(1, CONTROLLER, ("--scenario", name, "--target", where)),
        Controller(2, CONTROLLER, ("--scenario", name, *follow)),
    ]
    record = await fly(name, controllers, case, opts, attack_sysids=[2])
    leader = position_metrics(record.truth[1], lead, record.steps[1], record.estimates[1], record.window)
    follower = position_metrics(record.truth[2], None, record.steps[2], record.estimates[2], record.window)
    ranges = range_metrics(record.truth[1], record.truth[2], keep_m, record.window)
    return {
        "case": case.slug, "attack": case.attack, "secure": case.secure, "attack_ack": record.attack_ack.get(2),
        "range_error_m": ranges["range_error_m"],
        "collided": leader["collided"] or follower["collided"],
        "uav1": {k: v for k, v in leader.items() if k != "series"},
        "uav2": {k: v for k, v in follower.items() if k != "series"},
        "series": {"range": ranges["series"], "uav1": leader["series"], "uav2": follower["series"]},
    }  # fmt: skip


def summary(figures: dict[str, Any]) -> str:
    err = figures["range_error_m"]
    flagged = ", ".join(figures["uav2"]["flagged_by_proxy"]) or "none"
    return (
        f"range error rms {err['rms']:.2f} m, max {err['max']:.2f} m; uav2 flagged {flagged}; "
        f"collided {figures['collided']}"
    )
