"""Where the real sample files are: ``$AVDATA_REALDATA``, else ``../shared/realdata`` beside the checkout.

Tests that read them import :data:`REALDATA` (or use the ``realdata`` fixture). Without the folder (or with a
folder that lacks one of the sample folders of :data:`SOURCES`, e.g. an empty one), ``tests/conftest.py`` skips every test that
needs it, with one summary line saying what is missing and where the samples come from (README, "Real sample
files"); under CI (``CI=true``) a missing folder is a failure instead.
"""

from __future__ import annotations

import os
from pathlib import Path

REALDATA = Path(os.environ.get("AVDATA_REALDATA") or Path(__file__).resolve().parents[1].parent / "shared" / "realdata")

#: Each sample folder and where it was copied from (repository @ commit), as README lists them.
SOURCES = {
    "kitti": "kuixu/kitti_object_vis @ 12ce0a2, SysCV/vis4d @ 22dcdb7, JarnoRalli/python_camera_library @ 8e48406",
    "nuscenes": "SysCV/vis4d-test-data @ 8e92136, open-mmlab/mmdetection3d @ fe25f7a",
    "nuscenes_schema": "open-mmlab/mmdetection3d @ fe25f7a (tests/data, Lyft)",
    "argoverse2": "argoverse/av2-api @ b7321d1 (tests/unit/test_data)",
    "waymo_v1": "waymo-research/waymo-open-dataset @ 99a4cb3 (src/waymo_open_dataset/utils/testdata)",
    "waymo_v2": "waymo-research/waymo-open-dataset @ 99a4cb3 (v2/testdata)",
    "dair_v2x": "MassimoQu/v2i-calib @ c472e33 (data/DAIR-V2X)",
    "v2xset": "ucla-mobility/OpenCDA @ 928a37c (opencood/dummy_v2xset)",
}

#: The sample folders of :data:`SOURCES` that are not there (all of them without the folder).
MISSING = [name for name in SOURCES if not (REALDATA / name).is_dir()]
