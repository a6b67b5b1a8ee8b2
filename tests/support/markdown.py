"""Markdown tables as the report scripts print them (scripts/recorded_alarms.py, scripts/naming_sweep.py), read
back for the tests that run those scripts."""

from __future__ import annotations


def tables(markdown: str) -> list[list[list[str]]]:
    """Every markdown table: its rows (header first, the separator dropped), each a list of cells."""
    found: list[list[list[str]]] = []
    current: list[list[str]] = []
    for line in [*markdown.splitlines(), ""]:
        if line.startswith("|"):
            if not line.startswith("|---"):
                current.append([c.strip() for c in line.strip("|").split("|")])
        elif current:
            found.append(current)
            current = []
    return found
