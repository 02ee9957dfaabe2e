"""The source digest a resumable scene records: what changes it and what does not."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from avdata.executors import source_digest


def _digest_by_paths(paths: list[Path | str], root: Path) -> str:
    """The digest as first computed, with Path comparisons and ``relative_to``: records written so must still match."""
    digest = hashlib.sha256()
    for path in sorted({Path(p) for p in paths}):
        try:
            name = str(path.relative_to(root))
        except ValueError:
            name = str(path)
        if not path.exists():
            digest.update(f"{name}\0missing\n".encode())
        elif not path.is_file():
            digest.update(f"{name}\0not a regular file {path.stat().st_mode:o}\n".encode())
        elif path.stat().st_size <= 1 << 16:
            digest.update(f"{name}\0{path.stat().st_size}\0{hashlib.sha256(path.read_bytes()).hexdigest()}\n".encode())
        else:
            digest.update(f"{name}\0{path.stat().st_size}\0{path.stat().st_mtime_ns}\n".encode())
    return digest.hexdigest()


def test_digest_is_the_path_ordered_record_of_names_sizes_and_contents(tmp_path: Path) -> None:
    root = tmp_path / "src"
    # Names whose string order differs from their path order ("a-b" < "a/b" as strings, "a" < "a-b" as parts).
    for name in ("a/b.bin", "a-b/c.bin", "a.b", "z/big.bin"):
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_bytes(name.encode() * (40_000 if "big" in name else 1))
    os.mkfifo(root / "pipe")
    outside = tmp_path / "outside.txt"
    outside.write_text("x")
    paths: list[Path | str] = [root / "a/b.bin", str(root / "a-b/c.bin"), f"{root}//a.b", root / "z/big.bin",
                               root / "pipe", root / "gone.bin", outside, root / "a/b.bin"]
    expected = _digest_by_paths(paths, root)
    assert source_digest(paths, root) == (expected, 7)  # the repeated path counts once
    (root / "a.b").write_bytes(b"A.b")  # same size, other content: a small file is hashed whole
    assert source_digest(paths, root)[0] != expected
    assert source_digest(paths, root)[0] == _digest_by_paths(paths, root)


def test_temporary_files_of_every_writer_are_removed(tmp_path: Path) -> None:
    """A killed run leaves scene, index, marker and manifest temporaries; the next one (under the lock) removes them."""
    from avdata.outputs import remove_temporary_files, temporary_path

    kept = ["avdata.json", "errors.jsonl", "index/frames.parquet", "scenes/a.mcap", ".avdata.lock",
            ".avdata-export/scenes/a.json"]
    left = [temporary_path(Path(name)).as_posix() for name in kept[:-2]]
    assert left[3].startswith("scenes/.a.mcap.") and left[3].endswith(".tmp")
    for name in kept + left:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("x")
    remove_temporary_files(tmp_path)
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file()) == sorted(kept)
