"""Evaluation outputs: JSON (class -> metric -> value), a Markdown table, and PNG plots."""

from __future__ import annotations

import io
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from avdata.outputs import write_atomically

__all__ = ["plot_curves", "to_json", "to_markdown", "write_json"]


def _plain(value: Any) -> Any:
    if isinstance(value, (np.integer, int)) and not isinstance(value, bool):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return None if math.isnan(value) else float(value)
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    return value


def to_json(table: Mapping[str, Mapping[str, float | int]]) -> str:
    """``{class: {metric: value}}`` as JSON; NaN (undefined) becomes null, counts stay integers."""
    return json.dumps(_plain(table), indent=2, sort_keys=False)


def write_json(path: str | Path, table: Mapping[str, Mapping[str, float | int]]) -> None:
    """Writes :func:`to_json` to ``path`` (parent folders created) through a temporary file and a rename.

    Args:
        path: the JSON file; it appears complete or not at all.
        table: ``{class: {metric: value}}``.
    """
    write_atomically(path, to_json(table) + "\n")


def to_markdown(table: Mapping[str, Mapping[str, float | int]], columns: Sequence[str] | None = None) -> str:
    """A Markdown table, one row per class; fractions printed with 4 decimals, counts as integers.

    Args:
        table: ``{class: {metric: value}}``.
        columns: metrics to show, in order; None shows every metric of the first row.

    Returns:
        The table text.
    """
    rows = list(table.items())
    if not rows:
        return ""
    cols = list(columns) if columns is not None else list(rows[0][1])
    lines = ["| class | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for name, values in rows:
        cells = []
        for c in cols:
            v = values.get(c)
            if v is None or (isinstance(v, float) and math.isnan(v)):
                cells.append("–")
            elif isinstance(v, (int, np.integer)):
                cells.append(str(int(v)))
            else:
                cells.append(f"{float(v):.4f}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot_curves(
    path: str | Path,
    x: np.ndarray,
    curves: Mapping[str, np.ndarray],
    *,
    title: str,
    xlabel: str,
    ylabel: str = "score",
) -> None:
    """One PNG with several curves over a shared x axis (PR curves, HOTA vs alpha).

    Args:
        path: PNG file to write.
        x: (K,) x values.
        curves: label -> (K,) y values.
        title: plot title.
        xlabel: x axis label.
        ylabel: y axis label.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for label, y in curves.items():
        ax.plot(x, y, label=label)
    ax.set(xlim=(0, 1), ylim=(0, 1.02), xlabel=xlabel, ylabel=ylabel, title=title)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    png = io.BytesIO()
    fig.savefig(png, format="png", dpi=100)
    plt.close(fig)
    write_atomically(path, png.getbuffer())  # one line for a full disk or a folder in its place, never half a PNG
