"""Camera rendering in a persistent worker process, overlapped with the LiDAR work of the same frame.

pybullet's TinyRenderer holds the GIL for the whole image (about as long as all LiDARs of a V2I frame), so
a thread cannot overlap it. The worker is a child Python process with its own pybullet world built from
the same arguments as the scene's (:class:`~avdata.generators.bodies.BulletWorld`: same bodies in the same
order, hence the same body ids and the same pixels). Per frame the parent sends the objects' poses and the
cameras due; the worker poses its bodies, renders, PNG-encodes (OpenCV) and answers with the PNG bytes and
the object-id mask of every camera, while the parent casts the LiDARs.

Messages are pickles over the child's stdin and stdout, answered in order, one answer per message; the
child redirects its file descriptor 1 to stderr first, so nothing a C library prints can corrupt them.
It ends at end of input, i.e. when the parent closes the pipe or dies. A failure in the child comes back
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


class RenderWorker:
    """The parent's handle on a render worker: submit a frame's cameras, later receive their images.

    Args:
        scenery: the static town.
        object_ids: (N,) int object ids.
        object_classes: (N,) simulator classes of the objects.
        size_lwh: (N, 3) object box sizes.
    """

    def __init__(self, scenery: StaticScenery, object_ids: np.ndarray, object_classes: np.ndarray,
                 size_lwh: np.ndarray):
        self._process = subprocess.Popen([sys.executable, "-m", "avdata.generators.render_worker"],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self._expected: deque[str] = deque()
        # Not waited for here: the child builds its world while the parent warms the traffic up.
        self._send("init", (scenery, np.asarray(object_ids), np.asarray(object_classes), np.asarray(size_lwh)))

    def _send(self, kind: str, payload: Any) -> None:
        stdin = self._process.stdin
        assert stdin is not None
        try:
            pickle.dump((kind, payload), stdin, protocol=pickle.HIGHEST_PROTOCOL)
            stdin.flush()
        except (BrokenPipeError, OSError) as error:
            raise AvdataError(f"expected the camera render worker to take a {kind!r} request, "
                              f"got it gone ({self._status()}): {error}") from error
        self._expected.append(kind)

    def _status(self) -> str:
        code = self._process.poll()
        return "still running" if code is None else f"exit status {code}"

    def _answer(self) -> Any:
        kind = self._expected.popleft()
        stdout = self._process.stdout
        assert stdout is not None
        try:
            status, value = pickle.load(stdout)
        except (EOFError, pickle.UnpicklingError, OSError) as error:
            self._process.wait()
            raise AvdataError(f"expected the camera render worker to answer a {kind!r} request, got it gone "
                              f"({self._status()})") from error
        if status != "ok":
            raise AvdataError(f"camera render worker, {kind!r} request: {value}")
        return value

    def submit(self, center_world: np.ndarray, yaw_rad: np.ndarray,
               cameras: list[tuple[Transform, CameraConfig]]) -> None:
        """Starts rendering cameras in the given object poses; :meth:`receive` returns the images.

        Args:
            center_world: (N, 3) object box centres.
            yaw_rad: (N,) object headings.
            cameras: each camera's optical frame in the world and its config.
        """
        self._send("render", (np.asarray(center_world, dtype=np.float64), np.asarray(yaw_rad, dtype=np.float64),
                              cameras))

    def receive(self) -> list[RenderedImage]:
        """The images of the oldest :meth:`submit` not yet received, in the order of its cameras."""
        while self._expected[0] == "init":
            self._answer()
        return [RenderedImage(png=png, object_id=object_id) for png, object_id in self._answer()]

    def close(self) -> None:
        """Ends the worker (end of input) and waits for it."""
        if self._process.stdin is not None and not self._process.stdin.closed:
            try:
                self._process.stdin.close()
            except OSError:
                pass  # the child is already gone; wait() below reaps it
        self._process.wait()
        if self._process.stdout is not None:
            self._process.stdout.close()


def _serve(requests: BinaryIO, answers: BinaryIO) -> None:
    """The worker's loop: one answer per request until end of input."""
    import cv2

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
                center_world, yaw_rad, cameras = payload
                world.set_object_poses(center_world, yaw_rad)
                images = []
                for world_T_camera, cam in cameras:
                    image = world.render(world_T_camera, cam.width, cam.height, cam.vertical_fov_deg, cam.near_m,
                                         cam.far_m)
                    ok, png = cv2.imencode(".png", cv2.cvtColor(image.rgb, cv2.COLOR_RGB2BGR))
                    if not ok:
                        raise AvdataError(f"expected OpenCV to PNG-encode a {cam.width}x{cam.height} image, "
                                          "got a failure")
                    images.append((png.tobytes(), image.object_id))
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
    _serve(sys.stdin.buffer, answers)


if __name__ == "__main__":
    main()
