"""``secuav-plugins``: what this installation finds, and from which distribution.

    secuav-plugins              # the plugins: estimators (with their parameters), primitives, profiles, scenarios
    secuav-plugins --builtin    # the built-ins too
    secuav-plugins --json       # the same as one JSON document
    secuav-plugins --estimator huber   # one estimator (plugin or built-in): its parameters, one a line

Listing imports every plugin (that is how a broken one shows up): each that
fails is one line on stderr, and the exit code is 1; 0 when all loaded.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from secuav_common import plugins
from secuav_common.logs import add_common_flags


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="secuav-plugins", description=__doc__.splitlines()[0].split(": ", 1)[1])
    add_common_flags(p, log_flags=False)
    p.add_argument("--builtin", action="store_true", help="list the built-in estimators, primitives, profiles too")
    p.add_argument("--json", action="store_true", help="one JSON document instead of the table")
    p.add_argument("--estimator", metavar="NAME",
                   help="only this estimator (built-in, plugin or package.module:Class): what it is, and each "
                   "parameter with its default and declared range, one a line")  # fmt: skip
    return p


def _estimators(builtin: bool) -> list[dict[str, Any]]:
    from estimators import registry

    out = []
    for name in registry.names():
        entry = plugins.found(plugins.ESTIMATORS).get(name)
        if entry is None and not builtin:
            continue
        out.append(_estimator(name))
    return out


def _estimator(name: str) -> dict[str, Any]:
    """A listing row: ``params`` as text (``huber_k=1.345 in [0.5, 5]``), ``parameters`` as JSON
    (``estimators.registry.describe``: name -> default, low, high)."""
    from estimators import registry

    entry = registry.describe(name)
    cls = registry.get(name)
    return {"name": name, "dist": entry["dist"], "version": entry["version"], "object": entry["object"],
            "summary": entry["summary"], "params": [p.text() for p in registry.parameters(cls)],
            "parameters": entry["params"]}  # fmt: skip


def _one_estimator(name: str, as_json: bool) -> int:
    """``--estimator NAME``: what ``--help`` would say of it; 2 when NAME stands for no estimator."""
    try:
        row = _estimator(name)
    except ValueError as exc:  # unknown, or a module:Class that does not import: the message says which
        print(f"secuav-plugins: --estimator: {exc}", file=sys.stderr)
        return 2
    if as_json:
        print(json.dumps(row, indent=2))
        return 0
    print(f"{row['name']}: {row['summary']}")
    print(f"  from {row['dist']} {row['version']} ({row['object']})")
    print("\nparameters (keyword; default, declared range):")
    for pname, spec in row["parameters"].items():
        span = ""
        if spec["low"] is not None or spec["high"] is not None:
            low = "-inf" if spec["low"] is None else f"{spec['low']:g}"
            high = "inf" if spec["high"] is None else f"{spec['high']:g}"
            span = f"in [{low}, {high}]"
        print(f"  {pname:<22} {json.dumps(spec['default']):<10} {span}".rstrip())
    return 0


def _primitives(builtin: bool) -> list[dict[str, Any]]:
    from attack_profiles.primitives import BUILTIN_KINDS, load_all

    out = []
    for kind, cls in load_all().items():
        if kind in BUILTIN_KINDS and not builtin:
            continue
        dist, version = plugins.origin(cls)
        fields = [f for f in cls.rule_model.model_fields if f not in ("kind", "target", "start_s", "end_s",
                                                                       "repeat_period_s", "note")]  # fmt: skip
        out.append({"name": kind, "dist": dist, "version": version, "object": f"{cls.__module__}:{cls.__qualname__}",
                    "params": fields})  # fmt: skip
    return out


def _yaml(group: str, bundled: list[str], builtin: bool) -> list[dict[str, Any]]:
    from secuav_common import logs

    out = [{"name": n, "dist": "secuav", "version": logs.version(), "object": "bundled", "params": []}
           for n in bundled] if builtin else []  # fmt: skip
    taken = set(bundled)
    for stem, (path, entry) in sorted(plugins.yaml_catalogue(group).items()):
        shadowed = " (shadowed by the bundled one)" if stem in taken else ""
        out.append({"name": stem, "dist": entry.dist, "version": entry.version, "object": f"{path}{shadowed}",
                    "params": []})  # fmt: skip
    return out


def listing(builtin: bool) -> dict[str, list[dict[str, Any]]]:
    from attack_profiles import library
    from secuav_common.scenario import scenario_names

    return {
        plugins.ESTIMATORS: _estimators(builtin),
        plugins.PRIMITIVES: _primitives(builtin),
        plugins.PROFILES: _yaml(plugins.PROFILES, library.names(plugins=False), builtin),
        plugins.SCENARIOS: _yaml(plugins.SCENARIOS, scenario_names(with_plugins=False), builtin),
    }


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.estimator is not None:
        return _one_estimator(args.estimator, args.json)
    found = listing(args.builtin)
    failed = plugins.failures()
    if args.json:
        doc = {"groups": found, "failed": [{"group": g, "name": n, "error": e} for (g, n), e in failed.items()]}
        print(json.dumps(doc, indent=2))
    else:
        for group, rows in found.items():
            print(f"{group}: {len(rows)}")
            for r in rows:
                print(f"  {r['name']:<24} {r['dist']} {r['version']:<10} {r['object']}")
                if r.get("summary"):
                    print(f"  {'':<24} {r['summary']}")
                if r["params"]:
                    print(f"  {'':<24} params: {', '.join(r['params'])}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
