"""Warnings of the evaluation: inputs that are accepted but deserve a word (ignored extras, empty classes).

They are Python warnings of category :class:`EvalWarning`, so library users filter them as usual; the
command line prints each as one ``avdata: warning:`` line.
"""

from __future__ import annotations

import warnings

__all__ = ["EvalWarning", "warn"]


class EvalWarning(UserWarning):
    """An evaluation input that is used, but not as the user may have meant (ignored files, empty classes)."""


def warn(message: str) -> None:
    """Issues ``message`` as an :class:`EvalWarning` attributed to the caller of the evaluation function."""
    warnings.warn(message, EvalWarning, stacklevel=3)
