"""docker/: what can be checked without a Docker engine (none exists on the CI machines).

The compose file parses and wires the services the way the bench needs; every
command it runs is a console script of pyproject.toml whose entry point imports,
and its arguments are accepted by that command's real argument parser and
config builder (so a renamed flag or a bad URL fails here, not in a container);
the image installs the project the way the README's setup does.
"""

from __future__ import annotations

import importlib
import re
import sys
import tomllib
from pathlib import Path
from typing import Any

import pytest
import yaml
from packaging.specifiers import SpecifierSet

ROOT = Path(__file__).resolve().parent.parent
DOCKER = ROOT / "docker"
IMAGE_ROOT = "/app"  # where the Dockerfile copies the repository
_VAR = re.compile(r"\$\{(\w+)(?::?-([^}]*))?\}|\$\$")


def interpolate(value: Any) -> Any:
    """Compose's variable syntax with nothing set in the environment: defaults, and ``$$`` -> ``$``."""
    if isinstance(value, str):
        return _VAR.sub(lambda m: "$" if m.group(0) == "$$" else (m.group(2) or ""), value)
    if isinstance(value, list):
        return [interpolate(v) for v in value]
    if isinstance(value, dict):
        return {k: interpolate(v) for k, v in value.items()}
    return value


@pytest.fixture(scope="module")
def compose() -> dict[str, Any]:
    return interpolate(yaml.safe_load((DOCKER / "compose.yaml").read_text()))


@pytest.fixture(scope="module")
def scripts() -> dict[str, str]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]


def _flag(cmd: list[str], name: str) -> list[str]:
    return [cmd[i + 1] for i, part in enumerate(cmd) if part == name]


def _host_path(path: str) -> Path:
    assert path.startswith(IMAGE_ROOT + "/"), path
    return ROOT / path[len(IMAGE_ROOT) + 1 :]


def test_compose_has_the_bench_services_ports_and_network(compose: dict[str, Any]) -> None:
    services = compose["services"]
    assert {"mosquitto", "proxy", "sim"} <= set(services)
    assert "name" not in compose  # docker-compose v1 (1.29, Debian's) refuses the v2-only top-level key
    proxy, sim = services["proxy"], services["sim"]
    # Published on the host's loopback only, unless SECUAV_PUBLISH says otherwise.
    assert {"127.0.0.1:14540:14540/udp", "127.0.0.1:14550:14550/udp"} <= set(proxy["ports"])
    for svc in services.values():
        assert all(str(p).startswith("127.0.0.1:") for p in svc.get("ports", [])), svc.get("ports")
    assert services["mosquitto"]["image"].startswith("secuav-base/mosquitto:")  # docker/base-images.sh builds it
    for name in ("proxy", "sim"):
        build = services[name]["build"]
        assert (build["context"], build["dockerfile"]) == ("..", "docker/Dockerfile")
        assert build["args"]["BASE"] == "secuav-base/python:bookworm"
        assert (DOCKER / build["context"] / build["dockerfile"]).is_file()
        assert services[name]["healthcheck"]["test"][:4] == ["CMD", "python3", "-m", "secuav_common.health"]
    # Services find each other by name: the simulator sends to the proxy's service, whose ports are published.
    assert all(svc["networks"] == ["bench"] for svc in services.values()) and "bench" in compose["networks"]
    assert _flag(proxy["command"], "--vehicle") == ["udpin://0.0.0.0:14560"]
    assert _flag(sim["command"], "--mavlink") == ["udpout://proxy:14560"]
    assert _flag(proxy["command"], "--ground") == ["udpin://0.0.0.0:14540", "udpin://0.0.0.0:14550"]
    assert "tcp://dask-scheduler:8786" in services["dask-worker"]["command"]
    assert _flag(proxy["command"], "--broker") == ["mqtt://mosquitto:1883"]
    assert proxy["depends_on"]["mosquitto"]["condition"] == "service_healthy"
    assert sim["depends_on"]["proxy"]["condition"] == "service_healthy"
    assert "$SYS/broker/uptime" in services["mosquitto"]["healthcheck"]["test"][1]  # "$$" escaped in the file
    # Every account of the ACL logs in with its own password file, handed over as a compose secret.
    for name, account in (("proxy", "proxy"), ("sim", "sim"), ("console", "operator")):
        cmd = services[name]["command"]
        assert _flag(cmd, "--broker-username") == [account] and services[name]["secrets"] == [account]
        assert _flag(cmd, "--broker-password-file") == [f"/run/secrets/{account}"]
        assert compose["secrets"][account]["file"] == f"./secrets/{account}"
    conf = (DOCKER / "mosquitto.conf").read_text()
    assert re.search(r"^listener 1883$", conf, re.M) and re.search(r"^allow_anonymous false$", conf, re.M)
    mounts = dict(v.split(":")[:2] for v in services["mosquitto"]["volumes"])
    for setting in ("password_file", "acl_file"):
        inside = re.search(rf"^{setting} (\S+)$", conf, re.M).group(1)  # type: ignore[union-attr]
        host = next(h for h, c in mounts.items() if c == inside)
        assert host.startswith("./secrets/") or (DOCKER / host).is_file(), host
    acl = (DOCKER / "mosquitto.acl").read_text()
    assert {"proxy", "sim", "operator", "viewer"} == set(re.findall(r"^user (\w+)$", acl, re.M))


def test_every_command_is_a_console_script_whose_parser_accepts_its_arguments(
    compose: dict[str, Any], scripts: dict[str, str], tmp_path: Path
) -> None:
    ran = {}
    for name, svc in compose["services"].items():
        if "build" not in svc:
            continue
        cmd = svc["command"]
        if cmd[0] == "dask":  # the study services run Dask's own command, installed by the [study] extra
            assert svc["profiles"] == ["dask"] and cmd[1] in ("scheduler", "worker")
            assert (Path(sys.executable).parent / "dask").is_file()
            continue
        assert cmd[0] in scripts, f"service {name}: {cmd[0]} is not in pyproject.toml [project.scripts]"
        module, func = scripts[cmd[0]].split(":")
        assert callable(getattr(importlib.import_module(module), func))
        ran[cmd[0]] = cmd[1:]
    assert set(ran) == {"secuav-proxy", "secuav-sim", "secuav-console"}
    assert compose["services"]["console"]["profiles"] == ["console"]  # it needs a password: opt in

    from webconsole.cli import build_parser as console_parser

    console_args = console_parser().parse_args(ran["secuav-console"])
    assert console_args.listen == "0.0.0.0:8080" and console_args.broker == "mqtt://mosquitto:1883"

    from flightsim.cli import build_parser as sim_parser
    from flightsim.cli import endpoints_for
    from mitm_proxy.cli import build_parser as proxy_parser
    from mitm_proxy.cli import config_from_args
    from secuav_common.scenario import load_scenario

    sim_args = sim_parser().parse_args(ran["secuav-sim"])
    scenario = load_scenario(_host_path(sim_args.scenario))
    assert [str(e) for e in endpoints_for(sim_args.mavlink, scenario)] == ["udpout://proxy:14560"]
    proxy_args = proxy_parser().parse_args(ran["secuav-proxy"])
    proxy_args.scenario = _host_path(str(proxy_args.scenario))
    assert proxy_args.broker_password_file == Path("/run/secrets/proxy")
    secret = tmp_path / "proxy"  # the compose secret, as the container sees it
    secret.write_text("pw\n")
    secret.chmod(0o600)
    proxy_args.broker_password_file = secret
    cfg = config_from_args(proxy_args)
    assert cfg.broker == "mqtt://mosquitto:1883" and cfg.secure == "off"
    assert (cfg.broker_username, cfg.broker_password) == ("proxy", "pw")
    assert [ln.sysid for ln in cfg.links] == [v.sysid for v in scenario.vehicles]


def test_readme_commands_name_real_scripts(scripts: dict[str, str]) -> None:
    text = (DOCKER / "README.md").read_text()
    named = set(re.findall(r"\b(secuav-[a-z]+)\b(?![/:])", text))  # not image names (secuav-base/python:...)
    assert {"secuav-proxy", "secuav-sim", "secuav-attack"} <= named
    assert named <= set(scripts), named - set(scripts)


def test_image_installs_the_project_like_the_readme_setup() -> None:
    text = (DOCKER / "Dockerfile").read_text()
    lines = [ln.strip() for ln in text.splitlines()]
    # Two stages on one base (a venv copied between them needs the same Python at the same path).
    froms = [ln for ln in lines if ln.startswith("FROM ")]
    assert froms == ["FROM ${BASE} AS build", "FROM ${BASE}"], froms
    assert "ARG BASE=secuav-base/python:bookworm" in lines and "ARG EXTRAS=all" in lines
    assert "COPY --from=build /opt/secuav /opt/secuav" in lines
    # Every package pyproject.toml ships is copied into the build stage, and the install is pip's.
    include = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]["include"]
    packages = {p.rstrip("*") for p in include}
    copied = {ln.split()[1] for ln in lines if ln.startswith("COPY ") and "--from" not in ln}
    assert packages <= copied, packages - copied
    assert 'spec=".[$EXTRAS]"' in text and '/opt/secuav/bin/pip install "$spec"' in text
    # scripts/setup.sh (what the README runs) installs the same source tree, editable and with test tools.
    setup = (ROOT / "scripts" / "setup.sh").read_text()
    m = re.search(r"pip install -q -e \"\.\[test\]\"", setup)
    assert m, "the README's setup no longer installs the project from the repository root"
    requires = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    assert SpecifierSet(requires).contains("3.11.0"), f"bookworm's python3 (3.11) fails requires-python {requires}"
    ignore = (DOCKER / "Dockerfile.dockerignore").read_text().split()
    assert ".venv" in ignore and ".git" in ignore
    # The proxy's compiled fast path is built in the build stage (a compiler there) and checked to import;
    # a module built on the host for another Python never enters the context.
    build_stage = text.split("FROM ${BASE}\n")[0]
    assert "gcc" in build_stage and "native_udp.available()" in build_stage
    assert "**/*.so" in ignore


def _third_party_imports(package_dirs: list[Path]) -> dict[str, str]:
    """Top-level modules the installed packages import (module -> first file), minus stdlib and our own."""
    import ast
    import sys

    ours = {p.name for p in package_dirs}
    found: dict[str, str] = {}
    for pkg in package_dirs:
        for path in sorted(pkg.rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split(".")[0]
                    if top not in sys.stdlib_module_names and top not in ours:
                        found.setdefault(top, str(path.relative_to(ROOT)))
    return found


def _closure(names: set[str]) -> set[str]:
    """The declared distributions and everything they require, as installed here (markers honoured)."""
    from importlib.metadata import PackageNotFoundError, requires

    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    seen: set[str] = set()
    todo = list(names)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        try:
            reqs = requires(name) or []
        except PackageNotFoundError:
            continue
        for text in reqs:
            req = Requirement(text)
            if req.marker is None or req.marker.evaluate({"extra": ""}):
                todo.append(canonicalize_name(req.name))
    return seen


# What `pip install secuav` must run.
CORE = {"mitm_proxy", "mavframe", "attack_profiles", "estimators", "secuav_common"}


def _requirements(project: dict, extras: set[str]) -> set[str]:
    """Distribution names that ``pip install .[extras]`` asks for (self-references like secuav[sim] expanded)."""
    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    optional = project["project"]["optional-dependencies"]
    names = {canonicalize_name(Requirement(r).name) for r in project["project"]["dependencies"]}
    todo, seen = list(extras), set()
    while todo:
        extra = todo.pop()
        if extra in seen:
            continue
        seen.add(extra)
        for text in optional[extra]:
            req = Requirement(text)
            if canonicalize_name(req.name) == canonicalize_name(project["project"]["name"]):
                todo.extend(req.extras)
            else:
                names.add(canonicalize_name(req.name))
    return names


@pytest.mark.parametrize(("extras", "packages"), [(set(), CORE), ({"all"}, None)], ids=["proxy-only", "all"])
def test_every_third_party_import_is_installed_by_the_declared_dependencies(
    extras: set[str], packages: set[str] | None
) -> None:
    """``pip install .`` (the proxy image) runs the proxy and libraries; ``.[all]`` everything: nothing else needed."""
    from importlib.metadata import packages_distributions

    from packaging.utils import canonicalize_name

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    include = project["tool"]["setuptools"]["packages"]["find"]["include"]
    dirs = [ROOT / pat.rstrip("*") for pat in include if (ROOT / pat.rstrip("*") / "__init__.py").is_file()]
    assert {d.name for d in dirs} >= {"mitm_proxy", "flightsim", "secuav_common"}
    if packages is not None:
        dirs = [d for d in dirs if d.name in packages]
    installed = _closure(_requirements(project, extras))
    dists = packages_distributions()
    missing = {}
    for module, where in _third_party_imports(dirs).items():
        provided = {canonicalize_name(d) for d in dists.get(module, [module])}
        if not provided & installed:
            missing[module] = where
    assert not missing, f"imported, but no dependency of .[{','.join(extras)}] brings it: {missing}"
