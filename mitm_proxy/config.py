"""The proxy's settings: a YAML file validated by pydantic, then flags on top.

One :class:`ProxyConfig` describes the whole process: its links (one per
vehicle: a vehicle endpoint and any number of ground endpoints), the attack
stage's start state, recording, signing and the control plane. Everything a
user can get wrong is checked here, once, before a socket opens, and reported
as one line naming the file, the field and the value (``InputError``).

Defaults follow the port plan of docs/interfaces.md: link i (the vehicle with sysid i+1, or
the i-th vehicle of ``--scenario``) listens on ``udpin://127.0.0.1:(14560+i)``
and forwards to ``udpout://127.0.0.1:(14540+i)`` (MAVSDK) and
``udpout://127.0.0.1:14550`` (QGroundControl / MAVProxy). An endpoint URL that
several links name is one shared socket (the GCS port carries all vehicles).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from mitm_proxy.net.rules import EndpointRules, rules_to_query
from secuav_common.controlplane.states import Mode
from secuav_common.loading import InputError, load_model, validate
from secuav_common.ports import GCS_PORT, GROUND_API_BASE, LOOPBACK, PROXY_VEHICLE_BASE
from secuav_common.urls import Endpoint, parse_endpoint

MAX_LINKS = 64
SECURE_OFF = "off"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _check_url(url: str, role: str = "ground") -> str:
    ep = parse_endpoint(url)  # ValueError names the bad part; pydantic turns it into a field error
    if ep.options:  # routing rules (mitm_proxy.net.rules); checked here so a bad one stops the start
        from mitm_proxy.net.rules import rules_from_options

        try:
            rules = rules_from_options(ep)
        except InputError as exc:
            raise ValueError(exc.reason + (f" (got {exc.value!r})" if exc.value is not None else "")) from None
        if rules.listen_only and role == "vehicle":
            raise ValueError(f"{url}: listen_only is for ground endpoints (a vehicle endpoint must reach the vehicle)")
    return url


class EndpointEntry(_Strict):
    """The long form of an endpoint in the config file: its URL and its routing rules as a mapping.

    ``{url: "tcpin://0.0.0.0:5760", rules: {listen_only: true, down: {deny: [ATTITUDE]}}}`` is the same
    endpoint as ``tcpin://0.0.0.0:5760?listen_only=true&deny=ATTITUDE`` (docs/routes.md).
    """

    url: str = Field(description="the endpoint URL, without ?options")
    rules: dict[str, Any] = Field(default_factory=dict, description="EndpointRules: listen_only, down, up")


def _entry_url(entry: str | EndpointEntry) -> str:
    """An entry as the one URL spelling the rest of the proxy reads (rules as URL options)."""
    if isinstance(entry, str):
        return entry
    ep = parse_endpoint(entry.url)
    if ep.options:
        raise ValueError(f"{entry.url}: give the rules either as URL options or under rules:, not both")
    try:
        rules = EndpointRules.model_validate(entry.rules)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        reason = err["msg"].removeprefix("Value error, ")
        raise ValueError(f"rules.{where}: {reason} (got {err.get('input')!r})") from None
    query = rules_to_query(rules)
    return f"{ep}?{query}" if query else str(ep)


Entry = str | EndpointEntry


class LinkConfig(_Strict):
    """One vehicle: where its frames come from and which ground endpoints get them."""

    sysid: int = Field(ge=1, le=255)
    vehicle: Entry = Field(description="udpin://, udpout://, tcp://, tcpin://HOST:PORT or serial:///DEV?baud=N; "
                           "routing rules as URL options (?deny=..., docs/routes.md) or {url:, rules:}")
    ground: list[Entry] = Field(min_length=1, description="ground endpoints, each a URL or {url:, rules:}")

    @field_validator("vehicle")
    @classmethod
    def _vehicle_url(cls, v: Entry) -> str:
        return _check_url(_entry_url(v), "vehicle")

    @field_validator("ground")
    @classmethod
    def _ground_urls(cls, v: list[Entry]) -> list[str]:
        urls = []
        for i, entry in enumerate(v):
            try:
                urls.append(_check_url(_entry_url(entry)))
            except ValueError as exc:
                raise ValueError(f"[{i}]: {exc}") from None
        if len({parse_endpoint(u).without_options() for u in urls}) != len(urls):
            raise ValueError("the same ground endpoint is listed twice")
        return urls

    @property
    def vehicle_endpoint(self) -> Endpoint:
        return parse_endpoint(_entry_url(self.vehicle))

    @property
    def ground_endpoints(self) -> list[Endpoint]:
        return [parse_endpoint(_entry_url(u)) for u in self.ground]


class ProxyConfig(_Strict):
    """Everything ``secuav-proxy`` needs; the YAML file has the same keys (flags win)."""

    links: list[LinkConfig] = Field(default_factory=list, max_length=MAX_LINKS)
    vehicles: int | None = Field(None, ge=1, le=MAX_LINKS, description="links by the port plan when links is empty")
    scenario: Path | None = None
    attack: Mode = "on"
    profile: Path | None = None
    record: Path | None = None
    signing_key: Path | None = None
    secure: str | dict[str, Any] = SECURE_OFF  # an estimator name, off, or SecureConfig fields (needs scenario)
    secure_direction: Literal["downlink", "uplink", "both"] | None = Field(
        None, description="where the secure stage reads its sensor group and substitutes: downlink (toward the "
        "ground, the default), uplink (toward the vehicle) or both; overrides secure's own direction",
    )
    no_uplink_attacks: bool = Field(
        False, description="refuse any attack profile with a rule toward the vehicle (direction uplink or both)"
    )
    broker: str = "embedded"  # embedded | none | mqtt://[user:pass@]host[:port] | mqtts://...
    broker_port: int | None = Field(
        None, ge=1, le=65535,
        description="port of the broker on 127.0.0.1: where broker embedded starts (or finds) it (default 1883), "
        "or the port of the broker URL",
    )  # fmt: skip
    broker_username: str | None = None
    broker_password: str | None = None
    broker_tls_ca: Path | None = None
    instance: str | None = Field(
        None, pattern=r"^[A-Za-z0-9_.-]{1,64}$",
        description="name of this proxy on the broker (secuav/proxy/<instance>/...); default <host>-<pid>",
    )  # fmt: skip
    stats_interval_s: float = Field(5.0, gt=0.0)
    seed: int = 0

    @field_validator("attack", mode="before")
    @classmethod
    def _yaml_on_off(cls, v: Any) -> Any:
        """YAML 1.1 reads a bare ``on``/``off`` as a boolean."""
        return {True: "on", False: "bypass"}.get(v, v) if isinstance(v, bool) else v

    @field_validator("broker")
    @classmethod
    def _broker(cls, v: str) -> str:
        if v in ("embedded", "none"):
            return v
        from secuav_common.broker import parse_broker_url

        parse_broker_url(v)
        return v

    @model_validator(mode="after")
    def _broker_port_fits(self) -> ProxyConfig:
        if self.broker not in ("embedded", "none"):
            from secuav_common.controlplane.address import with_port

            with_port(self.broker, self.broker_port)  # a URL naming another port: ValueError
        return self

    @property
    def broker_url(self) -> str:
        """``broker`` with ``broker_port`` applied (embedded and none unchanged)."""
        from secuav_common.controlplane.address import with_port

        return self.broker if self.broker in ("embedded", "none") else with_port(self.broker, self.broker_port)

    @model_validator(mode="after")
    def _links_consistent(self) -> ProxyConfig:
        sysids = [ln.sysid for ln in self.links]
        if len(set(sysids)) != len(sysids):
            dup = next(s for s in sysids if sysids.count(s) > 1)
            raise ValueError(f"links: sysid {dup} is used by two links")
        vehicles = [ln.vehicle_endpoint for ln in self.links]
        for i, ep in enumerate(vehicles):
            if ep in vehicles[:i]:
                raise ValueError(f"links[{i}].vehicle: {ep} is already the vehicle endpoint of another link")
            for j, other in enumerate(self.links):
                if ep in other.ground_endpoints:
                    raise ValueError(f"links[{i}].vehicle: {ep} is also a ground endpoint of links[{j}]")
        return self


def effective(cfg: ProxyConfig) -> dict[str, Any]:
    """The whole configuration as the proxy will run it (``--print-config``): every default filled in,
    and each endpoint with rules in the long form, its rules spelled out by direction."""
    from mitm_proxy.net.rules import rules_from_options

    def endpoint(url: str) -> str | dict[str, Any]:
        ep = parse_endpoint(url)
        rules = rules_from_options(ep)
        return str(ep) if rules.empty else {"url": str(ep.without_options()),
                                            "rules": rules.model_dump(mode="json", exclude_defaults=True)}  # fmt: skip

    data = cfg.model_dump(mode="json")
    data["links"] = [{"sysid": ln.sysid, "vehicle": endpoint(str(ln.vehicle)),
                      "ground": [endpoint(str(g)) for g in ln.ground]} for ln in cfg.links]  # fmt: skip
    if data.get("broker_password"):
        data["broker_password"] = "***"
    return data


def plan_links(sysids: list[int]) -> list[LinkConfig]:
    """The port plan of docs/interfaces.md for vehicles with these sysids, in order (vehicle i at index i)."""
    return [
        LinkConfig(
            sysid=sysid,
            vehicle=f"udpin://{LOOPBACK}:{PROXY_VEHICLE_BASE + i}",
            ground=[f"udpout://{LOOPBACK}:{GROUND_API_BASE + i}", f"udpout://{LOOPBACK}:{GCS_PORT}"],
        )
        for i, sysid in enumerate(sysids)
    ]


def load_config(path: str | Path) -> dict[str, Any]:
    """Read and check a config file; returns its validated keys as a dict so flags can be laid on top."""
    cfg = load_model(ProxyConfig, path)
    return cfg.model_dump(exclude_unset=True)


def build_config(file_values: dict[str, Any], flags: dict[str, Any], source: str) -> ProxyConfig:
    """File values, then the flags that were given (None = not given); then fill in the links.

    ``source`` names where the values came from in errors (the file, or ``<flags>``).
    """
    merged = {**file_values, **{k: v for k, v in flags.items() if v is not None}}
    cfg = validate(ProxyConfig, merged, source)
    if cfg.links:
        return cfg
    sysids = _sysids(cfg, source)
    return cfg.model_copy(update={"links": plan_links(sysids)})


def override_endpoints(cfg: ProxyConfig, vehicle: list[str], ground: list[str], source: str) -> ProxyConfig:
    """Apply ``--vehicle`` / ``--ground`` flags to the links.

    ``--vehicle`` once: link i listens on that URL's port + i (as ``secuav-sim --mavlink`` numbers its vehicles);
    or once per link. ``--ground`` URLs replace every link's ground endpoints; with several links each URL is
    one endpoint shared by all of them (uplink routed by ``target_system``).
    """
    links = list(cfg.links)
    n = len(links)
    if vehicle:
        try:
            eps = [parse_endpoint(u) for u in vehicle]
        except ValueError as exc:
            raise InputError(source, "vehicle", vehicle, str(exc)) from None
        if len(eps) == 1 and n > 1:
            base = eps[0]
            if base.port + n - 1 > 65535:
                raise InputError(source, "vehicle", vehicle[0], f"port + {n - 1} links exceeds 65535")
            if base.mode == "serial":
                raise InputError(source, "vehicle", vehicle[0], f"one serial port cannot serve {n} links")
            eps = [Endpoint(base.mode, base.host, base.port + i, base.options) for i in range(n)]
        if len(eps) != n:
            raise InputError(source, "vehicle", vehicle, f"give it once or once per link ({n})")
        links = [ln.model_copy(update={"vehicle": str(ep)}) for ln, ep in zip(links, eps, strict=True)]
    if ground:
        links = [ln.model_copy(update={"ground": list(ground)}) for ln in links]
    data = cfg.model_dump()
    data["links"] = [ln.model_dump() for ln in links]
    return validate(ProxyConfig, data, source)


def _sysids(cfg: ProxyConfig, source: str) -> list[int]:
    if cfg.scenario is not None:
        from secuav_common.scenario import load_scenario

        scenario = load_scenario(cfg.scenario)
        if cfg.vehicles is not None and cfg.vehicles != len(scenario.vehicles):
            raise InputError(source, "vehicles", cfg.vehicles,
                             f"the scenario {cfg.scenario} has {len(scenario.vehicles)} vehicles")  # fmt: skip
        return [v.sysid for v in scenario.vehicles]
    return list(range(1, (cfg.vehicles or 1) + 1))
