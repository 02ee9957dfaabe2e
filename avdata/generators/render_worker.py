"""Camera rendering in persistent worker processes, overlapped with the LiDAR work of the same frame.

pybullet's TinyRenderer holds the GIL for the whole image (about as long as all LiDARs of a V2I frame), so
a thread cannot overlap it. The workers are child Python processes, each with its own pybullet world built
from the same arguments as the scene's (:class:`~avdata.generators.bodies.BulletWorld`: same bodies in the
same order, hence the same body ids and the same pixels). Its cost is per pixel, so each worker renders
one horizontal strip of every image (:meth:`~avdata.generators.bodies.BulletWorld.render` with ``rows``;
always two strips).
Per frame the parent sends the objects' poses and the cameras due; the workers pose their bodies and
render their strips while the parent casts the LiDARs; the parent then stacks the strips and PNG-encodes
(OpenCV).

Messages are pickles over a child's stdin and stdout, answered in order, one answer per message; the
child redirects its file descriptor 1 to stderr first, so nothing a C library prints can corrupt them.
It ends at end of input, i.e. when the parent closes the pipe or dies. A failure in a child comes back
as one line and is raised in the parent as :class:`~avdata.errors.AvdataError`.
"""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
from collections import deque
from dataclasses import dataclass
from typing import Any, BinaryIO

import cv2
import numpy as np

from avdata.errors import AvdataError
from avdata.frames import Transform
from avdata.generators.camera import CameraConfig
from avdata.generators.town import StaticScenery


@dataclass(frozen=True, slots=True, kw_only=True)
class RenderedImage:
    """One camera's image as written.

    Attributes:
        png: the PNG-encoded colour image.
        object_id: (H, W) int32 object id per pixel, -1 for static scenery and sky.
    """

    png: bytes
    object_id: np.ndarray


class _Child:
    """One worker process and the kinds of the requests it has not answered yet."""

    def __init__(self) -> None:
        try:
            self.process = subprocess.Popen([sys.executable, "-m", "avdata.generators.render_worker"],
                                            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        except OSError as error:
            raise AvdataError(f"expected to start a camera render worker ({sys.executable}), got {error}") from error
        self.expected: deque[str] = deque()

    def send(self, kind: str, payload: Any) -> None:
        stdin = self.process.stdin
        assert stdin is not None
        try:
            pickle.dump((kind, payload), stdin, protocol=pickle.HIGHEST_PROTOCOL)
            stdin.flush()
        except (BrokenPipeError, OSError) as error:
            raise AvdataError(f"expected the camera render worker to take a {kind!r} request, "
                              f"got it gone ({self.status()}): {error}") from error
        self.expected.append(kind)

    def status(self) -> str:
        code = self.process.poll()
        return "still running" if code is None else f"exit status {code}"

    def answer(self) -> Any:
        kind = self.expected.popleft()
        stdout = self.process.stdout
        assert stdout is not None
        try:
            status, value = pickle.load(stdout)
        except (EOFError, pickle.UnpicklingError, OSError) as error:
            self.process.wait()
            raise AvdataError(f"expected the camera render worker to answer a {kind!r} request, got it gone "
                              f"({self.status()})") from error
        if status != "ok":
            raise AvdataError(f"camera render worker, {kind!r} request: {value}")
        return value

    def close(self) -> None:
        # Both ends: a child still writing an answer nobody will read gets a broken pipe instead of blocking.
        for stream in (self.process.stdin, self.process.stdout):
            if stream is not None and not stream.closed:
                try:
                    stream.close()
                except OSError:
                    pass  # the child is already gone; wait() below reaps it
        self.process.wait()


def strip_rows(height: int, strip: int, strips: int) -> tuple[int, int]:
    """The first and end row of strip ``strip`` of ``strips`` of an image ``height`` rows high."""
    return strip * height // strips, (strip + 1) * height // strips


class RenderWorker:
    """The parent's handle on the render workers: submit a frame's cameras, later receive their images.

    Args:
        scenery: the static town.
        object_ids: (N,) int object ids.
        object_classes: (N,) simulator classes of the objects.
        size_lwh: (N, 3) object box sizes.
        strips: worker processes, each rendering one horizontal strip of every image. A fixed number (not the
            machine's cores): a strip's edge pixels may differ in rounding from the whole image's, so the
            same seed gives the same bytes only with the same strips.
    """

    def __init__(self, scenery: StaticScenery, object_ids: np.ndarray, object_classes: np.ndarray,
                 size_lwh: np.ndarray, strips: int = 2):
        self._children: list[_Child] = []
        try:
            for _ in range(strips):
                self._children.append(_Child())
                # Not waited for here: the child builds its world while the parent warms the traffic up.
                self._children[-1].send("init", (scenery, np.asarray(object_ids), np.asarray(object_classes),
                                                 np.asarray(size_lwh)))
        except BaseException:
            self.close()
            raise

    @property
    def pids(self) -> list[int]:
        """The worker processes' ids (to watch their CPU time, e.g. in the benchmark)."""
        return [child.process.pid for child in self._children]

    def submit(self, center_world: np.ndarray, yaw_rad: np.ndarray,
               cameras: list[tuple[Transform, CameraConfig]]) -> None:
        """Starts rendering cameras in the given object poses; :meth:`receive` returns the images.

        Args:
            center_world: (N, 3) object box centres.
            yaw_rad: (N,) object headings.
            cameras: each camera's optical frame in the world and its config.
        """
        center_world = np.asarray(center_world, dtype=np.float64)
        yaw_rad = np.asarray(yaw_rad, dtype=np.float64)
        for strip, child in enumerate(self._children):
            child.send("render", (center_world, yaw_rad, cameras, strip, len(self._children)))

    def receive(self) -> list[RenderedImage]:
        """The images of the oldest :meth:`submit` not yet received, in the order of its cameras."""
        strips = []
        for child in self._children:
            while child.expected[0] == "init":
                child.answer()
            strips.append(child.answer())
        images = []
        for parts in zip(*strips, strict=True):
            rgb = np.concatenate([part_rgb for part_rgb, _ in parts])
            ok, png = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            if not ok:
                raise AvdataError(f"expected OpenCV to PNG-encode a {rgb.shape[1]}x{rgb.shape[0]} image, got a failure")
            images.append(RenderedImage(png=png.tobytes(), object_id=np.concatenate([ids for _, ids in parts])))
        return images

    def close(self) -> None:
        """Ends the workers (end of input) and waits for them."""
        for child in self._children:
            child.close()


def _serve(requests: BinaryIO, answers: BinaryIO) -> None:
    """The worker's loop: one answer per request until end of input."""
    from avdata.generators.bodies import BulletWorld

    world: BulletWorld | None = None
    while True:
        try:
            kind, payload = pickle.load(requests)
        except EOFError:
            break
        try:
            if kind == "init":
                world = BulletWorld(*payload)
                answer: tuple[str, Any] = ("ok", None)
            elif kind == "render" and world is not None:
                center_world, yaw_rad, cameras, strip, strips = payload
                world.set_object_poses(center_world, yaw_rad)
                images = []
                for world_T_camera, cam in cameras:
                    image = world.render(world_T_camera, cam.width, cam.height, cam.vertical_fov_deg, cam.near_m,
                                         cam.far_m, rows=strip_rows(cam.height, strip, strips))
                    images.append((image.rgb, image.object_id))
                answer = ("ok", images)
            else:
                answer = ("error", f"expected 'init' then 'render' requests, got {kind!r}")
        except Exception as error:  # noqa: BLE001 - any failure goes back to the parent as one line
            answer = ("error", f"{type(error).__name__}: {error}")
        pickle.dump(answer, answers, protocol=pickle.HIGHEST_PROTOCOL)
        answers.flush()
    if world is not None:
        world.close()


def main() -> None:
    """Entry point of the worker process (``python -m avdata.generators.render_worker``)."""
    # Ctrl-C reaches the whole process group: the parent reports it, the child ends with its input.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    answers = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything printed to stdout from here on goes to stderr, not into the answers
    try:
        _serve(sys.stdin.buffer, answers)
    except BrokenPipeError:
        # The parent closed the pipe with an answer in flight (it stopped early): end without a word, and
        # without the interpreter's exit flushing into the broken pipe again.
        os._exit(0)


if __name__ == "__main__":
    main()
