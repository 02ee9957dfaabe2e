"""Scene-per-task work (convert, generate, export, studies) on one interface: a local process pool or a Ray cluster.

Each scene is one task: idempotent (a rerun skips scenes whose resume fingerprint matches, see
:mod:`avdata.executors.resume`), written under a unique temporary name and renamed, and run while the
driver holds the dataset folder's lock (:mod:`avdata.executors.lock`). :func:`make_executor` picks the
engine: ``local`` (the default; ``workers`` processes, or the calling process for one) or ``ray``.
"""

from avdata.executors.base import Executor, LocalExecutor, TaskFailure, make_executor
from avdata.executors.lock import dataset_lock
from avdata.executors.resume import RESUME_KEY, ResumableWriter, resume_fingerprint, source_digest

__all__ = [
    "RESUME_KEY",
    "Executor",
    "LocalExecutor",
    "ResumableWriter",
    "TaskFailure",
    "dataset_lock",
    "make_executor",
    "resume_fingerprint",
    "source_digest",
]
