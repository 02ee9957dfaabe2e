"""Object classes of the simulated traffic and their real size distributions.

Mean sizes (length, width, height in metres) come from published per-class means of real datasets:

- KITTI (car, van, truck, pedestrian, cyclist): the class means over the KITTI 3D-object training
  labels as tabulated by Frustum PointNets (``g_type_mean_size`` in ``kitti/kitti_util.py``,
  Qi et al. 2018): car 3.883 x 1.629 x 1.526, van 5.068 x 1.901 x 2.205, truck 10.136 x 2.585 x 3.252,
  pedestrian 0.844 x 0.661 x 1.763, cyclist 1.763 x 0.597 x 1.737.
- nuScenes (bus, motorcycle): the class means over the nuScenes training annotations used as anchor
  sizes by mmdetection3d (``configs/_base_/models/hv_pointpillars_fpn_nus.py``, stored there as
  w, l, h): bus 11.189 x 2.940 x 3.470, motorcycle 2.100 x 0.763 x 1.444.

Neither source publishes the spread next to the mean, so each dimension is drawn from a normal
distribution with the coefficient of variation below (an assumption, about the spread of the KITTI car
labels: lengths 3.2-4.7 m around 3.9 m), truncated at two standard deviations.

Every simulated class maps to one of avdata's unified classes (``van`` becomes ``car`` and keeps
"van" as its source class).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True, kw_only=True)
class ClassSpec:
    """One simulated object class.

    Attributes:
        name: the simulator's class name (written as the source class).
        unified_class: avdata's unified class.
        mean_lwh_m: (3,) mean length, width, height in metres.
        cv: coefficient of variation of each dimension (std / mean).
        desired_speed_mps: (2,) range of free-flow speeds in m/s, drawn uniformly per object.
        max_accel_mps2: IDM maximum acceleration.
        comfortable_decel_mps2: IDM comfortable deceleration.
        source: where the mean comes from.
    """

    name: str
    unified_class: str
    mean_lwh_m: tuple[float, float, float]
    cv: float
    desired_speed_mps: tuple[float, float]
    max_accel_mps2: float
    comfortable_decel_mps2: float
    source: str


CLASS_SPECS: dict[str, ClassSpec] = {
    spec.name: spec
    for spec in (
        ClassSpec(name="car", unified_class="car", mean_lwh_m=(3.883, 1.629, 1.526), cv=0.08,
                  desired_speed_mps=(10.0, 14.0), max_accel_mps2=2.0, comfortable_decel_mps2=2.5,
                  source="KITTI"),
        ClassSpec(name="van", unified_class="car", mean_lwh_m=(5.068, 1.901, 2.205), cv=0.08,
                  desired_speed_mps=(9.0, 13.0), max_accel_mps2=1.6, comfortable_decel_mps2=2.2,
                  source="KITTI"),
        ClassSpec(name="truck", unified_class="truck", mean_lwh_m=(10.136, 2.585, 3.252), cv=0.10,
                  desired_speed_mps=(8.0, 11.0), max_accel_mps2=1.0, comfortable_decel_mps2=2.0,
                  source="KITTI"),
        ClassSpec(name="bus", unified_class="bus", mean_lwh_m=(11.189, 2.940, 3.470), cv=0.05,
                  desired_speed_mps=(8.0, 11.0), max_accel_mps2=1.0, comfortable_decel_mps2=2.0,
                  source="nuScenes"),
        ClassSpec(name="motorcycle", unified_class="motorcycle", mean_lwh_m=(2.100, 0.763, 1.444), cv=0.08,
                  desired_speed_mps=(10.0, 15.0), max_accel_mps2=2.5, comfortable_decel_mps2=3.0,
                  source="nuScenes"),
        ClassSpec(name="cyclist", unified_class="cyclist", mean_lwh_m=(1.763, 0.597, 1.737), cv=0.06,
                  desired_speed_mps=(4.0, 7.0), max_accel_mps2=1.0, comfortable_decel_mps2=2.0,
                  source="KITTI"),
        ClassSpec(name="pedestrian", unified_class="pedestrian", mean_lwh_m=(0.844, 0.661, 1.763), cv=0.08,
                  desired_speed_mps=(1.0, 1.6), max_accel_mps2=0.5, comfortable_decel_mps2=1.0,
                  source="KITTI"),
    )
}
VEHICLE_CLASSES = ("car", "van", "truck", "bus", "motorcycle", "cyclist")
"""Classes that drive in the traffic lanes (cyclists ride with the traffic)."""


def sample_sizes(class_names: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Draws box sizes for objects of the given classes.

    Args:
        class_names: (N,) simulator class names (keys of :data:`CLASS_SPECS`).
        rng: the random generator.

    Returns:
        (N, 3) length, width, height in metres.
    """
    class_names = np.asarray(class_names)
    names = list(CLASS_SPECS)
    unique, inverse = np.unique(class_names, return_inverse=True)
    spec_index = np.array([names.index(str(c)) for c in unique], dtype=np.int64)[inverse.reshape(-1)]
    means = np.array([CLASS_SPECS[n].mean_lwh_m for n in names])[spec_index]
    cvs = np.array([CLASS_SPECS[n].cv for n in names])[spec_index]
    z = np.clip(rng.standard_normal((len(class_names), 3)), -2.0, 2.0)
    return means * (1.0 + cvs[:, None] * z)
