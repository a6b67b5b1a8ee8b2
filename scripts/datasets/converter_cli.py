"""The command line the dataset converters in this folder share (``lias_planar_uwb.py``, ``hanyang_outdoor_uwb.py``).

Each has two verbs: ``convert`` (one run to ``ranges.csv``, ``truth.csv`` and ``scenario.yaml``) and ``fit`` (the
noise over several runs, docs/datasets.md), and both read ``--source``, a local copy of the dataset, or download
what they need into ``--cache``. The converters import it from beside themselves (they are scripts, not a package).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from uwb_fit import fit_noise


def converter_parser(
    description: str, source_help: str, cache: Path
) -> tuple[argparse.ArgumentParser, argparse.ArgumentParser, argparse.ArgumentParser]:
    """The parser with its ``convert`` and ``fit`` verbs (returned too, for each converter's own options)."""
    p = argparse.ArgumentParser(description=description)
    sub = p.add_subparsers(dest="cmd", required=True)
    for name in ("convert", "fit"):
        c = sub.add_parser(name)
        c.add_argument("--source", type=Path, default=None, help=source_help)
        c.add_argument("--cache", type=Path, default=cache, help="download folder")
    return p, sub.choices["convert"], sub.choices["fit"]


def print_fit(result: dict[str, object], series: list[np.ndarray]) -> int:
    """``fit``'s answer: what the converter says of the dataset and its runs, with the fitted noise, as JSON."""
    result.update(fit_noise(series))
    print(json.dumps(result, indent=2))
    return 0
