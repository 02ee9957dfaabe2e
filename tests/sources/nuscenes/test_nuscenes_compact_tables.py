"""How the nuScenes tables are kept: arrays sized from the file, strings deflated per scene, links as rows.

Real inputs: the Lyft tables in ../shared/realdata/nuscenes_schema/lyft (64-hex tokens), with rows added
or changed where a case needs it; every value read back is compared with the JSON's own.
"""

from __future__ import annotations

import itertools
import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from avdata.sources.nuscenes import DANGLING, NuScenesTables
from avdata.sources.nuscenes.columns import ColumnBlocks, SceneStrings, max_rows, runs
from tests.realdata import REALDATA

LYFT = REALDATA / "nuscenes_schema" / "lyft" / "v1.01-train" / "v1.01-train"


def _copy_tables(dst: Path) -> dict[str, list[dict[str, Any]]]:
    tables = {path.stem: json.loads(path.read_text()) for path in LYFT.glob("*.json")}
    for name, rows in tables.items():
        (dst / f"{name}.json").write_text(json.dumps(rows))
    return tables


def test_rows_as_short_as_the_schema_allows_fit_the_arrays_sized_from_the_file(tmp_path: Path) -> None:
    tables = _copy_tables(tmp_path)
    # The shortest text a valid ego_pose row can have: one-character token, integers, no white space.
    short = [{"token": chr(0x41 + k % 26) + str(k), "translation": [0, 0, 0], "rotation": [1, 0, 0, 0]}
             for k in range(20_000)]
    text = json.dumps(tables["ego_pose"] + short, separators=(",", ":"))
    (tmp_path / "ego_pose.json").write_text(text)
    assert max_rows(tmp_path / "ego_pose.json", "ego_pose") >= len(tables["ego_pose"]) + len(short)
    parsed = NuScenesTables(tmp_path)
    assert parsed.ego_pose.shape == (len(tables["ego_pose"]) + len(short), 7)
    assert parsed.ego_pose[-1].tolist() == [1, 0, 0, 0, 0, 0, 0]


def test_scene_strings_give_back_each_scene_s_values_in_order() -> None:
    strings = SceneStrings(3)
    rng = np.random.default_rng(0)
    expected: list[list[bytes]] = [[], [], []]
    start = 0
    while start < 5_000:  # several deflated segments per scene, added in runs of 1 to 60 values
        scene = int(rng.integers(0, 2))  # scene 2 stays empty
        run = []
        for k in range(start, start + int(rng.integers(1, 61))):
            value = f"sweeps/LIDAR_TOP/n015-2018-07-24-11-22-45+0800__LIDAR_TOP__{1532402927647951 + 50_000 * k}".encode()
            run.append(value if k % 7 else "é/ß".encode() if k % 2 else b"")
        start += len(run)
        strings.extend(scene, run)
        expected[scene].extend(run)
    strings.finish()
    for scene in range(3):
        assert strings.values(scene).tolist() == expected[scene]
        assert strings.values(scene).dtype.kind == "S"


def test_tokens_filenames_and_links_read_back_as_in_the_tables(tmp_path: Path) -> None:
    tables = _copy_tables(tmp_path)
    annotations = tables["sample_annotation"]
    annotations[0]["prev"] = "no-such-annotation"
    annotations[1]["next"] = annotations[2]["token"]
    (tmp_path / "sample_annotation.json").write_text(json.dumps(annotations))
    parsed = NuScenesTables(tmp_path)
    sample_scene = {row["token"]: row["scene_token"] for row in tables["sample"]}
    dangling = []
    for scene in parsed.scene_tokens:
        rows = [row for row in tables["sample_data"] if sample_scene.get(row["sample_token"]) == scene]
        read = parsed.sample_data_rows(scene)
        assert [(r.token, r.filename) for r in read] == [(row["token"], row["filename"]) for row in rows]
        scene_annotations = [row for row in annotations if sample_scene.get(row["sample_token"]) == scene]
        columns = parsed.annotation_columns(scene)
        tokens = [row["token"] for row in scene_annotations]
        assert columns["token"].tolist() == [token.encode() for token in tokens]
        for name in ("prev", "next"):
            for k, row in enumerate(scene_annotations):
                link = row[name]
                if link == "":
                    assert columns[name][k] == -1
                elif link in tokens:
                    assert columns[name][k] == tokens.index(link)
                else:
                    assert columns[name][k] == DANGLING
                    assert parsed.dangling_link(scene, k, name) == link
                    dangling.append(link)
    assert "no-such-annotation" in dangling


def test_column_blocks_take_more_rows_than_their_capacity() -> None:
    columns = ColumnBlocks({"token": "S", "pose": "f8"}, capacity=3)
    rows = [(f"t{k}" * (1 + k // 5000), (k, 0, 0, 0, 0, 0, 0)) for k in range(10_000)]  # wider tokens later, too
    start = 0
    for size in itertools.cycle((1, 700, 4096, 13)):  # chunks smaller and larger than a block
        chunk = rows[start:start + size]
        columns.extend(([token for token, _ in chunk], [pose for _, pose in chunk]))
        start += size
        if start >= len(rows):
            break
    built = columns.columns()
    assert built["token"].tolist() == [token.encode() for token, _ in rows]
    assert built["pose"][:, 0].tolist() == list(range(10_000))


def test_runs_split_a_chunk_by_scene_in_table_order() -> None:
    assert list(runs([])) == []
    assert list(runs([4, 4, 4])) == [(4, 0, 3)]
    # Scenes may come back later in a table: each run is separate, in order.
    assert list(runs([1, 1, 0, 2, 2, 1])) == [(1, 0, 2), (0, 2, 3), (2, 3, 5), (1, 5, 6)]


def test_repeated_annotation_tokens_are_found_by_token_not_by_hash() -> None:
    # Table order: scenes [0, 1, 0, 0, 1], tokens [a, c, b, a, b]. Every hash is made equal (a collision
    # between all of them): only the rows whose token an earlier row has go, each named in its scene.
    tables = NuScenesTables.__new__(NuScenesTables)
    tables.scene_tokens = ["scene-0", "scene-1"]
    tables.problems = defaultdict(list)
    tables.annotation_tokens = SceneStrings(2)
    tables.annotation_tokens.extend(0, [b"a", b"b", b"a"])
    tables.annotation_tokens.extend(1, [b"c", b"b"])
    tables.annotation_tokens.finish()
    scenes = np.array([0, 1, 0, 0, 1], dtype=np.int32)
    repeated = tables._repeated("sample_annotation", np.full(5, 7, dtype=np.int64), scenes, tables.annotation_tokens)
    assert repeated.tolist() == [3, 4]
    message = "sample_annotation {}: expected unique tokens, got this token twice; the later row is dropped"
    assert dict(tables.problems) == {"scene-0": [("sample_annotation.json", message.format("a"))],
                                     "scene-1": [("sample_annotation.json", message.format("b"))]}
    # Distinct hashes: nothing is compared, nothing goes.
    assert tables._repeated("sample_annotation", np.arange(5, dtype=np.int64), scenes, tables.annotation_tokens).tolist() == []


def test_scene_strings_keep_drops_values_in_place() -> None:
    strings = SceneStrings(2)
    strings.extend(0, [b"x", b"", b"yz", b"w"])
    strings.extend(1, [b"q"])
    strings.finish()
    strings.keep(0, np.array([True, False, True, False]))
    assert strings.values(0).tolist() == [b"x", b"yz"] and strings.values(1).tolist() == [b"q"]
