# ruff: noqa: E501  (Markdown tables: one row a line)
"""The user's guide to the frame operations: docs/profile.md's section (scripts/gen_docs.py)."""
GUIDE = """\
Value rules change numbers inside frames that pass. Four rules work on whole frames instead, on any
message of MAVLink common + ardupilotmega (`target.message` is the message's name, e.g.
`COMMAND_LONG`), on a live link only (`secuav-eval`'s offline arrays have no frames to add):

| kind | what it does | difference to its neighbour |
|---|---|---|
| `inject` | sends a forged message: once at `start_s`, or at `rate_hz` (`count` times, or until `end_s`) | nothing is received: the frame is new |
| `duplicate` | each targeted frame is followed by `copies` copies | `delay` holds a frame back; this adds to it |
| `frame_replay` | records the targeted frames between `record_start_s` and `record_end_s`, and sends them again from `start_s`, spaced as they came (`loop` repeats; `replace` drops the live ones while it plays) | `replay` puts old *values* into the frames that pass; this sends old *frames* as extra ones |
| `mission_shift` | moves the waypoints of a mission upload `north_m`/`east_m`; `hide` (default) makes the read-back show what was sent | a `bias` on one field could not tell an upload from a download |

`target.where` narrows `duplicate` and `frame_replay` to frames whose fields hold given values, as
for value rules (`{message: COMMAND_LONG, where: {command: MAV_CMD_NAV_TAKEOFF}}`).
Direction: `uplink` travels to the vehicle (a command, a mission), `downlink` to the ground (a spoofed
HEARTBEAT); an `inject` goes one way. `target.sysid` names the vehicle of the link (its downlink
frames, and the uplink frames to it), not the sender. They run on the activation clock (a profile
with `clock: vehicle` and a frame operation is refused). Example, the library's `inject-rtl`::

    rules:
      - target: {message: COMMAND_LONG, direction: uplink}
        kind: inject
        fields: {command: MAV_CMD_NAV_RETURN_TO_LAUNCH}
        start_s: 5

Fields of an injected message are wire units, as pymavlink names them, and enum names where the
dialect has one (`command: MAV_CMD_NAV_RETURN_TO_LAUNCH`; a list of names ORs a bitmask:
`base_mode: [MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, MAV_MODE_FLAG_SAFETY_ARMED]`; a field with no enum,
such as a COMMAND_LONG `param1`, takes any enum name of the dialect). A field left out is 0;
`target_system`/`target_component` default to the link's vehicle and its autopilot (uplink) or the
ground station last heard (downlink). The sender (`from_sysid`/`from_compid`) defaults to the ground
station whose HEARTBEAT the proxy last saw on that link, else 255/190 (uplink), or the vehicle's
autopilot (downlink). A frame with these default ids waits, at most 1.5 s past its time, until that
sender has been heard since the profile was applied, so that it can take the sender's next sequence
number; give `from_sysid` to send exactly on time. An unknown message or field, a wrong enum name or a value outside the field's
type is refused with the closest valid names.

Sequence numbers: a frame the proxy adds takes the next sequence number of the sender it
impersonates, and that sender's later frames leave renumbered (header and CRC made anew; signed
ones re-signed with the key), so a receiver sees no gap and no repeat; in a direction the proxy adds
frames to, a frame a rule drops gives its number back as well. Every other sender's frames pass byte
for byte (and in a direction nothing is added to, a dropped frame shows as a gap, as a lost one would). The link stats count what was added per direction:
`injected` (all added frames), of them `duplicated` and `replayed` (docs/interfaces.md; `secuav-attack
status` prints them when there are some).

Missions: `mission_shift` rewrites the `x`/`y` (degE7) of MISSION_ITEM_INT, and the degrees of the
older float MISSION_ITEM, of mission items (`mission_type` 0; fences and rally points stay) whose
command is a navigation command with a position (waypoint, loiter, land, takeoff, spline waypoint,
...) in a global frame, during an upload (uplink). It keeps the original per vehicle and mission seq;
with `hide` the vehicle's answers to a download (downlink) that still hold the moved position get the
original back. An item at 0/0 ("here") stays.

Signing: on a link whose frames are signed (MAVLink 2 signing), the proxy can forge or change a frame
only with the key (`secuav-proxy --signing-key FILE`); with it, every frame it adds is signed on the
proxy's own link id. Without it, a profile that would write frames in a direction where signed frames
have already arrived (a value rule that rewrites a field, `inject`, `duplicate`, `frame_replay`,
`mission_shift`) is refused when it is applied, with one line saying why, and the previous profile stays.
`secuav-attack validate` checks a profile without a link, so it cannot know: a profile it accepts
may still be refused by the proxy of a signed link. If signing starts after the profile was applied,
the frames it would forge there are withheld and `attack.signed_no_key` says so.
"""
