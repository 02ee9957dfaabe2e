"""``avdata view``, ``avdata render`` and ``avdata stats``."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_viz_subparsers(subparsers: argparse._SubParsersAction) -> None:
    """Registers ``view``, ``render`` and ``stats``."""
    view = subparsers.add_parser("view", help="write a Foxglove layout for a dataset and say how to open it")
    view.add_argument("dataset", type=Path)
    view.add_argument("--scene", help="scene whose topics the layout shows (default: the first)")
    view.add_argument("--out", type=Path, help="layout file (default: DATASET/foxglove-layout.json)")
    view.set_defaults(run=_run_view)

    render = subparsers.add_parser("render", help="draw a frame (bird's-eye view + cameras with boxes) as PNG, or a scene as MP4")
    render.add_argument("dataset", type=Path)
    render.add_argument("out", type=Path, help="OUT.png (or OUT.mp4 with --video)")
    render.add_argument("--scene", help="scene (default: the first)")
    render.add_argument("--frame", type=int, default=0, help="frame index (default 0)")
    render.add_argument("--video", action="store_true", help="every frame of the scene as an MP4 video")
    render.add_argument("--display-frame", default="ego", help="frame of the bird's-eye view (default ego; e.g. world)")
    render.add_argument("--range-m", type=float, default=60.0, help="half the side of the bird's-eye view (default 60 m)")
    render.add_argument("--color-by", choices=("height", "agent"), default="height", help="point colours")
    render.set_defaults(run=_run_render)

    stats = subparsers.add_parser("stats", help="statistics of datasets side by side, and their distances")
    stats.add_argument("datasets", type=Path, nargs="+")
    stats.add_argument("--out", type=Path, required=True, help="folder for stats.md and the plots")
    stats.set_defaults(run=_run_stats)


def _run_view(args: argparse.Namespace) -> int:
    from avdata.schema import DatasetReader
    from avdata.viz.layout import write_layout

    ds = DatasetReader(args.dataset)
    scene = args.scene or (ds.scenes[0] if ds.scenes else None)
    path = write_layout(args.dataset, args.out or args.dataset / "foxglove-layout.json", scene)
    print(f"wrote {path}")
    print(f"1. In Foxglove (app or web), Open local file: {ds.scene(scene).path if scene else args.dataset}")
    print(f"2. Layouts menu > Import from file: {path}")
    return 0


def _run_render(args: argparse.Namespace) -> int:
    import cv2

    from avdata.errors import InputError
    from avdata.schema import DatasetReader
    from avdata.viz.render import BevView, render_frame, render_video

    ds = DatasetReader(args.dataset)
    scene = args.scene or (ds.scenes[0] if ds.scenes else "")
    if scene not in ds.scenes:
        raise InputError(f"{args.dataset}: expected a scene of {ds.scenes}, got {scene!r}")
    view = BevView(frame=args.display_frame, range_m=args.range_m, color_by=args.color_by)
    if args.video:
        if args.out.suffix.lower() != ".mp4":
            raise InputError(f"{args.out}: expected an .mp4 file with --video, got suffix {args.out.suffix!r}")
        print(f"wrote {render_video(ds, scene, args.out, view)}")
        return 0
    if args.out.suffix.lower() != ".png":
        raise InputError(f"{args.out}: expected a .png file, got suffix {args.out.suffix!r}")
    picture = render_frame(ds, scene, args.frame, view)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_name(f".{args.out.stem}.tmp.png")
    if not cv2.imwrite(str(tmp), picture):
        raise InputError(f"{args.out}: cannot write the picture there")
    tmp.replace(args.out)
    print(f"wrote {args.out}")
    return 0


def _run_stats(args: argparse.Namespace) -> int:
    from avdata.viz.stats import write_stats_report

    files = write_stats_report(list(args.datasets), args.out)
    print(f"wrote {files[0]} and {len(files) - 1} plots")
    return 0
