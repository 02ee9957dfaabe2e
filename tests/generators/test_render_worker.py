"""The camera render workers: the same pixels as rendering in-process, and one-line errors when one fails."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from avdata.errors import AvdataError
from avdata.frames import XFWD_T_OPTICAL, Transform
from avdata.generators.camera import CameraConfig
from avdata.generators.render_worker import RenderWorker
from avdata.generators.world import SimWorld
from tests.generators.scenes import scenery

CENTERS = np.array([[10.0, 1.0, 0.75], [14.0, 5.0, 0.9], [25.0, -4.0, 1.6]])
SIZES = np.array([[4.0, 1.8, 1.5], [0.8, 0.7, 1.8], [10.0, 2.6, 3.2]])
CLASSES = np.array(["car", "pedestrian", "truck"])
IDS = np.array([3, 4, 7])


@pytest.mark.parametrize("strips", [1, 2, 3])
def test_worker_images_equal_in_process_rendering_frame_after_frame(strips):
    static = scenery([([30.0, 12.0, 4.0], [6.0, 6.0, 8.0])])
    cameras = [
        (Transform.from_yaw(np.float64(0.2), translation=np.array([0.0, 0.0, 1.6])) @ XFWD_T_OPTICAL,
         CameraConfig(width=320, height=160, horizontal_fov_deg=90.0)),
        (Transform.from_yaw(np.float64(-0.4), translation=np.array([2.0, 3.0, 2.0])) @ XFWD_T_OPTICAL,
         CameraConfig(width=200, height=100, horizontal_fov_deg=60.0)),
    ]
    world = SimWorld(static, IDS, CLASSES, SIZES)
    worker = RenderWorker(static, IDS, CLASSES, SIZES, strips=strips)
    try:
        for step in range(2):  # objects move between frames; two frames in flight before the first is read
            worker.submit(CENTERS + [step * 1.5, 0.0, 0.0], np.array([0.4, 0.0, -0.3]) + step * 0.2, cameras)
        for step in range(2):
            images = worker.receive()
            world.set_object_poses(CENTERS + [step * 1.5, 0.0, 0.0], np.array([0.4, 0.0, -0.3]) + step * 0.2)
            assert len(images) == len(cameras)
            for image, (world_T_camera, cam) in zip(images, cameras, strict=True):
                expected = world.render(world_T_camera, cam.width, cam.height, cam.vertical_fov_deg, cam.near_m,
                                        cam.far_m)
                rgb = cv2.cvtColor(cv2.imdecode(np.frombuffer(image.png, np.uint8), cv2.IMREAD_COLOR),
                                   cv2.COLOR_BGR2RGB)
                np.testing.assert_array_equal(rgb, expected.rgb)
                np.testing.assert_array_equal(image.object_id, expected.object_id)
                assert image.object_id.dtype == np.int32
                assert set(np.unique(image.object_id).tolist()) <= {-1, *IDS.tolist()}
        assert {3, 4, 7} <= set(np.unique(images[0].object_id).tolist())  # every object in the first camera
    finally:
        worker.close()
        world.close()


def test_a_failing_request_is_one_line_error_and_a_dead_worker_is_reported():
    worker = RenderWorker(scenery([]), IDS, CLASSES, SIZES)
    try:
        # Two headings for three objects: pybullet's pose update fails inside the worker.
        worker.submit(CENTERS, np.zeros(2), [(Transform.identity() @ XFWD_T_OPTICAL, CameraConfig())])
        with pytest.raises(AvdataError, match="camera render worker, 'render' request: ValueError") as error:
            worker.receive()
        assert "\n" not in str(error.value)
        worker._children[1].process.kill()
        worker._children[1].process.wait()
        with pytest.raises(AvdataError, match="expected the camera render worker to"):
            worker.submit(CENTERS, np.zeros(3), [(Transform.identity() @ XFWD_T_OPTICAL, CameraConfig())])
            worker.receive()
    finally:
        worker.close()
