"""The ``avdata`` command: demo, info, validate, index, and one-line errors with exit status."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from avdata.schema import DatasetReader


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "avdata.cli", *args], capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    dst = tmp_path_factory.mktemp("demo") / "demo"
    result = run("demo", str(dst))
    assert result.returncode == 0, result.stderr
    assert "validate:  clean" in result.stdout
    assert "frames:    5 (5 annotated)" in result.stdout
    return dst


def test_demo_dataset_has_every_kind_of_message(demo: Path) -> None:
    reader = DatasetReader(demo)
    scene = reader.scene("demo-0000")
    assert set(scene.topics) >= {"/tf", "/tf_static", "/ego/lidar_top/points", "/ego/cam_front/image",
                                 "/ego/cam_front/calibration", "/labels/objects", "/labels/markers"}
    points = reader.points("demo-0000", 0, "ego/lidar_top")
    assert len(points) > 10_000 and points.dtype.names == ("x", "y", "z", "intensity")
    import cv2
    import numpy as np

    data, fmt = reader.image("demo-0000", 0, "ego/cam_front")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert fmt == "png" and image.shape == (360, 640, 3)
    vis = reader.visibility().to_pylist()
    lidar_rows = [v for v in vis if v["sensor"] == "ego/lidar_top" and v["frame_index"] == 0]
    assert {v["object_id"]: v["n_points"] > 0 for v in lidar_rows} == {"1": True, "2": True, "3": True}


def test_info_lists_scenes_sensors_classes_and_tree(demo: Path) -> None:
    result = run("info", str(demo))
    assert result.returncode == 0, result.stderr
    for expected in ("scenes:    1", "/ego/lidar_top/points", "10.00 Hz", "car                    10",
                     "ego (stamped, 5 samples)", "ego/cam_front (static)", "size:"):
        assert expected in result.stdout


def test_validate_reports_each_problem_on_one_line(demo: Path, tmp_path: Path) -> None:
    assert run("validate", str(demo)).returncode == 0
    broken = tmp_path / "broken"
    shutil.copytree(demo, broken)
    objects = pq.read_table(broken / "index" / "objects.parquet")
    pq.write_table(objects.slice(0, objects.num_rows - 1), broken / "index" / "objects.parquet")
    frames = pq.read_table(broken / "index" / "frames.parquet")
    column = frames.column("world_T_ego_x_m").to_pylist()
    column[1] += 0.5
    frames = frames.set_column(frames.schema.get_field_index("world_T_ego_x_m"), "world_T_ego_x_m",
                               pa.array(column, pa.float64()))
    pq.write_table(frames, broken / "index" / "frames.parquet")
    result = run("validate", str(broken))
    assert result.returncode == 1
    lines = result.stdout.strip().splitlines()
    assert any("index/objects.parquet" in line and "expected 15 rows" in line for line in lines)
    assert any("index/frames.parquet" in line and "world_T_ego_x_m" in line for line in lines)
    assert all(line.startswith("demo-0000: ") for line in lines)
    assert run("index", str(broken), "--quiet").returncode == 0
    assert run("validate", str(broken)).returncode == 0


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("missing", "dataset folder does not exist"),
        ("newer", "format version 9.0 is newer than this avdata supports"),
        ("truncated", "truncated MCAP file"),
        ("no-scene", "scene file listed in the manifest is missing"),
    ],
)
def test_bad_input_gives_one_line_error_and_nonzero_exit(demo: Path, tmp_path: Path, case: str, expected: str) -> None:
    target = tmp_path / "ds"
    if case != "missing":
        shutil.copytree(demo, target)
    scene = target / "scenes" / "demo-0000.mcap"
    if case == "newer":
        manifest = json.loads((target / "avdata.json").read_text())
        manifest["format_version"] = "9.0"
        (target / "avdata.json").write_text(json.dumps(manifest))
    elif case == "truncated":
        scene.write_bytes(scene.read_bytes()[:5000])
    elif case == "no-scene":
        scene.unlink()
    result = run("info", str(target))
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("avdata: error: ")
    assert expected in result.stderr


def test_usage_error_exits_2() -> None:
    result = run("info")
    assert result.returncode == 2 and "Traceback" not in result.stderr


@pytest.mark.parametrize(
    "argv",
    [
        ["convert", "kitti-object", "/nonexistent/kitti", "{tmp}/out"],
        ["convert", "nuscenes", "/nonexistent/nuscenes", "{tmp}/out", "--version", "v1.0-mini"],
        ["export", "kitti-object", "/nonexistent/dataset", "{tmp}/out"],
        ["generate", "/nonexistent/scenario.yaml", "{tmp}/out"],
        ["eval", "tracking", "--protocol", "kitti", "/nonexistent/gt", "/nonexistent/tracker"],
    ],
)
def test_every_command_reports_a_missing_input_in_one_line(tmp_path: Path, argv: list[str]) -> None:
    result = run(*[a.format(tmp=tmp_path) for a in argv])
    assert result.returncode == 1, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    assert result.stderr.startswith("avdata: error: ") and "/nonexistent" in result.stderr
    assert not (tmp_path / "out" / "avdata.json").exists()


def test_export_and_index_take_the_writer_lock_and_refuse_a_file_as_dst(demo: Path, tmp_path: Path) -> None:
    import os

    from avdata.executors import dataset_lock

    blocker = tmp_path / "blocker"
    blocker.write_text("not a folder")
    result = run("export", "kitti-object", str(demo), str(blocker))
    assert result.returncode == 1 and result.stderr.count("\n") == 1
    assert "expected a folder to write into, got a file" in result.stderr
    with dataset_lock(demo), dataset_lock(tmp_path / "other"):
        for argv in (["index", str(demo), "--quiet"], ["export", "kitti-object", str(demo), str(tmp_path / "other")]):
            result = run(*argv)
            assert result.returncode == 1 and result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
            assert f"(PID {os.getpid()}) is writing this folder" in result.stderr
    assert run("index", str(demo), "--quiet").returncode == 0


def test_library_error_text_over_several_lines_is_printed_on_one(monkeypatch, capsys) -> None:
    # pyarrow's Thrift errors end in a newline; embedded in a problem or an error they must not break the
    # one-line-per-problem output.
    from avdata.cli import main
    from avdata.errors import InputError
    from avdata.executors.scenes import Problem
    from avdata.schema.validate import ValidationProblem

    thrift = "Couldn't deserialize thrift: TProtocolException: Invalid data\n"
    assert str(Problem(severity="error", scene="s", file="f.parquet", message=thrift)).count("\n") == 0
    assert str(ValidationProblem(scene="s", topic="/t", time_ns=1, message=thrift)).count("\n") == 0

    def broken(args):
        raise InputError(f"f.parquet: expected a Parquet file ({thrift})")

    monkeypatch.setattr("avdata.cli._run_info", broken)
    assert main(["info", "anything"]) == 1
    err = capsys.readouterr().err
    assert err == "avdata: error: f.parquet: expected a Parquet file (Couldn't deserialize thrift: " \
                  "TProtocolException: Invalid data )\n"


# --- start-up, help texts, interrupts ---------------------------------------------------------------------------

_HEAVY = ("pyarrow.compute", "torch", "open3d", "pybullet", "ray", "matplotlib")


def test_import_and_top_level_help_load_no_heavy_stack() -> None:
    # `avdata --help` builds the parser with no command loaded; no stack of any command may come with it.
    code = ("import sys, contextlib, io\n"
            "from avdata.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
            "    main(['--help'])\n"
            f"print(' '.join(m for m in {_HEAVY!r} if m in sys.modules))\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == ""


def test_info_loads_no_heavy_stack(demo: Path) -> None:
    # info reads the manifest and the scenes' summaries, not the Parquet index: not even pyarrow itself.
    code = ("import sys\n"
            "from avdata.cli import main\n"
            f"assert main(['info', {str(demo)!r}]) == 0\n"
            f"print('HEAVY:', ' '.join(m for m in (*{_HEAVY!r}, 'pyarrow') if m in sys.modules))\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().splitlines()[-1] == "HEAVY:"


def _all_parsers(parser, path=("avdata",)):
    import argparse

    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _all_parsers(sub, (*path, name))


def test_every_command_row_registers_one_parser_with_its_help_line() -> None:
    import argparse

    from avdata.cli import COMMANDS, build_parser

    parser = build_parser(load=None)
    (subparsers,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    assert list(subparsers.choices) == [c.name for c in COMMANDS]
    assert {a.dest: a.help for a in subparsers._choices_actions} == {c.name: c.help for c in COMMANDS}


def test_every_option_and_argument_says_what_it_does_and_its_default() -> None:
    import argparse

    from avdata.cli import build_parser

    missing = []
    for path, parser in _all_parsers(build_parser(load=None)):
        for action in parser._actions:
            if isinstance(action, (argparse._HelpAction, argparse._VersionAction, argparse._SubParsersAction)):
                continue
            name = "/".join(action.option_strings) or action.dest
            text = (action.help or "").strip()
            if not text:
                missing.append(f"{' '.join(path)} {name}: no help")
            elif "``" in text or ":func:" in text:
                missing.append(f"{' '.join(path)} {name}: reStructuredText in {text!r}")
            elif (action.option_strings and not action.required and action.default not in (None, False, (), [])
                  and "default" not in text.lower()):
                missing.append(f"{' '.join(path)} {name}: default {action.default!r} not said in {text!r}")
        choices = [c for a in parser._actions if isinstance(a, argparse._SubParsersAction) for c in a._choices_actions]
        for choice in choices:
            if "``" in (choice.help or "") or not (choice.help or "").strip():
                missing.append(f"{' '.join(path)} {choice.dest}: help line {choice.help!r}")
    assert missing == []


@pytest.mark.parametrize("delay_s", [0.05, 0.3, 0.7])
def test_ctrl_c_while_starting_exits_130_with_one_line(demo: Path, tmp_path: Path, delay_s: float) -> None:
    # Timed from the moment main() is called (before it, the interpreter itself is starting up), through the
    # imports of the command's stack (matplotlib, scipy: ~1 s) and into its work.
    import signal
    import time

    code = ("import sys\nfrom avdata.cli import main\nprint('ready', file=sys.stderr, flush=True)\n"
            f"sys.exit(main(['stats', {str(demo)!r}, '--out', {str(tmp_path / 's')!r}]))\n")
    process = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert process.stderr is not None and process.stderr.readline() == "ready\n"
    time.sleep(delay_s)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130, err
    assert err == "avdata: interrupted\n"


@pytest.mark.parametrize("command", ["generate", "study run"])
def test_yaml_syntax_error_names_line_and_column(tmp_path: Path, command: str) -> None:
    config = tmp_path / "bad.yaml"
    config.write_text("scenes: 2\nframes: [1, 2\nseed: 3\n")
    result = run(*command.split(), str(config), str(tmp_path / "out"))
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert result.stderr == (f"avdata: error: {config}: expected valid YAML, got line 3, column 5: did not find expected "
                             "',' or ']' (while parsing a flow sequence)\n")


def test_convert_of_a_missing_folder_says_it_does_not_exist(tmp_path: Path) -> None:
    result = run("convert", "kitti-object", str(tmp_path / "nonexistent"), str(tmp_path / "out"))
    assert result.returncode == 1
    assert result.stderr == f"avdata: error: {tmp_path / 'nonexistent'}: source folder does not exist\n"


def test_an_interrupt_a_library_swallowed_still_exits_130(monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    # CI once saw `avdata stats` exit 0 after a Ctrl-C 0.3 s in: something under it caught the KeyboardInterrupt.
    import argparse
    import signal

    from avdata import cli

    def swallowing(args: argparse.Namespace) -> int:
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt:
            pass
        return 0

    parser = argparse.ArgumentParser()
    parser.set_defaults(run=swallowing)
    monkeypatch.setattr(cli, "build_parser", lambda load: parser)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a normal start
    try:
        assert cli.main([]) == 130
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # given back
    finally:
        signal.signal(signal.SIGINT, previous)
    assert capsys.readouterr().err == "avdata: interrupted\n"


@pytest.mark.parametrize("argv", [["info", "{long}"], ["validate", "{long}"], ["index", "{long}"], ["audit", "{long}"],
                                  ["convert", "kitti-object", "{long}", "{tmp}/out"]])
def test_a_path_too_long_for_the_system_is_one_line(tmp_path: Path, argv: list[str],
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    from avdata.cli import main

    long = str(tmp_path / ("x" * 300))  # one name over NAME_MAX: pathlib's exists and is_dir raised ENAMETOOLONG
    assert main([a.format(long=long, tmp=tmp_path) for a in argv]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"avdata: error: {long}: ") and err.endswith("does not exist\n")


@pytest.mark.parametrize(("argv", "option"), [
    (["convert", "kitti-object", "SRC", "DST", "--scenes", "a", "--scenes", "b"], "--scenes"),
    (["convert", "kitti-object", "SRC", "DST", "--compression", "zstd", "--compression", "lz4"], "--compression"),
    (["render", "D", "o.png", "--frame", "1", "--frame", "2"], "--frame"),
    (["study", "run", "s.yaml", "OUT", "--workers", "1", "--workers", "2"], "--workers"),
])
def test_an_option_given_twice_with_different_values_is_refused(argv: list[str], option: str,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    from avdata.cli import main

    # argparse kept the last value without a word: '--scenes a --scenes b' converted only b.
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert f"error: argument {option}: expected once, got " in capsys.readouterr().err


def test_an_option_given_twice_with_the_same_value_is_harmless() -> None:
    from avdata.cli import build_parser

    args = build_parser(load=("render",)).parse_args(["render", "D", "o.png", "--frame", "1", "--frame", "1"])
    assert args.frame == 1
