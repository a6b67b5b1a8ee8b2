"""Whatever a ground station sends, the PX4 personality answers and the vehicle's numbers stay finite.

Sans-I/O: the personality is fed encoded frames directly (no socket), the
simulation is stepped by hand, and hypothesis picks the commands, parameters
and setpoints, including NaN, infinities and ids nobody assigned.
"""

from __future__ import annotations

import logging
import math

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from flightsim.mavlink import Px4Personality
from flightsim.mavlink.commands import HANDLERS
from flightsim.vehicle import Vehicle
from tests.support.flight_helpers import airborne

floats32 = st.floats(width=32, allow_nan=True, allow_infinity=True)
command_ids = st.one_of(st.sampled_from(sorted(HANDLERS)), st.integers(0, 65535))
frames = st.sampled_from([0, 1, 6, 7, 8, 9, 12, 21, 255])  # assigned and unassigned MAV_FRAMEs


class _Bench:
    """One airborne vehicle and its personality, shared by the examples (they only check invariants)."""

    def __init__(self) -> None:
        self.sim, self.v = airborne("anchors8")
        self.out: list[bytes] = []
        self.p = Px4Personality(self.v, self.out.append)
        self.gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.reader = mavlink.MAVLink(None)

    def feed(self, msg: mavlink.MAVLink_message) -> list[mavlink.MAVLink_message]:
        self.out.clear()
        self.p.receive(msg.pack(self.gcs), 0.0)
        replies = []
        for frame in self.out:
            replies.extend(self.reader.parse_buffer(frame) or [])
        return replies

    def advance(self, seconds: float) -> None:
        self.sim.run_for(seconds)
        self.p.tick(self.sim.t_s, 0.0)


_bench: _Bench | None = None


def bench() -> _Bench:
    global _bench
    if _bench is None:
        _bench = _Bench()
    return _bench


def _finite(v: Vehicle) -> bool:
    s = v.truth
    return all(math.isfinite(c) for c in (*s.pos_ned_m, *s.vel_ned_m_s, *s.quat))


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(command=command_ids, params=st.tuples(*[floats32] * 7), as_int=st.booleans(), frame=frames)
def test_every_command_gets_exactly_one_ack_and_nothing_goes_nan(
    command: int, params: tuple[float, ...], as_int: bool, frame: int
) -> None:
    b = bench()
    if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and params[1] == 21196:
        params = (params[0], 0.0, *params[2:])  # a forced disarm in the air is a legal crash; keep the flight going
    if as_int:
        x = 0 if not math.isfinite(params[4]) else max(-(2**31), min(2**31 - 1, int(params[4])))
        y = 0 if not math.isfinite(params[5]) else max(-(2**31), min(2**31 - 1, int(params[5])))
        msg = mavlink.MAVLink_command_int_message(1, 1, frame, command, 0, 0, *params[:4], x, y, params[6])
    else:
        msg = mavlink.MAVLink_command_long_message(1, 1, command, 0, *params)
    replies = b.feed(msg)
    acks = [r for r in replies if r.get_type() == "COMMAND_ACK"]
    assert len(acks) == 1 and acks[0].command == command
    assert acks[0].result in (0, 1, 2, 3, 4)
    b.advance(0.05)
    assert _finite(b.v)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    mask=st.integers(0, 0xFFFF),
    frame=frames,
    values=st.tuples(*[floats32] * 11),
)
def test_any_offboard_setpoint_is_used_or_refused_and_never_poisons_the_loops(
    mask: int, frame: int, values: tuple[float, ...]
) -> None:
    b = bench()
    before = (b.p.stats.offboard_setpoints, b.p.stats.offboard_rejected)
    b.feed(mavlink.MAVLink_set_position_target_local_ned_message(0, 1, 1, frame, mask, *values))
    after = (b.p.stats.offboard_setpoints, b.p.stats.offboard_rejected)
    assert sum(after) == sum(before) + 1  # counted one way or the other
    b.advance(0.05)
    assert _finite(b.v)
    assert all(math.isfinite(c) for c in b.v.estimate.pos_ned_m)


_INT_RANGES = {
    f"{sign}int{bits}_t": (0, 2**bits - 1) if sign == "u" else (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1)
    for sign in ("u", "")
    for bits in (8, 16, 32, 64)
}
_GCS_MESSAGES = [
    mavlink.MAVLink_param_set_message,
    mavlink.MAVLink_param_request_read_message,
    mavlink.MAVLink_param_request_list_message,
    mavlink.MAVLink_mission_count_message,
    mavlink.MAVLink_mission_item_int_message,
    mavlink.MAVLink_mission_item_message,
    mavlink.MAVLink_mission_request_int_message,
    mavlink.MAVLink_mission_request_list_message,
    mavlink.MAVLink_mission_set_current_message,
    mavlink.MAVLink_mission_clear_all_message,
    mavlink.MAVLink_mission_ack_message,
    mavlink.MAVLink_set_mode_message,
    mavlink.MAVLink_set_position_target_global_int_message,
    mavlink.MAVLink_set_attitude_target_message,
    mavlink.MAVLink_timesync_message,
    mavlink.MAVLink_file_transfer_protocol_message,
]


def _field(ftype: str, length: int) -> st.SearchStrategy[object]:
    if ftype == "char":
        return st.binary(max_size=length)
    one: st.SearchStrategy[object]
    if ftype in ("float", "double"):
        one = floats32
    else:
        lo, hi = _INT_RANGES[ftype]
        one = st.one_of(st.integers(lo, hi), st.sampled_from([lo, hi, 0, 1]))
    return st.lists(one, min_size=length, max_size=length) if length else one


@st.composite
def gcs_messages(draw: st.DrawFn) -> mavlink.MAVLink_message:
    cls = draw(st.sampled_from(_GCS_MESSAGES))
    values = {}
    types = dict(zip(cls.fieldnames, cls.fieldtypes, strict=True))  # declaration order
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))  # wire order
    for name in cls.fieldnames:
        values[name] = draw(_field(types[name], lengths[name]))
    if "target_system" in values:
        values["target_system"] = draw(st.sampled_from([0, 1, values["target_system"]]))
    if "target_component" in values:
        values["target_component"] = draw(st.sampled_from([0, 1, values["target_component"]]))
    return cls(**values)


class _Errors(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(msgs=st.lists(gcs_messages(), min_size=1, max_size=4))
def test_no_ground_message_makes_a_handler_fail(msgs: list[mavlink.MAVLink_message]) -> None:
    b = bench()
    errors = _Errors()
    logger = logging.getLogger("flightsim.mavlink.personality")
    logger.addHandler(errors)
    try:
        for msg in msgs:
            b.feed(msg)
        b.advance(0.04)
    finally:
        logger.removeHandler(errors)
    assert errors.records == [], [r.exc_info for r in errors.records]
    assert _finite(b.v)
