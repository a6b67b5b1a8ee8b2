"""What a user reads names no thesis and no figure numbers of one (issue 36): the CLIs' help (docs/cli.md is
generated from it and kept current by test_docs_current), the docs, the console page, the bundled scenario,
study and attack profile files (``secuav-attack list`` and docs/profile.md show the profiles' descriptions),
and the titles of the demo and evaluation plots.
"""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# "seed" as the thesis ("the seed's split", "seed Fig. A.5", "Seed test case 1"), not a random seed ("--seed",
# "noise seed", "every seed"); and any figure number ("Fig. 5.3", "Figs. 5.4-5.6").
THESIS = re.compile(r"(?i)\bseed(?:'s|\s+(?:thesis|fig|test case|table|layout|anchors8|wall hover|scenarios)\b)")
FIGURE = re.compile(r"\bFigs?\.\s*[A-Z0-9]")


def _files() -> list[Path]:
    docs = list((REPO / "docs").glob("*.md"))
    page = sorted((REPO / "webconsole/static").glob("*.[hj]*"))
    data = [*(REPO / "secuav_common/scenarios").glob("*.yaml"), *(REPO / "studies").glob("*.yaml"),
            *(REPO / "attack_profiles/library").glob("*.yaml")]
    return [*docs, *page, *data, REPO / "README.md"]


def _plot_titles() -> list[str]:
    titles = []
    for p in (REPO / "demos").glob("*.py"):
        titles += re.findall(r"set_title\((.*)\)|suptitle\((.*)\)|title=(.*)", p.read_text())  # type: ignore[arg-type]
    for p in (REPO / "evaluation").glob("*.py"):
        titles += re.findall(r"set_title\((.*)\)|suptitle\((.*)\)", p.read_text())  # type: ignore[arg-type]
    return [" ".join(t) for t in titles]


def test_no_thesis_and_no_figure_numbers_where_users_read() -> None:
    found = []
    for path in _files():
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if THESIS.search(line) or FIGURE.search(line):
                found.append(f"{path.relative_to(REPO)}:{n}: {line.strip()[:100]}")
    found += [f"plot title: {t}" for t in _plot_titles() if THESIS.search(t) or FIGURE.search(t)]
    assert found == [], "\n".join(found)
    assert len(_files()) > 20 and _plot_titles()  # the scan reads what it says it reads


def test_the_patterns_catch_the_old_wording_and_spare_random_seeds() -> None:
    old_wording = ("# Seed Fig. A.5: a wall ahead", "the seed's split", "Attack over time (cf. seed Fig. 5.3)",
                   "Hold a position (seed test case 1: the area's centre).")
    for old in old_wording:
        assert THESIS.search(old) or FIGURE.search(old), old
    for fine in ("--seed SEED  noise seed (default: the scenario's seed)", "every seed re-runs", "seeds: 20"):
        assert not (THESIS.search(fine) or FIGURE.search(fine)), fine
