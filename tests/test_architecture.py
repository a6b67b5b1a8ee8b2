"""The import floors of docs/architecture.md, read off the source: no import runs back up, and no import loop.

Every ``import`` and ``from ... import`` of every module of the project's packages is read with ``ast``: at the top
of a module and inside functions (a lazy import is an import all the same), and a ``"package.module:attribute"``
string, which ``importlib`` loads by name, counts as an import of that module. Only what sits under
``if TYPE_CHECKING:`` is left out (it never runs). Three kinds of violation:

- an import that runs back up: a package importing one on its own floor or above (docs/architecture.md draws
  the floors), or, inside ``mitm_proxy``, a room importing one on its own floor or above;
- an import loop: modules that import each other, directly or round a ring (a package's ``__init__`` importing
  its own modules is not one: that is how a package names what it offers);
- a pure library (``estimators``, ``attack_profiles``, ``mavframe``) importing sockets, asyncio, threads,
  processes or an MQTT client.

Today's violations, which other work is removing, are listed by name in ``KNOWN``: the test fails on any
violation not in it, and on any name in it that no longer occurs (remove it from ``KNOWN``), so the list only
shrinks. Print the current list, its count and the tables of the page with
``.venv/bin/python -m tests.test_architecture`` (``--known`` prints it as the Python set to paste).
"""

from __future__ import annotations

import ast
import re
import sys
from collections import defaultdict
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "architecture.md"

# Top floor first. A package may import its own modules and any package on a floor below its own; packages on
# one floor never import each other (the services run as processes and talk over MAVLink and MQTT).
FLOORS: tuple[tuple[str, ...], ...] = (
    ("study",),
    ("evaluation", "demos"),
    ("flightsim", "mitm_proxy", "webconsole"),
    ("estimators", "attack_profiles"),
    ("mavframe",),
    ("secuav_common",),
)
# The proxy's rooms (its modules and subpackages), top floor first, by the same rule.
PROXY = "mitm_proxy"
PROXY_FLOORS: tuple[tuple[str, ...], ...] = (
    ("__main__",),
    ("cli",),
    ("app",),
    ("tools", "config"),
    ("control",),
    ("stages", "net"),
    ("core",),
)
PURE = ("estimators", "attack_profiles", "mavframe")
NOT_PURE = ("asyncio", "socket", "selectors", "threading", "subprocess", "multiprocessing", "concurrent",
            "aiomqtt", "amqtt", "paho")  # fmt: skip

# Violations allowed for now, by name: none. A new one fails; so does a name listed here that is no longer found.
KNOWN: frozenset[str] = frozenset()

BY_NAME = re.compile(r"^([a-z_][a-z0-9_]*(?:\.[a-z_][a-z0-9_]*)*):[A-Za-z_][\w.]*$")


@dataclass(frozen=True)
class Import:
    source: str
    target: str
    line: int
    how: str  # "import", "lazy" (inside a function) or "by name" (a "module:attribute" string)


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def project_modules(root: Path, packages: Iterable[str]) -> dict[str, Path]:
    """Every module of ``packages`` under ``root``: dotted name -> file."""
    return {module_name(p, root): p for pkg in packages for p in sorted((root / pkg).rglob("*.py"))}


def _type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def imports_of(name: str, path: Path, modules: dict[str, Path]) -> Iterator[Import]:
    """The project modules ``name`` imports, each as the deepest module the import names."""
    packages = {m.split(".")[0] for m in modules}
    is_package = path.name == "__init__.py"

    def resolve(target: str) -> str | None:
        if target.split(".")[0] not in packages:
            return None
        while target not in modules and "." in target:
            target = target.rsplit(".", 1)[0]
        return target if target in modules else None

    def walk(node: ast.AST, lazy: bool) -> Iterator[Import]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _type_checking(child):
                for other in child.orelse:
                    yield from one(other, lazy)
            else:
                yield from one(child, lazy)

    def one(node: ast.AST, lazy: bool) -> Iterator[Import]:
        how = "lazy" if lazy else "import"
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                here = name.split(".") if is_package else name.split(".")[:-1]
                base = ".".join(here[: len(here) - (node.level - 1)] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            # ``from package import module`` imports the module; ``from module import name`` the module
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and (m := BY_NAME.match(node.value)):
            targets, how = [m.group(1)], "by name"
        for target in targets:
            resolved = resolve(target)
            if resolved is not None and resolved != name:
                yield Import(name, resolved, node.lineno, how)  # type: ignore[attr-defined]
        yield from walk(node, lazy or isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda))

    yield from walk(ast.parse(path.read_text(encoding="utf-8"), str(path)), False)


def third_party_imports(path: Path) -> Iterator[tuple[str, int]]:
    """Top-level names of every module ``path`` imports (outside TYPE_CHECKING), with the line."""
    def walk(node: ast.AST) -> Iterator[tuple[str, int]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _type_checking(child):
                nodes: list[ast.AST] = list(child.orelse)
            else:
                nodes = [child]
            for n in nodes:
                if isinstance(n, ast.Import):
                    yield from ((a.name.split(".")[0], n.lineno) for a in n.names)
                elif isinstance(n, ast.ImportFrom) and not n.level and n.module:
                    yield n.module.split(".")[0], n.lineno
                yield from walk(n)

    yield from walk(ast.parse(path.read_text(encoding="utf-8"), str(path)))


def rank(floors: tuple[tuple[str, ...], ...], room: str) -> int | None:
    """The room's floor, 0 at the bottom; None for a room no floor names."""
    for i, floor in enumerate(reversed(floors)):
        if room in floor:
            return i
    return None


def room_of(module: str) -> str | None:
    """The proxy's room a module is in (``mitm_proxy.stages.secure.stage`` -> ``stages``); None for the package."""
    parts = module.split(".")
    return parts[1] if parts[0] == PROXY and len(parts) > 1 else None


def runs_up(imp: Import) -> str | None:
    """Why an import runs back up (None if it does not)."""
    src, dst = imp.source.split(".")[0], imp.target.split(".")[0]
    if src != dst:
        s, d = rank(FLOORS, src), rank(FLOORS, dst)
        if s is None or d is None:
            return f"{src if s is None else dst} is on no floor of {PAGE.name}: draw it there"
        if d >= s:
            return f"{src} may not import {dst} ({'the same floor' if d == s else 'a floor above'})"
        return None
    rs, rd = room_of(imp.source), room_of(imp.target)
    if src != PROXY or rs is None or rd is None or rs == rd:
        return None
    s, d = rank(PROXY_FLOORS, rs), rank(PROXY_FLOORS, rd)
    if s is None or d is None:
        return f"{PROXY}.{rs if s is None else rd} is on no floor of {PAGE.name}: draw it there"
    if d >= s:
        return f"{PROXY}'s {rs} may not import its {rd} ({'the same floor' if d == s else 'a floor above'})"
    return None


def loops(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:  # depth below 100 for this project (its modules' import chains)
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            scc = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                scc.append(w)
                if w == v:
                    break
            if len(scc) > 1:
                found.append(sorted(scc))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def all_imports(root: Path, packages: Iterable[str]) -> list[Import]:
    modules = project_modules(root, packages)
    return [imp for name, path in modules.items() for imp in imports_of(name, path, modules)]


def import_graph(imports: Iterable[Import], root: Path) -> dict[str, set[str]]:
    """Module -> the modules it imports, less a package's ``__init__`` importing its own modules."""
    graph: dict[str, set[str]] = defaultdict(set)
    for imp in imports:
        package_init = (root / imp.source.replace(".", "/") / "__init__.py").is_file()
        if not (package_init and imp.target.startswith(imp.source + ".")):
            graph[imp.source].add(imp.target)
    return graph


def violations(root: Path = ROOT, packages: Iterable[str] | None = None) -> dict[str, str]:
    """Every violation: its name (as ``KNOWN`` lists it) -> why, and where."""
    packages = tuple(packages or (p for floor in FLOORS for p in floor))
    imports = all_imports(root, packages)
    found: dict[str, str] = {}
    for imp in imports:
        why = runs_up(imp)
        if why:
            where = f"{imp.source.replace('.', '/')}.py:{imp.line} ({imp.how})"
            name = f"{imp.source} -> {imp.target}"
            if name not in found:
                found[name] = f"{why}: {where}"
            elif where not in found[name]:  # ``from m import a, b`` is one import
                found[name] += f"; {where}"
    for scc in loops(import_graph(imports, root)):
        members = set(scc)
        arrows = sorted({f"{i.source} -> {i.target}" for i in imports if i.source in members and i.target in members})
        found[f"loop: {', '.join(scc)}"] = "modules that import each other: " + "; ".join(arrows)
    for pkg in (p for p in PURE if p in packages):
        for path in sorted((root / pkg).rglob("*.py")):
            for top, line in third_party_imports(path):
                if top in NOT_PURE:
                    name = f"{module_name(path, root)} -> {top}"
                    found[name] = f"{pkg} is a pure library (no sockets, no asyncio, no threads): {path}:{line}"
    return found


def who_imports_whom(root: Path = ROOT) -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """What each package imports of the others, and each proxy room of the other rooms (upward ones left out)."""
    packages: dict[str, set[str]] = defaultdict(set)
    rooms: dict[str, set[str]] = defaultdict(set)
    for imp in all_imports(root, (p for floor in FLOORS for p in floor)):
        if runs_up(imp):
            continue
        src, dst = imp.source.split(".")[0], imp.target.split(".")[0]
        if src != dst:
            packages[src].add(dst)
        elif (rs := room_of(imp.source)) and (rd := room_of(imp.target)) and rs != rd:
            rooms[rs].add(rd)
    return packages, rooms


def tables(root: Path = ROOT) -> str:
    """The page's two tables of who imports whom, as Markdown (top floor first)."""
    packages, rooms = who_imports_whom(root)

    def table(head: str, floors: tuple[tuple[str, ...], ...], edges: dict[str, set[str]]) -> list[str]:
        order = [room for floor in floors for room in floor]
        lines = [f"| {head} | floor | imports |", "|---|---|---|"]
        nothing = "nothing of the project" if floors is FLOORS else "no other room"
        for room in order:
            names = [f"`{r}`" for r in order if r in edges.get(room, ())]
            lines.append(f"| `{room}` | {rank(floors, room)} | {', '.join(names) or nothing} |")
        return lines

    return "\n".join([*table("package", FLOORS, packages), "", *table(f"`{PROXY}` room", PROXY_FLOORS, rooms)])


# --- the checks ---------------------------------------------------------------------------------------------------


def test_no_import_runs_back_up_and_none_loops() -> None:
    found = violations()
    new = {name: why for name, why in found.items() if name not in KNOWN}
    gone = sorted(KNOWN - found.keys())
    listed = "\n".join(f"{n}\n    {w}" for n, w in sorted(new.items()))
    assert not new, f"imports against docs/architecture.md:\n{listed}"
    assert not gone, "no longer found, remove it from KNOWN in tests/test_architecture.py:\n" + "\n".join(gone)


def test_the_page_draws_the_floors_and_tables_of_today() -> None:
    page = PAGE.read_text(encoding="utf-8")
    for floors in (FLOORS, PROXY_FLOORS):
        drawing = "\n".join("   ".join(floor) for floor in floors)
        assert drawing in page, f"{PAGE.name} must draw the floors as the test holds them:\n{drawing}"
    assert tables() in page, (f"{PAGE.name}'s tables are out of date; print them with "
                              f".venv/bin/python -m tests.test_architecture --tables:\n{tables()}")


def test_every_package_and_proxy_room_is_on_a_floor() -> None:
    on_floors = {p for floor in FLOORS for p in floor}
    packages = {p.parent.name for p in ROOT.glob("*/__init__.py")} - {"tests"}
    assert packages == on_floors, f"put each package on a floor of FLOORS and of {PAGE.name}: {packages ^ on_floors}"
    rooms = {module_name(p, ROOT).split(".")[1] for p in (ROOT / PROXY).glob("*") if p.name != "__init__.py"
             and (p.suffix == ".py" or (p / "__init__.py").is_file())}  # fmt: skip
    drawn = {r for floor in PROXY_FLOORS for r in floor}
    assert rooms == drawn, f"put each room of {PROXY} on a floor of PROXY_FLOORS and of {PAGE.name}: {rooms ^ drawn}"


# --- the reader itself, on a small tree of its own --------------------------------------------------------------


def _tree(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_lazy_and_by_name_imports_count_and_type_checking_ones_do_not(tmp_path: Path) -> None:
    _tree(tmp_path, {
        "secuav_common/__init__.py": "",
        "secuav_common/a.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import mavframe.x\n",
        "secuav_common/b.py": "def f():\n    from mavframe import x\n    return x\n",
        "secuav_common/c.py": 'SPEC = "mitm_proxy.control.s:Thing.build"\n',
        "mavframe/__init__.py": "", "mavframe/x.py": "from . import y\n", "mavframe/y.py": "",
        "mitm_proxy/__init__.py": "", "mitm_proxy/control/__init__.py": "", "mitm_proxy/control/s.py": "",
    })  # fmt: skip
    found = violations(tmp_path, ("secuav_common", "mavframe", "mitm_proxy"))
    assert set(found) == {"secuav_common.b -> mavframe.x", "secuav_common.c -> mitm_proxy.control.s"}
    lazy = found["secuav_common.b -> mavframe.x"]
    assert "(lazy)" in lazy and "a floor above" in lazy
    assert "(by name)" in found["secuav_common.c -> mitm_proxy.control.s"]


def test_a_ring_is_a_loop_and_a_package_naming_its_modules_is_not(tmp_path: Path) -> None:
    _tree(tmp_path, {
        "study/__init__.py": "from study.a import A\nfrom study.b import B\n",
        "study/a.py": "from study import B\nA = 1\n",
        "study/b.py": "B = 2\n",
        "study/c.py": "def f():\n    from .d import g\n",
        "study/d.py": "from .e import h\ndef g(): ...\n",
        "study/e.py": "import study.c\ndef h(): ...\n",
    })  # fmt: skip
    found = violations(tmp_path, ("study",))
    assert set(found) == {"loop: study.c, study.d, study.e"}
    assert "study.e -> study.c" in found["loop: study.c, study.d, study.e"]


def test_inside_the_proxy_a_stage_may_not_import_the_control_code_nor_a_pure_library_asyncio(tmp_path: Path) -> None:
    _tree(tmp_path, {
        "mitm_proxy/__init__.py": "", "mitm_proxy/stages/__init__.py": "", "mitm_proxy/control/__init__.py": "",
        "mitm_proxy/core/__init__.py": "",
        "mitm_proxy/stages/s.py": "from mitm_proxy.core import p\nfrom mitm_proxy.control import k\n",
        "mitm_proxy/core/p.py": "", "mitm_proxy/control/k.py": "import mitm_proxy.stages.s\n",
        "estimators/__init__.py": "", "estimators/m.py": "import asyncio.tasks\nimport numpy\n",
    })  # fmt: skip
    found = violations(tmp_path, ("mitm_proxy", "estimators"))
    assert set(found) == {"mitm_proxy.stages.s -> mitm_proxy.control.k", "estimators.m -> asyncio",
                          "loop: mitm_proxy.control.k, mitm_proxy.stages.s"}
    assert "stages may not import its control (a floor above)" in found["mitm_proxy.stages.s -> mitm_proxy.control.k"]


def known_text(found: Iterable[str]) -> str:
    """``KNOWN`` as Python source holding ``found``, a long name cut into adjacent strings."""
    lines = ["KNOWN: frozenset[str] = frozenset({"]
    for name in sorted(found):
        pieces, piece = [], ""
        for word in name.split(" "):
            if piece and len(piece) + len(word) > 100:
                pieces.append(piece)
                piece = ""
            piece += word + " "
        pieces.append(piece.rstrip(" "))
        lines += [f'    "{p}"' for p in pieces[:-1]] + [f'    "{pieces[-1]}",']
    return "\n".join([*lines, "})  # fmt: skip"])


def main(argv: list[str]) -> int:
    found = violations()
    if "--known" in argv:
        print(known_text(found))
        return 0
    if "--tables" in argv:
        print(tables())
        return 0
    for name, why in sorted(found.items()):
        print(f"{name}\n    {why}{'' if name in KNOWN else '  (NEW)'}")
    gone = sorted(KNOWN - found.keys())
    print(f"{len(found)} violations ({len(found) - len(set(found) & KNOWN)} not in KNOWN); "
          f"{len(gone)} in KNOWN no longer found{': ' + ', '.join(gone) if gone else ''}")
    return 0 if set(found) == KNOWN else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
