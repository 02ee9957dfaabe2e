"""Bad DAIR-V2X input costs the object it is in, with one line naming file and entry (issue 34)."""

from __future__ import annotations

import json
from pathlib import Path

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.dair_v2x import DairV2xConverter
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from tests.converters.test_dair_v2x import build_dair


def test_a_label_world_entry_given_twice_is_an_error_not_a_second_object(tmp_path: Path) -> None:
    # The copied entry became a second object at the same place.
    build_dair(tmp_path / "src", skew=0.0)
    path = tmp_path / "src" / "cooperative" / "label_world" / "017314.json"
    entries = json.loads(path.read_text())
    path.unlink()
    path.write_text(json.dumps([*entries, entries[1]]))
    result = run_conversion(DairV2xConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "out", quiet=True)))
    errors = [p for p in result.problems if p.severity == "error"]
    assert [(e.file, e.message) for e in errors] == [
        (str(path), f"object [{len(entries)}]: expected one entry per object, got the same as object [1]; dropped")]
    assert DatasetReader(tmp_path / "out").objects().num_rows == len(entries)
    assert validate_dataset(tmp_path / "out") == []
