"""The .tlog reader and stamp: against pymavlink's own log reader, and on damaged logs."""

from __future__ import annotations

from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink import mavutil

from mavframe import tlog
from mavframe.frames import split
from tests.support.frames_support import distance, heartbeat, local_position, pack, unknown_frame


def _log(frames: list[bytes], t0: float = 1_700_000_000.0) -> bytes:
    return b"".join(tlog.stamp(t0 + 0.01 * k) + f for k, f in enumerate(frames))


def _frames() -> list[bytes]:
    return [pack(distance(cm=100 + k, sensor_id=k % 3)) if k % 2 else pack(heartbeat()) for k in range(40)]


def test_stamp_is_big_endian_microseconds() -> None:
    assert tlog.stamp(1.5) == (1_500_000).to_bytes(8, "big")


def test_reads_what_pymavlink_reads_with_the_same_stamps(tmp_path: Path) -> None:
    frames = [*_frames(), pack(local_position())]
    path = tmp_path / "a.tlog"
    path.write_bytes(_log(frames))
    ours = list(tlog.read(path))
    assert [e.raw for e in ours] == frames
    conn = mavutil.mavlink_connection(str(path))
    theirs = []
    while (msg := conn.recv_match(blocking=False)) is not None:
        theirs.append((msg._timestamp, bytes(msg.get_msgbuf())))
    conn.close()
    assert [raw for _, raw in theirs] == frames
    assert all(abs(a.t_s - b) < 1e-6 for a, (b, _) in zip(ours, theirs, strict=True))


def test_a_damaged_entry_costs_that_entry_only() -> None:
    frames = _frames()
    data = bytearray(_log(frames))
    at = len(_log(frames[:10])) + tlog.STAMP_LEN + 12  # inside frame 10's payload
    data[at] ^= 0xFF
    reader = tlog.TlogReader(bytes(data) + b"\x00\x01\x02")  # and a torn tail
    got = [e.raw for e in reader]
    assert got == frames[:10] + frames[11:]
    assert reader.skipped == 2


def test_a_frame_of_an_unknown_message_is_kept() -> None:
    frames = [pack(heartbeat()), unknown_frame(), pack(distance())]
    assert [e.raw for e in tlog.TlogReader(_log(frames))] == frames


@settings(max_examples=200, deadline=None)
@given(cut=st.integers(0, 2000), noise=st.binary(max_size=40))
def test_fuzz_garbage_spliced_in_never_loses_a_frame_outside_it(cut: int, noise: bytes) -> None:
    frames = _frames()
    data = _log(frames)
    cut = min(cut, len(data))
    damaged = data[:cut] + noise + data[cut:]
    got = [e.raw for e in tlog.TlogReader(damaged)]
    # Every entry wholly before the cut survives, and every entry wholly after it (noise cannot forge a CRC).
    ends, pos = [], 0
    for f in frames:
        pos += tlog.STAMP_LEN + len(f)
        ends.append(pos)
    before = [f for f, end in zip(frames, ends, strict=True) if end <= cut]
    after = [f for f, end in zip(frames, ends, strict=True) if end - len(f) - tlog.STAMP_LEN >= cut]
    assert got[: len(before)] == before
    if after:
        assert got[-len(after) :] == after
    assert all(split(raw).clean for raw in got)
