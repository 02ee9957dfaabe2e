"""``avdata info`` counts what the Parquet index holds, read from the manifest and the scenes without pyarrow."""

from __future__ import annotations

import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from avdata.schema import DatasetReader
from avdata.schema.info import describe_dataset


def _index_lines(root: Path) -> list[str]:
    """The frames and classes lines as counted from the index tables (what ``info`` printed before)."""
    reader = DatasetReader(root)
    frames, objects = reader.frames(), reader.objects()
    lines = [f"frames:    {frames.num_rows} ({frames.column('annotated').to_pylist().count(True)} annotated)",
             "classes:"]
    counts = Counter(objects.column("class").to_pylist())
    lines += [f"  {cls:<22} {count}" for cls, count in sorted(counts.items(), key=lambda kv: -kv[1])]
    return lines


def test_info_counts_are_the_index_counts_with_ties_in_index_order(dataset: Path) -> None:
    # The shared dataset has a frame that is not annotated and two classes with the same count.
    text = describe_dataset(dataset).splitlines()
    expected = _index_lines(dataset)
    assert "frames:    5 (4 annotated)" in expected and expected[2:] == ["  car                    4",
                                                                         "  pedestrian             4"]
    assert text[text.index(expected[0]): text.index(expected[0]) + 1] == expected[:1]
    start = text.index("classes:")
    assert text[start: start + len(expected) - 1] == expected[1:]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="VmHWM of /proc/self/status is Linux's")
def test_info_runs_without_pyarrow_and_reports_its_peak_memory(dataset: Path) -> None:
    code = ("import resource, sys\n"
            "from avdata.cli import main\n"
            f"assert main(['info', {str(dataset)!r}]) == 0\n"
            "print('PYARROW:', sorted(m for m in sys.modules if m.split('.')[0] == 'pyarrow'))\n"
            "hwm = [line.split()[1] for line in open('/proc/self/status') if line.startswith('VmHWM:')]\n"
            "print('PEAK_MB:', int(hwm[0]) / 1024, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[-2] == "PYARROW: []"
    # VmHWM is this process's own peak; ru_maxrss also counts the memory of the process that exec'd it (Linux
    # keeps the larger across execve, and subprocess may vfork from pytest), so it is only reported.
    peak_mb, maxrss_mb = map(float, lines[-1].split()[1:])
    print(f"avdata info peak RSS: {peak_mb:.1f} MB (VmHWM), ru_maxrss {maxrss_mb:.1f} MB")
    assert peak_mb < 60, f"avdata info used {peak_mb:.1f} MB at its peak, expected under 60 MB"
