"""Memoised frame-graph lookups of one scene, for the loaders."""

from __future__ import annotations

import numpy as np

from avdata.errors import ExtrapolationError, FrameLookupError
from avdata.frames import FrameGraph, Transform

_EYE3 = np.eye(3)


def is_identity(transform: Transform) -> bool:
    """Whether a single transform moves nothing (exactly: callers skip the work it would do)."""
    return not transform.translation.any() and bool((transform.rotation == _EYE3).all())


class SceneTransforms:
    """Memoised lookups in one scene's frame graph (a pure cache, one per scene and process).

    A chain of static edges is looked up once; a chain with time-stamped edges is looked up once for
    every frame and sensor time of the scene in one batched (vectorised) query, then indexed. Times
    outside that set, or a batch that some time cannot satisfy, are looked up one by one, so errors
    (extrapolation, unknown frames) surface exactly as :meth:`FrameGraph.lookup` raises them.
    Lookups between two times are :meth:`FrameGraph.lookup_fixed` through ``world``, memoised per query.

    Args:
        graph: the scene's frame graph.
        times_ns: (T,) sorted unique times to batch stamped lookups over.
    """

    def __init__(self, graph: FrameGraph, times_ns: np.ndarray):
        self.graph = graph
        self._times_ns = times_ns
        self._static: dict[tuple[str, str], Transform] = {}
        self._batched: dict[tuple[str, str], Transform | None] = {}
        self._fixed: dict[tuple[str, int, str, int], Transform] = {}

    def lookup(self, target: str, source: str, time_ns: int) -> Transform:
        """``target_T_source`` at ``time_ns``."""
        key = (target, source)
        if key in self._static:
            return self._static[key]
        if key not in self._batched:
            try:
                self._static[key] = self.graph.lookup(target, source, None)
                return self._static[key]
            except ExtrapolationError:
                pass  # a time-stamped edge lies on the chain: batch it
            try:
                self._batched[key] = self.graph.lookup(target, source, self._times_ns)
            except FrameLookupError:
                self._batched[key] = None
        batch = self._batched[key]
        i = int(np.searchsorted(self._times_ns, time_ns))
        if batch is not None and i < len(self._times_ns) and self._times_ns[i] == time_ns:
            return batch[i]
        return self.graph.lookup(target, source, time_ns)

    def between(self, target: str, t_target: int, source: str, t_source: int) -> Transform:
        """``target(t_target)_T_source(t_source)``: :meth:`FrameGraph.lookup_fixed` through ``world``.

        At one time that is :meth:`lookup` (the batched cache); across two, the graph's answer is kept.
        """
        if t_target == t_source:
            return self.lookup(target, source, t_target)
        key = (target, t_target, source, t_source)
        found = self._fixed.get(key)
        if found is None:
            found = self._fixed[key] = self.graph.lookup_fixed(target, t_target, source, t_source)
        return found
