"""A fleet spread over two proxy processes behind one broker is one status view (docs/interfaces.md,
"Many vehicles, many cores").

Real processes: the first ``secuav-proxy`` starts the embedded broker on a free port, the second finds it
there; each serves its own vehicle (the second from a config file naming sysid 2). ``secuav-attack status``
sees both instances, each with its vehicle, and both vehicles' states and stats.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]
REPO = Path(__file__).resolve().parents[3]


def attack(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mitm_proxy.tools.attack_cli", *argv],
                          cwd=REPO, capture_output=True, text=True, timeout=60)  # fmt: skip


def wait_until(check: Callable[[], bool], timeout_s: float = 40.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not check():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.3)


def stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture
def two_proxies(tmp_path: Path, tcp_port: Callable[[], int], udp_port: Callable[[], int]) -> Iterator[str]:
    port = tcp_port()
    broker = f"mqtt://127.0.0.1:{port}"
    second = tmp_path / "fleet-b.yaml"
    second.write_text(f"instance: fleet-b\nbroker: embedded\nbroker_port: {port}\nlinks:\n"
                      f"  - sysid: 2\n    vehicle: udpin://127.0.0.1:{udp_port()}\n"
                      f"    ground: [udpout://127.0.0.1:{udp_port()}]\n", encoding="utf-8")  # fmt: skip
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    procs: list[subprocess.Popen[bytes]] = []
    logs = [(tmp_path / f"proxy-{i}.log").open("wb") for i in range(2)]
    try:
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "mitm_proxy", "--instance", "fleet-a", "--broker", "embedded",
             "--broker-port", str(port), "--vehicle", f"udpin://127.0.0.1:{udp_port()}",
             "--ground", f"udpout://127.0.0.1:{udp_port()}"],
            cwd=REPO, stdout=logs[0], stderr=subprocess.STDOUT, env=env))  # fmt: skip
        wait_until(lambda: attack("status", "--timeout", "1", "--broker", broker).returncode == 0)
        procs.append(subprocess.Popen([sys.executable, "-m", "mitm_proxy", "--config", str(second)],
                                      cwd=REPO, stdout=logs[1], stderr=subprocess.STDOUT, env=env))  # fmt: skip
        yield broker
    finally:
        for proc in reversed(procs):  # the broker's host last
            stop(proc)
        for log in logs:
            log.close()


def test_two_proxy_processes_are_one_status_view(two_proxies: str) -> None:
    broker = two_proxies

    def both() -> dict[str, object] | None:
        done = attack("status", "--json", "--timeout", "2", "--broker", broker)
        report = json.loads(done.stdout) if done.returncode == 0 else {}
        vehicles = report.get("vehicles", {})
        if not all(isinstance(vehicles.get(v, {}).get("stats"), dict) for v in ("v1", "v2")):
            return None
        return report

    wait_until(lambda: both() is not None)
    report = both()
    assert report is not None
    instances = report["instances"]
    assert isinstance(instances, dict)
    assert {name: (rec["online"], rec["vehicles"]) for name, rec in instances.items()} == {
        "fleet-a": (True, [1]),
        "fleet-b": (True, [2]),
    }
    assert instances["fleet-a"]["pid"] != instances["fleet-b"]["pid"]  # two processes
    for v in ("v1", "v2"):  # each vehicle's own state, from the process that serves it
        state = report["vehicles"][v]["attack/state"]  # type: ignore[index]
        assert state["sysid"] == int(v[1:])
    text = attack("status", "--timeout", "2", "--broker", broker)
    assert text.returncode == 0, text.stderr
    lines = text.stdout.splitlines()
    assert any(ln.startswith("proxy fleet-a: online") and ln.endswith("vehicles v1") for ln in lines)
    assert any(ln.startswith("proxy fleet-b: online") and ln.endswith("vehicles v2") for ln in lines)
    assert not any("served by" in ln for ln in lines)  # no vehicle claimed twice
