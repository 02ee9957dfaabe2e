"""The one exception hierarchy of avdata.

Every error a user can cause by giving bad input derives from :class:`AvdataError`; the command
line prints those as one line and exits non-zero, without a traceback. Messages read
"expected X, got Y" and name the file, field and value (or the frames and times).
"""

from __future__ import annotations

import stat


class AvdataError(Exception):
    """Base of every expected avdata failure."""


def one_line(error: BaseException | str) -> str:
    """A library's error text on one line (pyarrow's and others' span several), for embedding in ours."""
    return " ".join(str(error).split())


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
