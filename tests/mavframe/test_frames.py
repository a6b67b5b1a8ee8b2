"""The splitter: every valid frame found, in order, byte for byte; every skipped byte has a reason."""

from __future__ import annotations

from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from mavframe.frames import (
    BAD_CRC,
    BAD_FLAGS,
    BAD_LENGTH,
    CRC_EXTRA,
    GARBAGE,
    TEXT,
    TRUNCATED,
    MagicCursor,
    StreamFramer,
    crc_of,
    next_magic,
    split,
    tiles,
)
from tests.support.frames_support import (
    DISTANCE_SENSOR,
    distance,
    frames,
    garbage,
    heartbeat,
    local_position,
    mav,
    pack,
    parse_all,
    signed_mav,
    statustext,
    unknown_frame,
)


def test_one_v2_frame_is_the_datagram_itself() -> None:
    frame = pack(distance(cm=777, sensor_id=12), mav(sysid=3, compid=1, seq=42))
    res = split(frame)
    assert res.bad == [] and res.unknown == 0 and res.clean
    ((h, raw),) = res.frames
    assert raw is frame
    assert (h.version, h.msgid, h.sysid, h.compid, h.seq, h.signed) == (2, DISTANCE_SENSOR, 3, 1, 42, False)
    assert h.payload_len == len(frame) - 12


def test_v1_frame_header() -> None:
    frame = pack(heartbeat(), mav(sysid=9, compid=190, seq=200), v1=True)
    ((h, raw),) = split(frame).frames
    assert raw == frame and frame[0] == 0xFE
    assert (h.version, h.msgid, h.sysid, h.compid, h.seq, h.payload_len) == (1, 0, 9, 190, 200, 9)


def test_several_frames_in_order_v1_and_v2_mixed() -> None:
    m = mav()
    parts = [pack(heartbeat(), m), pack(distance(), m, v1=True), pack(local_position(), m), pack(statustext(), m)]
    res = split(b"".join(parts))
    assert [raw for _, raw in res.frames] == parts
    assert [h.seq for h, _ in res.frames] == [0, 1, 2, 3]
    assert res.bad == []


def test_signed_frame_recognised_with_its_13_byte_block() -> None:
    m = signed_mav()
    a, b = pack(distance(), m), pack(heartbeat(), m)
    res = split(a + b)
    assert [raw for _, raw in res.frames] == [a, b]
    h = res.frames[0][0]
    assert h.signed and h.incompat_flags == 1
    assert len(a) == 10 + h.payload_len + 2 + 13


def test_garbage_before_between_and_after_is_skipped_and_named() -> None:
    a, b = pack(distance()), pack(heartbeat())
    res = split(b"\x00junk" + a + b"\x07more junk" + b + b"\x80\x81")  # printable words alone are TEXT (below)
    assert [raw for _, raw in res.frames] == [a, b]
    assert res.bad == [GARBAGE, GARBAGE, GARBAGE]


def test_bad_crc_resyncs_one_byte_so_a_frame_inside_the_claimed_length_is_found() -> None:
    a, b = pack(distance()), pack(heartbeat())
    broken = bytearray(a)
    broken[1] += 5  # the claimed frame now ends 5 bytes into b
    res = split(bytes(broken) + b)
    assert [raw for _, raw in res.frames] == [b]
    assert res.bad == [BAD_CRC]


def test_corrupted_payload_byte_is_bad_crc_and_the_next_frame_survives() -> None:
    a, b = pack(distance()), pack(heartbeat())
    broken = bytearray(a)
    broken[14] ^= 0x40
    res = split(bytes(broken) + b)
    assert [raw for _, raw in res.frames] == [b]
    assert res.bad == [BAD_CRC]


def test_crc_uses_crc_extra() -> None:
    a = pack(distance())
    plen = a[1]
    good = crc_of(a, 10 + plen, CRC_EXTRA[DISTANCE_SENSOR])
    assert good == int.from_bytes(a[10 + plen : 12 + plen], "little")
    assert crc_of(a, 10 + plen, (CRC_EXTRA[DISTANCE_SENSOR] + 1) % 256) != good


def test_truncated_tail_and_short_header() -> None:
    a, b = pack(distance()), pack(heartbeat())
    res = split(a + b[:-3])
    assert [raw for _, raw in res.frames] == [a]
    assert res.bad == [TRUNCATED]
    res = split(a + b"\xfd\x05")
    assert [raw for _, raw in res.frames] == [a] and res.bad == [TRUNCATED]
    res = split(b"\xfe\x09")
    assert res.frames == [] and res.bad == [TRUNCATED]


def test_unknown_message_id_is_kept_and_counted() -> None:
    a, u, b = pack(distance()), unknown_frame(), pack(heartbeat())
    res = split(a + u + b)
    assert [raw for _, raw in res.frames] == [a, u, b]
    assert res.unknown == 1 and res.bad == []
    assert res.frames[1][0].msgid == 0xABCDE


def test_unknown_looking_garbage_never_hides_a_known_frame() -> None:
    b = pack(heartbeat())
    fake = unknown_frame(payload=bytes(30))[:12]  # header claims 30 bytes of payload: b starts inside it
    res = split(fake + b + bytes(30))
    assert b in [raw for _, raw in res.frames]
    assert res.bad and res.bad[0] == GARBAGE


def test_unknown_incompat_flags_are_refused() -> None:
    a = bytearray(pack(distance()))
    a[2] = 0x02
    b = pack(heartbeat())
    res = split(bytes(a) + b)
    assert [raw for _, raw in res.frames] == [b]
    assert res.bad == [BAD_FLAGS]


def test_v1_longer_than_its_message_is_refused_without_a_crc() -> None:
    a = bytearray(pack(heartbeat(), v1=True))
    a[1] = 40  # HEARTBEAT has 9 payload bytes and v1 has no extensions
    b = pack(heartbeat())
    res = split(bytes(a) + bytes(40) + b)
    assert [raw for _, raw in res.frames] == [b]
    assert res.bad == [BAD_LENGTH]


def test_empty_and_pure_garbage() -> None:
    assert split(b"").frames == [] and split(b"").bad == []
    res = split(b"\x00" * 100)
    assert res.frames == [] and res.bad == [GARBAGE]


def test_agrees_with_pymavlink_on_a_clean_stream() -> None:
    m = mav(sysid=2)
    parts = [pack(msg, m) for msg in (heartbeat(), distance(100), distance(200, 1), local_position(), statustext())]
    data = b"".join(parts)
    ours = [(h.msgid, h.seq) for h, _ in split(data).frames]
    theirs = [(msg.get_msgId(), msg.get_seq()) for msg in parse_all(data)]
    assert ours == theirs


FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FUZZ
@given(st.lists(st.tuples(garbage, frames()), min_size=1, max_size=8), garbage)
def test_fuzz_every_valid_frame_found_in_order_unchanged(chunks: list[tuple[bytes, bytes]], tail: bytes) -> None:
    data = b"".join(g + f for g, f in chunks) + tail
    valid = [f for _, f in chunks]
    res = split(data)
    found = [raw for _, raw in res.frames]
    # Garbage that happens to be a CRC-valid known frame (~1 in 65536 per look-alike header) *is*
    # a valid frame to any MAVLink parser; such draws say nothing about resynchronisation.
    assume(not any(h.msgid in CRC_EXTRA and raw not in valid for h, raw in res.frames))
    # The valid frames are a subsequence of what was found, in order, byte for byte...
    it = iter(found)
    assert all(any(f == x for x in it) for f in valid)
    # ...and anything else found is an unknown-id frame made of garbage bytes (not CRC-checkable).
    extra = [h for h, raw in res.frames if raw not in valid]
    assert all(h.msgid not in CRC_EXTRA for h in extra)
    if not any(g for g, _ in chunks) and not tail:
        assert found == valid and res.bad == []


@FUZZ
@given(st.lists(frames(), min_size=1, max_size=6), st.data())
def test_fuzz_single_byte_corruption_loses_at_most_that_frame(parts: list[bytes], data: st.DataObject) -> None:
    k = data.draw(st.integers(0, len(parts) - 1))
    frame = bytearray(parts[k])
    pos = data.draw(st.integers(1, len(frame) - 1))
    frame[pos] ^= data.draw(st.integers(1, 255))
    corrupted = [*parts[:k], bytes(frame), *parts[k + 1 :]]
    res = split(b"".join(corrupted))
    found = [raw for _, raw in res.frames]
    others = [p for i, p in enumerate(parts) if i != k]
    # A corrupted header whose CRC still matches by chance is a valid frame to any parser: skip such draws.
    assume(not any(h.msgid in CRC_EXTRA and raw not in parts and raw != bytes(frame) for h, raw in res.frames))
    it = iter(found)
    assert all(any(p == x for x in it) for p in others)


@FUZZ
@given(st.lists(frames(), min_size=1, max_size=5), st.integers(0, 12), st.data())
def test_a_signature_cut_short_never_swallows_the_next_frame(
    parts: list[bytes], keep: int, data: st.DataObject
) -> None:
    """A signed frame whose 13-byte signature lost bytes is dropped as truncated; every frame after it survives."""
    signed = pack(distance(cm=data.draw(st.integers(0, 65535))), signed_mav())
    cut = signed[: len(signed) - 13 + keep]  # the CRC still matches: only the signature is short
    k = data.draw(st.integers(0, len(parts)))
    stream = [*parts[:k], cut, *parts[k:]]
    res = split(b"".join(stream))
    # Bytes of the dropped frame that happen to form a CRC-valid known frame are one to any parser: skip those
    # draws; an unknown-id frame found among them (not CRC-checkable) is what the other fuzz tests allow too.
    assume(not any(h.msgid in CRC_EXTRA and raw not in parts for h, raw in res.frames))
    assert [raw for h, raw in res.frames if h.msgid in CRC_EXTRA] == parts
    assert TRUNCATED in res.bad


@FUZZ
@given(st.lists(frames(), min_size=0, max_size=8), st.binary(min_size=1, max_size=40))
def test_fuzz_tiles_is_true_for_back_to_back_frames_and_false_once_bytes_are_cut_off(
    chunks: list[bytes], tail: bytes
) -> None:
    data = b"".join(chunks)
    assert tiles(data)
    if chunks:
        assert not tiles(data[:-1])  # the last frame cut short
    if tail[0] not in (0xFD, 0xFE):
        assert not tiles(tail + data)  # garbage in front


@FUZZ
@given(st.binary(max_size=300), st.lists(st.integers(0, 40), max_size=60))
def test_the_magic_cursor_finds_what_a_fresh_search_finds(data: bytes, steps: list[int]) -> None:
    """The remembering search (each byte searched once per magic byte) answers like a search from scratch."""
    cursor = MagicCursor(data, len(data))
    lo = 0
    for step in steps:
        lo = min(lo + step, len(data))
        assert cursor.at_or_after(lo) == next_magic(data, lo, len(data))


@FUZZ
@given(
    st.lists(st.one_of(frames(), garbage, st.binary(max_size=8).map(lambda p: unknown_frame(payload=p))), max_size=8),
    st.lists(st.integers(1, 64), min_size=1, max_size=20),
)
def test_a_stream_with_unknown_ids_cut_anywhere_yields_the_frames_of_the_whole(
    parts: list[bytes], cuts: list[int]
) -> None:
    """An unknown-id frame is judged by whether a known frame starts inside it, whichever read it arrived in."""
    stream = b"".join(parts)
    framer = StreamFramer()
    got: list[bytes] = []
    i, k = 0, 0
    while i < len(stream):
        size = cuts[k % len(cuts)]
        got.extend(raw for _h, raw in split(framer.feed(stream[i : i + size])).frames)
        i, k = i + size, k + 1
    tail = b"\x00" * 600  # enough bytes behind anything held to show what it was
    got.extend(raw for _h, raw in split(framer.feed(tail)).frames)
    assert framer.held == 0
    assert got == [raw for _h, raw in split(stream + tail).frames]


def test_an_autopilots_boot_text_is_named_text_not_garbage() -> None:
    """ArduPilot SITL prints "Init ArduCopter ..." lines on its MAVLink serial link before and between frames."""
    a, b = pack(heartbeat()), pack(distance(cm=250))
    res = split(b"Init ArduCopter V4.7.0-dev (abc123)\r\n" + a + b"Free RAM: 123456\n" + b + b"\x00\x13\x88garbage")
    assert [raw for _, raw in res.frames] == [a, b]
    assert res.bad == [TEXT, TEXT, GARBAGE]  # the tail holds binary bytes: noise, whatever words follow
    assert split(b"ok" + a).bad == [GARBAGE]  # too short to call words


@FUZZ
@given(st.binary(min_size=1, max_size=60))
def test_only_printable_runs_are_text(junk: bytes) -> None:
    res = split(junk + pack(heartbeat()))
    printable = all(0x20 <= c < 0x7F or c in b"\t\n\r" for c in junk)
    if res.bad == [TEXT]:
        assert printable
    if printable and len(junk) >= 3 and len(res.frames) == 1:
        assert res.bad == [TEXT]


def test_a_printing_sender_has_its_short_printable_runs_named_text() -> None:
    """ArduPilot's console writes "Init Gyro" then its progress stars one at a time between frames, and a TCP
    read can cut a line to "0 ": while the caller knows the sender prints, such runs are text too."""
    a = pack(heartbeat())
    assert split(b"ok" + a).bad == [GARBAGE]
    assert split(b"*" + a + b"0 " + a + b"\n", printing=True).bad == [TEXT, TEXT, TEXT]
    assert split(b"\x00*" + a, printing=True).bad == [GARBAGE]  # a binary byte is never text
