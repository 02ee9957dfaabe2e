"""Warnings of the evaluation: inputs that are accepted but deserve a word (ignored extras, empty classes).

They are Python warnings of category :class:`EvalWarning`, so library users filter them as usual; the
command line prints each as one ``avdata: warning:`` line.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

from avdata.errors import InputError

__all__ = ["EvalWarning", "check_ground_truth", "warn"]


class EvalWarning(UserWarning):
    """An evaluation input that is used, but not as the user may have meant (ignored files, empty classes)."""


def warn(message: str) -> None:
    """Issues ``message`` as an :class:`EvalWarning` attributed to the caller of the evaluation function."""
    warnings.warn(message, EvalWarning, stacklevel=3)


def check_ground_truth(where: str, classes: Sequence[str], empty: Sequence[str], consequence: str) -> None:
    """The one rule of every protocol for evaluated classes without ground truth.

    All of them empty is an :class:`InputError` (every score would be 0 or undefined: the wrong dataset, split or
    filter, more likely than a result); some of them empty is one warning naming them and what their scores mean.

    Args:
        where: the ground truth (its path, or "ground truth").
        classes: the evaluated classes.
        empty: those of them without ground truth (after the protocol's own filters).
        consequence: what their scores are, e.g. "their AP is 0".
    """
    if not empty:
        return
    if set(empty) >= set(classes):
        raise InputError(f"{where}: expected ground truth of the evaluated classes ({', '.join(classes)}), got none")
    warnings.warn(f"{where}: no object of class(es) {', '.join(empty)}; {consequence}", EvalWarning, stacklevel=3)
