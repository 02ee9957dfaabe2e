"""``avdata study run STUDY.yaml OUT`` and ``avdata study report OUT``."""

from __future__ import annotations

import argparse
from pathlib import Path

from avdata.executors.base import EXECUTORS


def add_study_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Registers ``study`` with ``run`` and ``report``."""
    parser = subparsers.add_parser("study", help="run trade studies from configuration tables (cases x trials)")
    sub = parser.add_subparsers(dest="study_task", required=True)
    run = sub.add_parser("run", help="generate the trials and evaluate every case on each (resumable)")
    run.add_argument("study", type=Path, help="study file (YAML), e.g. studies/v2i-comm-range.yaml")
    run.add_argument("out",
                     help="output folder (trials, per-run results, results.parquet; a path, s3://... or gs://...)")
    run.add_argument("--workers", type=int, default=1, help="tasks in parallel processes (--executor local; default 1)")
    run.add_argument("--executor", choices=EXECUTORS, default="local",
                     help="local: a process pool on this machine (default); ray: one Ray task per trial and per run")
    run.add_argument("--ray-address", default=None,
                     help="Ray cluster to join, e.g. 'auto' or HOST:6379 (default: start a local Ray instance)")
    run.add_argument("--trials", type=int, help="override the number of trials")
    run.add_argument("--frames", type=int, help="override the frames per trial")
    run.add_argument("--quiet", action="store_true", help="no progress lines")
    run.add_argument("--no-report", action="store_true", help="do not write the report after the run")
    run.set_defaults(run=_run)
    report = sub.add_parser("report", help="aggregate results.parquet into report.md, report.csv and plots")
    report.add_argument("out", help="the output folder of 'avdata study run' (a path or a URI)")
    report.set_defaults(run=_report)
    return parser


def _run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from avdata.errors import InputError
    from avdata.outputs import refuse_output_in_input
    from avdata.schema.dataset import dataset_root
    from avdata.storage import path_or_location
    from avdata.studies import load_study, run_study, write_report
    from avdata.studies.config import check_sizes

    study = load_study(args.study)
    out = path_or_location(args.out)
    # OUT at or under a studied dataset wrote the trial results and report into it.
    studied = dict.fromkeys(dataset_root(path) for _, path, _ in study.sources() or [])
    refuse_output_in_input(out, list(studied), "the study's dataset")
    if args.workers < 1:
        raise InputError(f"--workers: expected >= 1, got {args.workers}")
    if study.sources() is not None and (args.trials is not None or args.frames is not None):
        raise InputError(f"{args.study}: --trials and --frames apply to generated trials; this study runs on the "
                         "scenes of existing datasets (one trial per scene)")
    if args.trials is not None or args.frames is not None:
        study = replace(study, trials=study.trials if args.trials is None else args.trials,
                        frames=study.frames if args.frames is None else args.frames)
        check_sizes(study, f"{args.study} with --trials {study.trials} --frames {study.frames}")
    run_study(study, out, executor=args.executor, workers=args.workers, ray_address=args.ray_address,
              progress=not args.quiet)
    if not args.no_report:
        for path in write_report(out):
            print(f"wrote {path}")
    return 0


def _report(args: argparse.Namespace) -> int:
    from avdata.storage import path_or_location
    from avdata.studies import write_report

    for path in write_report(path_or_location(args.out)):
        print(f"wrote {path}")
    return 0
