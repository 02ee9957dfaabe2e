"""The one exception hierarchy of avdata.

Every error a user can cause by giving bad input derives from :class:`AvdataError`; the command
line prints those as one line and exits non-zero, without a traceback. Messages read
"expected X, got Y" and name the file, field and value (or the frames and times).
"""

from __future__ import annotations

import reprlib
import stat


class AvdataError(Exception):
    """Base of every expected avdata failure."""


def one_line(error: BaseException | str) -> str:
    """A library's error text on one line (pyarrow's and others' span several), for embedding in ours."""
    return " ".join(str(error).split())


_SHOWN = reprlib.Repr()
_SHOWN.maxlevel, _SHOWN.maxstring, _SHOWN.maxother = 2, 80, 80
_SHOWN.maxtuple = _SHOWN.maxlist = _SHOWN.maxdict = _SHOWN.maxset = 8


def shown(value: object) -> str:
    """``repr(value)`` cut to a few levels and items, for messages.

    ``f"{value!r:.80}"`` builds the whole repr first: a YAML value of aliases (10 lines, 10^9 numbers) took minutes
    and gigabytes to be named.
    """
    return _SHOWN.repr(value)


def yaml_problem(error: BaseException) -> str:
    """A PyYAML parse error as ``line L, column C: problem``, 1-based as editors count (PyYAML's marks are 0-based)."""
    mark = getattr(error, "problem_mark", None) or getattr(error, "context_mark", None)
    problem = getattr(error, "problem", None) or one_line(error)
    context = getattr(error, "context", None)
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    return f"{where}{problem}{f' ({context})' if context else ''}"


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, for messages: "file", "folder", "FIFO", ..."""
    kinds = {stat.S_IFREG: "file", stat.S_IFDIR: "folder", stat.S_IFIFO: "FIFO", stat.S_IFSOCK: "socket",
             stat.S_IFCHR: "character device", stat.S_IFBLK: "block device"}
    return kinds.get(stat.S_IFMT(mode), "special file")


class InputError(AvdataError):
    """A source or dataset file is missing, malformed or holds an impossible value."""


class OutputError(AvdataError):
    """An output file cannot be written where it was asked for (a folder in its place, no permission, a full disk)."""


class DiskFullError(OutputError):
    """The disk (or the quota) holding an output is full: the run stops there, keeping what is complete."""


class FormatVersionError(AvdataError):
    """A dataset was written with a format version this reader does not support."""


class FrameLookupError(AvdataError):
    """A frame-graph query cannot be answered (base of the graph errors, as in tf2)."""


class UnknownFrameError(FrameLookupError):
    """A frame name that the graph does not hold."""


class ConnectivityError(FrameLookupError):
    """Two frames exist but no chain of transforms joins them."""


class ExtrapolationError(FrameLookupError):
    """A time outside the recorded range of a time-stamped edge, beyond the allowed tolerance."""
