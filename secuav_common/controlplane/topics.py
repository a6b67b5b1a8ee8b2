"""The topic grammar of the control plane, spelled once: builders and the one parser.

Every topic is ``secuav/<key>/<leaf>[/<verb>]``
(docs/interfaces.md#mqtt-control-plane-json-payloads-vehicle-key-vsysid):

- ``key`` is a vehicle (``v<sysid>``), ``proxy`` or ``console``;
- a vehicle's ``leaf`` may have two levels (``attack/mode``), a proxy's or a
  console's has one, and under ``proxy``/``console`` the leaf may follow an
  instance or console id (``secuav/proxy/<instance>/routes/state``);
- ``verb`` is ``set`` (a request to the proxy) or ``state`` (its retained
  answer); streams (``stats``, ``estimate``, ``truth``, ``readings``) and the
  online records have none.

:func:`parse` turns a topic into a :class:`Topic` (or ``None`` when it is not
ours); the builders below are the only places that write one.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

PREFIX = "secuav"
PROXY_KEY = "proxy"
CONSOLE_KEY = "console"
VERBS = ("set", "state")
ANY = "+"  # one topic level, any value (MQTT wildcard)

# Vehicle leaves the proxy and the simulator publish as streams; the switches' leaves, which also take the
# verbs, are declared by the switches themselves (secuav_common/controlplane/switches/).
STREAMS = ("stats", "estimate", "truth", "readings")
INSTANCE_RE = re.compile(r"\A[A-Za-z0-9_.-]{1,64}\Z")
_VEHICLE_KEY = re.compile(r"\Av(\d{1,3})\Z")

Scope = Literal["vehicle", "proxy", "console"]
Verb = Literal["set", "state"]


@dataclass(frozen=True, slots=True)
class Topic:
    """A parsed topic: ``scope`` (vehicle, proxy, console), ``key`` (``v3``, an instance or console id, or
    ``None`` for a proxy-wide topic), ``leaf`` (``attack/mode``, ``stats``, ``online``...) and ``verb``."""

    scope: Scope
    key: str | None
    leaf: str
    verb: Verb | None = None

    @property
    def sysid(self) -> int | None:
        """The vehicle's sysid (1-255) for a vehicle topic whose key is well formed, else ``None``."""
        return parse_vehicle_key(self.key) if self.scope == "vehicle" and self.key is not None else None

    def with_verb(self, verb: Verb | None) -> str:
        """This topic spelled with another verb (``set`` -> ``state``: where the answer goes)."""
        return build(self.scope, self.key, self.leaf, verb)


def parse_vehicle_key(key: str) -> int | None:
    """``v<sysid>`` -> sysid (1-255 fit in three digits; 0 and above 255 are not vehicles)."""
    m = _VEHICLE_KEY.match(key)
    return int(m.group(1)) if m and int(m.group(1)) <= 255 else None


def parse(topic: str) -> Topic | None:
    """``secuav/...`` -> :class:`Topic`; anything that is not a well-formed topic of ours -> ``None``."""
    parts = topic.split("/")
    if len(parts) < 3 or parts[0] != PREFIX or any(not p for p in parts):
        return None
    key, rest = parts[1], parts[2:]
    verb: Verb | None = None
    if rest[-1] in VERBS:
        verb = rest[-1]  # type: ignore[assignment]
        rest = rest[:-1]
    if not rest:
        return None
    if key in (PROXY_KEY, CONSOLE_KEY):
        scope: Scope = "proxy" if key == PROXY_KEY else "console"
        if len(rest) == 1:
            return Topic(scope, None, rest[0], verb)
        if len(rest) == 2:
            return Topic(scope, rest[0], rest[1], verb)
        return None
    if len(rest) > 2:
        return None
    return Topic("vehicle", key, "/".join(rest), verb)


def build(scope: Scope, key: str | None, leaf: str, verb: Verb | None = None) -> str:
    """The one place a topic is spelled; ``key`` may be :data:`ANY` for a subscription."""
    head = {"vehicle": [], "proxy": [PROXY_KEY], "console": [CONSOLE_KEY]}[scope]
    levels = [PREFIX, *head, *([key] if key is not None else []), leaf, *([verb] if verb else [])]
    return "/".join(levels)


def vehicle_key(sysid: int) -> str:
    return f"v{sysid}"


def vehicle_topic(sysid: int | str, leaf: str, verb: Verb | None = None) -> str:
    """``secuav/v<sysid>/<leaf>[/<verb>]``; ``sysid`` :data:`ANY` subscribes to every vehicle."""
    key = sysid if isinstance(sysid, str) else vehicle_key(sysid)
    return build("vehicle", key, leaf, verb)


def proxy_topic(instance: str | None, leaf: str, verb: Verb | None = None) -> str:
    """``secuav/proxy/<instance>/<leaf>[/<verb>]``; ``instance`` None: the proxy-wide topic."""
    return build("proxy", instance, leaf, verb)


def console_topic(console_id: str, leaf: str = "online") -> str:
    """``secuav/console/<id>/online``: a console's retained record."""
    return build("console", console_id, leaf)


PROXY_ONLINE = proxy_topic(None, "online")  # the single-proxy flag; fleets read each instance's record
INSTANCES_ONLINE = proxy_topic(ANY, "online")
CONSOLES_ONLINE = console_topic(ANY)
