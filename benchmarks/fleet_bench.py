"""A fleet over 1 to 8 proxy processes on one machine: aggregate throughput and CPU (docs/interfaces.md,
"Many vehicles, many cores").

    nice .venv/bin/python benchmarks/fleet_bench.py [--procs 1,2,4,8] [--rate 15000] [--seconds 3]

For each process count N: N ``secuav-proxy`` processes, one vehicle each (attack bypassed, ``--broker
none``: the control plane is not what is measured), N paced senders replaying the vehicle frames of the
ArduPilot tlog (one frame per datagram, ``--rate`` frames/s each, one source port per vehicle as a real
vehicle has) and one receiver process counting what comes out of each proxy. Printed per N: the offered
and the delivered aggregate frames/s, the frames lost, the proxies' CPU (cores busy, summed over the
processes) and their CPU time per frame.

The senders and the receiver are Python and run on the same cores: on a 2-core machine the aggregate
flattens once the cores are full (then the cores, not the proxy, are the limit, and the senders' share of
them grows with N). That flattening is the honest figure for such a machine; on more cores it goes on.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import selectors
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from proxy_bench import _sender, cpu_s, free_port, load_tlog, ready, udp_socket  # noqa: E402


def _receiver(ports: list[int], counts: object, stop: object, up: object) -> None:
    """Count datagrams (one frame each) arriving on each port until ``stop`` is set."""
    sel = selectors.DefaultSelector()
    socks = []
    for i, port in enumerate(ports):
        s = udp_socket(port)
        s.setblocking(False)
        sel.register(s, selectors.EVENT_READ, i)
        socks.append(s)
    up.set()  # type: ignore[attr-defined]
    while not stop.is_set():  # type: ignore[attr-defined]
        for key, _ in sel.select(0.2):
            sock: socket.socket = key.fileobj  # type: ignore[assignment]
            n = 0
            while True:
                try:
                    sock.recv(65535)
                except BlockingIOError:
                    break
                n += 1
            counts[key.data] += n  # type: ignore[index]
    for s in socks:
        s.close()


def measure(n: int, datagrams: list[bytes], rate: float, seconds: float) -> dict[str, float]:
    ins, outs, srcs = [free_port() for _ in range(n)], [free_port() for _ in range(n)], [free_port() for _ in range(n)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = [subprocess.Popen([sys.executable, "-m", "mitm_proxy", "--broker", "none", "-q", "--attack", "bypass",
                               "--vehicle", f"udpin://127.0.0.1:{ins[k]}", "--ground", f"udpout://127.0.0.1:{outs[k]}"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
             for k in range(n)]  # fmt: skip
    try:
        for k in range(n):  # each proxy forwards, and has pinned its vehicle's source port
            probe = udp_socket(outs[k])
            if not ready(datagrams, ins[k], probe, src=srcs[k]):
                raise SystemExit(f"fleet_bench: proxy {k} forwarded nothing within 20 s")
            probe.close()
        counts = mp.Array("q", n, lock=True)
        stop, up = mp.Event(), mp.Event()
        rx = mp.Process(target=_receiver, args=(outs, counts, stop, up))
        rx.start()
        up.wait(10)
        c0 = sum(cpu_s(p.pid) for p in procs)
        senders = []
        t0 = time.monotonic()
        for k in range(n):
            done = mp.Value("d", 0.0)
            p = mp.Process(target=_sender, args=(ins[k], datagrams, rate, seconds, None, done, srcs[k]))
            p.start()
            senders.append((p, done))
        for p, _ in senders:
            p.join()
        elapsed = time.monotonic() - t0
        time.sleep(0.5)  # what is in flight
        cpu = sum(cpu_s(p.pid) for p in procs) - c0
        stop.set()
        rx.join()
        sent = n * int(rate * seconds)
        got = sum(counts[:])
        return {"n": n, "offered": sent / elapsed, "delivered": got / elapsed, "lost": sent - got,
                "sent": sent, "cores": cpu / elapsed, "cpu_us": cpu / max(got, 1) * 1e6}  # fmt: skip
    finally:
        for p in procs:
            p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--procs", default="1,2,3,4,6,8", help="process counts to measure")
    ap.add_argument("--rate", type=float, default=40000.0, help="offered frames/s per vehicle (per process)")
    ap.add_argument("--seconds", type=float, default=3.0, help="seconds of load per process count")
    ap.add_argument("--tlog", type=Path, default=ROOT / "tests/data/ardupilot-copter-guided.tlog")
    args = ap.parse_args()
    recorded = load_tlog(args.tlog)
    print(
        f"stream: {args.tlog.name}, {len(recorded)} frames, one per datagram; {args.rate:.0f} frames/s offered per "
        f"process for {args.seconds:g} s; machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}"
    )
    print(f"{'procs':>5} {'offered f/s':>12} {'delivered f/s':>14} {'x 1 proc':>9} {'lost':>8} {'cores busy':>11} "
          f"{'CPU us/f':>9}")  # fmt: skip
    base = 0.0
    for n in (int(x) for x in args.procs.split(",")):
        r = measure(n, recorded, args.rate, args.seconds)
        base = base or r["delivered"]
        print(f"{n:>5} {r['offered']:12.0f} {r['delivered']:14.0f} {r['delivered'] / base:9.2f} "
              f"{int(r['lost']):8d} {r['cores']:11.2f} {r['cpu_us']:9.1f}", flush=True)  # fmt: skip
    print(
        "delivered: frames/s out of all proxies together; cores busy: the proxies' CPU seconds per second, "
        "summed; CPU us/f: that CPU per frame delivered. Senders and receiver share the same cores: where frames\n"
        "are lost while the proxies' cores busy stay under the machine's cores, the bench's own Python senders and\n"
        "receiver were the limit, not the proxies."
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
