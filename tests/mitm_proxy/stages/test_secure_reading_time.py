"""The secure stage times each reading by the vehicle's stamp, through the real proxy on loopback UDP.

A vehicle approaches and backs off a wall (wall_hover's five forward sensors, 20 Hz) and stamps every reading
with its time_boot_ms; the link delivers the readings late: a jitter of up to 120 ms and, every second, 300 ms of
readings held back and released in one burst (a router or an autopilot batching). The same datagrams go to two
real proxies, one timing readings by their stamps (the default), one by their arrival, and what their ground
sides receive is compared with the true distance at the moment it arrives. Timed by arrival, a burst's readings
look fresh and the estimate trails the vehicle by the delay; timed by stamp, the filter places them in the past
and predicts to now. The schedule is drawn from a fixed seed; the assertions are on the estimates' errors only
(a late wake-up of this loop adds delay, which the stamps absorb and the arrival timing suffers).
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavframe.frames import split
from mavframe.layout import DISTANCE_SENSOR
from mitm_proxy.app import Proxy
from mitm_proxy.config import LinkConfig, ProxyConfig
from mitm_proxy.stages.secure.config import config_from_payload
from mitm_proxy.stages.secure.stage import SecureConfig, SecureStage
from secuav_common.loading import InputError
from secuav_common.scenario import load_scenario
from tests.support.secure_streams import StreamMaker, packet_of, wire_fields
from tests.support.udp_peers import Peer

FORWARD = 0
SET_PERIOD_S = 0.05
DURATION_S = 8.0
WARMUP_S = 2.0
SEED = 7
PARAMS = {"q_mps2": 2.0}  # the filters' white acceleration: the trajectory's peak is 0.8 (2 pi / 4)^2 = 2.0 m/s^2


def distance_m(t_s: float) -> float:
    """The true distance to the wall: 2.5 m +- 0.8 m over 4 s (up to 1.3 m/s)."""
    return 2.5 + 0.8 * math.sin(2 * math.pi * t_s / 4.0)


def schedule(seed: int = SEED) -> list[tuple[float, float]]:
    """(taken, released) of each set, seconds from the start: FIFO, 5 ms + up to 120 ms of jitter, and every
    second the sets taken in a 300 ms stretch held back until its end."""
    rng = np.random.default_rng(seed)
    out: list[tuple[float, float]] = []
    released = 0.0
    for k in range(round(DURATION_S / SET_PERIOD_S)):
        taken = k * SET_PERIOD_S
        release = taken + 0.005 + 0.12 * rng.random()
        phase = taken % 1.0
        if 0.5 <= phase < 0.8:  # held: out with the burst at the stretch's end
            release = max(release, taken - phase + 0.8 + 0.005)
        released = max(released, release)
        out.append((taken, released))
    return out


def wall_frames(mav: mavlink2.MAVLink, rng: np.random.Generator, boot_ms: int, taken_s: float) -> list[bytes]:
    true_m = distance_m(taken_s)
    return [mav.distance_sensor_encode(boot_ms, 10, 4000, round((true_m + 0.01 * rng.standard_normal()) * 100), 0,
                                       sid, FORWARD, 0, signal_quality=100).pack(mav)
            for sid in range(5)]  # fmt: skip


async def listen(peer: Peer, into: list[tuple[float, bytes]]) -> None:
    loop = asyncio.get_running_loop()
    while True:
        data, _ = await loop.sock_recvfrom(peer.sock, 65535)
        now = time.monotonic()
        into.extend((now, f) for _h, f in split(data).frames)


def errors(received: list[tuple[float, bytes]], start: float) -> np.ndarray:
    """Substituted distance of sensor 4 minus the true distance when it reached the ground, after the warm-up.

    Sensor 4 is the last of each set: the frame that completes a set carries the estimate of that set (the others
    carry the one before, which after a hold is as old as the hold whatever the timing)."""
    mav = mavlink2.MAVLink(None)
    out = []
    for t, raw in received:
        msg = mav.parse_char(bytearray(raw))
        if msg is None or msg.get_msgId() != DISTANCE_SENSOR or msg.id != 4 or t - start < WARMUP_S:
            continue
        out.append(msg.current_distance / 100.0 - distance_m(t - start))
    return np.asarray(out)


@pytest.mark.timeout(90)
@pytest.mark.parametrize("estimator", ["ekf", "secekf"])
async def test_stamp_timing_tracks_a_delayed_bursty_link_better_than_arrival_timing(
    udp_port: Callable[[], int], estimator: str
) -> None:
    ports = {mode: udp_port() for mode in ("stamp", "arrival")}
    grounds = {mode: Peer() for mode in ports}
    vehicle = Peer()
    cfgs = {mode: ProxyConfig(
        links=[LinkConfig(sysid=1, vehicle=f"udpin://127.0.0.1:{ports[mode]}",
                          ground=[f"udpout://127.0.0.1:{grounds[mode].port}"])],
        broker="none", scenario="wall_hover",
        secure={"estimator": estimator, "executor": "inline", "reading_time": mode, "params": PARAMS})
        for mode in ports}  # fmt: skip
    received: dict[str, list[tuple[float, bytes]]] = {mode: [] for mode in ports}
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    rng = np.random.default_rng(SEED)
    snaps: dict[str, dict[str, Any]] = {}
    try:
        async with Proxy(cfgs["stamp"]) as by_stamp, Proxy(cfgs["arrival"]) as by_arrival:
            tasks = [asyncio.create_task(listen(grounds[m], received[m])) for m in ports]
            start = time.monotonic()
            boot_ms = 10_000  # the vehicle booted 10 s before
            for taken, released in schedule():
                wait = start + released - time.monotonic()
                if wait > 0.002:
                    await asyncio.sleep(wait)
                for frame in wall_frames(mav, rng, boot_ms + round(taken * 1000), taken):
                    for port in ports.values():
                        vehicle.send(frame, port)
            await asyncio.sleep(0.3)
            for task in tasks:
                task.cancel()
            snaps = {"stamp": by_stamp.stats_snapshot()[1], "arrival": by_arrival.stats_snapshot()[1]}
    finally:
        for peer in (*grounds.values(), vehicle):
            peer.close()
    err = {mode: errors(received[mode], start) for mode in ports}
    rmse = {mode: float(np.sqrt(np.mean(e**2))) for mode, e in err.items()}
    print(estimator, {m: round(v, 3) for m, v in rmse.items()},
          {m: round(float(np.max(np.abs(e))), 3) for m, e in err.items()}, {m: e.size for m, e in err.items()})
    assert min(e.size for e in err.values()) > 80
    assert rmse["stamp"] < 0.5 * rmse["arrival"], rmse  # measured: 0.3-0.4 x
    by_stamp_stats, by_arrival_stats = snaps["stamp"]["secure"], snaps["arrival"]["secure"]
    assert by_stamp_stats["reading_time"] == "stamp" and by_arrival_stats["reading_time"] == "arrival"
    assert by_stamp_stats["readings_stamped"] == by_stamp_stats["readings"] == 5 * len(schedule())
    assert by_stamp_stats["readings_unstamped"] == 0 and by_stamp_stats["clock_sources"] == 1
    assert by_stamp_stats["clock_reanchors"] == 0  # bursts and jitter are no time jump
    assert by_arrival_stats["readings_stamped"] == 0


def stage_errors(estimator: str, mode: str) -> np.ndarray:
    """The same link through a SecureStage alone, each frame handed over at its planned release: deterministic."""
    stage = SecureStage(SecureConfig(estimator=estimator, executor="inline", reading_time=mode, params=PARAMS),
                        load_scenario("wall_hover"), 1)  # fmt: skip
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    rng = np.random.default_rng(SEED)
    out = []
    for taken, released in schedule():
        for frame in wall_frames(mav, rng, 10_000 + round(taken * 1000), taken):
            pkt = packet_of(frame, released)
            stage.process(pkt, released)
            fields = wire_fields(pkt)
            if fields["id"] == 4 and released >= WARMUP_S:
                out.append(fields["current_distance"] / 100.0 - distance_m(released))
    return np.asarray(out)


@pytest.mark.parametrize("estimator", ["ekf", "secekf"])
def test_the_same_link_without_the_network_gives_the_documented_margin(estimator: str) -> None:
    """The schedule of the end-to-end test with no wake-up of a loop in it. With ``-s`` it prints the figures
    docs/interfaces.md quotes (measured: ekf 0.048 / 0.127 m against 0.134 / 0.329, secekf 0.058 / 0.129 against
    0.151 / 0.374, RMSE / max)."""
    err = {mode: stage_errors(estimator, mode) for mode in ("stamp", "arrival")}
    rmse = {mode: float(np.sqrt(np.mean(e**2))) for mode, e in err.items()}
    worst = {mode: float(np.max(np.abs(e))) for mode, e in err.items()}
    print(estimator, "RMSE / max [m]", {m: f"{rmse[m]:.3f} / {worst[m]:.3f}" for m in err})
    assert rmse["stamp"] < 0.5 * rmse["arrival"] and worst["stamp"] < 0.5 * worst["arrival"], (rmse, worst)
    assert rmse["stamp"] < 0.08, rmse  # the sensors' own noise and the filter's lag on a 2 m/s^2 turn


def test_the_choice_is_a_field_of_secure_set() -> None:
    assert config_from_payload({"estimator": "ekf", "reading_time": "arrival"}).reading_time == "arrival"
    with pytest.raises(InputError, match="reading_time"):
        config_from_payload({"estimator": "ekf", "reading_time": "gps"})


@pytest.mark.timeout(60)
@pytest.mark.parametrize("estimator", ["ekf", "secekf"])
def test_a_link_without_delay_gets_the_same_frames_whichever_the_timing(estimator: str) -> None:
    """Stamps and arrivals agree on a link without delay: byte for byte the same frames to the ground."""
    scenario = load_scenario("anchors8")
    stages = {mode: SecureStage(SecureConfig(estimator=estimator, executor="inline", reading_time=mode), scenario, 1)
              for mode in ("stamp", "arrival")}  # fmt: skip
    maker = StreamMaker(scenario, seed=3, sway_m=0.5)
    same = changed = 0
    for fr in maker.frames(8.0):
        pkts = {mode: packet_of(fr.raw, fr.t_s) for mode in stages}
        if pkts["stamp"].header.msgid not in stages["stamp"].message_ids:
            continue
        for mode, stage in stages.items():
            stage.process(pkts[mode], fr.t_s)
        same += wire_fields(pkts["stamp"]) == wire_fields(pkts["arrival"])
        changed += pkts["stamp"].changed
        assert wire_fields(pkts["stamp"]) == wire_fields(pkts["arrival"])
    assert changed > 500 and same > 500


def test_the_stats_keep_their_keys_and_add_the_clock() -> None:
    stage = SecureStage(SecureConfig(estimator="ekf", executor="inline"), load_scenario("wall_hover"), 1)
    st = stage.stats()
    for key in ("active", "estimator", "group", "executor", "steps", "readings", "substituted_frames", "warnings"):
        assert key in st
    assert list(st)[-1] == "warnings"
    assert {k: st[k] for k in ("reading_time", "readings_stamped", "readings_unstamped", "clock_sources",
                               "clock_reanchors")} == {"reading_time": "stamp", "readings_stamped": 0,
                                                       "readings_unstamped": 0, "clock_sources": 0,
                                                       "clock_reanchors": 0}  # fmt: skip
    off = SecureStage(SecureConfig(), load_scenario("wall_hover"), 1)
    assert off.stats()["reading_time"] == "stamp"

