"""The console under a four-vehicle fleet: update rate, CPU and memory of the service and of the page.

Starts a broker and a real ``secuav-console`` process, then plays four proxies
and a simulator onto the broker at the rates the bench produces (per vehicle:
truth and estimate at 20 Hz, readings of six sensors at 10 Hz, stats at 1 Hz,
retained states and an instance record). Reads the page's event stream for
vehicle 1 and, with ``--browser``, opens the real page in chromium and samples
its JavaScript heap and how long a frame takes. Prints figures every
``--every`` seconds and a summary; no assertions (issue 13 asks for 10 Hz or
more with four vehicles and smooth plots over a 10-minute session).

    .venv/bin/python benchmarks/console_bench.py [--duration 60] [--browser]
    .venv/bin/python benchmarks/console_bench.py --duration 600 --browser    # the 10-minute session
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import shutil
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import aiomqtt
import psutil

from secuav_common.broker import EmbeddedBroker, port_in_use

VEHICLES = 4
ROOT = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def play_fleet(port: int, stop: asyncio.Event) -> int:
    """Publish what four proxies and a simulator would; returns the number of messages sent."""
    sent = 0
    async with aiomqtt.Client("127.0.0.1", port) as client:
        for v in range(1, VEHICLES + 1):
            await client.publish(f"secuav/proxy/bench-{v}/online", json.dumps(
                {"instance": f"bench-{v}", "online": True, "since": time.time(), "vehicles": [v]}), retain=True)
            await client.publish(f"secuav/v{v}/attack/state", json.dumps(
                {"sysid": v, "profile": "wall-spoof", "hash": "0" * 64, "since": time.time(), "ok": True}), retain=True)
            await client.publish(f"secuav/v{v}/secure/state", json.dumps({"sysid": v, "estimator": "secekf",
                                                                          "ok": True}), retain=True)
        t0, tick, frames = time.monotonic(), 0, 0
        while not stop.is_set():
            t = time.monotonic() - t0
            for v in range(1, VEHICLES + 1):
                pos = [v + math.cos(t / 5), math.sin(t / 5), -2.5]
                await client.publish(f"secuav/v{v}/truth", json.dumps({"t_s": t, "pos_ned_m": pos}))
                await client.publish(f"secuav/v{v}/estimate", json.dumps(
                    {"estimator": "secekf", "distance_m": 2.5, "attacked": [0] if tick % 40 < 20 else []}))
                sent += 2
                if tick % 2 == 0:
                    sensors = {str(i): {"original_m": 2.5 + 0.01 * i, "forwarded_m": 2.5 + 0.1 * t % 1,
                                        "flagged": i == 0} for i in range(6)}
                    await client.publish(f"secuav/v{v}/readings", json.dumps(
                        {"sysid": v, "sensors": sensors, "position": {"original_ned_m": pos, "forwarded_ned_m": pos}}))
                    sent += 1
                if tick % 20 == 0:
                    frames += 200
                    await client.publish(f"secuav/v{v}/stats", json.dumps(
                        {"downlink": {"frames_in": frames, "frames_out": frames, "rewritten": frames // 10},
                         "uplink": {}, "latency_ms": {"p50": 0.3, "p99": 0.9}}))
                    sent += 1
            tick += 1
            await asyncio.sleep(max(0.0, t0 + tick * 0.05 - time.monotonic()))
    return sent


class StreamReader(threading.Thread):
    """Reads ``/api/stream?vehicle=1`` and counts events, samples and bytes."""

    def __init__(self, url: str) -> None:
        super().__init__(daemon=True)
        self.url = url
        self.events = self.samples = self.bytes = 0
        self.stop = threading.Event()

    def run(self) -> None:
        with urllib.request.urlopen(self.url, timeout=30) as response:
            for raw in response:
                if self.stop.is_set():
                    return
                self.bytes += len(raw)
                if raw.startswith(b"data:"):
                    self.events += 1
                    self.samples += len(json.loads(raw[5:])["samples"])


def open_browser(url: str) -> object | None:
    chromium, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if chromium is None or driver is None:
        print("--browser: chromium and chromium-driver are not installed; skipping the page", file=sys.stderr)
        return None
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1400,1200",
                "--enable-precise-memory-info"):
        options.add_argument(arg)
    browser = webdriver.Chrome(service=Service(driver), options=options)
    browser.get(url)
    return browser


PAGE_PROBE = """
const done = arguments[arguments.length - 1];
const times = []; let last = performance.now(); let n = 0;
function tick(now) { times.push(now - last); last = now; if (++n < 60) requestAnimationFrame(tick);
  else { times.sort((a, b) => a - b);
    done({heap_mb: performance.memory ? performance.memory.usedJSHeapSize / 1e6 : null,
          frame_p50_ms: times[30], frame_max_ms: times[times.length - 1],
          points: [...document.querySelectorAll('#plots .plot')].length}); } }
requestAnimationFrame(tick);
"""


async def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=60.0)
    p.add_argument("--every", type=float, default=10.0)
    p.add_argument("--browser", action="store_true", help="also open the page in chromium and sample it")
    args = p.parse_args()
    port, web = _free_port(), _free_port()
    async with EmbeddedBroker(port=port):
        console = subprocess.Popen([sys.executable, "-m", "webconsole", "--broker", f"mqtt://127.0.0.1:{port}",
                                    "--listen", f"127.0.0.1:{web}", "-q"], cwd=ROOT,
                                   env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip
        while not port_in_use("127.0.0.1", web):
            await asyncio.sleep(0.1)
        proc = psutil.Process(console.pid)
        stop = asyncio.Event()
        player = asyncio.create_task(play_fleet(port, stop))
        await asyncio.sleep(1.0)
        reader = StreamReader(f"http://127.0.0.1:{web}/api/stream?vehicle=1")
        reader.start()
        browser = await asyncio.to_thread(open_browser, f"http://127.0.0.1:{web}/") if args.browser else None
        proc.cpu_percent()
        t0 = time.monotonic()
        last_events, last_t = 0, t0
        rss0 = proc.memory_info().rss / 1e6
        print(f"{'t_s':>6} {'updates/s':>9} {'samples/s':>9} {'console cpu %':>13} {'rss MB':>7} {'page heap MB':>12}"
              f" {'frame p50/max ms':>16}")  # fmt: skip
        heap: list[float] = []
        while (now := time.monotonic()) - t0 < args.duration:
            await asyncio.sleep(min(args.every, args.duration - (now - t0)))
            now = time.monotonic()
            rate = (reader.events - last_events) / (now - last_t)
            last_events, last_t = reader.events, now
            page = await asyncio.to_thread(browser.execute_async_script, PAGE_PROBE) if browser else {}  # type: ignore[attr-defined]
            if page.get("heap_mb") is not None:
                heap.append(page["heap_mb"])
            frame = f"{page['frame_p50_ms']:.1f}/{page['frame_max_ms']:.1f}" if page else "-"
            print(f"{now - t0:6.0f} {rate:9.1f} {reader.samples / (now - t0):9.1f} {proc.cpu_percent():13.1f} "
                  f"{proc.memory_info().rss / 1e6:7.1f} {page.get('heap_mb') or 0:12.1f} {frame:>16}", flush=True)
        stop.set()
        sent = await player
        reader.stop.set()
        if browser is not None:
            browser.quit()  # type: ignore[attr-defined]
        rss1 = proc.memory_info().rss / 1e6
        console.terminate()
        console.wait(10)
    print(f"\nmessages published {sent} ({sent / args.duration:.0f}/s for {VEHICLES} vehicles); "
          f"stream {reader.events / args.duration:.1f} updates/s, {reader.bytes / args.duration / 1e3:.1f} kB/s; "
          f"console rss {rss0:.1f} -> {rss1:.1f} MB"
          + (f"; page heap {heap[0]:.1f} -> {heap[-1]:.1f} MB (max {max(heap):.1f})" if heap else ""))


if __name__ == "__main__":
    asyncio.run(main())
