"""Which way a profile's rules act: toward the ground (downlink) or toward the vehicle (uplink).

Every rule's target has a ``direction``; leaving it out means ``downlink``:

- ``downlink`` (the default): the frames the vehicle sends. The ground station,
  MAVSDK, the console and the secure stage (on its default side) get the
  change; the autopilot itself never sees it, and flies on its own sensors.
- ``uplink``: the frames travelling to the vehicle, from a ground station or a
  companion computer. The autopilot is fed the change: a DISTANCE_SENSOR rule
  toward the vehicle lies to an offboard (MAVLink) rangefinder input, e.g.
  ArduPilot's ``RNGFNDx_TYPE 10`` or PX4's MAVLink distance sensor, and the
  autopilot's own estimate follows the lie. The ground sees only what the
  autopilot then reports.
- ``both``: either; a message that travels both ways is changed both ways.

A +5 m lie fed to the autopilot's MAVLink rangefinder 0, whatever the ground is told::

    rules:
      - target: {message: DISTANCE_SENSOR, sensor_id: 0, direction: uplink}
        kind: bias
        offset: 5

Where a lie toward the vehicle lands depends on which MAVLink inputs the autopilot
is set to take from a companion; measured on ArduCopter SITL and PX4 SIH, with
the parameters that enable each path, in docs/vehicle-inputs.md:

| message toward the vehicle | ArduPilot | PX4 |
|---|---|---|
| DISTANCE_SENSOR | ``RNGFNDn_TYPE 10``; as height ``EK3_SRC1_POSZ 2`` | always; ``EKF2_RNG_CTRL 1`` |
| VISION_POSITION_ESTIMATE, ODOMETRY | ``VISO_TYPE 1``, ``EK3_SRC1_POSXY 6`` | ``EKF2_EV_CTRL 1`` |
| GPS_INPUT | ``GPS1_TYPE 14`` | not taken |
| HIL_GPS | not taken | ``MAV_USEHILGPS 1`` |

ArduPilot matches a MAVLink rangefinder by orientation, not by DISTANCE_SENSOR
id; PX4 takes HIL_GPS only from the vehicle's own sysid.
Commands, missions and parameters (COMMAND_LONG/INT, MISSION_ITEM_INT,
PARAM_SET, SET_POSITION_TARGET_*) reach every autopilot without a parameter:
a rule toward the vehicle on them changes what it is told to do.

A profile touches the union of its rules' directions. The proxy says which
(``directions`` in ``secuav/v<N>/attack/state``: ``["downlink"]``, ``["uplink"]``,
both, or ``[]`` for no profile; ``secuav-attack apply`` and ``status``, the
console's vehicle panel, ``secuav-attack validate``, the ``attack.applied`` log
line and ``proxy.ready`` say it in words: "toward the ground", "toward the
vehicle"). A recording (``secuav-proxy --record DIR``) lists each profile and its
directions in ``profiles.json`` beside ``index.json``, whose entries name each
changed frame's own direction; ``secuav-record`` hears only what the vehicle
sends, so a rule toward the vehicle changes nothing there (it says so).

True copies, per direction. A rule toward the ground that rewrites a value in
one message leaves the truth in the vehicle's other messages that carry it
(the table below): ArduPilot sends its primary downward rangefinder in
RANGEFINDER as well as DISTANCE_SENSOR. ``secuav-attack validate``, which knows
no vehicle, warns as a condition ("RANGEFINDER.distance still carries the true
value if the vehicle sends it"); the proxy warns (``attack.true_copy``) only once
the vehicle is seen sending such a message, naming only those it sent: flightsim
and PX4 send no RANGEFINDER, so nothing is said there. RANGEFINDER carries the
lowest-id downward rangefinder, never a UWB anchor link (ids from 10) or a
range to a peer (from 50): a rule on such ids leaves it no twin. A rule toward
the vehicle leaves no true twin at all: the autopilot consumes the lie and
reports it in its own messages (ArduPilot in its DISTANCE_SENSOR and
RANGEFINDER). It is said once, as a note (``validate``'s ``note:`` lines, the
proxy's ``attack.vehicle_reports`` log line), not as a warning. A ``both`` rule is
judged on its downlink part and noted for its uplink part.

A deployment that must never change what the vehicle receives starts the
proxy with ``--no-uplink-attacks`` (config file: ``no_uplink_attacks: true``): a
profile with any rule toward the vehicle (``uplink`` or ``both``) is refused
wherever it comes from (``--profile`` at start, its file reload, MQTT
``attack/set``, ``secuav-attack apply``), with one line naming the rule, and the
profile in force stays.

The secure stage has a direction of its own (``--secure-direction``, ``direction``
in ``secure/set``, default ``downlink``): with ``uplink`` it reads its sensor group
from the frames travelling to the vehicle (a companion's redundant rangefinders)
and substitutes the secure estimate in them, so the autopilot receives it,
while everything the vehicle sends passes byte for byte
(mitm_proxy/README.md). With UWB anchor ranges fed alongside external vision,
the anchors group also writes its secure position into the VISION_POSITION_ESTIMATE
frames travelling to the vehicle (while degraded, the last position that was not):
a second source standing in for a vision feed that may lie (docs/px4.md, the
vision demo).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from secuav_common.loading import InputError

if TYPE_CHECKING:
    from attack_profiles.profile import Profile
    from attack_profiles.rule import RuleBase

DOWNLINK, UPLINK = "downlink", "uplink"
ORDER: tuple[str, ...] = (DOWNLINK, UPLINK)
WORDS = {DOWNLINK: "toward the ground", UPLINK: "toward the vehicle"}
_OF_TARGET = {"downlink": (DOWNLINK,), "uplink": (UPLINK,), "both": (DOWNLINK, UPLINK)}
# The deployment switch that forbids every change toward the vehicle, as its flag is spelt.
NO_UPLINK_FLAG = "--no-uplink-attacks"


def rule_directions(rule: RuleBase) -> tuple[str, ...]:
    """The directions one rule acts on, in :data:`ORDER`. A frame operation may act on more than its
    target says (``mission_shift`` with ``hide`` rewrites the read-back toward the ground too): it names them."""
    own = getattr(rule, "directions", None)
    if own is not None:
        return tuple(d for d in ORDER if d in {str(x) for x in own})
    return _OF_TARGET[rule.target.direction]


def directions_of(profile: Profile | None) -> list[str]:
    """The directions some rule of ``profile`` acts on, in :data:`ORDER` (empty: no profile, or no rules)."""
    if profile is None:
        return []
    found = {d for rule in profile.rules for d in rule_directions(rule)}
    return [d for d in ORDER if d in found]


def describe(directions: list[str] | tuple[str, ...]) -> str:
    """``toward the ground``, ``toward the vehicle``, ``toward the ground and toward the vehicle`` or
    ``nothing`` (a profile without rules)."""
    words = [WORDS[d] for d in ORDER if d in directions]
    return " and ".join(words) if words else "nothing"


def check_no_uplink(profile: Profile, source: str) -> None:
    """Refuse a profile that would change anything toward the vehicle (the deployment forbids it).

    One ``InputError`` naming the first such rule, its target and its direction.
    """
    for i, rule in enumerate(profile.rules):
        if UPLINK in rule_directions(rule):
            t = rule.target
            what = t.message if t.message is not None else f"quantity {t.quantity}"
            raise InputError(
                source,
                f"rules[{i}].target.direction",
                t.direction,
                f"{rule.kind} on {what} would change frames toward the vehicle, which this proxy forbids "
                f"({NO_UPLINK_FLAG})",
            )
