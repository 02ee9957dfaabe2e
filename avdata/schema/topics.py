"""Topic names and format constants of the unified format (docs/format.md)."""

from __future__ import annotations

from avdata.errors import FormatVersionError

#: Version of the on-disk format. Readers accept the same major version and refuse a newer one.
FORMAT_VERSION = "1.0"
SUPPORTED_MAJOR = 1

TF_STATIC = "/tf_static"
TF = "/tf"
OBJECTS = "/labels/objects"
MARKERS = "/labels/markers"
SCENE_METADATA = "avdata.scene"

POINTS_SUFFIX = "points"
IMAGE_SUFFIX = "image"
CALIBRATION_SUFFIX = "calibration"
VISIBILITY_SUFFIX = "visibility"


def sensor_topic(sensor_frame: str, suffix: str) -> str:
    """``/<agent>/<sensor>/<suffix>`` for a sensor frame ``<agent>/<sensor>``."""
    return f"/{sensor_frame}/{suffix}"


def sensor_of_topic(topic: str) -> str | None:
    """The sensor frame of a sensor topic, or None for the scene-wide topics."""
    if topic in (TF_STATIC, TF, OBJECTS, MARKERS):
        return None
    return topic.strip("/").rsplit("/", 1)[0]


def check_version(version: str, what: str) -> None:
    """Raises FormatVersionError when ``version`` has a newer major than this reader supports."""
    try:
        major = int(str(version).split(".")[0])
    except ValueError as error:
        raise FormatVersionError(f"{what}: expected a format version like '1.0', got {version!r}") from error
    if major > SUPPORTED_MAJOR:
        raise FormatVersionError(
            f"{what}: format version {version} is newer than this avdata supports "
            f"(major {SUPPORTED_MAJOR}); upgrade avdata to read it"
        )
