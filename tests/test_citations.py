"""Every document the code and the docs cite is in the repository, and every anchor they name exists.

Scans the tracked ``.py``, ``.md`` and ``.js`` files for citations of documents
a user of the repository does not have (the old design file, private notes,
anything under a ``shared/`` folder outside the tree), for Markdown links to
relative paths, and for repository paths such as ``docs/interfaces.md#ports``
written in code and text. A path must exist; a ``#anchor`` on a Markdown file
must be one of its headings as GitHub spells them.
"""

from __future__ import annotations

import os
import re
import subprocess
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SUFFIXES = {".py", ".md", ".js"}

# Built from parts so this file does not cite them itself.
FORBIDDEN = [
    re.compile(re.escape("DESIGN" + ".md")),
    re.compile(r"\bnotes " + "§"),
    re.compile(r"(?<![\w.-])" + "shared" + r"/(?:notes|DESIGN|STYLE|reference)"),
]
MD_LINK = re.compile(r"\]\(([^)\s]+)\)")
# A repository path written in prose or code: a known top-level folder, then a file with a doc suffix.
TOP = "docs|estimators|attack_profiles|flightsim|mitm_proxy|mavframe|secuav_common|evaluation|demos|study|webconsole"
REPO_PATH = re.compile(rf"(?<![\w/.-])((?:{TOP})/[\w./-]*\.md)(#[\w-]+)?")


@cache
def tracked() -> list[Path]:
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    files = [ROOT / line for line in out.splitlines()]
    this = Path(__file__).resolve()  # holds bad citations on purpose, as test data
    return [f for f in files if f.suffix in SUFFIXES and "vendor" not in f.parts and f.is_file() and f != this]


def slug(heading: str) -> str:
    """A heading's anchor as GitHub makes it: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


@cache
def anchors(page: Path) -> frozenset[str]:
    found: set[str] = set()
    in_code = False
    for line in page.read_text().splitlines():
        if line.startswith("```"):
            in_code = not in_code
        elif not in_code and line.startswith("#"):
            found.add(slug(line.lstrip("#")))
    return frozenset(found)


def check_target(source: Path, target: Path, anchor: str | None) -> str | None:
    if not target.exists():
        return f"{source.relative_to(ROOT)} cites {os.path.relpath(target, ROOT)}, which does not exist"
    if anchor and target.suffix == ".md" and anchor not in anchors(target):
        return f"{source.relative_to(ROOT)} cites {os.path.relpath(target, ROOT)}#{anchor}: no such heading"
    return None


def problems_in(path: Path, text: str | None = None) -> list[str]:
    """What is wrong with the citations of ``path`` (or of ``text``, read as if it were that file)."""
    text = path.read_text(errors="replace") if text is None else text
    found = [f"{path.relative_to(ROOT)} cites {m.group(0)!r}, not in the repository"
             for pattern in FORBIDDEN for m in pattern.finditer(text)]  # fmt: skip
    if path.suffix == ".md":
        for m in MD_LINK.finditer(text):
            link = m.group(1)
            if re.match(r"^[a-z][a-z0-9+.-]*:", link):  # http:, mailto:, ...
                continue
            where, _, anchor = link.partition("#")
            target = (path.parent / where).resolve() if where else path
            found.append(check_target(path, target, anchor or None) or "")
    for m in REPO_PATH.finditer(text):
        found.append(check_target(path, ROOT / m.group(1), (m.group(2) or "#")[1:] or None) or "")
    return [p for p in found if p]


def test_the_scan_sees_the_repository() -> None:
    names = {f.relative_to(ROOT).as_posix() for f in tracked()}
    assert {"README.md", "docs/interfaces.md", "mitm_proxy/app.py"} <= names


@pytest.mark.parametrize("bad", [
    "See DESIGN" + ".md for the port plan.",
    "Equations (notes " + "§2.1).",
    "what MAVSDK needs: `../shared" + "/notes/mavlink.md`",
    "the contract is docs/no-such-page.md",
    "see docs/interfaces.md#no-such-heading",
])  # fmt: skip
def test_a_citation_of_a_missing_document_is_caught(bad: str) -> None:
    assert problems_in(ROOT / "docs" / "probe.md", bad)
    assert problems_in(ROOT / "mitm_proxy" / "probe.py", f'"""{bad}"""')


def test_a_citation_that_exists_passes() -> None:
    text = "See [the ports](interfaces.md#endpoint-urls), [cli](cli.md) and estimators/README.md#api.\n"
    assert problems_in(ROOT / "docs" / "probe.md", text) == []


def test_every_citation_points_into_the_repository() -> None:
    problems = [p for f in tracked() for p in problems_in(f)]
    assert not problems, "\n".join(problems)
