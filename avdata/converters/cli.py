"""``avdata convert NAME SRC DST``: one sub-command per registered converter."""

from __future__ import annotations

import argparse
import sys
from dataclasses import fields

from avdata.converters.base import CONVERTERS, ConvertConfig, converter_class, run_conversion
from avdata.executors.base import add_executor_arguments


def add_convert_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers ``convert`` and one sub-command per converter in :data:`CONVERTERS`."""
    convert = subparsers.add_parser("convert", help="convert a source dataset into the unified format")
    names = convert.add_subparsers(title="sources", metavar="SOURCE", dest="name")
    for name in CONVERTERS:
        cls = converter_class(name)
        parser = names.add_parser(name, help=(cls.__doc__ or name).strip().splitlines()[0])
        parser.add_argument("src", help="source folder, in the dataset's published layout (or s3://, gs:// URI)")
        parser.add_argument("dst", help="unified dataset folder to write (or s3://, gs:// URI)")
        parser.add_argument("--strict", action="store_true",
                            help="stop at the first error (default: skip the bad record, report it, go on)")
        parser.add_argument("--quiet", action="store_true", help="no progress output (default: progress on stderr)")
        parser.add_argument("--compression", choices=("none", "zstd", "lz4"), default="none",
                            help="MCAP chunk compression (default none: fastest, random access by offset)")
        parser.add_argument("--scenes", nargs="+", default=(), help="convert only these scenes (default: all)")
        add_executor_arguments(parser, "scenes converted")
        cls.add_arguments(parser)
        parser.set_defaults(run=_run_convert)


def _run_convert(args: argparse.Namespace) -> int:
    from avdata.errors import InputError
    from avdata.inputs import is_present
    from avdata.storage import path_or_location

    args.src, args.dst = path_or_location(args.src), path_or_location(args.dst)
    if not is_present(args.src):
        raise InputError(f"{args.src}: source folder does not exist")
    cls = converter_class(args.name)
    config = ConvertConfig(
        src=args.src,
        dst=args.dst,
        strict=args.strict,
        workers=args.workers,
        quiet=args.quiet,
        compression=args.compression,
        scenes=tuple(args.scenes),
        # The typed instance, never a dict: code still reading ``config.options.get(...)`` fails loudly.
        options=cls.Options(**{option.name: getattr(args, option.name) for option in fields(cls.Options)}),
        force=args.force,
        executor=args.executor,
        ray_address=args.ray_address,
    )
    result = run_conversion(cls(config))
    for problem in result.problems:
        print(problem, file=sys.stderr)
    n_warnings = len(result.problems) - result.n_errors
    removed = f", {len(result.removed)} stale scenes removed" if result.removed else ""
    print(
        f"{args.name}: {len(result.written)} scenes written, {len(result.complete)} already complete, "
        f"{len(result.failed)} failed{removed}; {result.n_errors} errors, {n_warnings} warnings -> {args.dst}"
    )
    return 1 if result.n_errors or result.failed else 0
