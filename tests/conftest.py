"""Shared fixtures: loopback ports that nobody else is using; every test leaves the logging set-up as it found it.

The suite runs side by side on several pytest-xdist workers (scripts/test.sh: ``-n``, ``--dist loadgroup``). A test
is safe to run beside any other when it shares nothing with it:

- Ports: take every port from ``udp_port()`` / ``tcp_port()`` (fixtures), ``free_udp_port()`` / ``free_tcp_port()``
  or ``free_port_block(n)`` (n consecutive ports) below; never a literal port, and never a command's default port
  (the embedded broker's 1883, the console's 8080, PX4's 14540/14550/14560): pass the port explicitly.
- Files: write under ``tmp_path`` only, never into the repository (``out/``) or ``~/.cache``; point a cache at
  ``tmp_path`` through its environment variable (``SECUAV_ARDUPILOT_CACHE``).
- Environment, working directory, module state: change them through ``monkeypatch`` so they are undone; the
  logging set-up is undone by ``_logging_as_found`` below.
- Time: a worker shares 2 cores with the others, so a process may start or answer seconds late. Wait for an event
  with a generous deadline (readiness, a reply, N frames arrived) instead of a fixed sleep, and judge rates and
  durations by the simulator's clock (``time_boot_ms``) or by counts, never by frames per wall-clock second.
- A test that takes more than about 20 s: mark it ``@pytest.mark.slow``; slow tests are handed out first.
- Only if two tests truly must not overlap, mark both ``@pytest.mark.xdist_group("name")``: loadgroup runs a group
  on one worker, one test after the other. Two groups exist for the machine's CPU (2 cores in CI), which their
  members would otherwise take from each other's real-time parts: ``flight_stack`` (a test that flies a whole
  demo stack: broker, simulator, proxy, MAVSDK controllers) and ``dask_study`` (a test that runs a Dask study).
"""

from __future__ import annotations

import logging
import os
import random
import socket
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hypothesis import settings

# No per-example deadline: a worker shares 2 cores with the others, and a property test judges values, never time
# (speed belongs in benchmarks/). Hypothesis's default 200 ms deadline failed examples that merely waited for a core.
settings.register_profile("secuav", deadline=None)
settings.load_profile("secuav")

# Ports are handed out from a band below the kernel's ephemeral range (32768-60999 on Linux), where no socket bound
# to port 0 (an MQTT client's side of a connection, a udpout's source port, a test's own bind to 0) can take one
# between our check and the test's bind; and below the band secuav-study draws its demo blocks from (20000-40000,
# study/closed_loop.py), leaving out the ports other MAVLink programs on the machine send to or bind (PX4 SITL's
# 14540/14550/14560+i and 18570+i, MAVProxy's 14550/14551). Each xdist worker draws from a slice of its own, so two
# workers never hand out one port.
BAND = (10_000, 20_000)
NOT_IN_BAND = (range(14_500, 14_700), range(18_500, 18_800))


def _ephemeral_low() -> int:
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


class _Ports:
    """This worker's slice of ``BAND``, walked from a random start (so two pytest sessions on one machine rarely
    meet) and never handing out a port twice until the slice wraps round; each port is checked free for UDP and
    TCP when it is handed out."""

    def __init__(self) -> None:
        workers = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
        index = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw") or 0) % workers
        band = [p for p in range(*BAND) if not any(p in r for r in NOT_IN_BAND)]
        size = len(band) // workers
        self.ports, self.size = band[index * size : (index + 1) * size], size
        self.next = random.randrange(size)
        self.lock = threading.Lock()
        # A machine whose ephemeral range starts inside the band: let the kernel choose (the old way).
        self.kernel_picks = _ephemeral_low() < BAND[1]

    def block(self, count: int) -> int:
        """The first of ``count`` consecutive ports, all free for UDP and TCP a moment ago."""
        with self.lock:
            for _ in range(self.size):
                start = self.next if self.next + count <= self.size else 0  # a block never runs past the slice
                self.next = (start + count) % self.size
                base = self.ports[start]
                if self.ports[start + count - 1] == base + count - 1 and all(map(_free, range(base, base + count))):
                    return base
        raise RuntimeError(f"no {count} free consecutive loopback ports in {self.ports[0]}-{self.ports[-1]}")


def _free(port: int) -> bool:
    for kind in (socket.SOCK_DGRAM, socket.SOCK_STREAM):
        with socket.socket(socket.AF_INET, kind) as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


_PORTS = _Ports()


def _kernel_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that was free a moment ago and that no other test of this session is given."""
    return _kernel_port(socket.SOCK_DGRAM) if _PORTS.kernel_picks else _PORTS.block(1)


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago and that no other test of this session is given."""
    return _kernel_port(socket.SOCK_STREAM) if _PORTS.kernel_picks else _PORTS.block(1)


def free_port_block(count: int) -> int:
    """The first of ``count`` consecutive loopback ports (UDP and TCP) for a command that takes a base port
    (``secuav-demo --base-port``)."""
    if _PORTS.kernel_picks:
        from study.closed_loop import free_port_block as study_block

        return study_block()
    return _PORTS.block(count)


@pytest.fixture
def udp_port() -> Callable[[], int]:
    return free_udp_port


@pytest.fixture
def tcp_port() -> Callable[[], int]:
    return free_tcp_port


@pytest.fixture(autouse=True)
def _logging_as_found() -> Iterator[None]:
    """A command's ``main()`` run in-process sets up logging for the whole process (secuav_common.logs): its
    handler writes to the stderr of that moment, a test's capture, and replaces pytest's own. Undone after each
    test (pytest's capture handlers come and go per phase and are left to it), so the next test logs where
    pytest expects."""
    root = logging.getLogger()
    before, level = set(root.handlers), root.level
    levels = {name: lg.level for name, lg in logging.root.manager.loggerDict.items() if isinstance(lg, logging.Logger)}
    yield
    for handler in root.handlers[:]:
        if handler not in before and not type(handler).__module__.startswith("_pytest"):
            root.removeHandler(handler)
    root.setLevel(level)
    for name, lg in logging.root.manager.loggerDict.items():
        if isinstance(lg, logging.Logger) and name in levels:
            lg.setLevel(levels[name])


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Tests marked ``slow`` first, in their order: xdist hands tests out in this order, so the long ones start at
    once and the run ends on short tests instead of waiting for a long one that started last. The sort is stable
    and the same on every worker (xdist checks that they all collect one order)."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
    if getattr(config.option, "loadgroup", False):  # set on xdist's workers under --dist loadgroup
        for item in items:
            _name_the_group(item)


def _name_the_group(item: pytest.Item) -> None:
    """``--dist loadgroup`` keeps tests together whose node id ends in ``@group``. pytest-xdist 3.8 appends it by
    setting ``item._nodeid``, which pytest 9.2 no longer reads (the id is ``item._id`` there), so every
    ``xdist_group`` mark was silently ignored; this appends it where xdist's own step did not take."""
    names = sorted({str(m.args[0] if m.args else m.kwargs.get("name", "default"))
                    for m in item.iter_markers("xdist_group")})  # fmt: skip
    if not names or "@" in item.nodeid.rsplit("]", 1)[-1]:
        return
    grouped = f"{item.nodeid}@{'_'.join(names)}"
    if hasattr(item, "_id"):
        from _pytest.nodeid import coerce_node_id  # pytest >= 9.2

        item._id = coerce_node_id(grouped)
    else:
        item._nodeid = grouped


def require_fast_path() -> None:
    """Skip a test of the compiled fast path where it is not built, as a user without a C compiler would have it;
    under CI it must be built (scripts/setup.sh installs the compiler), so a missing one fails instead."""
    from mitm_proxy.net import native_udp

    if native_udp.available():
        return
    if os.environ.get("CI"):
        pytest.fail("the compiled fast path is not built, but CI must test it (scripts/setup.sh installs gcc)")
    pytest.skip("the compiled fast path is not built here (no C compiler when the project was installed)")


@pytest.fixture
def fast_path() -> None:
    """A test of the compiled fast path itself (see :func:`require_fast_path`)."""
    require_fast_path()


@pytest.fixture(params=["native", "python"])
def proxy_path(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Run a proxy test on both forwarding paths: the compiled fast path and the pure-Python one
    (mitm_proxy/README.md, "The fast path"). Proxies started in-process or as a subprocess after this fixture
    (``secuav-proxy`` inherits the environment) take the path asked for. Use it on a whole module with
    ``pytestmark = pytest.mark.usefixtures("proxy_path")``."""
    from mitm_proxy.net import native_udp

    if request.param == "native":
        require_fast_path()
        monkeypatch.delenv(native_udp.FORCE_PYTHON_ENV, raising=False)
    else:
        monkeypatch.setenv(native_udp.FORCE_PYTHON_ENV, "1")
    return str(request.param)
