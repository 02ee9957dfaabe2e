"""``avdata view``, ``avdata render`` and ``avdata stats`` (registered lazily by :mod:`avdata.cli`)."""

from __future__ import annotations

import argparse
from pathlib import Path

_DATASET_HELP = "unified dataset folder (written by avdata convert, generate or demo)"


def add_view_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers ``view``."""
    from avdata.cli import COMMANDS

    view = subparsers.add_parser("view", help=next(c.help for c in COMMANDS if c.name == "view"))
    view.add_argument("dataset", help=_DATASET_HELP)
    view.add_argument("--scene", help="scene to show (default: the first scene of the dataset)")
    view.add_argument("--out", type=Path, help="Foxglove layout file to write (default: DATASET/foxglove-layout.json)")
    view.add_argument("--rerun", action="store_true",
                      help="log the scene to Rerun instead (needs pip install 'avdata[rerun]'; default: Foxglove layout)")
    view.add_argument("--save", type=Path, metavar="OUT.rrd",
                      help="with --rerun: write a Rerun recording file (default: open the Rerun viewer)")
    view.set_defaults(run=_run_view)


def add_render_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers ``render``."""
    from avdata.cli import COMMANDS

    render = subparsers.add_parser("render", help=next(c.help for c in COMMANDS if c.name == "render"))
    render.add_argument("dataset", help=_DATASET_HELP)
    render.add_argument("out", type=Path, help="picture to write: OUT.png, or OUT.mp4 with --video")
    render.add_argument("--scene", help="scene to draw (default: the first scene of the dataset)")
    render.add_argument("--frame", type=int, help="frame index within the scene (default: 0; not with --video)")
    render.add_argument("--video", action="store_true",
                        help="draw every frame of the scene into OUT.mp4 instead of one frame (default: off)")
    render.add_argument("--display-frame", default="ego",
                        help="frame of the bird's-eye view, e.g. world or an agent's name (default: ego)")
    render.add_argument("--range-m", type=float, default=60.0,
                        help="half the side of the bird's-eye view in metres (default: 60)")
    render.add_argument("--color-by", choices=("height", "agent"), default="height",
                        help="point colours: height in the display frame, or one colour per agent (default: height)")
    render.set_defaults(run=_run_render)


def add_stats_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers ``stats``."""
    from avdata.cli import COMMANDS

    stats = subparsers.add_parser("stats", help=next(c.help for c in COMMANDS if c.name == "stats"))
    stats.add_argument("datasets", nargs="+", help="unified dataset folders (or s3://, gs:// URIs) to compare, one or more")
    stats.add_argument("--out", type=Path, required=True,
                       help="folder to write report.html, stats.md and the PNG plots into (required)")
    stats.set_defaults(run=_run_stats)


def _run_view(args: argparse.Namespace) -> int:
    from avdata.errors import InputError
    from avdata.schema import DatasetReader
    from avdata.storage import is_remote
    from avdata.viz.layout import write_layout

    if args.rerun:
        if args.out is not None:
            raise InputError("view --rerun: expected --save OUT.rrd for the recording, got --out (a Foxglove layout)")
        from avdata.viz.rerun_log import write_rerun

        scene, counts = write_rerun(args.dataset, args.scene, args.save)
        print(f"{scene}: {counts.transforms} transforms, {counts.point_clouds} point clouds ({counts.points} points), "
              f"{counts.images} images, {counts.boxes} boxes in {counts.box_sets} frames, "
              f"{counts.visibility} visibility messages -> {args.save or 'Rerun viewer'}")
        return 0
    if args.save is not None:
        raise InputError("view --save: expected --rerun with it (--save writes a Rerun recording)")
    if args.out is not None and args.out.suffix.lower() != ".json":  # as render's .png and --save's .rrd
        raise InputError(f"{args.out}: expected a .json file for the layout, got suffix {args.out.suffix!r}")

    if is_remote(args.dataset):
        raise InputError(f"{args.dataset}: Foxglove opens scene files on this machine; a dataset in an object store is "
                         "viewed with --rerun (read by ranged requests)")
    ds = DatasetReader(args.dataset)
    # None, not falsy: --scene '' showed the first scene without a word.
    shown: str | None = args.scene if args.scene is not None else (ds.scenes[0] if ds.scenes else None)
    path = write_layout(args.dataset, args.out or Path(args.dataset) / "foxglove-layout.json", shown)
    print(f"wrote {path}")
    print(f"1. In Foxglove (app or web), Open local file: {ds.scene(shown).path if shown is not None else args.dataset}")
    print(f"2. Layouts menu > Import from file: {path}")
    return 0


def _run_render(args: argparse.Namespace) -> int:
    import cv2

    from avdata.errors import InputError, OutputError
    from avdata.outputs import write_atomically
    from avdata.schema import DatasetReader
    from avdata.viz.render import BevView, render_frame, render_video

    view = BevView(frame=args.display_frame, range_m=args.range_m, color_by=args.color_by)
    ds = DatasetReader(args.dataset, verify=True)
    scene = args.scene if args.scene is not None else (ds.scenes[0] if ds.scenes else "")  # --scene '' is refused
    if scene not in ds.scenes:
        raise InputError(f"{args.dataset}: expected a scene of {ds.scenes}, got {scene!r}")
    if args.video:
        if args.frame is not None:  # the video draws every frame: the index would be ignored
            raise InputError(f"--frame {args.frame}: expected no frame index with --video (it draws every frame)")
        if args.out.suffix.lower() != ".mp4":
            raise InputError(f"{args.out}: expected an .mp4 file with --video, got suffix {args.out.suffix!r}")
        print(f"wrote {render_video(ds, scene, args.out, view)}")
        return 0
    if args.out.suffix.lower() != ".png":
        raise InputError(f"{args.out}: expected a .png file, got suffix {args.out.suffix!r}")
    ok, png = cv2.imencode(".png", render_frame(ds, scene, 0 if args.frame is None else args.frame, view))
    if not ok:
        raise OutputError(f"{args.out}: OpenCV cannot encode the picture as PNG")
    write_atomically(args.out, png.tobytes())
    print(f"wrote {args.out}")
    return 0


def _run_stats(args: argparse.Namespace) -> int:
    from avdata.viz.stats import write_stats_report

    files = write_stats_report(list(args.datasets), args.out)
    print(f"wrote {files[0]} and {len(files) - 1} more files")
    return 0
