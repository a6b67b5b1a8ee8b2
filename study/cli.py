"""``secuav-study``: run a whole study (attacks x magnitudes x estimators x seeds) on Dask, resumably.

    secuav-study run studies/stealth.yaml --out out/stealth                 # embedded LocalCluster, one worker per core
    secuav-study run studies/stealth.yaml --out out/stealth --workers 2
    secuav-study run studies/stealth.yaml --out out/stealth --scheduler tcp://10.0.0.5:8786
    secuav-study run studies/stealth.yaml --out out/stealth --workers 2 --ports 9100   # cluster on 9100-9107
    secuav-study report out/stealth                                          # rewrite report.md and figures/
    secuav-study validate studies/stealth.yaml
    secuav-study schema
    secuav-study export out/stealth bundle/                                   # study, inputs, environment, results
    secuav-study export out/stealth bundle/ --with-sources                    # ... and the plugins' sources
    secuav-study suite run --quick --out out/suite --add huber                # the benchmark suite, your method added
    secuav-study suite check out/suite                                        # leaderboard and expected bands

``run`` prints a progress bar (cells done, failed, ETA) and, last, one JSON
line ``{"cells", "ran", "skipped", "failed", "changed", "fresh", "out"}``: ``failed`` counts the
cells of the study whose rows in DIR carry an error; ``changed`` the cells run
again only because the code of a row changed (an estimator's source or default,
a primitive's, the secuav version: docs/study.md, "Provenance"), also said on
stderr; ``fresh`` the cells a worker ran in a new process because it had loaded
older code than the client's (docs/bench.md, "Long-lived workers"). Exit 0 when none failed,
1 when some did (they are in the results), 2 on bad input, 130 when
interrupted (what finished is kept; run again to go on). With ``SECUAV_STUDY_SMOKE=1`` in the environment every
study is cut to its first two cells (one seed, one leg, 3 s), to try commands (docs/bench.md); such a directory
is never a score.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from secuav_common.extras import require
from secuav_common.loading import InputError
from secuav_common.logs import add_common_flags

PORTS_HELP = ("the embedded cluster's loopback ports: BASE (scheduler), BASE+1 (its HTTP), then per worker three "
              "(nanny, worker, worker HTTP): 2+3*workers in all (default: any free ones)")  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="secuav-study", description=__doc__.splitlines()[0])
    add_common_flags(p, log_flags=False)
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run the cells not yet in DIR, then write the report")
    run.add_argument("study", type=Path)
    run.add_argument("--out", required=True, type=Path)
    where = run.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="LocalCluster worker processes (default: cores)")
    where.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT", help="a running dask scheduler")
    run.add_argument("--ports", type=int, default=None, metavar="BASE", help=PORTS_HELP)
    run.add_argument("--retry-failed", action="store_true", help="run again the cells recorded as failed")
    run.add_argument("--no-progress", action="store_true", help="no progress bar (the JSON line still comes)")
    rep = sub.add_parser("report", help="(re)write DIR/report.md and DIR/figures/ from DIR/results.parquet")
    rep.add_argument("out", type=Path)
    val = sub.add_parser("validate", help="check a study file and count its cells")
    val.add_argument("study", type=Path)
    sub.add_parser("schema", help="print the JSON Schema of a study file")
    suite = sub.add_parser("suite", help="the versioned benchmark suite: list, run, check (docs/bench.md)")
    steps = suite.add_subparsers(dest="suite_command", required=True)
    what = "the suite's studies and their cells (quick and full)"
    steps.add_parser("list", help=what, description=what).add_argument(
        "--version", default="v1", help="suite version (default v1)")
    what = "run every study of the suite into OUT/<study>"
    srun = steps.add_parser("run", help=what, description=what)
    srun.add_argument("--out", required=True, type=Path, help="where the results go: OUT/<study> for each study")
    srun.add_argument("--quick", action="store_true", help="the quick variant (minutes on a laptop)")
    srun.add_argument("--version", default="v1", help="suite version (default v1)")
    srun.add_argument("--add", action="append", default=[], metavar="ENTRY",
                      help="a method under test, as in a study's estimators: NAME, package.module:Class, or "
                      "'{name: huber, params: {huber_k: [1.0, 1.345]}}' (YAML); repeatable")  # fmt: skip
    srun.add_argument("--only", action="append", default=[], metavar="STUDY", help="run only this study (repeatable)")
    srun.add_argument("--split", choices=("evaluation", "tuning"), default="evaluation",
                      help="tuning: where a method's parameters are chosen (other seeds, anchor layouts and hover "
                      "points, OUT/tuning/); evaluation (default): the scored cells, where a method given with a grid "
                      "runs only at its best tuning point")  # fmt: skip
    swhere = srun.add_mutually_exclusive_group()
    swhere.add_argument("--workers", type=int, default=None, help="LocalCluster worker processes (default: cores)")
    swhere.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT", help="a running dask scheduler")
    srun.add_argument("--ports", type=int, default=None, metavar="BASE", help=PORTS_HELP)
    srun.add_argument("--no-progress", action="store_true", help="no progress bars")
    what = "the leaderboard (Markdown and CSV) and the built-ins' expected bands"
    scheck = steps.add_parser("check", help=what, description=what)
    scheck.add_argument("out", type=Path, metavar="OUT", help="what `suite run --out OUT` wrote")
    scheck.add_argument("--version", default="v1", help="suite version (default v1)")
    scheck.add_argument("--record-bands", action="store_true",
                        help="(maintainers) write the suite's expected bands from OUT's built-in rows")  # fmt: skip
    exp = sub.add_parser("export", help="write DIR's study, inputs, environment and results to BUNDLE (reproducible)")
    exp.add_argument("out", type=Path, metavar="DIR")
    exp.add_argument("bundle", type=Path, metavar="BUNDLE")
    exp.add_argument("--with-sources", action="store_true",
                     help="also the source of every plugin that computed the rows (BUNDLE/plugins/), from the "
                     "folder it was installed from; `run BUNDLE/study.yaml` installs the missing ones")  # fmt: skip
    exp.add_argument("--source", action="append", type=Path, default=[], metavar="PATH",
                     help="a plugin's project folder, sdist or wheel to ship (implies --with-sources; repeatable)")
    return p


def _run(args: argparse.Namespace) -> int:
    from study.launch import run_study

    return run_study(args.study, args.out, workers=args.workers, scheduler=args.scheduler, ports=args.ports,
                     retry_failed=args.retry_failed, progress=not args.no_progress)  # fmt: skip


def _suite(args: argparse.Namespace) -> int:
    import yaml

    from study.suite import run as suite

    try:
        if args.suite_command == "list":
            print(suite.list_text(args.version))
            return 0
        if args.suite_command == "check":
            if args.record_bands:
                print(suite.record_bands(args.out, args.version))
            return suite.check(args.out, args.version)
        added = [yaml.safe_load(text) for text in args.add]
        return suite.run(args.out, quick=args.quick, version=args.version, added=added, only=args.only,
                         workers=args.workers or None, scheduler=args.scheduler or None, ports=args.ports,
                         progress=not args.no_progress, split=args.split)  # fmt: skip
    except (InputError, ValueError) as err:
        print(f"secuav-study: {err}", file=sys.stderr)
        return 2


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    require("secuav-study")
    if args.command == "schema":
        from study.spec import Study

        print(json.dumps(Study.model_json_schema(), indent=2))
        return 0
    if args.command == "validate":
        from study.launch import load

        try:
            study, cells = load(args.study)
        except InputError as err:
            print(f"secuav-study: {err}", file=sys.stderr)
            return 2
        n = len(study.variants())
        print(f"{args.study}: ok; {len(cells)} cells x {n} estimator variants = {len(cells) * n} runs ({study.mode})")
        return 0
    if args.command == "suite":
        return _suite(args)
    if args.command == "export":
        from study.bundle import export

        try:
            print(export(args.out, args.bundle, with_sources=args.with_sources, sources=args.source))
        except InputError as err:
            print(f"secuav-study: {err}", file=sys.stderr)
            return 2
        return 0
    if args.command == "report":
        from study.report import write_report

        if not (args.out / "results.parquet").is_dir():
            print(f"secuav-study: {args.out}: no results.parquet here (run a study first)", file=sys.stderr)
            return 2
        print(write_report(args.out))
        return 0
    return _run(args)


if __name__ == "__main__":
    sys.exit(main())
