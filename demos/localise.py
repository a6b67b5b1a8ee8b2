"""The localisation demo (seed test case 1, live): hold (2.5, 2.5) among eight UWB anchors.

The controller (``demos/controllers/localise.py``) fixes its position from the
anchor ranges it receives through the proxy; the default attack ramps two
links (11 and 14). Scored from truth: horizontal error from the hold point, and
the error of the controller's own fix.
"""

from __future__ import annotations

from typing import Any

from demos.catalog import SCENARIO_OF_DEMO
from demos.flight import Case, Controller, Options, fly
from demos.scoring import position_metrics
from secuav_common.scenario import Scenario, load_scenario

SCENARIO = SCENARIO_OF_DEMO["localise"]
CONTROLLER = "demos.controllers.localise"
TARGET = (2.5, 2.5)
DEFAULT_ATTACK = "anchors-ramp"
DEFAULT_SECURE = "secekf"
AUTOPILOTS = ("flightsim",)  # the vehicles it flies: secuav-sim's


async def run_case(case: Case, opts: Options) -> dict[str, Any]:
    name = opts.scenario or SCENARIO
    target = TARGET if opts.scenario is None else hold_point(load_scenario(name), 1)
    controller = Controller(1, CONTROLLER, ("--scenario", name, "--target", f"{target[0]},{target[1]}"))
    record = await fly(name, [controller], case, opts, attack_sysids=[1])
    figures = position_metrics(record.truth[1], target, record.steps[1], record.estimates[1], record.window)
    figures.update(case=case.slug, attack=case.attack, secure=case.secure, attack_ack=record.attack_ack.get(1))
    return figures


def hold_point(scenario: Scenario, sysid: int) -> tuple[float, float]:
    """North, east of vehicle ``sysid``'s hold target (demos.catalog.demo_for checked that it has one)."""
    target = next(v for v in scenario.vehicles if v.sysid == sysid).target
    return float(target.pos_ned_m[0]), float(target.pos_ned_m[1])  # type: ignore[union-attr]


def summary(figures: dict[str, Any]) -> str:
    err, fix = figures["position_error_m"], figures.get("fix_error_m", {})
    flagged = ", ".join(f"{k} ({v:.0%})" for k, v in figures["flagged_by_proxy"].items()) or "none"
    return (
        f"position error rms {err['rms']:.2f} m, max {err['max']:.2f} m; "
        f"controller fix error rms {fix.get('rms', float('nan')):.2f} m; flagged {flagged}; "
        f"collided {figures['collided']}"
    )
