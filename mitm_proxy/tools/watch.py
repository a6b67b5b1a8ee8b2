"""``secuav-attack status --watch``: a live terminal table of every vehicle on the broker.

The MQTT listener of :mod:`mitm_proxy.tools.attack_cli` keeps the latest message per
topic on a :class:`~mitm_proxy.tools.board.Board`; this module only draws it,
once per ``--interval``, until Ctrl-C. Frame rates come from the difference of
two stats messages, so they are the proxy's own counts, not guesses.

Every declared vehicle switch shows: ``attack``, ``mode`` and ``secure`` in
their own words, and any other (a module in secuav_common/controlplane/switches/)
in a column of its own after them, headed by its kind, with what its state holds
(:func:`state_cell`).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from typing import TYPE_CHECKING, Any

from secuav_common.controlplane import switches
from secuav_common.controlplane.topics import parse, vehicle_topic

if TYPE_CHECKING:
    from mitm_proxy.tools.board import Board

HEAD = ("vehicle", "proxy", "attack", "mode", "secure")  # then one column per other vehicle switch
TAIL = ("down in/s", "out/s", "rewritten", "dropped", "bad", "p50 ms", "p99 ms", "stats age")
COLUMNS = HEAD + TAIL  # with the built-in switches alone
SHOWN = ("attack", "attack/mode", "secure")  # the switches the first columns spell out
STALE_S = 3.0  # stats older than this: the proxy stopped publishing (the table says so)
CELL_CHARS = 32  # a generic switch's cell is cut here
BOOKKEEPING = frozenset({"sysid", "since", "request_id", "ok", "error", "warnings"})  # not what a state holds


def other_switches() -> list[str]:
    """Every declared vehicle switch the first columns do not already show."""
    return [s.kind for s in switches.contracts() if s.scope == "vehicle" and s.kind not in SHOWN]


def state_cell(state: Any) -> str:
    """A switch's state in a few characters: its one field's value, or ``name=value`` pairs (no ids, times or
    verdicts); ``!`` after it when its last request was refused, ``(N warnings)`` when it has any."""
    if not isinstance(state, dict):
        return "-"
    held = {k: v for k, v in state.items() if k not in BOOKKEEPING}
    if len(held) == 1:
        text = _plain(next(iter(held.values())))
    else:
        text = " ".join(f"{k}={_plain(v)}" for k, v in held.items()) or "-"
    if len(text) > CELL_CHARS:
        text = text[: CELL_CHARS - 3] + "..."
    if state.get("ok") is False:
        text += " !"
    warnings = state.get("warnings")
    if isinstance(warnings, list) and warnings:
        text += f" ({len(warnings)} warning{'s' if len(warnings) > 1 else ''})"
    return text


def _profile_cell(attack: dict[str, Any]) -> str:
    """The profile's name; marked when it changes frames toward the vehicle (the default is toward the ground)."""
    name = attack.get("profile")
    if not name:
        return "none"
    directions = attack.get("directions")
    if not isinstance(directions, list) or "uplink" not in directions:
        return str(name)
    return f"{name} ({'both ways' if 'downlink' in directions else 'to vehicle'})"


def _plain(value: Any) -> str:
    return "-" if value is None else value if isinstance(value, str) else json.dumps(value, separators=(",", ":"))


class Rates:
    """Frames per second from consecutive stats snapshots of each vehicle."""

    def __init__(self) -> None:
        self._last: dict[int, tuple[float, int, int]] = {}  # sysid -> (arrival, frames_in, frames_out)
        self.rates: dict[int, tuple[float, float]] = {}

    def update(self, sysid: int, stats: dict[str, Any], arrived_s: float) -> None:
        down = stats.get("downlink") or {}
        now = (arrived_s, int(down.get("frames_in", 0)), int(down.get("frames_out", 0)))
        last = self._last.get(sysid)
        if last is not None and now[0] - last[0] > 0.2 and now[1] >= last[1]:
            dt = now[0] - last[0]
            self.rates[sysid] = ((now[1] - last[1]) / dt, (now[2] - last[2]) / dt)
        if last is None or now[0] - last[0] > 0.2:
            self._last[sysid] = now


def table(board: Board, rates: Rates, now_s: float) -> list[str]:
    """The rows to print (header first), from what the board holds now."""
    owners: dict[int, list[str]] = {}  # two names: two proxies claim the sysid (status says so)
    for name, rec in board.instances().items():
        for v in rec.get("vehicles", []) if rec.get("online") else []:
            owners.setdefault(v, []).append(name)
    others = other_switches()
    header = (*HEAD, *others, *TAIL)
    rows = [header]
    for sysid in _vehicles(board):
        attack = board.latest.get(vehicle_topic(sysid, "attack/state")) or {}
        mode = (board.latest.get(vehicle_topic(sysid, "attack/mode/state")) or {}).get("mode") or "-"
        secure = board.latest.get(vehicle_topic(sysid, "secure/state")) or {}
        stats = board.latest.get(vehicle_topic(sysid, "stats"))
        arrived = board.arrivals.get(vehicle_topic(sysid, "stats"))
        cells = [f"v{sysid}", ",".join(owners.get(sysid, ["?"])), _profile_cell(attack), mode,
                 "n/a" if secure.get("available") is False else (secure.get("estimator") or "off")]  # fmt: skip
        cells += [state_cell(board.latest.get(vehicle_topic(sysid, f"{kind}/state"))) for kind in others]
        if isinstance(stats, dict) and arrived is not None:
            rates.update(sysid, stats, arrived)
            down, up, lat = stats.get("downlink") or {}, stats.get("uplink") or {}, stats.get("latency_ms") or {}
            rate_in, rate_out = rates.rates.get(sysid, (None, None))
            age = now_s - arrived
            cells += [_num(rate_in), _num(rate_out),
                      str(down.get("rewritten", 0) + up.get("rewritten", 0)),
                      str(down.get("dropped", 0) + up.get("dropped", 0)),
                      str(down.get("bad_total", 0) + up.get("bad_total", 0)),
                      _num(lat.get("p50"), 3), _num(lat.get("p99"), 3),
                      f"{age:.1f} s" + (" STALE" if age > STALE_S else "")]  # fmt: skip
        else:
            cells += ["-"] * 8
        rows.append(tuple(cells))
    widths = [max(len(str(r[i])) for r in rows) for i in range(len(header))]
    return ["  ".join(str(c).ljust(w) for c, w in zip(row, widths, strict=True)).rstrip() for row in rows]


def _vehicles(board: Board) -> list[int]:
    found = set()
    for topic in board.latest:
        parsed = parse(topic)
        if parsed is not None and parsed.sysid is not None:
            found.add(parsed.sysid)
    return sorted(found)


def _num(value: Any, digits: int = 0) -> str:
    return "-" if not isinstance(value, int | float) else f"{value:.{digits}f}"


async def watch(board: Board, args: argparse.Namespace) -> int:
    """Redraw until Ctrl-C (exit 0); on a terminal the screen is cleared first, piped output gets blocks."""
    rates = Rates()
    tty = sys.stdout.isatty()
    try:
        while True:
            lines = table(board, rates, time.monotonic())
            stamp = time.strftime("%H:%M:%S")
            header = f"secuav-attack status --watch  {args.broker}  {stamp}  (Ctrl-C to stop)"
            text = "\n".join([header, *lines]) + "\n"
            sys.stdout.write(("\x1b[H\x1b[2J" if tty else "\n") + text)
            sys.stdout.flush()
            await asyncio.sleep(args.interval)
    except asyncio.CancelledError:
        return 0
