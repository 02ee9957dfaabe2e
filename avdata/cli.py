"""The ``avdata`` command: parses arguments and calls library functions, nothing more.

Expected failures (``AvdataError``) print one line, ``avdata: error: ...``, and exit 1; argparse
usage errors exit 2; an interrupt exits 130. Tracebacks are only for bugs.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from avdata import __version__
from avdata.errors import AvdataError, one_line


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "run", None):
        parser.print_help()
        return 2
    try:
        return int(args.run(args) or 0)
    except AvdataError as error:
        print(f"avdata: error: {one_line(error)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("avdata: interrupted", file=sys.stderr)
        return 130


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser with every subcommand."""
    from avdata.converters.cli import add_convert_subparser
    from avdata.eval.cli import add_eval_subparser
    from avdata.exporters.cli import add_export_subparser
    from avdata.generators.cli import add_generate_subparser
    from avdata.perception.cli import add_track_subparser
    from avdata.studies.cli import add_study_subparser
    from avdata.viz.cli import add_viz_subparsers

    parser = argparse.ArgumentParser(prog="avdata", description="Autonomous-driving data in one trustworthy format.")
    parser.add_argument("--version", action="version", version=f"avdata {__version__}")
    subparsers = parser.add_subparsers(title="commands", metavar="COMMAND")

    demo = subparsers.add_parser("demo", help="write a small built-in example dataset and print its info")
    demo.add_argument("dst", type=Path, help="folder to write the dataset to")
    demo.set_defaults(run=_run_demo)

    info = subparsers.add_parser("info", help="summarise a unified dataset")
    info.add_argument("dataset", type=Path)
    info.set_defaults(run=_run_info)

    validate = subparsers.add_parser("validate", help="check a unified dataset; exit 1 with one line per problem")
    validate.add_argument("dataset", type=Path)
    validate.set_defaults(run=_run_validate)

    index = subparsers.add_parser("index", help="rebuild the Parquet index from the MCAP files")
    index.add_argument("dataset", type=Path)
    index.add_argument("--quiet", action="store_true", help="no progress bar")
    index.set_defaults(run=_run_index)

    audit = subparsers.add_parser("audit", help="dataset checks (split overlap, calibrations, poses, ids); exit 1 if any")
    audit.add_argument("datasets", type=Path, nargs="+")
    audit.set_defaults(run=_run_audit)

    add_convert_subparser(subparsers)
    add_export_subparser(subparsers)
    add_generate_subparser(subparsers)
    add_eval_subparser(subparsers)
    add_study_subparser(subparsers)
    add_track_subparser(subparsers)
    add_viz_subparsers(subparsers)
    return parser


def _run_audit(args: argparse.Namespace) -> int:
    from avdata.audit import audit

    findings = audit(args.datasets)
    for finding in findings:
        print(finding)
    print(f"audit: {len(findings)} findings in {len(args.datasets)} datasets", file=sys.stderr)
    return 1 if findings else 0


def _run_demo(args: argparse.Namespace) -> int:
    from avdata.demo import write_demo
    from avdata.schema.info import describe_dataset
    from avdata.schema.validate import validate_dataset

    root = write_demo(args.dst)
    problems = validate_dataset(root)
    for problem in problems:
        print(problem, file=sys.stderr)
    print(describe_dataset(root))
    print(f"validate:  {'clean' if not problems else f'{len(problems)} problems'}")
    return 1 if problems else 0


def _run_info(args: argparse.Namespace) -> int:
    from avdata.schema.info import describe_dataset

    print(describe_dataset(args.dataset))
    return 0


def _run_validate(args: argparse.Namespace) -> int:
    from avdata.schema.validate import validate_dataset

    problems = validate_dataset(args.dataset)
    for problem in problems:
        print(problem)
    if problems:
        print(f"{len(problems)} problems", file=sys.stderr)
        return 1
    print(f"{args.dataset}: clean")
    return 0


def _run_index(args: argparse.Namespace) -> int:
    from avdata.executors import dataset_lock
    from avdata.schema import build_index

    if not Path(args.dataset).is_dir():
        raise AvdataError(f"{args.dataset}: dataset folder does not exist")
    with dataset_lock(args.dataset):
        build_index(args.dataset, progress=not args.quiet and sys.stderr.isatty())
    print(f"{args.dataset}: index rebuilt")
    return 0


if __name__ == "__main__":
    sys.exit(main())
