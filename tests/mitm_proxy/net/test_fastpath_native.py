"""The compiled fast path (mitm_proxy/net/_fastpath.c, native_udp.py) against the Python splitter and pipeline.

The verdict on one datagram is checked against :func:`mavframe.frames.split` on frames pymavlink packs
(v1, v2, signed) with garbage, bit flips and cuts: the fast path may only forward a datagram the Python
path would also forward untouched. Then whole proxies on loopback, on both paths: a real ArduPilot
recording goes through byte for byte and in order, and a rewrite profile's frames go up to Python between
frames that do not, and a runtime swap takes effect from the next datagram on.
"""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mavframe import codec, tlog
from mavframe.frames import CRC_EXTRA, split
from mavframe.packet import Direction, Packet
from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from mitm_proxy.core.pipeline import _selected
from mitm_proxy.net import native_udp
from tests.support.frames_support import (
    distance,
    frames,
    garbage,
    heartbeat,
    mav,
    mavlink,
    pack,
    parse_all,
    repacked,
    signed_mav,
    unknown_frame,
)

pytestmark = pytest.mark.timeout(60)


@st.composite
def ds_frames(draw: st.DrawFn) -> bytes:
    """A DISTANCE_SENSOR of a few sensor ids: v1, v2 (often truncated before the id), or signed."""
    sid = draw(st.integers(0, 7))
    tail = draw(st.integers(0, 1))  # orientation and what follows: 0 lets MAVLink 2 truncate down to the id
    msg = mavlink.MAVLink_distance_sensor_message(draw(st.integers(0, 2**32 - 1)), 10, 4000,
                                                  draw(st.integers(0, 65535)), draw(st.integers(0, 1)), sid,
                                                  tail * 25, tail * 255)  # fmt: skip
    kind = draw(st.sampled_from(["v1", "v2", "v2", "signed"]))
    m = signed_mav() if kind == "signed" else mav()
    m.seq = draw(st.integers(0, 255))
    return pack(msg, m, v1=kind == "v1")
TLOG = Path(__file__).resolve().parents[2] / "data" / "ardupilot-copter-guided.tlog"
NOBODY = native_udp.id_bits(frozenset())
needs_native = pytest.mark.usefixtures("fast_path")  # skipped where it is not built, a failure under CI


def _python_verdict(data: bytes, wanted: frozenset[int]) -> int:
    """Frames the Python pipeline would forward as they came with nothing to do, or -1."""
    res = split(data)
    if res.bad or res.unknown or not res.frames or any(h.msgid in wanted for h, _ in res.frames):
        return -1
    return len(res.frames)


@needs_native
@given(st.lists(st.one_of(frames(), garbage), min_size=1, max_size=6), st.data())
def test_fast_verdict_never_forwards_what_python_would_not(parts: list[bytes], data: st.DataObject) -> None:
    from mitm_proxy.net import _fastpath  # type: ignore[attr-defined]

    datagram = b"".join(parts)
    cut = data.draw(st.sampled_from(["none", "flip", "truncate"]))
    if cut == "flip" and datagram:
        i = data.draw(st.integers(0, len(datagram) - 1))
        datagram = datagram[:i] + bytes([datagram[i] ^ (1 << data.draw(st.integers(0, 7)))]) + datagram[i + 1 :]
    elif cut == "truncate" and len(datagram) > 1:
        datagram = datagram[: data.draw(st.integers(1, len(datagram) - 1))]
    wanted = frozenset(data.draw(st.sets(st.sampled_from([0, 30, 32, 33, 132, 253]), max_size=2)))
    fast = _fastpath.check(datagram, native_udp.id_bits(wanted))
    python = _python_verdict(datagram, wanted)
    assert fast == -1 or fast == python, (datagram.hex(), fast, python)


@needs_native
@given(st.lists(frames(), min_size=1, max_size=5))
def test_fast_verdict_forwards_clean_frames_of_ids_nobody_wants(parts: list[bytes]) -> None:
    """The fast path is not merely safe: valid v1/v2/signed frames nobody wants stay in C (a signature that
    happens to hold a magic byte is left to Python, which looks for a frame starting inside it)."""
    from mitm_proxy.net import _fastpath  # type: ignore[attr-defined]

    datagram = b"".join(parts)
    want = len(parts)
    for h, raw in split(datagram).frames:
        if h.signed and (b"\xfd" in raw[-13:] or b"\xfe" in raw[-13:]):
            want = -1
    assert _fastpath.check(datagram, NOBODY) == want


@needs_native
def test_fast_verdict_leaves_unknown_ids_and_wanted_ids_to_python() -> None:
    from mitm_proxy.net import _fastpath  # type: ignore[attr-defined]

    hb, ds = pack(heartbeat()), pack(distance())
    assert _fastpath.check(hb + ds, NOBODY) == 2
    assert _fastpath.check(hb + ds, native_udp.id_bits(frozenset({132}))) == -1
    assert _fastpath.check(hb + unknown_frame(), NOBODY) == -1
    assert _fastpath.check(b"", NOBODY) == -1
    assert _fastpath.check(pack(heartbeat(), mav(v1=True), v1=True), NOBODY) == 1
    assert max(CRC_EXTRA) < 65536  # the route's id bitmap covers the whole dialect


FILTER_IDS = st.sets(st.integers(0, 7), max_size=3)


def _python_filtered_verdict(data: bytes, wanted: frozenset[int], values: frozenset[int]) -> int:
    """As :func:`_python_verdict`, with DISTANCE_SENSOR narrowed to sensor ids ``values`` (the pipeline's rule)."""
    res = split(data)
    if res.bad or res.unknown or not res.frames:
        return -1
    for h, raw in res.frames:
        if h.msgid in wanted or (h.msgid == 132 and (h.signed or _selected(h, raw, (11, values)))):
            return -1
    return len(res.frames)


@needs_native
@given(st.lists(st.one_of(frames(), ds_frames(), garbage), min_size=1, max_size=6), FILTER_IDS, st.data())
def test_a_field_filter_never_forwards_what_python_would_not(parts: list[bytes], values: set[int],
                                                             data: st.DataObject) -> None:  # fmt: skip
    from mitm_proxy.net import _fastpath  # type: ignore[attr-defined]

    datagram = b"".join(parts)
    if data.draw(st.booleans()) and datagram:
        i = data.draw(st.integers(0, len(datagram) - 1))
        datagram = datagram[:i] + bytes([datagram[i] ^ (1 << data.draw(st.integers(0, 7)))]) + datagram[i + 1 :]
    wanted = frozenset(data.draw(st.sets(st.sampled_from([0, 30, 33]), max_size=1)))
    spec = native_udp.filter_specs({132: (11, frozenset(values))})
    fast = _fastpath.check(datagram, native_udp.id_bits(wanted), spec)
    python = _python_filtered_verdict(datagram, wanted, frozenset(values))
    assert fast == -1 or fast == python, (datagram.hex(), fast, python)


@needs_native
@given(st.lists(ds_frames(), min_size=1, max_size=5), FILTER_IDS)
def test_a_field_filter_keeps_untargeted_sensors_in_c(parts: list[bytes], values: set[int]) -> None:
    """Unsigned DISTANCE_SENSOR frames (v1, v2, payloads truncated before the id) of sensors outside the
    filter stay in C; one of a targeted sensor, or a signed one, sends the datagram up."""
    from mitm_proxy.net import _fastpath  # type: ignore[attr-defined]

    datagram = b"".join(parts)
    frames_in = split(datagram).frames
    up = any(h.signed or _selected(h, raw, (11, frozenset(values))) for h, raw in frames_in)
    want = -1 if up else len(parts)
    assert _fastpath.check(datagram, NOBODY, native_udp.filter_specs({132: (11, frozenset(values))})) == want


@needs_native
def test_a_field_filter_reads_0_past_a_truncated_payload() -> None:
    from mitm_proxy.net import _fastpath  # type: ignore[attr-defined]

    short = pack(mavlink.MAVLink_distance_sensor_message(1000, 10, 4000, 500, 0, 0, 0, 0))
    assert short[1] <= 11  # the id byte is not on the wire
    assert _fastpath.check(short, NOBODY, native_udp.filter_specs({132: (11, frozenset({1}))})) == 1
    assert _fastpath.check(short, NOBODY, native_udp.filter_specs({132: (11, frozenset({0}))})) == -1
    assert _fastpath.check(short, NOBODY, native_udp.filter_specs({132: (255, frozenset({0}))})) == -1
    with pytest.raises(ValueError):
        _fastpath.check(short, NOBODY, [(132, 256, bytes(32))])


@needs_native
def test_more_filters_than_the_route_holds_leave_the_rest_wanted_whole() -> None:
    from mitm_proxy.net import _fastpath  # type: ignore[attr-defined]

    many = {msgid: (0, frozenset({1})) for msgid in range(200, 200 + _fastpath.MAX_FILTERS + 4)}
    whole, specs, memo = native_udp.route_wants(frozenset(many) | {0}, many)
    assert memo == []
    assert [msgid for msgid, _, _ in specs] == sorted(many)[: _fastpath.MAX_FILTERS]
    assert whole == native_udp.id_bits(frozenset(sorted(many)[_fastpath.MAX_FILTERS :]) | {0})
    _fastpath.check(b"", whole, specs)  # the route takes them


# -- whole proxies on loopback, both paths ------------------------------------------------------------------


class _Gcs:
    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]

    async def datagrams(self, count: int, timeout_s: float = 10.0) -> list[bytes]:
        loop = asyncio.get_running_loop()
        out: list[bytes] = []
        while len(out) < count:
            out.append(await asyncio.wait_for(loop.sock_recv(self.sock, 65535), timeout_s))
        return out


def _vehicle_frames() -> list[bytes]:
    entries = list(tlog.TlogReader(TLOG.read_bytes()))
    return [e.raw for e in entries if e.header.sysid == 1]


async def _send_paced(sock: socket.socket, datagrams: list[bytes], port: int) -> None:
    for i, d in enumerate(datagrams):
        sock.sendto(d, ("127.0.0.1", port))
        if i % 50 == 49:
            await asyncio.sleep(0.002)  # the kernel's buffers, not the proxy, would otherwise be the test


@pytest.mark.usefixtures("proxy_path")
async def test_recording_goes_through_byte_for_byte_in_order(udp_port: Callable[[], int], proxy_path: str) -> None:
    recorded = _vehicle_frames()[:3000]
    datagrams = recorded[:1500] + [b"".join(recorded[i : i + 3]) for i in range(1500, len(recorded), 3)]
    gcs, port = _Gcs(), udp_port()
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{port}", ground=[f"udpout://127.0.0.1:{gcs.port}"])
    try:
        async with Proxy(ProxyConfig(links=[link], broker="none", attack="bypass")) as proxy:
            ep = proxy.links[0].vehicle
            assert isinstance(ep, native_udp.NativeUdpEndpoint) == (proxy_path == "native")
            await _send_paced(vehicle, datagrams, port)
            got = await gcs.datagrams(len(datagrams))
            assert got == datagrams  # the same datagrams, the same bytes, the same order
            down = proxy.stats_snapshot()[1]["downlink"]
            assert (down["datagrams_in"], down["frames_in"], down["frames_out"]) == (
                len(datagrams),
                len(recorded),
                len(recorded),
            )
            assert down["bytes_out"] == down["bytes_in"] == sum(map(len, datagrams))
            assert proxy.stats_snapshot()[1]["latency_ms"]["count"] == len(datagrams)
            assert ep.rx == len(datagrams) and proxy.links[0].grounds[0].tx == len(datagrams)
            if proxy_path == "native":  # all but the first (it pins the vehicle's address) stayed in C
                assert ep.fast_datagrams == len(datagrams) - 1
    finally:
        vehicle.close()
        gcs.sock.close()


@pytest.mark.usefixtures("proxy_path")
async def test_rewritten_frames_keep_their_place_among_forwarded_ones(
    udp_port: Callable[[], int], tmp_path: Path
) -> None:
    """A rewrite profile's frames go up to Python; the ones around them are not overtaken."""
    profile = tmp_path / "bias.yaml"
    profile.write_text("name: b\nrules:\n  - target: {message: DISTANCE_SENSOR, field: current_distance}\n"
                       "    kind: bias\n    offset_m: 1.0\n")  # fmt: skip
    gcs, port = _Gcs(), udp_port()
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    m = mav()
    sent = [pack(distance(cm=100 + i), m) if i % 4 == 0 else pack(heartbeat(), m) for i in range(400)]
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{port}", ground=[f"udpout://127.0.0.1:{gcs.port}"])
    try:
        async with Proxy(ProxyConfig(links=[link], broker="none", profile=profile)) as proxy:
            for d in sent:  # all at once: batches mix frames for Python and frames for the fast path
                vehicle.sendto(d, ("127.0.0.1", port))
            got = await gcs.datagrams(len(sent))
            for i, (before, after) in enumerate(zip(sent, got, strict=True)):
                if i % 4:
                    assert after == before
                else:
                    h, _raw = split(after).frames[0]
                    assert h.msgid == 132 and h.seq == split(before).frames[0][0].seq and after != before
            assert proxy.stats_snapshot()[1]["downlink"]["rewritten"] == 100
            ep = proxy.links[0].vehicle
            if isinstance(ep, native_udp.NativeUdpEndpoint):
                assert ep.fast_datagrams >= 290  # the heartbeats (but the first)
    finally:
        vehicle.close()
        gcs.sock.close()


@pytest.mark.usefixtures("proxy_path")
async def test_a_sensor_filter_rewrites_its_sensor_passes_the_others_and_moves_with_a_swap(
    udp_port: Callable[[], int],
) -> None:
    """A bias on DISTANCE_SENSOR sensor 3: its frames are rewritten, the other sensors' leave byte for byte (on the
    fast path without going up to Python, and sensor 3's too once the first taught the route its rewrite); a swap
    to sensor 0, acknowledged, moves that from the next datagram on, and no frame is lost or reordered on the way."""
    from attack_profiles.profile import parse_profile

    def bias_on(sid: int) -> Any:
        return parse_profile({"name": f"s{sid}", "rules": [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": sid},
                                                            "kind": "bias", "offset_m": 1.0}]}, "t.yaml")  # fmt: skip

    gcs, port = _Gcs(), udp_port()
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    m = mav()

    def batch(n: int) -> list[bytes]:  # sensors 0..3 in turn, a heartbeat now and then; sensor 0 truncated
        out = []
        for i in range(n):
            sid = i % 4
            msg = mavlink.MAVLink_distance_sensor_message(1000 + i, 10, 4000, 500, 0, sid, 0, 0)
            out.append(pack(heartbeat(), m) if i % 10 == 9 else pack(msg, m))
        return out

    def check(sent: list[bytes], got: list[bytes], target: int) -> int:
        rewritten = 0
        for before, after in zip(sent, got, strict=True):
            h, raw = split(before).frames[0]
            sid = codec.decode(Packet(raw, h, Direction.DOWNLINK, 0, 0.0))["id"] if h.msgid == 132 else None
            if sid == target:
                assert after != before and parse_all(after)[0].current_distance == 600
                assert split(after).frames[0][0].seq == h.seq
                assert after == repacked(before, current_distance=600)  # Python's re-pack, wherever it was made
                rewritten += 1
            else:
                assert after == before  # byte for byte
        return rewritten

    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{port}", ground=[f"udpout://127.0.0.1:{gcs.port}"])
    try:
        async with Proxy(ProxyConfig(links=[link], broker="none")) as proxy:
            assert proxy.slots[1].offer(bias_on(3)).ok
            first = batch(200)
            await _send_paced(vehicle, first, port)
            assert check(first, await gcs.datagrams(len(first)), 3) == 40  # i % 4 == 3, but no heartbeat
            ep = proxy.links[0].vehicle
            fast = ep.fast_datagrams if isinstance(ep, native_udp.NativeUdpEndpoint) else None
            if fast is not None:  # all but the first datagram and sensor 3's first frame stayed in C: sensor 3's
                assert fast == 200 - 1 - 1  # others differ from it only in their time, and the route repeats it
                assert ep.fast_rewritten == 40 - 1
            assert proxy.slots[1].offer(bias_on(0)).ok
            second = batch(200)
            await _send_paced(vehicle, second, port)
            assert check(second, await gcs.datagrams(len(second)), 0) == 50
            down = proxy.stats_snapshot()[1]["downlink"]
            assert down["frames_in"] == down["frames_out"] == 400 and down["rewritten"] == 90
            if fast is not None:  # the swap made the route forget sensor 3: sensor 0's first frame taught it
                assert ep.fast_datagrams - fast == 200 - 1
                assert ep.fast_rewritten == 40 - 1 + 50 - 1
                assert proxy.stats_snapshot()[1]["endpoints"][ep.name]["fast"] == {
                    "datagrams": ep.fast_datagrams, "rewritten": 88}
    finally:
        vehicle.close()
        gcs.sock.close()


@pytest.mark.usefixtures("proxy_path")
async def test_two_grounds_get_the_same_stream_with_a_filtered_sensor_rewritten_in_place(
    udp_port: Callable[[], int],
) -> None:
    """The default configuration's shape, two ground endpoints, and a bias on sensor 0: each ground gets every
    datagram, in order, sensor 0's rewritten and identical on both, the other sensors' byte for byte."""
    from attack_profiles.profile import parse_profile

    profile = {"name": "s0", "rules": [{"target": {"message": "DISTANCE_SENSOR", "sensor_id": 0},
                                        "kind": "bias", "offset_m": 1.0}]}  # fmt: skip
    gcs, mavsdk, port = _Gcs(), _Gcs(), udp_port()
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    m = mav()
    sent = [pack(distance(cm=500, sensor_id=i % 3), m) if i % 5 else pack(heartbeat(), m) for i in range(300)]
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{port}",
                      ground=[f"udpout://127.0.0.1:{gcs.port}", f"udpout://127.0.0.1:{mavsdk.port}"])  # fmt: skip
    try:
        async with Proxy(ProxyConfig(links=[link], broker="none")) as proxy:
            assert proxy.slots[1].offer(parse_profile(profile, "t.yaml")).ok
            await _send_paced(vehicle, sent, port)
            one, two = await gcs.datagrams(len(sent)), await mavsdk.datagrams(len(sent))
            assert one == two
            changed = [i for i, (a, b) in enumerate(zip(sent, one, strict=True)) if a != b]
            assert changed == [i for i in range(300) if i % 5 and i % 3 == 0]
            assert all(parse_all(one[i])[0].current_distance == 600 for i in changed)
            assert [ep.tx for ep in proxy.links[0].grounds] == [len(sent), len(sent)]
    finally:
        vehicle.close()
        gcs.sock.close()
        mavsdk.sock.close()


@pytest.mark.usefixtures("proxy_path")
async def test_hostile_input_is_counted_and_over_budget_while_valid_frames_pass(udp_port: Callable[[], int]) -> None:
    """More garbage than the per-second budget (pipeline.HOSTILE_BYTES_PER_S) between valid datagrams: the
    garbage is counted and, once over budget, dropped unsplit; every valid datagram still leaves as it came."""
    gcs, port = _Gcs(), udp_port()
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    m = mav()
    junk = b"\x00\x13" * 1000  # 2000 bytes, no magic byte: cheap for the Python splitter too
    valid: list[bytes] = []
    plan: list[bytes] = []
    for i in range(200):  # 400 kB of garbage in all, well over the 256 kB budget
        good = pack(heartbeat(), m) + pack(distance(cm=i), m)
        valid.append(good)
        plan += [good, junk, good[:12] + junk[:50]]  # a whole datagram, garbage, a frame cut short
    link = LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{port}", ground=[f"udpout://127.0.0.1:{gcs.port}"])
    try:
        async with Proxy(ProxyConfig(links=[link], broker="none", attack="bypass")) as proxy:
            for start in range(0, len(plan), 30):  # in steps the proxy has taken, so no kernel buffer overflows
                for d in plan[start : start + 30]:
                    vehicle.sendto(d, ("127.0.0.1", port))
                for _ in range(500):
                    if proxy.stats_snapshot()[1]["downlink"]["datagrams_in"] >= min(start + 30, len(plan)):
                        break
                    await asyncio.sleep(0.005)
            got = await gcs.datagrams(len(valid))
            assert got == valid
            down = proxy.stats_snapshot()[1]["downlink"]
            assert down["datagrams_in"] == len(plan) and down["frames_out"] == 2 * len(valid)
            assert down["bad"].get("over_budget", 0) > 0 and down["bad"].get("garbage", 0) > 0
    finally:
        vehicle.close()
        gcs.sock.close()


@needs_native
async def test_what_the_kernel_would_not_take_leaves_in_order_before_anything_newer(
    udp_port: Callable[[], int],
) -> None:
    """The send queue of a fast-path endpoint (a full send buffer is rare on loopback, so it is filled here
    directly): what waits goes first and a datagram written meanwhile goes behind it."""
    from secuav_common.urls import parse_endpoint

    gcs = _Gcs()
    ep = native_udp.NativeUdpEndpoint(parse_endpoint(f"udpout://127.0.0.1:{gcs.port}"), "ground")
    await ep.open()
    try:
        m = mav()
        a, b, c = pack(heartbeat(), m), pack(distance(cm=1), m), pack(distance(cm=2), m)
        assert ep._queue([a, b]) and ep._write(c)
        assert await gcs.datagrams(3) == [a, b, c]
        assert ep.queued == 3 and ep.tx == 3 and not ep._backlog
    finally:
        ep.close()
        gcs.sock.close()
