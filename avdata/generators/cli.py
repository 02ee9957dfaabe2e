"""The ``avdata generate`` subcommand."""

from __future__ import annotations

import argparse
import sys

from avdata.errors import InputError
from avdata.executors.base import add_executor_arguments


def add_generate_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Registers ``generate`` on an argparse subparsers object."""
    from avdata.generators.config import PRESETS

    parser: argparse.ArgumentParser = subparsers.add_parser(
        "generate", help="simulate V2I scenes (pybullet world, ray-cast sensors, labels)")
    parser.add_argument("paths", nargs="+", metavar="[CONFIG.yaml] DST",
                        help="a scenario file and the dataset folder (a path, s3://... or gs://...), or only DST with --preset")
    parser.add_argument("--preset", choices=PRESETS, help="a built-in scenario instead of CONFIG.yaml")
    parser.add_argument("--scenes", type=int, help="override the number of scenes")
    parser.add_argument("--frames", type=int, help="override the frames per scene")
    parser.add_argument("--seed", type=int, help="override the seed")
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    add_executor_arguments(parser, "scenes generated")
    parser.set_defaults(run=run_generate)
    return parser


def run_generate(args: argparse.Namespace) -> int:
    """Runs ``avdata generate``; returns the exit status."""
    from avdata.generators.config import load_preset, load_scenario, scenario_from_dict
    from avdata.storage import path_or_location

    if args.preset:
        if len(args.paths) != 1:
            raise InputError(f"generate --preset: expected only DST, got {args.paths}")
        config = load_preset(args.preset)
        dst = path_or_location(args.paths[0])
    else:
        if len(args.paths) != 2:
            raise InputError(f"generate: expected CONFIG.yaml DST (or --preset NAME DST), got {args.paths}")
        config = load_scenario(args.paths[0])
        dst = path_or_location(args.paths[1])
    overrides = {k: getattr(args, k) for k in ("scenes", "frames", "seed") if getattr(args, k) is not None}
    if overrides:
        config = scenario_from_dict({**config.to_dict(), **overrides}, "command line")
    if args.workers < 1:
        raise InputError(f"--workers: expected >= 1, got {args.workers}")
    # Imported only now: pybullet prints a banner on import, which should not precede an input error.
    from avdata.generators.driver import generate_scenes

    result = generate_scenes(config, dst, executor=args.executor, workers=args.workers, ray_address=args.ray_address,
                             force=args.force, quiet=args.quiet)
    for problem in result.problems:
        print(problem, file=sys.stderr)
    removed = f", {len(result.removed)} stale scenes removed" if result.removed else ""
    if not args.quiet:
        print(f"generate: {len(result.written)} scenes written, {len(result.complete)} already complete, "
              f"{len(result.failed)} failed{removed} -> {dst}")
    return 1 if result.failed else 0
