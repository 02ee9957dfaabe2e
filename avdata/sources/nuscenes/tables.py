"""The nuScenes schema's tables as the lookups a conversion needs, streamed with bounded memory."""

import array
import itertools
import json
import operator
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from avdata.errors import InputError
from avdata.inputs import folder_entries, is_present
from avdata.sources.nuscenes.columns import (
    ColumnBlocks,
    SceneStrings,
    grouped,
    max_rows,
    rank_in_group,
    repeated_rows,
    return_freed_heap,
    runs,
    s_bytes,
    take,
)
from avdata.sources.nuscenes.jsonio import iter_json_chunks, us_to_ns
from avdata.sources.nuscenes.rowcheck import repaired_rotation_field, row_problem, rows_valid
from avdata.storage import Location

#: Every table of the nuScenes schema this converter reads (``map`` is optional: map name only).
REQUIRED_TABLES: tuple[str, ...] = (
    "attribute",
    "calibrated_sensor",
    "category",
    "ego_pose",
    "instance",
    "log",
    "sample",
    "sample_annotation",
    "sample_data",
    "scene",
    "sensor",
    "visibility",
)


@dataclass(frozen=True, slots=True, kw_only=True)
class SampleDataRow:
    """The fields of one sample_data row this converter uses (time already in ns)."""

    token: str
    sample_token: str
    ego_pose_row: int
    calibrated_sensor_token: str
    timestamp_ns: int
    filename: str
    is_key_frame: bool
    width: int
    height: int


_SAMPLE_TOKEN = operator.itemgetter("sample_token")
_CS_TOKEN = operator.itemgetter("calibrated_sensor_token")
_INSTANCE_TOKEN = operator.itemgetter("instance_token")
#: An annotation's visibility token that names no visibility row.
_UNKNOWN = -3

#: An annotation's prev / next link whose token is of no annotation of its scene.
DANGLING = -2


class NuScenesTables:
    """The lookups the conversion needs, built from one version directory of nuScenes-schema tables.

    Small tables are kept as token -> row dicts (instance: its tokens and category tokens only). Of
    the big ones (sample_data, ego_pose, sample_annotation) only the fields the conversion uses are
    kept, with no Python object per row: numbers and references (int32 row numbers; annotations'
    prev / next as rows of their own scene) in numpy columns sorted by scene, so a scene's rows are
    one slice, and tokens and filenames in deflated per-scene buffers (:class:`~avdata.sources.nuscenes.columns.SceneStrings`), so
    memory grows by a compact row per record. Dangling tokens found while
    parsing are kept per scene in ``problems`` (file, message) and the record is dropped; records
    whose sample does not exist belong to no scene and are kept in ``orphans``. Every row is checked
    against :data:`SCHEMA` (:func:`row_problem`): a bad row is dropped and reported (in ``problems``
    when its scene is known, else in ``orphans``), so only the records that need it are lost; a
    duplicate token or scene name is an error naming both, and the later row is dropped.
    Quaternions normalised beyond float noise are listed in ``warnings``.

    Args:
        table_dir: the folder of ``*.json`` tables (``<dataroot>/<version>``).
    """

    def __init__(self, table_dir: Path | Location):
        """Parses the tables of ``table_dir`` (see the class docstring)."""
        # Anything under a table's name (a broken link, a folder ...) is damage its reader names.
        present = {p.name for p in folder_entries(table_dir)}
        missing = [t for t in REQUIRED_TABLES if f"{t}.json" not in present]
        if missing:
            raise InputError(f"{table_dir}: expected the nuScenes tables {list(REQUIRED_TABLES)}, missing {', '.join(missing)}")
        self.table_dir = table_dir

        self.problems: dict[str, list[tuple[str, str]]] = defaultdict(list)
        #: (file, message) of records that belong to no scene, reported with the first scene
        self.orphans: list[tuple[str, str]] = []
        #: (file, message) of repairs beyond float noise, reported with the first scene
        self.warnings: list[tuple[str, str]] = []

        self._read_small_tables()
        self._read_map()
        sample_row = self._read_samples()
        scene_of_sample: list[int] = self.sample_scene.tolist()  # per-row lookups: a list beats numpy indexing
        # Parsed before sample_data, whose rows refer to them; the tokens are freed once those are joined.
        pose_columns = self._read_ego_poses()
        self._read_sample_data(sample_row, scene_of_sample, pose_columns)
        self._read_annotations(sample_row, scene_of_sample)
        return_freed_heap()

    def _small(self, name: str) -> dict[str, dict[str, Any]]:
        """A small table as token -> row; a repeated token is reported and its later row dropped."""
        rows: dict[str, dict[str, Any]] = {}
        for row in self._good_rows(name):
            if row["token"] in rows:
                self.orphans.append((f"{name}.json", f"{name} {row['token']}: expected unique tokens, got this "
                                                     f"token twice; the later row is dropped"))
                continue
            rows[row["token"]] = row
        return rows

    def _read_small_tables(self) -> None:
        """scene, log, sensor, calibrated_sensor, category, attribute, visibility and instance."""
        self.scene = self._small("scene")
        self.log = self._small("log")
        self.sensor = self._small("sensor")
        self.calibrated_sensor = self._small("calibrated_sensor")
        self.category = self._small("category")
        self.attribute = self._small("attribute")
        self.visibility = self._small("visibility")
        instances = self._small("instance")
        #: instance tokens, and each one's category token (the one field of instance.json used)
        self.instance_tokens = list(instances)
        self.instance_category: list[str] = [row["category_token"] for row in instances.values()]
        del instances  # 64k row dicts on trainval
        self.scene_by_name: dict[str, str] = {}
        for token, row in list(self.scene.items()):
            first = self.scene_by_name.setdefault(row["name"], token)
            if first != token:
                self.orphans.append(("scene.json", f"scene {token}: expected unique scene names, got {row['name']!r} "
                                                   f"again (first: scene {first}); the later scene is not converted"))
                del self.scene[token]
        self.scene_tokens = list(self.scene)
        self.cs_tokens = list(self.calibrated_sensor)
        self.visibility_tokens = list(self.visibility)

    def _read_map(self) -> None:
        """map.json, optional: when there, unreadable costs the map names only."""
        self.map_of_log: dict[str, dict[str, Any]] = {}
        map_path = self.table_dir / "map.json"
        if is_present(map_path):
            try:
                for row in self._good_rows("map"):
                    for log_token in row["log_tokens"]:
                        self.map_of_log[log_token] = row
            except InputError as error:
                message = str(error).removeprefix(f"{map_path}: ")
                self.orphans.append(("map.json", f"{message}; every scene is written without its map"))
                self.map_of_log.clear()

    def _read_samples(self) -> dict[str, int]:
        """sample.json as columns; returns sample token -> row."""
        scene_index = {token: i for i, token in enumerate(self.scene)}
        #: sample tokens, (S,) scene index, (S,) timestamp as stored (microseconds), (S,) int64 ns
        self.sample_tokens: list[str] = []
        sample_scene, sample_us, sample_ns = [], [], []
        for row in self._good_rows("sample"):
            self.sample_tokens.append(row["token"])
            sample_scene.append(scene_index.get(row["scene_token"], -1))
            sample_us.append(float(row["timestamp"]))
            sample_ns.append(us_to_ns(row["timestamp"]))
        self.sample_scene = np.asarray(sample_scene, dtype=np.int64)
        self.sample_us = np.asarray(sample_us, dtype=np.float64)
        self.sample_ns = np.asarray(sample_ns, dtype=np.int64)
        for i in np.flatnonzero(self.sample_scene < 0):
            self.orphans.append(("sample.json", f"sample {self.sample_tokens[i]}: dangling scene_token"))
        return {token: i for i, token in enumerate(self.sample_tokens)}

    def _read_ego_poses(self) -> dict[str, np.ndarray]:
        """ego_pose.json: sets :attr:`ego_pose`; returns the columns, ``token`` (P,) among them."""
        poses = ColumnBlocks({"token": "S", "pose": "f8"}, max_rows(self.table_dir / "ego_pose.json", "ego_pose"))
        # A bad pose is dropped: the sample_data using it are then reported with a dangling ego_pose_token.
        for rows in self._good_chunks("ego_pose"):
            poses.extend(([row["token"] for row in rows], [(*row["rotation"], *row["translation"]) for row in rows]))
        pose_columns = poses.columns()
        #: (P, 7) ego poses: quaternion (w, x, y, z) then translation, in ego_pose.json order.
        self.ego_pose = pose_columns["pose"].reshape(-1, 7)
        return pose_columns

    def _read_sample_data(self, sample_row: dict[str, int], scene_of_sample: list[int],
                          pose_columns: dict[str, np.ndarray]) -> None:
        """sample_data.json as columns grouped by scene, its tokens and filenames per scene.

        Args:
            sample_row: sample token -> row.
            scene_of_sample: each sample row's scene (-1: none).
            pose_columns: the ego_pose columns; their ``token`` is taken out (and freed once joined).
        """
        cs_row = {token: i for i, token in enumerate(self.cs_tokens)}
        #: each scene's sample_data tokens and filenames (the columns' order within the scene)
        self.sample_data_tokens = SceneStrings(len(self.scene))
        self.sample_data_filenames = SceneStrings(len(self.scene))
        columns = ColumnBlocks(
            {
                "scene": "i4",
                "sample": "i4",
                "pose_token": "S",
                "cs": "i4",
                "time_ns": "i8",
                "key": "?",
                "width": "i4",
                "height": "i4",
            },
            max_rows(self.table_dir / "sample_data.json", "sample_data"),
        )
        # Each kept row's token hash, for the duplicate check after the table (as for annotations).
        sample_data_hashes = array.array("q")
        for rows in self._good_chunks("sample_data", sample_row):
            rows, samples, scenes, sensors = self._linked_sample_data(rows, sample_row, scene_of_sample, cs_row)
            tokens = [s_bytes(row["token"]) for row in rows]
            sample_data_hashes.extend(map(hash, tokens))
            filenames = [row["filename"].encode() for row in rows]
            for scene, start, end in runs(scenes):
                self.sample_data_tokens.extend(scene, tokens[start:end])
                self.sample_data_filenames.extend(scene, filenames[start:end])
            columns.extend((
                scenes,
                samples,
                [row["ego_pose_token"] for row in rows],
                sensors,
                [us_to_ns(row["timestamp"]) for row in rows],
                [bool(row["is_key_frame"]) for row in rows],
                [int(row.get("width") or 0) for row in rows],
                [int(row.get("height") or 0) for row in rows],
            ))
        self.sample_data_tokens.finish()
        self.sample_data_filenames.finish()
        # Joined before grouping: the pose tokens become row numbers before the columns are reordered.
        sample_data = self._join_poses(columns.columns(), pose_columns.pop("token"))
        # A repeated token's later row is skipped like a row whose pose dangles (its columns stay aligned).
        sample_data["pose"][self._repeated("sample_data", np.frombuffer(sample_data_hashes, dtype=np.int64),
                                           sample_data["scene"], self.sample_data_tokens)] = -1
        del sample_data_hashes
        self.sample_data = grouped(sample_data, "scene")
        self.sample_data_offsets = np.searchsorted(self.sample_data.pop("scene"), np.arange(len(self.scene) + 1))

    def _linked_sample_data(self, rows: list[dict[str, Any]], sample_row: dict[str, int], scene_of_sample: list[int],
                            cs_row: dict[str, int]) -> tuple[list[Any], ...]:
        """(rows, sample rows, scenes, calibrated_sensor rows) of a chunk's rows whose links resolve.

        A chunk of rows at a time, a column at a time; row by row only for a chunk with a dangling link,
        whose rows are reported and left out.
        """
        samples = [sample_row.get(token, -1) for token in map(_SAMPLE_TOKEN, rows)]
        scenes = [scene_of_sample[sample] if sample >= 0 else -1 for sample in samples]
        sensors = [cs_row.get(token, -1) for token in map(_CS_TOKEN, rows)]
        if -1 not in scenes and -1 not in sensors:
            return rows, samples, scenes, sensors
        kept = []
        for k, row in enumerate(rows):
            if scenes[k] < 0:
                self.orphans.append(
                    ("sample_data.json", f"sample_data {row['token']}: dangling sample_token {row['sample_token']}")
                )
            elif sensors[k] < 0:
                self.problems[self.scene_tokens[scenes[k]]].append(
                    ("sample_data.json", f"sample_data {row['token']}: dangling calibrated_sensor_token "
                                         f"{row['calibrated_sensor_token']}")
                )
            else:
                kept.append(k)
        return take(kept, rows, samples, scenes, sensors)

    def _read_annotations(self, sample_row: dict[str, int], scene_of_sample: list[int]) -> None:
        """sample_annotation.json as columns grouped by scene, its tokens per scene, prev / next resolved.

        Args:
            sample_row: sample token -> row.
            scene_of_sample: each sample row's scene (-1: none).
        """
        instance_row = {token: i for i, token in enumerate(self.instance_tokens)}
        #: distinct attribute-token tuples; annotations hold an index into this list
        self.attribute_sets: list[tuple[str, ...]] = []
        attribute_set_row: dict[tuple[str, ...], int] = {}
        #: each scene's annotation tokens (the columns' order within the scene)
        self.annotation_tokens = SceneStrings(len(self.scene))
        links = {name: SceneStrings(len(self.scene)) for name in ("prev", "next")}
        columns = ColumnBlocks(
            {
                "scene": "i4",
                "sample": "i4",
                "instance": "i4",
                "box": "f8",
                "attributes": "i4",
                "visibility": "i4",
                "num_lidar_pts": "i4",
                "num_radar_pts": "i4",
            },
            max_rows(self.table_dir / "sample_annotation.json", "sample_annotation"),
        )
        # Each kept row's token hash, for the duplicate check after the table (8 bytes a row; a set of the
        # tokens holds a Python string per row, a large share of the conversion's peak memory).
        token_hashes = array.array("q")
        # Visibility token -> row; "" (and a missing or null field) is no visibility.
        visibility_index = {"": -1, **{token: i for i, token in enumerate(self.visibility_tokens)}}
        for rows in self._good_chunks("sample_annotation", sample_row):
            rows, samples, scenes, instance_rows, attributes, visibilities = self._linked_annotations(
                rows, sample_row, scene_of_sample, instance_row, visibility_index)
            token_hashes.extend([hash(row["token"]) for row in rows])
            attribute_sets = []
            for attribute_tokens in attributes:
                index = attribute_set_row.get(attribute_tokens)
                if index is None:
                    index = attribute_set_row[attribute_tokens] = len(self.attribute_sets)
                    self.attribute_sets.append(attribute_tokens)
                attribute_sets.append(index)
            annotation_tokens = [s_bytes(row["token"]) for row in rows]
            link_values = {name: [s_bytes(row.get(name, "")) for row in rows] for name in links}
            for scene, start, end in runs(scenes):
                self.annotation_tokens.extend(scene, annotation_tokens[start:end])
                for name, strings in links.items():
                    strings.extend(scene, link_values[name][start:end])
            columns.extend((
                scenes,
                samples,
                instance_rows,
                [(*row["translation"], *row["size"], *row["rotation"]) for row in rows],
                attribute_sets,
                visibilities,
                [int(row.get("num_lidar_pts", -1)) for row in rows],
                [int(row.get("num_radar_pts", -1)) for row in rows],
            ))
        self.annotation_tokens.finish()
        for strings in links.values():
            strings.finish()
        annotations = columns.columns()
        repeated = self._repeated("sample_annotation", np.frombuffer(token_hashes, dtype=np.int64), annotations["scene"],
                                  self.annotation_tokens)
        del token_hashes
        self.annotations = grouped(self._without_rows(annotations, repeated, links), "scene")
        self.annotation_offsets = np.searchsorted(self.annotations.pop("scene"), np.arange(len(self.scene) + 1))
        #: (annotation row, "prev" | "next") -> the token of a link that is not to an annotation of its scene
        self.dangling_links: dict[tuple[int, str], str] = {}
        self._resolve_links(links)

    def _linked_annotations(self, rows: list[dict[str, Any]], sample_row: dict[str, int], scene_of_sample: list[int],
                            instance_row: dict[str, int], visibility_index: dict[str, int]) -> tuple[list[Any], ...]:
        """(rows, sample rows, scenes, instance rows, attribute tuples, visibility rows) of rows whose links resolve.

        Row by row only for a chunk with a dangling link, whose rows are reported and left out.
        """
        samples = [sample_row.get(token, -1) for token in map(_SAMPLE_TOKEN, rows)]
        scenes = [scene_of_sample[sample] if sample >= 0 else -1 for sample in samples]
        instance_rows = [instance_row.get(token, -1) for token in map(_INSTANCE_TOKEN, rows)]
        attributes = [tuple(row.get("attribute_tokens", ())) for row in rows]
        visibility_tokens = [row.get("visibility_token") or "" for row in rows]
        visibilities = [visibility_index.get(token, _UNKNOWN) if type(token) is str else _UNKNOWN
                        for token in visibility_tokens]
        if not (-1 in scenes or -1 in instance_rows or _UNKNOWN in visibilities
                or not all(token in self.attribute for token in itertools.chain.from_iterable(attributes))):
            return rows, samples, scenes, instance_rows, attributes, visibilities
        kept = []
        for k, row in enumerate(rows):
            if scenes[k] < 0:
                self.orphans.append(("sample_annotation.json", f"sample_annotation {row['token']}: dangling "
                                                               f"sample_token {row['sample_token']}"))
                continue
            bad = [("instance_token", row["instance_token"])] if instance_rows[k] < 0 else []
            bad += [("attribute_token", t) for t in attributes[k] if t not in self.attribute]
            bad += [("visibility_token", visibility_tokens[k])] if visibilities[k] == _UNKNOWN else []
            if bad:
                self.problems[self.scene_tokens[scenes[k]]].append(
                    ("sample_annotation.json", f"sample_annotation {row['token']}: dangling {bad[0][0]} "
                                               f"{bad[0][1]}"))
                continue
            kept.append(k)
        return take(kept, rows, samples, scenes, instance_rows, attributes, visibilities)

    def _without_rows(self, annotations: dict[str, np.ndarray], repeated: np.ndarray,
                      links: dict[str, SceneStrings]) -> dict[str, np.ndarray]:
        """``annotations`` without the ``repeated`` rows, also taken from their scenes' token and link strings."""
        if not len(repeated):
            return annotations
        # The later rows go, from the columns and from their scenes' strings (aligned with the columns).
        keep = np.ones(len(annotations["scene"]), dtype=bool)
        keep[repeated] = False
        scene_of_row = annotations["scene"]
        for scene in np.unique(scene_of_row[repeated]).tolist():
            in_scene = keep[scene_of_row == scene]
            for strings in (self.annotation_tokens, *links.values()):
                strings.keep(scene, in_scene)
        return {name: column[keep] for name, column in annotations.items()}

    def _good_chunks(self, table: str, sample_row: dict[str, int] | None = None) -> Iterator[list[dict[str, Any]]]:
        """The rows of ``table`` that pass :func:`row_problem`, a chunk read at a time (never an empty one).

        The others are reported (:meth:`_bad`) and skipped. A chunk of rows is checked at once by
        :func:`rows_valid`; row by row only when it finds something.
        """
        for rows in iter_json_chunks(self.table_dir / f"{table}.json"):
            if not rows_valid(table, rows):
                rows = [row for row in rows if not self._bad(table, row, sample_row)]
            if rows:
                yield rows

    def _good_rows(self, table: str) -> Iterator[dict[str, Any]]:
        """The rows of :meth:`_good_chunks` one by one."""
        for rows in self._good_chunks(table):
            yield from rows

    def _bad(self, table: str, row: Any, sample_row: dict[str, int] | None = None) -> bool:
        """Whether ``row`` fails :func:`row_problem` (then reported, per scene when its sample is known)."""
        if not isinstance(row, dict):
            self.orphans.append((f"{table}.json", f"{table}: expected an object per row, got {json.dumps(row)[:80]}"))
            return True
        error, warning = row_problem(table, row)
        if warning is not None:
            self.warnings.append((f"{table}.json", warning))
            repaired_rotation_field(row)
        if error is None:
            return False
        token = row.get("sample_token")  # a list or an object here is unhashable: it is no sample's, as a missing one
        sample = sample_row.get(token, -1) if sample_row is not None and isinstance(token, str) else -1
        if sample >= 0 and self.sample_scene[sample] >= 0:
            self.problems[self.scene_tokens[self.sample_scene[sample]]].append((f"{table}.json", f"{error}; dropped"))
        else:
            self.orphans.append((f"{table}.json", f"{error}; dropped"))
        return True

    def _join_poses(self, sample_data: dict[str, np.ndarray], pose_tokens: np.ndarray) -> dict[str, np.ndarray]:
        """Replaces the ``pose_token`` column by ``pose``, the row in ``ego_pose``, -1 when it dangles (in place).

        A row whose pose dangles is reported here and skipped by :meth:`sample_data_rows` (kept in the
        columns, which stay aligned with the scene's tokens and filenames).

        Args:
            sample_data: the sample_data columns.
            pose_tokens: (P,) ego_pose tokens in table order (freed here when the caller holds no other reference).
        """
        wanted = sample_data.pop("pose_token")
        order = np.argsort(pose_tokens, kind="stable")
        # A token given twice: the first row is the one found (stable order), the later one is reported.
        for token in np.unique(pose_tokens[order][1:][pose_tokens[order][1:] == pose_tokens[order][:-1]]).tolist():
            self.orphans.append(("ego_pose.json", f"ego_pose {token.decode()}: expected unique tokens, got this token "
                                                  "twice; the later row is dropped"))
        # Searched in sorted order through ``sorter``: no sorted copy of the tokens (one of the largest arrays held).
        position = np.clip(np.searchsorted(pose_tokens, wanted, sorter=order), 0, max(len(order) - 1, 0))
        found = pose_tokens[order[position]] == wanted if len(order) else np.zeros(len(wanted), dtype=bool)
        del pose_tokens
        missing = np.flatnonzero(~found)
        if len(missing):
            # Each such row's place among its scene's rows (table order), where its token is.
            scenes = sample_data["scene"]
            place = rank_in_group(scenes)[missing]
            tokens: dict[int, np.ndarray] = {}
            for i, k in zip(missing.tolist(), place.tolist(), strict=True):
                scene = int(scenes[i])
                if scene not in tokens:
                    tokens[scene] = self.sample_data_tokens.values(scene)
                self.problems[self.scene_tokens[scene]].append(
                    ("sample_data.json", f"sample_data {tokens[scene][k].decode()}: dangling ego_pose_token "
                                         f"{wanted[i].decode()}")
                )
        sample_data["pose"] = np.where(found, order[position] if len(order) else -1, -1).astype(np.int32)
        return sample_data

    def _repeated(self, table: str, token_hashes: np.ndarray, scenes: np.ndarray, strings: SceneStrings) -> np.ndarray:
        """(R,) rows (table order) whose ``table`` token an earlier row has, each reported as an error.

        Args:
            table: "sample_data" or "sample_annotation".
            token_hashes: (N,) ``hash`` of each kept row's token, in table order.
            scenes: (N,) each row's scene.
            strings: each scene's tokens, in table order.
        """
        repeated = repeated_rows(token_hashes, scenes, strings)
        for row, token in repeated:
            self.problems[self.scene_tokens[int(scenes[row])]].append(
                (f"{table}.json", f"{table} {token.decode()}: expected unique tokens, got this token twice; "
                                  "the later row is dropped"))
        return np.asarray([row for row, _ in repeated], dtype=np.int64)

    def _resolve_links(self, links: dict[str, SceneStrings]) -> None:
        """Adds the annotations' ``prev`` / ``next`` columns: the linked annotation's row in its scene.

        -1: no link (empty token); :data:`DANGLING`: a token of no annotation of the scene (another
        scene's or none at all), kept in ``dangling_links``.

        Args:
            links: "prev" / "next" -> each scene's link tokens (emptied here, a scene at a time).
        """
        offsets = self.annotation_offsets
        for name in links:
            self.annotations[name] = np.full(offsets[-1], -1, dtype=np.int32)
        for scene, (start, end) in enumerate(zip(offsets[:-1].tolist(), offsets[1:].tolist(), strict=True)):
            if start == end:
                continue
            scene_tokens = self.annotation_tokens.values(scene)
            order = np.argsort(scene_tokens, kind="stable")
            tokens_sorted = scene_tokens[order]
            for name, strings in links.items():
                scene_links = strings.values(scene)
                strings.drop(scene)
                position = np.minimum(np.searchsorted(tokens_sorted, scene_links), end - start - 1)
                found = tokens_sorted[position] == scene_links
                linked = scene_links != b""
                self.annotations[name][start:end] = np.where(linked & found, order[position],
                                                             np.where(linked, DANGLING, -1))
                for k in np.flatnonzero(linked & ~found).tolist():
                    self.dangling_links[start + k, name] = scene_links[k].decode()

    def dangling_link(self, scene_token: str, k: int, name: str) -> str:
        """The token of annotation ``k`` (of the scene's) ``name`` ("prev" | "next") link, which is :data:`DANGLING`."""
        return self.dangling_links[int(self.annotation_offsets[self.scene_tokens.index(scene_token)]) + k, name]

    def sample_data_rows(self, scene_token: str) -> list[SampleDataRow]:
        """The scene's sample_data rows (in table order), without those whose ego pose dangles."""
        i = self.scene_tokens.index(scene_token)
        part = slice(self.sample_data_offsets[i], self.sample_data_offsets[i + 1])
        c = {name: column[part] for name, column in self.sample_data.items()}
        c["token"], c["filename"] = self.sample_data_tokens.values(i), self.sample_data_filenames.values(i)
        if not np.all(c["pose"] >= 0):
            c = {name: column[c["pose"] >= 0] for name, column in c.items()}
        return [
            SampleDataRow(
                token=token.decode(),
                sample_token=self.sample_tokens[sample],
                ego_pose_row=pose,
                calibrated_sensor_token=self.cs_tokens[cs],
                timestamp_ns=time_ns,
                filename=filename.decode(),
                is_key_frame=key,
                width=width,
                height=height,
            )
            for token, sample, pose, cs, time_ns, filename, key, width, height in zip(
                c["token"].tolist(),
                c["sample"].tolist(),
                c["pose"].tolist(),
                c["cs"].tolist(),
                c["time_ns"].tolist(),
                c["filename"].tolist(),
                c["key"].tolist(),
                c["width"].tolist(),
                c["height"].tolist(),
                strict=True,
            )
        ]

    def annotation_columns(self, scene_token: str) -> dict[str, np.ndarray]:
        """The scene's sample_annotation rows (in table order) as column views.

        Returns:
            ``token`` (N,) bytes; ``sample`` (N,) rows of the sample columns; ``instance`` (N,) indexes
            into ``instance_tokens``; ``box`` (N, 10) translation, size (w, l, h), rotation (w, x, y, z);
            ``attributes`` (N,) indexes into ``attribute_sets``; ``visibility`` (N,) indexes into
            ``visibility_tokens`` or -1; ``num_lidar_pts``, ``num_radar_pts`` (N,) (-1 when absent);
            ``prev``, ``next`` (N,) the linked annotation's position in these columns, -1 when none,
            :data:`DANGLING` when its token is of no annotation of this scene (:meth:`dangling_link`).
        """
        i = self.scene_tokens.index(scene_token)
        part = slice(self.annotation_offsets[i], self.annotation_offsets[i + 1])
        columns = {name: column[part] for name, column in self.annotations.items()}
        columns["token"] = self.annotation_tokens.values(i)
        columns["box"] = columns["box"].reshape(-1, 10)
        return columns
