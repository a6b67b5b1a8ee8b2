"""Container health checks that need no network client: ``python -m secuav_common.health CHECK...``.

Reads the kernel's socket tables of the container's network namespace
(``/proc/net/udp``, ``udp6``, ``tcp``, ``tcp6``), so a check costs a few
milliseconds and never becomes a peer of the service it checks (a UDP ground
endpoint pins its first peer; a probe must not be that peer).

- ``udp-bound PORT``: a UDP socket is bound to local PORT (the proxy's endpoints are open);
- ``tcp-peer PORT``: a TCP connection to remote PORT is established (connected to the broker).

Exit 0 when every check holds, else 1 with one line naming the first that failed.
"""

from __future__ import annotations

import sys
from pathlib import Path

_ESTABLISHED = "01"


def _rows(kind: str) -> list[list[str]]:
    rows: list[list[str]] = []
    for name in (kind, f"{kind}6"):
        path = Path("/proc/net") / name
        if path.exists():
            rows += [line.split() for line in path.read_text().splitlines()[1:] if line.strip()]
    return rows


def _port(address: str) -> int:
    return int(address.rsplit(":", 1)[1], 16)


def udp_bound(port: int) -> bool:
    return any(_port(row[1]) == port for row in _rows("udp"))


def tcp_peer(port: int) -> bool:
    return any(_port(row[2]) == port and row[3] == _ESTABLISHED for row in _rows("tcp"))


CHECKS = {"udp-bound": udp_bound, "tcp-peer": tcp_peer}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args or len(args) % 2:
        print("usage: python -m secuav_common.health (udp-bound PORT | tcp-peer PORT)...", file=sys.stderr)
        return 2
    for name, value in zip(args[::2], args[1::2], strict=True):
        check = CHECKS.get(name)
        if check is None or not value.isdigit():
            print(f"health: unknown check {name} {value}", file=sys.stderr)
            return 2
        if not check(int(value)):
            print(f"health: {name} {value}: no", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
