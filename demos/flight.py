"""One demo flight: broker, simulator, proxy and one MAVSDK controller per vehicle.

Each demo says which scenario, which controller script per vehicle and how to
score; this module does the rest the same way for all of them. Controllers
write JSON lines (events "holding", "landing", "done" and control steps, each
with ``wall_s``) so the flight can be followed and joined with ground truth,
which arrives on ``secuav/v<sysid>/truth`` and is stamped on arrival.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from demos.mqtt_tap import Tap
from demos.scoring import Window
from demos.stack import Ports, Processes, tool
from secuav_common.broker import EmbeddedBroker
from secuav_common.controlplane.topics import CONSOLES_ONLINE, parse, vehicle_topic

if TYPE_CHECKING:
    from demos.px4 import Px4Options
    from demos.sitl import SitlOptions, Truth


@dataclass(frozen=True, slots=True)
class Case:
    attack: str | None  # library name or profile file; None = no attack
    secure: str  # estimator name, or "off"

    @property
    def slug(self) -> str:
        return f"attack-{'on' if self.attack else 'off'}_secure-{'off' if self.secure == 'off' else 'on'}"


@dataclass(frozen=True, slots=True)
class Controller:
    sysid: int
    module: str  # run as ``python -m module``
    args: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class Options:
    out: Path
    seconds: float = 40.0  # hold time; the first settle_s of it is not scored
    settle_s: float = 5.0
    seed: int | None = None
    ports: Ports = field(default_factory=Ports)
    attack_params: dict[str, Any] | None = None
    progress: bool = True  # a progress bar per flight on stderr
    sitl: SitlOptions | None = None  # the demos that fly ArduPilot SITL (secuav-demo --autopilot ardupilot)
    px4: Px4Options | None = None  # the demos that fly PX4 SIH (secuav-demo --autopilot px4)
    scenario: str | None = None  # a name (bundled or a plugin's) or a file of the demo's shape; None: its own


@dataclass
class Record:
    """What one flight left behind, by sysid."""

    window: Window
    truth: dict[int, list[tuple[float, dict[str, Any]]]]
    estimates: dict[int, list[tuple[float, dict[str, Any]]]]
    steps: dict[int, list[dict[str, Any]]]
    attack_ack: dict[int, dict[str, Any]]


def attack_payload(attack: str, params: dict[str, Any] | None) -> dict[str, Any]:
    """What goes on ``secuav/v<sysid>/attack/set``: a library name, or the content of a profile file."""
    path = Path(attack)
    if path.suffix in (".yaml", ".yml", ".json") or path.exists():
        from attack_profiles.profile import load_profile

        # Checked here (one line naming the file and a parameter it does not declare), then sent resolved:
        # the document with its parameters' values in place of their defaults.
        profile = load_profile(path, **(params or {}))
        return profile.model_dump(mode="json", exclude_none=True)
    # The demo applies the profile when the scored window opens, so it starts at once.
    return {"library": attack, "parameters": {"start_s": 0.0, **(params or {})}}


def read_jsonl(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


async def wait_for_event(path: Path, event: str, procs: Processes, name: str, timeout_s: float) -> float:
    """Wall time at which the controller logged ``event``; fails early if a process died."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        procs.check_alive()
        for entry in read_jsonl(path):
            if entry.get("kind") == "event" and entry.get("event") == event:
                return float(entry["wall_s"])
        proc = procs.running.get(name)
        if proc is not None and proc.returncode is not None:
            raise RuntimeError(f"{name} exited ({proc.returncode}) before {event!r}: see {path.parent}/{name}.log")
        await asyncio.sleep(0.2)
    raise TimeoutError(f"{name} did not reach {event!r} within {timeout_s:.0f} s: see {path.parent}/{name}.log")


class FlightProgress:
    """One bar per flight: the phase as its label, and the seconds of the hold (settle + scored) as progress."""

    def __init__(self, label: str, hold_s: float, enabled: bool) -> None:
        from tqdm import tqdm

        self._label = label
        self._bar = tqdm(total=round(hold_s), unit="s", leave=False, disable=not enabled,
                         bar_format="{desc} |{bar}| {n:.0f}/{total} s of hold")  # fmt: skip
        self._ticker: asyncio.Task[None] | None = None
        self.phase("starting broker, proxy, simulator")

    def phase(self, text: str) -> None:
        self._bar.set_description_str(f"    {self._label}: {text}")

    async def _tick(self, since: float) -> None:
        while True:
            self._bar.n = min(float(self._bar.total), time.time() - since)
            self._bar.refresh()
            await asyncio.sleep(0.5)

    def holding_since(self, wall_s: float) -> None:
        self._ticker = asyncio.create_task(self._tick(wall_s))

    async def __aenter__(self) -> FlightProgress:
        return self

    async def __aexit__(self, *exc: object) -> None:
        if self._ticker is not None:
            self._ticker.cancel()
        self._bar.close()


_announced: set[str] = set()


def announce_consoles(tap: Tap) -> None:
    """A ``secuav-console`` on this broker: say where to watch (once per URL and run)."""
    from tqdm import tqdm

    for sample in tap.samples:
        body = sample.payload
        topic = parse(sample.topic)
        if topic is not None and topic.scope == "console" and isinstance(body, dict) and body.get("online"):
            url = str(body.get("url"))
            if url not in _announced:
                _announced.add(url)
                tqdm.write(f"    watch live: {url} (secuav-console)")


async def apply_attack(tap: Tap, case: Case, opts: Options, sysids: list[int]) -> dict[int, dict[str, Any]]:
    """Push the case's attack to each vehicle's proxy over MQTT (what ``secuav-attack apply`` does); the acks."""
    acks: dict[int, dict[str, Any]] = {}
    if case.attack is None:
        return acks
    payload = attack_payload(case.attack, opts.attack_params)
    for s in sysids:
        ack = await tap.request(vehicle_topic(s, "attack", "set"), payload)
        if not ack.get("ok"):
            raise RuntimeError(f"the proxy rejected attack {case.attack!r} on vehicle {s}: {ack.get('error')}")
        acks[s] = ack
    return acks


async def hold_and_attack(bar: FlightProgress, tap: Tap, procs: Processes, log: Path, case: Case, opts: Options,
                          sysid: int, armed_timeout_s: float, arming: str = "waiting to arm, taking off",
                          ) -> tuple[float, float, float, dict[int, dict[str, Any]]]:  # fmt: skip
    """One vehicle whose controller (``controller1``) logs ``holding``, ``landing`` and ``done``: wait for the hold,
    settle, push the attack, wait for the landing. Returns (hold, scored from, landing, acks), wall-clock seconds."""
    bar.phase(arming)
    hold_s = await wait_for_event(log, "holding", procs, "controller1", armed_timeout_s)
    bar.holding_since(hold_s)
    bar.phase("settling")
    await asyncio.sleep(opts.settle_s)
    bar.phase("holding, attack on" if case.attack is not None else "holding")
    t_scored = time.time()
    acks = await apply_attack(tap, case, opts, [sysid])
    landing = await wait_for_event(log, "landing", procs, "controller1", opts.seconds + 60.0)
    bar.phase("landing")
    await wait_for_event(log, "done", procs, "controller1", 120.0)
    return hold_s, t_scored, landing, acks


def check_window(window: Window, truth: dict[int, list[tuple[float, dict[str, Any]]]], out: Path) -> None:
    """Refuse to score a flight whose scored window holds no ground truth of some vehicle (its figures would be
    NaN), saying why: the window's bounds, or a truth stream that stopped."""
    for sysid, samples in truth.items():
        if not any(window.start_s <= t <= window.end_s for t, _ in samples):
            raise RuntimeError(
                f"no ground truth of vehicle {sysid} in the scored window: it ran {window.end_s - window.start_s:.2f} s"
                f" (scored from {window.start_s:.2f}, first landing at {window.end_s:.2f}), {len(samples)} truth"
                f" samples in all; see {out}"
            )


@dataclass
class SitlHold:
    """What :func:`hold_on_sitl` leaves: the times of :func:`hold_and_attack` (wall-clock s), the acks, the proxy's
    estimates, the controller's log entries, and the true heights since arming with the ground's altitude."""

    hold_s: float
    t_scored: float
    landing: float
    acks: dict[int, dict[str, Any]]
    estimates: list[tuple[float, dict[str, Any]]]
    entries: list[dict[str, Any]]
    heights: list[tuple[float, float]]
    ground_m: float


async def hold_on_sitl(bar: FlightProgress, tap: Tap, procs: Processes, log: Path, case: Case, opts: Options,
                       truth: Truth, sysid: int, armed_timeout_s: float, arming: str = "waiting to arm, taking off",
                       ) -> SitlHold:  # fmt: skip
    """An ArduPilot SITL flight whose controller is started and whose ``truth`` follows SITL's state: arm, take off,
    hold under the case's attack and land (:func:`hold_and_attack`), then stop ``truth`` and read its heights from
    the controller's ``armed`` event on (from the scored window when it logged none)."""
    try:
        hold_s, t_scored, landing, acks = await hold_and_attack(
            bar, tap, procs, log, case, opts, sysid, armed_timeout_s, arming=arming
        )
    finally:
        truth.stop()
    estimates = [(x.wall_s, x.payload) for x in tap.on(vehicle_topic(sysid, "estimate"))]
    if truth.error:
        raise RuntimeError(truth.error)
    entries = read_jsonl(log)
    armed_s = next((float(e["wall_s"]) for e in entries if e.get("event") == "armed"), t_scored)
    heights, ground = truth.heights(armed_s)
    return SitlHold(hold_s, t_scored, landing, acks, estimates, entries, heights, ground)


def dump_jsonl(path: Path, rows: list[tuple[float, dict[str, Any]]]) -> None:
    path.write_text("".join(json.dumps({"wall_s": t, **d}) + "\n" for t, d in rows), encoding="utf-8")


async def fly(
    scenario: str, controllers: list[Controller], case: Case, opts: Options, attack_sysids: list[int]
) -> Record:
    """Fly ``case``; raw material (logs, truth, estimates, recordings) stays in ``out/<slug>/``."""
    out = opts.out / case.slug
    out.mkdir(parents=True, exist_ok=True)
    p = opts.ports
    n = len(controllers)
    sysids = [c.sysid for c in controllers]
    topics = [vehicle_topic(s, leaf, verb) for s in sysids
              for leaf, verb in (("truth", None), ("estimate", None), ("attack", "state"), ("secure", "state"))]
    topics.append(CONSOLES_ONLINE)
    seed = [] if opts.seed is None else ["--seed", str(opts.seed)]
    logs = {c.sysid: out / f"controller{c.sysid}.jsonl" for c in controllers}
    for path in logs.values():
        path.unlink(missing_ok=True)
    all_holding = out / "all-holding"  # the controllers' --hold-from: their holds end together
    all_holding.unlink(missing_ok=True)
    bar = FlightProgress(case.slug, opts.settle_s + opts.seconds, opts.progress)
    async with bar, EmbeddedBroker(port=p.mqtt), Tap("127.0.0.1", p.mqtt, topics) as tap, Processes(out) as procs:
        proxy = [tool("secuav-proxy"), "--scenario", scenario, "--secure", case.secure, "--broker", p.broker_url,
                 "--record", str(out / "record")]  # fmt: skip
        for i in range(n):
            proxy += ["--link", f"udpin://127.0.0.1:{p.proxy_vehicle + i}",
                      f"udpout://127.0.0.1:{p.api + i}", f"udpout://127.0.0.1:{p.gcs}"]  # fmt: skip
        await procs.start("proxy", proxy)
        await procs.start("sim", [
            tool("secuav-sim"), scenario, "--mavlink", f"udpout://127.0.0.1:{p.proxy_vehicle}",
            "--broker", p.broker_url, "--truth-csv", str(out / "truth.csv"), *seed,
        ])  # fmt: skip
        for i, c in enumerate(controllers):
            await procs.start(f"controller{c.sysid}", [
                sys.executable, "-m", c.module, "--url", f"udpin://127.0.0.1:{p.api + i}",
                "--seconds", str(opts.seconds), "--hold-from", str(all_holding), "--log", str(logs[c.sysid]), *c.args,
            ])  # fmt: skip
        announce_consoles(tap)
        bar.phase("taking off")
        holds = [await wait_for_event(logs[s], "holding", procs, f"controller{s}", 120.0) for s in sysids]
        all_holding.write_text(f"{time.time()}\n", encoding="utf-8")
        bar.holding_since(max(holds))
        bar.phase("settling")
        await asyncio.sleep(opts.settle_s)
        bar.phase("holding, attack on" if case.attack is not None else "holding")
        t_scored = time.time()
        acks = await apply_attack(tap, case, opts, attack_sysids)
        landings = [
            await wait_for_event(logs[s], "landing", procs, f"controller{s}", opts.seconds + 60.0) for s in sysids
        ]
        bar.phase("landing")
        for s in sysids:
            await wait_for_event(logs[s], "done", procs, f"controller{s}", 60.0)
        truth = {s: [(x.wall_s, x.payload) for x in tap.on(vehicle_topic(s, "truth"))] for s in sysids}
        estimates = {s: [(x.wall_s, x.payload) for x in tap.on(vehicle_topic(s, "estimate"))] for s in sysids}
    for s in sysids:
        dump_jsonl(out / f"truth{s}.jsonl", truth[s])
        dump_jsonl(out / f"estimates{s}.jsonl", estimates[s])
    window = Window(start_s=t_scored, end_s=min(landings), hold_s=max(holds))
    check_window(window, truth, out)
    steps = {s: [e for e in read_jsonl(logs[s]) if e.get("kind") == "step"] for s in sysids}
    return Record(window, truth, estimates, steps, acks)
