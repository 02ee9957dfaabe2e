"""The one place where avdata loads pybullet.

pybullet's C extension prints "pybullet build time: ..." to the process's standard error when it is imported,
in front of avdata's own messages (and of its one-line errors). It is imported here with file descriptor 2
pointed at /dev/null for the duration of the import only; the generator reports its own progress.
"""

from __future__ import annotations

import ctypes
import os
import sys
from types import ModuleType


def load_pybullet() -> ModuleType:
    """Imports pybullet without its build banner; returns the module."""
    loaded = sys.modules.get("pybullet")
    if loaded is not None:
        return loaded
    sys.stderr.flush()
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        import pybullet

        ctypes.CDLL(None).fflush(None)  # anything C buffered goes to /dev/null too
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
    module: ModuleType = pybullet
    return module
