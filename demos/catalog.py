"""What others need to know about the demos without starting one: which demo flies which scenario, and the
block of loopback ports a run takes (``secuav-study`` runs demos side by side and needs both).

``secuav-demo --base-port B`` puts vehicle i's proxy port at B+i, its MAVSDK port at B+10+i, the GCS at
B+20 and the MQTT broker at B+21: a run takes :data:`PORT_SPAN` ports from B.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from secuav_common.scenario import Scenario

# the closed-loop demos that fly secuav-sim; height-hold, rangefinder-feed (ArduCopter SITL by default, a binary
# built outside the package), vision (PX4 SIH) and command-tamper (it scores a takeoff and a mission, not a hold)
# are not here
SCENARIO_OF_DEMO = {"wall-hover": "wall_hover", "localise": "anchors8", "formation": "formation"}
PROXY_OFFSET, API_OFFSET, GCS_OFFSET, MQTT_OFFSET = 0, 10, 20, 21
PORT_SPAN = MQTT_OFFSET + 1


def demo_for(scenario: Scenario) -> str:
    """The demo that flies this scenario; ``ValueError`` unless it is one of the demos' bundled scenarios."""
    from secuav_common.scenario import load_scenario

    for demo, bundled in SCENARIO_OF_DEMO.items():
        if load_scenario(bundled) == scenario:
            return demo
    known = ", ".join(SCENARIO_OF_DEMO.values())
    raise ValueError(f"closed-loop cells fly the demos, whose scenarios are the bundled {known}; "
                     f"{scenario.name!r} is none of them")  # fmt: skip
