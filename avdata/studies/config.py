"""Study files: the generator scenario, trials, evaluation settings and the table of cases."""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from avdata.errors import InputError, shown, yaml_problem
from avdata.inputs import UniqueKeyLoader, refuse_special_file
from avdata.perception.detections import NOISE_LEVELS
from avdata.storage import is_remote

if TYPE_CHECKING:
    from avdata.storage import Location

__all__ = ["CASE_AXES", "DETECTOR_KINDS", "METRICS", "OPTIONAL_METRICS", "CaseConfig", "DatasetEntry", "DetectorConfig",
           "EvaluationConfig", "StudyConfig", "load_study", "study_from_dict"]

#: The axes a case may set, with their meaning.
CASE_AXES = {
    "comm_range_m": "communication range in metres; null = no collaboration (base case)",
    "rate_hz": "how often collaborators send detections",
    "noise": f"collaborators' detection noise level, one of {sorted(NOISE_LEVELS)}",
    "latency_frames": "frames between a collaborator's measurement and its arrival",
    "ego_noise": "noise level of the ego's own detections",
}

#: Per-trial metrics a study reports. precision/recall: the ego's detections against the evaluated ground
#: truth (3D centre distance within ``match_distance_m``, class-agnostic, Hungarian per frame);
#: precision_2d/recall_2d: the same in the image of the detector's camera (2D IoU >= 0.5,
#: :mod:`avdata.eval.detection.image`), for detectors whose detections carry 2D boxes (null otherwise).
METRICS = ("sensors_in_range", "collaborative_detections", "precision", "recall", "precision_2d", "recall_2d", "HOTA",
           "DetA", "AssA", "MOTA", "MOTP", "IDF1", "ADE", "FDE", "rss_violating_frame_fraction", "rss_missed_violations",
           "rss_invented_violations")

#: Metrics shown in a report only when some row has them (a study without a camera has no 2D columns).
OPTIONAL_METRICS = ("precision_2d", "recall_2d")

#: Where a case's detections come from.
DETECTOR_KINDS = {
    "simulated": "noise model of the ground truth ({kind: simulated, noise: LEVEL}, LEVEL sets ego_noise; with "
                 "camera: NAME, what that camera sees, with 2D boxes: avdata.perception.camera)",
    "files": "a detector's result files ({kind: files, path: PATH, format: FORMAT, camera: NAME}, read by "
             "avdata.perception.detection_files; camera: the image their 2D boxes are in)",
    "model": "a model ({kind: model, callable: 'pkg.mod:factory', checkpoint: PATH}, see avdata.perception.detector)",
}

#: The default tracker and predictor of a case; any other value is a "pkg.mod:factory" name.
KALMAN = "kalman"
CONSTANT_VELOCITY = "constant-velocity"


@dataclass(frozen=True, slots=True, kw_only=True)
class DetectorConfig:
    """Where a case's (ego) detections come from.

    Attributes:
        kind: one of :data:`DETECTOR_KINDS`.
        path: ``files``: the detection files (a file or folder).
        format: ``files``: the format name of :mod:`avdata.perception.detection_files`.
        callable: ``model``: the factory ``"pkg.mod:fn"``, called with ``checkpoint`` (or nothing), giving a
            :class:`~avdata.perception.detector.Detector`.
        checkpoint: ``model``: the weights file.
        min_score: ``files``/``model``: detections scored below this are dropped before tracking (None: none;
            in the detector's own score units, e.g. PointRCNN's logits).
        cameras: ``simulated``: the camera that detects (:mod:`avdata.perception.camera`; empty: the ego's
            lidars); ``files``: the camera whose image the files' 2D boxes are in (``box2d_px``; empty: no 2D
            scores). Each scene uses the first of these it has (datasets name their front cameras differently),
            and the 2D precision/recall are scored in that camera's image. YAML key ``camera``: a name or a list.
    """

    kind: str = "simulated"
    path: str | None = None
    format: str | None = None
    callable: str | None = None
    checkpoint: str | None = None
    min_score: float | None = None
    cameras: tuple[str, ...] = ()

    def label(self) -> str:
        """A short name for reports: ``simulated``, ``simulated:camera``, ``files:FORMAT`` or ``model:CHECKPOINT-NAME``."""
        if self.kind == "simulated" and self.cameras:
            return "simulated:camera"
        if self.kind == "files":
            return f"files:{self.format}"
        if self.kind == "model":
            return f"model:{Path(self.checkpoint).name if self.checkpoint else self.callable}"
        return self.kind


@dataclass(frozen=True, slots=True, kw_only=True)
class CaseConfig:
    """One row of the case table.

    Attributes:
        name: the case name (``C1-Ideal``).
        comm_range_m: communication range; None means no collaboration.
        rate_hz: collaborators' send rate.
        noise: collaborators' noise level.
        latency_frames: collaborators' latency.
        ego_noise: the ego's own detection noise level (simulated detector).
        detector: where the ego's detections come from.
        tracker: ``kalman`` or a factory ``"pkg.mod:fn"`` giving a fresh tracker per scene.
        predictor: ``constant-velocity`` or ``"pkg.mod:fn"`` with the signature of
            :func:`~avdata.perception.predictor.predict_constant_velocity`.
    """

    name: str
    comm_range_m: float | None = None
    rate_hz: float = 10.0
    noise: str = "none"
    latency_frames: int = 0
    ego_noise: str = "low"
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    tracker: str = KALMAN
    predictor: str = CONSTANT_VELOCITY
    datasets: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True, kw_only=True)
class DatasetEntry:
    """One dataset of a multi-dataset study (a transfer table).

    Attributes:
        name: its name in the report (``kitti-tracking``).
        path: the unified dataset folder.
        scenes: its scenes used as trials.
    """

    name: str
    path: str
    scenes: tuple[str, ...]


@dataclass(frozen=True, slots=True, kw_only=True)
class EvaluationConfig:
    """How each trial is evaluated.

    Attributes:
        max_range_m: ground truth within this BEV distance of the ego is evaluated (AVstack: 100 m).
        max_occlusion: ground truth seen by some sensor with at most this occlusion level (1 = "partly").
        prediction_horizon_s: how far ahead trajectories are predicted.
        match_distance_m: a track predicts the ground-truth object it is matched to within this distance.
    """

    max_range_m: float = 100.0
    max_occlusion: int = 1
    prediction_horizon_s: float = 2.0
    match_distance_m: float = 2.0


@dataclass(frozen=True, slots=True, kw_only=True)
class StudyConfig:
    """A whole study.

    Attributes:
        name: the study name.
        description: what it asks.
        preset: the generator preset the trials start from.
        overrides: generator settings over the preset (nested mapping, merged key by key).
        trials: number of trials; trial i uses scene seed ``seed + i``.
        seed: the first scene seed.
        frames: frames per trial.
        ego: the receiving agent.
        evaluation: evaluation settings.
        cases: the case table (a case with ``datasets`` runs on those datasets only).
        plots: (metric, axis) pairs to plot, one line per value of the other axes.
        dataset: an existing unified dataset to study instead of generating trials (converted real data);
            then each trial is one of its scenes and ``preset``/``overrides``/``frames`` are unused.
        scenes: with ``dataset``, the scenes to use as trials (default: all, in the manifest's order).
        datasets: several existing datasets instead (a transfer table): the trials are all their scenes and
            the report has one row per case and dataset.
    """

    name: str
    description: str = ""
    preset: str = "v2i-town"
    overrides: dict[str, Any] = field(default_factory=dict)
    trials: int = 3
    seed: int = 0
    frames: int = 60
    ego: str = "ego"
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
    cases: tuple[CaseConfig, ...] = ()
    plots: tuple[tuple[str, str], ...] = ()
    dataset: str | None = None
    scenes: tuple[str, ...] = ()
    datasets: tuple[DatasetEntry, ...] = ()

    def sources(self) -> list[tuple[str, str, str]] | None:
        """(dataset name, path, scene) of every trial when the study runs on existing data, else None."""
        if self.datasets:
            return [(d.name, d.path, scene) for d in self.datasets for scene in d.scenes]
        if self.dataset is not None:
            return [(Path(self.dataset).name, self.dataset, scene) for scene in self.scenes]
        return None

    def scenario(self, trial: int) -> dict[str, Any]:
        """The generator scenario of ``trial`` as a plain mapping."""
        from avdata.generators.config import load_preset

        base = load_preset(self.preset).to_dict()
        merged = _merge(base, self.overrides)
        merged.update(scenes=1, frames=self.frames, seed=self.seed + trial)
        return merged

    def fingerprint(self, *parts: Any) -> str:
        """A hash of the study's inputs and ``parts`` (a case, a trial): what a stored result must match."""
        data = json.dumps([asdict(self), [asdict(p) if hasattr(p, "__dataclass_fields__") else p for p in parts]],
                          sort_keys=True, default=str)
        return hashlib.sha256(data.encode()).hexdigest()[:16]


def _detector(value: Any, where: str, source: str, kwargs: dict[str, Any]) -> dict[str, Any]:
    """Parses a case's ``detector`` into ``kwargs["detector"]``; returns axes it sets (a simulated noise level)."""
    if not isinstance(value, dict) or not isinstance(value.get("kind"), str) or value["kind"] not in DETECTOR_KINDS:
        raise InputError(f"{where}: expected detector to be a mapping with kind in {sorted(DETECTOR_KINDS)}, got {shown(value)}")
    kind = value["kind"]
    allowed = {"simulated": {"noise", "camera"}, "files": {"path", "format", "min_score", "camera"},
               "model": {"callable", "checkpoint", "min_score"}}[kind]
    required = {"simulated": set(), "files": {"path", "format"}, "model": {"callable"}}[kind]
    extra, missing = sorted(set(value) - allowed - {"kind"}, key=str), sorted(required - set(value))
    if extra or missing:
        raise InputError(f"{where}: detector of kind {kind}: expected keys {sorted(allowed)} (required {sorted(required)}),"
                         f" got {sorted(value, key=str)}")
    fields: dict[str, Any] = {k: _typed(v, str, where, f"detector.{k}") for k, v in value.items()
                              if k not in ("kind", "noise", "min_score", "camera")}
    if "camera" in value:
        cameras = [value["camera"]] if isinstance(value["camera"], str) else value["camera"]
        if not isinstance(cameras, list) or not cameras or not all(isinstance(c, str) and c for c in cameras):
            raise InputError(f"{where}: expected detector.camera to be a camera name or a list of them, got "
                             f"{shown(value['camera'])}")
        fields["cameras"] = tuple(cameras)
    if "min_score" in value:
        fields["min_score"] = _typed(value["min_score"], float, where, "detector.min_score")
    for key in ("path", "checkpoint"):  # $VARIABLES expanded, relative to the study file, as datasets are
        if key in fields:
            text = os.path.expandvars(fields[key])
            if "$" in text:
                raise InputError(f"{where}: detector.{key}: an environment variable in {fields[key]!r} is not set")
            if is_remote(text):  # read as local files (and stat'ed for the resume fingerprint)
                raise InputError(f"{where}: detector.{key}: expected a local file or folder, got the object store URI "
                                 f"{text!r} (detections and checkpoints are read from local files; copy them to a disk)")
            fields[key] = str(Path(source).resolve().parent / text) if not Path(text).is_absolute() else text
    if kind == "files":
        try:
            from avdata.perception import detection_files
        except ImportError:
            raise InputError(f"{where}: detector kind files needs avdata.perception.detection_files, which this "
                             "installation lacks") from None
        formats = getattr(detection_files, "FORMATS", None)
        if formats is not None and fields["format"] not in formats:
            raise InputError(f"{where}: expected detector.format in {sorted(formats)}, got {fields['format']!r}")
    if kind == "model" and ":" not in fields["callable"]:
        raise InputError(f"{where}: expected detector.callable as 'pkg.mod:factory', got {fields['callable']!r}")
    kwargs["detector"] = DetectorConfig(kind=kind, **fields)
    return {"ego_noise": value["noise"]} if "noise" in value else {}


def _dataset_path(value: Any, source: str, key: str) -> Path | Location:
    """A unified dataset named in a study: ``$VARIABLES`` expanded, a folder relative to the study file.

    An object-store URI (``s3://``, ``gs://``) names a dataset read in place by ranged requests.
    """
    from avdata.schema.dataset import dataset_root

    text = os.path.expandvars(_typed(value, str, source, key))
    if "$" in text:
        raise InputError(f"{source}: {key}: an environment variable in {value!r} is not set")
    root = dataset_root(text)
    if isinstance(root, Path) and not root.is_absolute():
        root = Path(source).resolve().parent / root
    if not (root / "avdata.json").is_file():
        raise InputError(f"{source}: expected {key} to be a unified dataset folder, got {str(root)!r}")
    return root


def _datasets(value: Any, source: str) -> tuple[DatasetEntry, ...]:
    """The study's ``datasets``: a list of {name, path, scenes (optional)}."""
    from avdata.schema import DatasetReader

    if not isinstance(value, list) or not value:
        raise InputError(f"{source}: expected 'datasets' to be a non-empty list, got {shown(value)}")
    entries = []
    for i, row in enumerate(value):
        where = f"datasets[{i}]"
        if not isinstance(row, dict) or not {"name", "path"} <= set(row) or set(row) - {"name", "path", "scenes"}:
            raise InputError(f"{source}: {where}: expected a mapping with name, path and optional scenes, got {shown(row)}")
        path = _dataset_path(row["path"], source, f"{where}.path")
        available = DatasetReader(path).scenes
        scenes = row.get("scenes") or available
        if not isinstance(scenes, list) or not all(isinstance(x, str) for x in scenes) or set(scenes) - set(available):
            raise InputError(f"{source}: {where}: expected scenes of {path} (it has {available}), got {shown(scenes)}")
        entries.append(DatasetEntry(name=_typed(row["name"], str, source, f"{where}.name"), path=str(path),
                                    scenes=tuple(scenes)))
    names = [e.name for e in entries]
    if len(set(names)) != len(names):
        raise InputError(f"{source}: expected unique dataset names, got {names}")
    return tuple(entries)


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in over.items():
        out[key] = _merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def _absent_is(value: Any, default: Any) -> Any:
    """``value``, or ``default`` when the key is absent or null (YAML ``overrides:``); another empty value stays itself."""
    return default if value is None else value


def _typed(value: Any, kind: type, where: str, name: str) -> Any:
    if kind is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise InputError(f"{where}: expected {name} to be a finite number, got {shown(value)}")
        return float(value)
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise InputError(f"{where}: expected {name} to be {kind.__name__}, got {shown(value)}")
    return value


#: Upper limits of a study's numbers: beyond them a value is a slip, refused before any work (README, tolerances).
MAX_TRIALS = 1_000
MAX_FRAMES = 100_000
MAX_SEED = 2**32 - 1
MAX_RANGE_M = 100_000.0
MAX_RATE_HZ = 1_000.0


def _case(row: Any, where: str, source: str) -> CaseConfig:
    """One entry of ``cases``, validated."""
    if not isinstance(row, dict) or "name" not in row:
        raise InputError(f"{where}: expected a mapping with a 'name', got {shown(row)}")
    bad = sorted(set(row) - set(CASE_AXES) - {"name", "detector", "tracker", "predictor", "datasets"}, key=str)
    if bad:
        raise InputError(f"{where}: unknown axis {bad}; expected some of "
                         f"{sorted(CASE_AXES) + ['datasets', 'detector', 'predictor', 'tracker']}")
    kwargs: dict[str, Any] = {"name": _typed(row["name"], str, where, "name")}
    if "datasets" in row:
        names = row["datasets"]
        if not isinstance(names, list) or not names or not all(isinstance(x, str) for x in names):
            raise InputError(f"{where}: expected datasets to be a non-empty list of dataset names, got {shown(names)}")
        kwargs["datasets"] = tuple(names)
    if "detector" in row:
        row = {**row, **_detector(row["detector"], where, source, kwargs)}
    for component, default in (("tracker", KALMAN), ("predictor", CONSTANT_VELOCITY)):
        if component in row:
            value = row[component]
            if not isinstance(value, str) or (value != default and ":" not in value):
                raise InputError(f"{where}: expected {component} to be {default!r} or 'pkg.mod:factory', got {shown(value)}")
            kwargs[component] = value
    if row.get("comm_range_m") is not None:
        kwargs["comm_range_m"] = _typed(row["comm_range_m"], float, where, "comm_range_m")
        if not 0 <= kwargs["comm_range_m"] <= MAX_RANGE_M:
            raise InputError(f"{where}: expected comm_range_m in [0, {MAX_RANGE_M:g}], got {kwargs['comm_range_m']}")
    if "rate_hz" in row:
        kwargs["rate_hz"] = _typed(row["rate_hz"], float, where, "rate_hz")
        if not 0 < kwargs["rate_hz"] <= MAX_RATE_HZ:
            raise InputError(f"{where}: expected rate_hz in (0, {MAX_RATE_HZ:g}], got {kwargs['rate_hz']}")
    for level in ("noise", "ego_noise"):
        if level in row:
            if not isinstance(row[level], str) or row[level] not in NOISE_LEVELS:
                raise InputError(f"{where}: expected {level} in {sorted(NOISE_LEVELS)}, got {shown(row[level])}")
            kwargs[level] = row[level]
    if "latency_frames" in row:
        kwargs["latency_frames"] = _typed(row["latency_frames"], int, where, "latency_frames")
        if not 0 <= kwargs["latency_frames"] <= MAX_FRAMES:
            raise InputError(f"{where}: expected latency_frames in [0, {MAX_FRAMES}], got {kwargs['latency_frames']}")
    detector = kwargs.get("detector", DetectorConfig())
    if (detector.kind != "simulated" or detector.cameras) and kwargs.get("comm_range_m") is not None:
        raise InputError(f"{where}: expected comm_range_m null with a {detector.label()} detector "
                         "(collaborators' detections are simulated for lidars only)")
    return CaseConfig(**kwargs)


def _evaluation(evaluation: Any, source: str) -> EvaluationConfig:
    """The ``evaluation`` mapping, validated (missing keys take :class:`EvaluationConfig`'s defaults)."""
    if not isinstance(evaluation, dict):
        raise InputError(f"{source}: expected 'evaluation' to be a mapping, got {shown(evaluation)}")
    eval_fields = set(EvaluationConfig.__dataclass_fields__)
    if set(evaluation) - eval_fields:
        raise InputError(f"{source}: evaluation: unknown key(s) {sorted(set(evaluation) - eval_fields, key=str)}")
    ev = EvaluationConfig(**{k: _typed(v, int if k == "max_occlusion" else float, source, f"evaluation.{k}")
                             for k, v in evaluation.items()})
    for key, high in (("max_range_m", MAX_RANGE_M), ("prediction_horizon_s", 3_600.0), ("match_distance_m", MAX_RANGE_M)):
        if not 0 < getattr(ev, key) <= high:
            raise InputError(f"{source}: expected evaluation.{key} in (0, {high:g}], got {getattr(ev, key)}")
    if not 0 <= ev.max_occlusion <= 3:
        raise InputError(f"{source}: expected evaluation.max_occlusion in 0..3 (KITTI levels), got {ev.max_occlusion}")
    return ev


def _plots(rows: Any, source: str) -> tuple[tuple[str, str], ...]:
    if not isinstance(rows, list | None):
        raise InputError(f"{source}: expected 'plots' to be a list of {{metric, axis}} mappings, got {shown(rows)}")
    plots = []
    for p in rows or []:
        if not (isinstance(p, dict) and set(p) == {"metric", "axis"}):
            raise InputError(f"{source}: expected plots as {{metric, axis}} mappings, got {shown(p)}")
        if not (isinstance(p["metric"], str) and isinstance(p["axis"], str)) or p["metric"] not in METRICS \
                or p["axis"] not in CASE_AXES:
            raise InputError(f"{source}: expected a plot metric in {list(METRICS)} and axis in {sorted(CASE_AXES)}, "
                             f"got {shown(p)}")
        plots.append((p["metric"], p["axis"]))
    return tuple(plots)


def _one_dataset(data: dict[str, Any], source: str) -> tuple[str | None, list[str]]:
    """``dataset`` (a unified dataset folder, relative to the study file) and its ``scenes`` (default: all)."""
    dataset, scenes = data.get("dataset"), data.get("scenes") or []
    if dataset is None:
        if scenes:
            raise InputError(f"{source}: 'scenes' needs 'dataset'")
        return None, []
    dataset_path = _dataset_path(dataset, source, "dataset")
    if not isinstance(scenes, list) or not all(isinstance(x, str) for x in scenes):
        raise InputError(f"{source}: expected 'scenes' to be a list of scene names, got {shown(scenes)}")
    from avdata.schema import DatasetReader

    available = DatasetReader(dataset_path).scenes
    unknown = sorted(set(scenes) - set(available))
    if unknown:
        raise InputError(f"{source}: scenes {unknown} are not in {dataset_path} (it has {available})")
    return str(dataset_path), scenes or list(available)


def study_from_dict(data: Any, source: str) -> StudyConfig:
    """Validates a parsed study file; every problem names the file, the key and the value."""
    if not isinstance(data, dict):
        raise InputError(f"{source}: expected a mapping at the top level, got {type(data).__name__}")
    known = {"name", "description", "preset", "overrides", "trials", "seed", "frames", "ego", "evaluation", "cases", "plots",
             "dataset", "scenes", "datasets"}
    unknown = sorted(set(data) - known, key=str)
    if unknown:
        raise InputError(f"{source}: unknown key(s) {unknown}; expected some of {sorted(known)}")
    if "name" not in data or "cases" not in data:
        raise InputError(f"{source}: expected keys 'name' and 'cases', got {sorted(data, key=str)}")
    cases_raw = data["cases"]
    if not isinstance(cases_raw, list) or not cases_raw:
        raise InputError(f"{source}: expected 'cases' to be a non-empty list, got {shown(cases_raw)}")
    cases = [_case(row, f"{source}: cases[{i}]", source) for i, row in enumerate(cases_raw)]
    names = [c.name for c in cases]
    if len(set(names)) != len(names):
        duplicates = sorted({n for n in names if names.count(n) > 1})
        raise InputError(f"{source}: expected unique case names, got duplicates {duplicates}")
    ev = _evaluation(_absent_is(data.get("evaluation"), {}), source)
    plots = _plots(data.get("plots", []), source)
    overrides = _absent_is(data.get("overrides"), {})
    if not isinstance(overrides, dict):
        raise InputError(f"{source}: expected 'overrides' to be a mapping, got {shown(overrides)}")
    entries = _datasets(data.get("datasets"), source) if "datasets" in data else ()
    if entries:
        if "dataset" in data or "scenes" in data:
            raise InputError(f"{source}: expected either 'dataset' (with 'scenes') or 'datasets', got both")
        known_names = {e.name for e in entries}
        for case in cases:
            unknown_names = sorted(set(case.datasets) - known_names)
            if unknown_names:
                raise InputError(f"{source}: case {case.name}: datasets {unknown_names} are not in 'datasets' "
                                 f"({sorted(known_names)})")
        data = {**data, "trials": sum(len(e.scenes) for e in entries)}
    elif any(case.datasets for case in cases):
        raise InputError(f"{source}: a case's 'datasets' needs the study's 'datasets'")
    dataset, scenes = _one_dataset(data, source)
    if dataset is not None:
        data = {**data, "trials": len(scenes)}
    study = StudyConfig(
        name=_typed(data["name"], str, source, "name"),
        description=_typed(_absent_is(data.get("description"), ""), str, source, "description"),
        preset=_typed(data.get("preset", "v2i-town"), str, source, "preset"), overrides=overrides,
        trials=_typed(data.get("trials", 3), int, source, "trials"), seed=_typed(data.get("seed", 0), int, source, "seed"),
        frames=_typed(data.get("frames", 60), int, source, "frames"), ego=_typed(data.get("ego", "ego"), str, source, "ego"),
        evaluation=ev, cases=tuple(cases), plots=plots, dataset=dataset, scenes=tuple(scenes), datasets=entries,
    )
    check_sizes(study, source)
    if study.sources() is not None:
        return study
    from avdata.generators.config import PRESETS, scenario_from_dict

    if study.preset not in PRESETS:
        raise InputError(f"{source}: expected preset in {list(PRESETS)}, got {study.preset!r}")
    scenario = scenario_from_dict(study.scenario(0), f"{source} (preset {study.preset} + overrides)")  # now, not in a worker
    egos = [ego.name for ego in scenario.egos]
    if study.ego not in egos:  # found only after every trial was generated
        raise InputError(f"{source}: expected ego to be one of the scenario's egos {egos}, got {study.ego!r}")
    return study


def check_sizes(study: StudyConfig, source: str) -> None:
    """Raises InputError unless the study's trials, frames and seed are in range (``source`` names where they came from).

    Also for ``study run --trials/--frames`` overrides: --trials 2**31 was a MemoryError traceback, 2**63 an
    OverflowError.
    """
    if not (1 <= study.trials <= MAX_TRIALS and 2 <= study.frames <= MAX_FRAMES
            and 0 <= study.seed <= MAX_SEED - study.trials + 1):
        raise InputError(f"{source}: expected trials in [1, {MAX_TRIALS}], frames in [2, {MAX_FRAMES}], seed in "
                         f"[0, {MAX_SEED} - trials + 1], got {study.trials}, {study.frames}, {study.seed}")


def load_study(path: str | Path) -> StudyConfig:
    """Reads and validates a study YAML file."""
    path = Path(path)
    refuse_special_file(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the study file ({exc.__class__.__name__}: {exc})") from None
    try:
        data = yaml.load(text, Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except ValueError as exc:  # a key given twice (DuplicateKeyError), an integer of 5000 digits
        raise InputError(f"{path}: {exc}") from None
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: expected valid YAML, got {yaml_problem(exc)}") from None
    return study_from_dict(data, str(path))
