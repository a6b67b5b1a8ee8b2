"""``secuav-feed [SCENARIO] --to URL [--truth SRC] [--sensors LIST] ...``: a companion computer's sensor feed.

Makes the readings the scenario's ``external`` block declares (or ``--sensors``) from a true state, with
flightsim's noise models, and sends them to the autopilot as MAVLink from the companion's own component
(``--compid``, default 158 MAV_COMP_ID_PERIPHERAL; system id the vehicle's), through the proxy like any
ground station, so an uplink rule of the attack profile rewrites them on their way. A reading is made when
a true state arrives: the truth source's rate bounds the feed's (``secuav-sim --truth-hz``).

Bad input is one line on stderr and exit 2; a socket that cannot open, exit 1; Ctrl-C or SIGTERM stop it
cleanly (exit 130), the end of a recording with exit 0.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from flightsim.companion.feed import SENSORS
from secuav_common.broker import parse_broker_url
from secuav_common.controlplane.address import with_port
from secuav_common.loading import InputError
from secuav_common.logs import add_common_flags, cli_error, setup_logging
from secuav_common.scenario import Scenario, load_scenario
from secuav_common.urls import Endpoint, parse_endpoint

PROG = "secuav-feed"
RESTART_S = 1.0  # truth this far behind the last state is a restarted simulator, not a late sample
log = logging.getLogger(PROG)
EXAMPLES = """\
flightsim holding its height on a fed rangefinder, the feed through the proxy (it starts the broker):
  secuav-proxy --ground udpout://127.0.0.1:14540 --ground udpout://127.0.0.1:14550 \\
               --ground udpin://127.0.0.1:14600 --profile vehicle-bias.yaml --attack bypass
  secuav-sim companion_feed --broker mqtt://127.0.0.1:1883
  secuav-feed companion_feed --to udpout://127.0.0.1:14600 --truth mqtt://127.0.0.1:1883
  (take off to 5 m from QGroundControl/MAVProxy on 14550 or MAVSDK on 14540), then
  secuav-attack mode on          # the vehicle descends 2 m; its own altitude still says 5 m
with vehicle-bias.yaml:
  name: vehicle-bias
  rules:
    - target: {message: DISTANCE_SENSOR, sensor_id: 0, field: current_distance, direction: uplink}
      kind: bias
      offset_m: 2
ArduCopter SITL (RNGFND1_TYPE 10) from its own truth on a second serial port:
  secuav-feed ardupilot_height --sensors rangefinders --to udpout://127.0.0.1:14600 \\
              --truth tcp://127.0.0.1:5762
exit: 0 done (a recording ended), 1 a socket would not open, 2 bad input, 130 stopped (Ctrl-C, SIGTERM)
"""
SENSOR_NAMES = SENSORS


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Feed an autopilot a companion's sensor readings over MAVLink, through the proxy,\n"
        "from a true state and flightsim's noise models.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scenario", nargs="?", default="companion_feed",
                   help="scenario file or bundled name (its vehicle's external block says what to feed); "
                   "default companion_feed")  # fmt: skip
    p.add_argument("--to", required=True, metavar="URL",
                   help="where the autopilot is reached: a proxy ground endpoint, udpout://HOST:PORT "
                   "(the proxy listens there: --ground udpin://...) or udpin://HOST:PORT "
                   "(the proxy sends there, as to a GCS)")  # fmt: skip
    p.add_argument("--sysid", type=int, default=None, help="the vehicle to feed (default: the scenario's first)")
    p.add_argument("--truth", default=None, metavar="SRC",
                   help="mqtt://HOST[:PORT] (secuav-sim --broker: secuav/v<sysid>/truth; default "
                   "mqtt://127.0.0.1:1883, or --broker-port's); "
                   "udpin://, udpout:// or tcp://HOST:PORT (a SITL's truth: SIM_STATE, HIL_STATE_QUATERNION); "
                   "or a .tlog file")  # fmt: skip
    p.add_argument("--broker-port", type=int, metavar="N",
                   help="the broker's port (the truth's, without --truth: mqtt://127.0.0.1:N)")
    p.add_argument("--sensors", metavar="LIST",
                   help=f"comma-separated, of {', '.join(SENSOR_NAMES)} (default: what the scenario's "
                   "external block declares)")  # fmt: skip
    p.add_argument("--rate", type=float, metavar="HZ", help="every sensor at HZ (default: each sensor's rate_hz)")
    p.add_argument("--compid", type=int, default=158,
                   help="source component (default 158 PERIPHERAL; 197 VISUAL_INERTIAL_ODOMETRY, "
                   "191 ONBOARD_COMPUTER)")  # fmt: skip
    p.add_argument("--source-sysid", type=int, metavar="N",
                   help="source system id (default: the scenario's external.source_sysid, "
                   "else the vehicle's)")  # fmt: skip
    p.add_argument("--seed", type=int, help="noise seed (default: the scenario's seed)")
    p.add_argument("--speed", type=float, default=1.0, help="pace of a .tlog replay (0: as fast as possible)")
    p.add_argument("--status-interval", type=float, default=5.0, metavar="S",
                   help="one status line every S seconds (default 5)")  # fmt: skip
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    p.add_argument("-q", "--quiet", action="store_true", help="no status lines; warnings and errors only")
    add_common_flags(p)
    return p


@dataclass(slots=True)
class FeedConfig:
    scenario: Scenario
    sysid: int
    to: Endpoint
    truth: str
    sensors: list[str]
    rate_hz: float | None
    compid: int
    source_sysid: int
    seed: int | None
    speed: float
    status_interval_s: float
    quiet: bool


def parse_config(args: argparse.Namespace) -> FeedConfig:
    """The checked configuration; ``InputError`` or ``ValueError`` naming the flag and value otherwise."""
    from flightsim.companion.feed import default_sensors

    scenario = load_scenario(args.scenario)
    sysid = args.sysid if args.sysid is not None else scenario.vehicles[0].sysid
    try:
        vehicle = scenario.vehicle(sysid)
    except KeyError as exc:
        raise ValueError(f"--sysid {sysid}: {exc.args[0]}") from None
    to = parse_endpoint(args.to)
    if to.mode not in ("udpin", "udpout") or to.options:
        raise ValueError(f"--to {args.to}: the feed speaks udpin://HOST:PORT or udpout://HOST:PORT")
    sensors = [s.strip() for s in args.sensors.split(",") if s.strip()] if args.sensors else default_sensors(vehicle)
    for s in sensors:
        if s not in SENSOR_NAMES:
            raise ValueError(f"--sensors {args.sensors}: {s!r} is not one of {', '.join(SENSOR_NAMES)}")
    if not sensors:
        raise ValueError(f"{args.scenario}: vehicle {sysid} has no external block; name what to feed with --sensors")
    if args.rate is not None and not args.rate > 0:
        raise ValueError(f"--rate {args.rate}: must be positive")
    if not 1 <= args.compid <= 255:
        raise ValueError(f"--compid {args.compid}: must be 1..255")
    ext = vehicle.external
    source = args.source_sysid or (ext.source_sysid if ext and ext.source_sysid else sysid)
    if not 1 <= source <= 255:
        raise ValueError(f"--source-sysid {source}: must be 1..255")
    if not args.speed >= 0:
        raise ValueError(f"--speed {args.speed}: must be 0 (as fast as possible) or positive")
    if not args.status_interval > 0:
        raise ValueError(f"--status-interval {args.status_interval}: must be positive")
    truth = args.truth or "mqtt://127.0.0.1"
    if truth.startswith(("mqtt://", "mqtts://")):
        truth = with_port(truth, args.broker_port)
        parse_broker_url(truth)
    elif args.broker_port is not None:
        raise ValueError(f"--broker-port {args.broker_port}: the truth comes from {truth}, not from a broker")
    elif "://" in truth:
        ep = parse_endpoint(truth)
        if ep.mode not in ("udpin", "udpout", "tcp"):
            raise ValueError(f"--truth {truth}: a MAVLink truth source is udpin://, udpout:// or tcp://HOST:PORT")
    elif not Path(truth).is_file():
        raise ValueError(f"--truth {truth}: no such recording (or give mqtt://, udpin://, udpout://, tcp://)")
    return FeedConfig(scenario, sysid, to, truth, sensors, args.rate, args.compid, source, args.seed, args.speed,
                      args.status_interval, args.quiet)  # fmt: skip


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        config = parse_config(args)
        from flightsim.companion.feed import FeedBuilder
        from flightsim.mavlink.wire import Encoder

        # Built once here too, so a scenario the builder refuses (no rangefinders to feed) is bad input.
        FeedBuilder(config.scenario, config.sysid, config.sensors, Encoder(config.source_sysid, config.compid).mav)
    except (InputError, ValueError) as exc:
        return cli_error(PROG, str(exc), 2)
    setup_logging(args.verbose, args.quiet, noisy=("aiomqtt", "asyncio", "jsbsim"), json_lines=args.log_json)
    try:
        return asyncio.run(serve(config))
    except OSError as exc:
        return cli_error(PROG, f"cannot open a socket: {exc.strerror or exc}", 1)
    except KeyboardInterrupt:
        return 130


async def serve(config: FeedConfig, stop: asyncio.Event | None = None) -> int:
    """Feed until ``stop`` is set, SIGINT/SIGTERM arrive, or a recording ends."""
    from flightsim.companion.feed import FeedBuilder
    from flightsim.companion.truth import MavlinkTruth, MqttTruth, TlogTruth
    from flightsim.mavlink.udp import UdpLink
    from flightsim.mavlink.wire import Encoder

    stop = stop or asyncio.Event()
    signalled: list[int] = []
    loop = asyncio.get_running_loop()

    def on_signal(sig: int) -> None:
        signalled.append(sig)
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(sig, on_signal, sig)
    encoder = Encoder(config.source_sysid, config.compid)
    builder = FeedBuilder(config.scenario, config.sysid, config.sensors, encoder.mav, config.seed, config.rate_hz)
    home = config.scenario.world.home
    truth = config.truth
    source: MqttTruth | MavlinkTruth | TlogTruth
    if truth.startswith(("mqtt://", "mqtts://")):
        source = MqttTruth(parse_broker_url(truth), config.sysid)
    elif "://" in truth:
        source = MavlinkTruth(parse_endpoint(truth), home, config.sysid)
    else:
        source = TlogTruth(Path(truth), home, config.sysid, config.speed)
    link = await UdpLink(config.to, lambda data, now: None).open()
    out = sys.stdout
    if not config.quiet:
        print(f"{PROG}: vehicle {config.sysid} <- {', '.join(config.sensors)} as ({config.source_sysid}, "
              f"{config.compid}) to {config.to}, truth from {truth}", file=out, flush=True)  # fmt: skip
    last_t: float | None = None
    next_status = time.monotonic() + config.status_interval_s

    async def pump() -> None:
        nonlocal last_t, next_status
        nonlocal builder
        async for s in source.states():
            if last_t is not None and s.t_s + RESTART_S < last_t:
                # The simulator started again (its clock went back): new sensor clocks, same counts.
                counts = builder.counts
                builder = FeedBuilder(config.scenario, config.sysid, config.sensors, encoder.mav, config.seed,
                                      config.rate_hz)  # fmt: skip
                builder.counts = counts
                log.info("feed.truth_restarted", extra={"from_t_s": round(last_t, 2), "to_t_s": round(s.t_s, 2)})
            elif last_t is not None and s.t_s + 1e-9 < last_t:
                continue  # out of order (a reconnect's stale sample): the sensors' clocks only go forward
            last_t = s.t_s
            for msg in builder.messages(s):
                link.send(encoder.pack(msg))
            link.flush()
            now = time.monotonic()
            if not config.quiet and now >= next_status:
                next_status = now + config.status_interval_s
                sent = " ".join(f"{k}={v}" for k, v in sorted(builder.counts.sent.items()))
                print(f"{PROG}: t={s.t_s:.1f}s states={builder.counts.states} {sent or 'nothing sent'}",
                      file=out, flush=True)  # fmt: skip

    task = asyncio.create_task(pump(), name="feed")
    waiter = asyncio.create_task(stop.wait())
    try:
        await asyncio.wait({task, waiter}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for t in (task, waiter):
            t.cancel()
        for t in (task, waiter):
            with contextlib.suppress(asyncio.CancelledError, Exception):  # the feed's own error: raised below
                await t
        link.close()
    if task.done() and not task.cancelled() and task.exception() is not None:
        raise task.exception()  # type: ignore[misc]
    if not config.quiet:
        sent = " ".join(f"{k}={v}" for k, v in sorted(builder.counts.sent.items()))
        print(f"{PROG}: stopped after {builder.counts.states} states, {sent or 'nothing sent'}", file=out, flush=True)
    return 130 if signalled else 0


if __name__ == "__main__":
    sys.exit(main())
