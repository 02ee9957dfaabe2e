"""Output files that appear whole or not at all: written under a temporary name in their folder, then renamed.

Results, reports, exports and state files go through :func:`write_atomically` (scene files and the index have
their own writers), so an output path that cannot be written is one line naming it, never a traceback, and a
crash never leaves a half-written file under the final name.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from avdata.errors import OutputError, one_line


def write_atomically(path: str | Path, data: bytes | bytearray | memoryview | str) -> None:
    """Writes ``data`` (text as UTF-8) to ``path``, creating its folders, through a temporary file and a rename.

    The temporary file is ``.<name>.<pid>.<random>.tmp`` beside the target (hidden, so folder listings and
    globs for the final names pass it over), created exclusively with the usual permissions.

    Raises:
        OutputError: it cannot be written there (a folder in its place, a file where its folder goes, no
            permission, a full disk), naming the path and why.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):  # a file in the way, at the parent or above it
        raise OutputError(f"{path}: cannot write this file (a file is where its folder should be)") from None
    except OSError as error:
        raise OutputError(f"{path}: cannot write this file ({error.strerror or one_line(error)})") from None
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666)
        with os.fdopen(fd, "wb") as stream:
            stream.write(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except OSError as error:
        raise OutputError(f"{path}: cannot write this file ({error.strerror or one_line(error)})") from None
    finally:
        if os.path.lexists(tmp):
            os.unlink(tmp)
