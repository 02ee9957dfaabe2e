"""The ``avdata`` command: parses arguments and calls library functions, nothing more.

Expected failures (``AvdataError``) print one line, ``avdata: error: ...``, and exit 1; argparse
usage errors exit 2; an interrupt, at any moment, prints one line and exits 130. Tracebacks are only for bugs.

Start-up stays fast because a command's module is imported only when that command runs or shows its help:
each command is one :class:`Command` row in :data:`COMMANDS` naming its help line and the function that adds
its full parser. To add a command, add a row; its module's ``add_<name>_subparser(subparsers)`` must register
exactly one parser named like the row, with the same help line (tests/test_cli.py checks both).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from importlib import import_module
from pathlib import Path
from types import FrameType
from typing import Any


@dataclass(frozen=True, slots=True)
class Command:
    """One subcommand of ``avdata``, registered lazily.

    Attributes:
        name: the word typed after ``avdata``.
        help: its line in ``avdata --help`` (the same text its own parser is registered with).
        register: ``"module:function"``; the function takes the subparsers object and adds this command's
            full parser (arguments and ``run``). Its module is imported only when the command is used.
    """

    name: str
    help: str
    register: str


COMMANDS: tuple[Command, ...] = (
    Command("demo", "write a small built-in example dataset and print its info", "avdata.cli:add_demo_subparser"),
    Command("info", "summarise a unified dataset (scenes, sensors, classes, frame tree, size)",
            "avdata.cli:add_info_subparser"),
    Command("validate", "check a unified dataset; exit 1 with one line per problem", "avdata.cli:add_validate_subparser"),
    Command("index", "rebuild the Parquet index from the MCAP files", "avdata.cli:add_index_subparser"),
    Command("audit", "dataset checks (split overlap, calibrations, poses, ids); exit 1 if any",
            "avdata.cli:add_audit_subparser"),
    Command("convert", "convert a source dataset into the unified format", "avdata.converters.cli:add_convert_subparser"),
    Command("export", "write a unified dataset in another dataset's file layout",
            "avdata.exporters.cli:add_export_subparser"),
    Command("generate", "simulate V2I scenes (pybullet world, ray-cast sensors, labels)",
            "avdata.generators.cli:add_generate_subparser"),
    Command("eval", "evaluate detections, tracks or trajectory predictions", "avdata.eval.cli:add_eval_subparser"),
    Command("track", "track a detector's result files over a dataset's scenes; write its tracking format",
            "avdata.perception.cli:add_track_subparser"),
    Command("study", "run trade studies from configuration tables (cases x trials)", "avdata.studies.cli:add_study_subparser"),
    Command("view", "open a scene in Foxglove (a layout file) or in Rerun (--rerun)", "avdata.viz.cli:add_view_subparser"),
    Command("render", "draw a frame (bird's-eye view + cameras with boxes) as PNG, or a scene as MP4",
            "avdata.viz.cli:add_render_subparser"),
    Command("stats", "statistics of datasets side by side, and their distances (report.html, stats.md, plots)",
            "avdata.viz.cli:add_stats_subparser"),
)


def main(argv: Sequence[str] | None = None) -> int:
    """Runs the command line; returns the exit status."""
    interrupted = _latch_interrupts()
    try:
        return _main(argv, interrupted)
    finally:
        if signal.getsignal(signal.SIGINT) is _on_sigint:
            signal.signal(signal.SIGINT, signal.default_int_handler)


def _main(argv: Sequence[str] | None, interrupted: Callable[[], bool]) -> int:
    try:
        argv = list(sys.argv[1:] if argv is None else argv)
        from avdata.errors import AvdataError, one_line

        parser = build_parser(load=(_command_word(argv),))
        args = parser.parse_args(argv)
        if not getattr(args, "run", None):
            parser.print_help()
            return 2
        try:
            status = int(args.run(args) or 0)
            if interrupted():  # a library swallowed the KeyboardInterrupt (CI saw exit 0 after Ctrl-C in `stats`)
                raise KeyboardInterrupt
            return status
        except AvdataError as error:
            print(f"avdata: error: {one_line(error)}", file=sys.stderr)
            return 1
    except KeyboardInterrupt:
        print("avdata: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of stdout went away (``avdata info D | head``): not an error of ours
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except Exception as error:
        # Ctrl-C inside a compiled module's import (scipy's Cython init) arrives wrapped as the cause of
        # another exception: still an interruption, not a crash.
        cause: BaseException | None = error
        for _ in range(32):  # a bounded walk: exception chains can loop
            if cause is None or isinstance(cause, KeyboardInterrupt):
                break
            cause = cause.__cause__ or cause.__context__
        if not isinstance(cause, KeyboardInterrupt):
            raise
        print("avdata: interrupted", file=sys.stderr)
        return 130


_interrupts: list[int] = []


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    """Python's own SIGINT behaviour (KeyboardInterrupt), remembered."""
    _interrupts.append(signum)
    raise KeyboardInterrupt


def _latch_interrupts() -> Callable[[], bool]:
    """Installs ``_on_sigint`` where Python's default handler is (the main thread of a normal start).

    Returns whether a SIGINT arrived since; elsewhere the check is always False.
    """
    if threading.current_thread() is not threading.main_thread() \
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return lambda: False
    _interrupts.clear()
    signal.signal(signal.SIGINT, _on_sigint)
    return lambda: bool(_interrupts)


def _command_word(argv: Sequence[str]) -> str | None:
    """The command named on the command line: the first word that is not an option (top-level options take no value)."""
    return next((word for word in argv if not word.startswith("-")), None)


class _StoreOnce(argparse._StoreAction):
    """argparse's ``store``, refusing an option given twice with different values.

    argparse keeps the last one without a word: ``--scenes a --scenes b`` converted only ``b``.
    """

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        given: dict[str, str] = namespace.__dict__.setdefault("_given_options", {})
        if option_string is not None:
            shown = repr(values)  # compared as shown: NaN is not equal to itself
            if given.setdefault(self.dest, shown) != shown:
                raise argparse.ArgumentError(self, f"expected once, got {given[self.dest]} and then {shown}")
        super().__call__(parser, namespace, values, option_string)


class _Parser(argparse.ArgumentParser):
    """The parser of ``avdata`` and of every command under it (subparsers take their parent's class)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for name in (None, "store"):  # None: an add_argument without action=
            self.register("action", name, _StoreOnce)

    def _get_values(self, action: argparse.Action, arg_strings: list[str]) -> Any:
        """The values of ``action``; an empty string is refused.

        ``Path('')`` is the working folder, and ``''`` given for a dataset, an output folder or a scene picked the
        working folder or the first scene without a word. A command's own parser checks its own arguments.
        """
        if action.nargs not in (argparse.PARSER, argparse.REMAINDER) and "" in arg_strings:
            raise argparse.ArgumentError(action, "expected a value, got ''")
        return super()._get_values(action, arg_strings)


def build_parser(load: Collection[str | None] | None = None) -> argparse.ArgumentParser:
    """The argument parser with every command.

    Args:
        load: the commands whose full parsers (and so modules) to load; the others get only their help line.
            None loads every command (for tests and documentation).
    """
    from avdata import __version__

    parser = _Parser(prog="avdata", description="Autonomous-driving data in one trustworthy format.")
    parser.add_argument("--version", action="version", version=f"avdata {__version__}")
    subparsers = parser.add_subparsers(title="commands", metavar="COMMAND")
    for command in COMMANDS:
        if load is None or command.name in load:
            module, function = command.register.split(":")
            getattr(import_module(module), function)(subparsers)
        else:
            subparsers.add_parser(command.name, help=command.help, add_help=False)
    return parser


def add_demo_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers ``demo``."""
    demo = subparsers.add_parser("demo", help=_help("demo"))
    demo.add_argument("dst", type=Path, help="folder to write the dataset to (must not hold another dataset)")
    demo.set_defaults(run=_run_demo)


def add_info_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers ``info``."""
    info = subparsers.add_parser("info", help=_help("info"))
    info.add_argument("dataset", help=f"{_DATASET_HELP} (or its s3://, gs:// URI)")
    info.set_defaults(run=_run_info)


def add_validate_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers ``validate``."""
    validate = subparsers.add_parser("validate", help=_help("validate"))
    validate.add_argument("dataset", help=f"{_DATASET_HELP} (or its s3://, gs:// URI)")
    validate.set_defaults(run=_run_validate)


def add_index_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers ``index``."""
    index = subparsers.add_parser("index", help=_help("index"))
    index.add_argument("dataset", help=_DATASET_HELP)
    index.add_argument("--quiet", action="store_true", help="no progress bar (default: a bar on a terminal)")
    index.set_defaults(run=_run_index)


def add_audit_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers ``audit``."""
    audit = subparsers.add_parser("audit", help=_help("audit"))
    audit.add_argument("datasets", nargs="+", help="unified dataset folders or their s3://, gs:// URIs, checked together "
                       "(split overlap is looked for across them)")
    audit.set_defaults(run=_run_audit)


_DATASET_HELP = "unified dataset folder (written by avdata convert, generate or demo)"


def _help(name: str) -> str:
    return next(command.help for command in COMMANDS if command.name == name)


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
    from avdata.errors import AvdataError, InputError
    from avdata.executors import dataset_lock
    from avdata.executors.lock import LOCAL_FOLDERS_ONLY
    from avdata.schema import build_index
    from avdata.storage import is_remote

    if is_remote(args.dataset):
        raise InputError(f"{args.dataset}: {LOCAL_FOLDERS_ONLY}")
    if not os.path.isdir(args.dataset):  # not Path.is_dir: it raises for a name too long (a traceback)
        raise AvdataError(f"{args.dataset}: dataset folder does not exist")
    with dataset_lock(Path(args.dataset)):
        build_index(Path(args.dataset), progress=not args.quiet and sys.stderr.isatty())
    print(f"{args.dataset}: index rebuilt")
    return 0


if __name__ == "__main__":
    sys.exit(main())
