"""Progress of long jobs: a tqdm bar on a terminal, otherwise one line per finished task.

A job run by a scheduler or piped into a log file has no terminal to draw a bar on, and a bar's carriage
returns make a log unreadable; there it prints ``<desc>: <done>/<total> <unit>s (<task> finished, <elapsed> s)``
on stderr as each task ends, so a log shows how far a long job got and how fast it goes.
"""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING, NoReturn

if TYPE_CHECKING:  # tqdm is imported only when a bar is drawn
    from tqdm import tqdm

__all__ = ["Progress"]


class Progress:
    """Counts finished tasks: ``update(name)`` after each; ``close()`` at the end (or use as a context manager)."""

    def __init__(self, total: int, desc: str, unit: str, quiet: bool = False) -> None:
        self._total, self._desc, self._unit, self._quiet = total, desc, unit, quiet
        self._done = 0
        self._start = time.monotonic()
        self._bar: tqdm[NoReturn] | None = None
        if not quiet and sys.stderr.isatty():
            from tqdm import tqdm

            self._bar = tqdm(total=total, desc=desc, unit=unit)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def update(self, name: str) -> None:
        """One more task finished; ``name`` says which."""
        self._done += 1
        if self._bar is not None:
            self._bar.update()
        elif not self._quiet:
            print(f"{self._desc}: {self._done}/{self._total} {self._unit}s ({name} finished, "
                  f"{time.monotonic() - self._start:.1f} s)", file=sys.stderr, flush=True)

    def close(self) -> None:
        """Ends the bar (nothing to do for lines)."""
        if self._bar is not None:
            self._bar.close()
