"""A tree of named frames with static and time-stamped edges, queried like ROS tf2.

Each frame has at most one parent. An edge holds ``parent_T_child`` (the child's pose in the
parent), either once (static: calibrations) or as samples over time (poses). ``lookup(target,
source, time_ns)`` returns ``target_T_source`` by walking both frames up to their common ancestor,
interpolating every time-stamped edge on the way (slerp + lerp) and refusing to extrapolate beyond
``max_extrapolation_ns``; inside that tolerance the nearest sample is held.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avdata.errors import AvdataError, ConnectivityError, ExtrapolationError, UnknownFrameError
from avdata.frames.transform import Transform


@dataclass(frozen=True, slots=True, kw_only=True)
class StampedEdge:
    """Samples of ``parent_T_child`` at strictly increasing ``timestamps_ns`` (T,)."""

    timestamps_ns: np.ndarray
    parent_T_child: Transform


class FrameGraph:
    """Named frames joined by static and time-stamped rigid transforms (a tree, checked on insert)."""

    def __init__(self) -> None:
        self._parent: dict[str, str] = {}
        self._static: dict[str, Transform] = {}
        self._stamped: dict[str, StampedEdge] = {}
        self._frames: set[str] = set()

    # ----------------------------------------------------------------- building
    @property
    def frames(self) -> frozenset[str]:
        """Every frame name the graph knows."""
        return frozenset(self._frames)

    def parent(self, frame: str) -> str | None:
        """The parent of ``frame``, or None for a root."""
        self._require_known(frame)
        return self._parent.get(frame)

    def children(self, frame: str) -> list[str]:
        """The direct children of ``frame``, sorted."""
        self._require_known(frame)
        return sorted(child for child, parent in self._parent.items() if parent == frame)

    def is_static(self, child: str) -> bool:
        """Whether the edge from ``child`` to its parent is static."""
        return child in self._static

    def stamped_edge(self, child: str) -> StampedEdge:
        """The time-stamped samples of the edge from ``child`` to its parent."""
        if child not in self._stamped:
            raise AvdataError(f"expected a time-stamped edge above frame {child!r}, got none")
        return self._stamped[child]

    def add_frame(self, frame: str) -> None:
        """Declares a frame that may have no edges yet (e.g. a root such as ``world``)."""
        _check_name(frame)
        self._frames.add(frame)

    def add_static(self, parent: str, child: str, parent_T_child: Transform) -> None:
        """Adds or replaces a static edge: the child's fixed pose in the parent."""
        if parent_T_child.shape != ():
            raise AvdataError(f"expected one static transform {parent}->{child}, got shape {parent_T_child.shape}")
        self._link(parent, child)
        if child in self._stamped:
            raise AvdataError(f"frame {child!r} already has a time-stamped edge to {parent!r}; cannot also be static")
        self._static[child] = parent_T_child

    def add_stamped(
        self, parent: str, child: str, timestamps_ns: np.ndarray, parent_T_child: Transform
    ) -> None:
        """Adds time-stamped samples of the child's pose in the parent (merged with earlier ones).

        Args:
            parent: parent frame name.
            child: child frame name.
            timestamps_ns: (T,) int64 times.
            parent_T_child: (T,) transforms, proper rotations.

        Raises:
            AvdataError: on shapes that disagree, non-finite values, or two different poses at one time.
        """
        timestamps_ns = np.atleast_1d(np.asarray(timestamps_ns, dtype=np.int64))
        if parent_T_child.shape == ():
            parent_T_child = Transform(rotation=parent_T_child.rotation[None], translation=parent_T_child.translation[None])
        if parent_T_child.shape != timestamps_ns.shape:
            raise AvdataError(
                f"expected {timestamps_ns.shape[0]} transforms for {parent}->{child}, got shape {parent_T_child.shape}"
            )
        if not (np.all(np.isfinite(parent_T_child.rotation)) and np.all(np.isfinite(parent_T_child.translation))):
            raise AvdataError(f"expected finite poses for {parent}->{child}, got NaN or inf")
        self._link(parent, child)
        if child in self._static:
            raise AvdataError(f"frame {child!r} already has a static edge to {parent!r}; cannot also be time-stamped")
        if child in self._stamped:
            old = self._stamped[child]
            timestamps_ns = np.concatenate([old.timestamps_ns, timestamps_ns])
            parent_T_child = Transform(
                rotation=np.concatenate([old.parent_T_child.rotation, parent_T_child.rotation]),
                translation=np.concatenate([old.parent_T_child.translation, parent_T_child.translation]),
            )
        order = np.argsort(timestamps_ns, kind="stable")
        timestamps_ns = timestamps_ns[order]
        parent_T_child = parent_T_child[order]
        duplicate = np.flatnonzero(np.diff(timestamps_ns) == 0)
        if duplicate.size:
            same = np.all(
                np.isclose(parent_T_child.rotation[duplicate], parent_T_child.rotation[duplicate + 1], atol=1e-12)
                .reshape(len(duplicate), -1), axis=1
            ) & np.all(
                np.isclose(parent_T_child.translation[duplicate], parent_T_child.translation[duplicate + 1], atol=1e-9),
                axis=1,
            )
            if not np.all(same):
                time_ns = int(timestamps_ns[duplicate[~same][0]])
                raise AvdataError(f"expected one pose of {child!r} in {parent!r} at {time_ns} ns, got two different ones")
            keep = np.ones(len(timestamps_ns), dtype=bool)
            keep[duplicate + 1] = False
            timestamps_ns = timestamps_ns[keep]
            parent_T_child = parent_T_child[keep]
        self._stamped[child] = StampedEdge(timestamps_ns=timestamps_ns, parent_T_child=parent_T_child)

    def _link(self, parent: str, child: str) -> None:
        _check_name(parent)
        _check_name(child)
        if parent == child:
            raise AvdataError(f"expected distinct parent and child, got {parent!r} twice")
        existing = self._parent.get(child)
        if existing is not None and existing != parent:
            raise AvdataError(f"frame {child!r} already has parent {existing!r}; cannot also hang under {parent!r}")
        ancestor: str | None = parent
        while ancestor is not None:
            if ancestor == child:
                raise AvdataError(f"adding {parent!r} -> {child!r} would close a loop in the frame tree")
            ancestor = self._parent.get(ancestor)
        self._parent[child] = parent
        self._frames.update((parent, child))

    # ----------------------------------------------------------------- queries
    def can_lookup(
        self, target: str, source: str, time_ns: int | np.ndarray | None = None, max_extrapolation_ns: int = 0
    ) -> bool:
        """Whether :meth:`lookup` would succeed with the same arguments."""
        try:
            self.lookup(target, source, time_ns, max_extrapolation_ns=max_extrapolation_ns)
        except AvdataError:
            return False
        return True

    def lookup(
        self,
        target: str,
        source: str,
        time_ns: int | np.ndarray | None = None,
        max_extrapolation_ns: int = 0,
    ) -> Transform:
        """``target_T_source`` at ``time_ns``: maps points in ``source`` into ``target``.

        Args:
            target: frame to express things in.
            source: frame the things are in now.
            time_ns: a time or (Q,) times in ns; may be None only if the path is all static.
            max_extrapolation_ns: how far outside a time-stamped edge's recorded range a query may
                fall; inside this tolerance the nearest sample is held.

        Returns:
            A single transform, or a (Q,) batch for an array of times.

        Raises:
            UnknownFrameError: a frame is not in the graph.
            ConnectivityError: the frames are in different trees.
            ExtrapolationError: a time lies outside an edge's samples beyond the tolerance.
        """
        self._require_known(target)
        self._require_known(source)
        times = None if time_ns is None else np.asarray(time_ns, dtype=np.int64)
        source_chain = self._chain_to_root(source)
        target_chain = self._chain_to_root(target)
        target_set = set(target_chain)
        common = next((frame for frame in source_chain if frame in target_set), None)
        if common is None:
            raise ConnectivityError(
                f"cannot look up {target!r} <- {source!r}: no common ancestor "
                f"({source!r} hangs under root {source_chain[-1]!r}, {target!r} under root {target_chain[-1]!r})"
            )
        common_T_source = self._chain_transform(source_chain, common, times, target, source, max_extrapolation_ns)
        common_T_target = self._chain_transform(target_chain, common, times, target, source, max_extrapolation_ns)
        return common_T_target.inverse() @ common_T_source

    def lookup_fixed(
        self,
        target: str,
        target_time_ns: int | np.ndarray,
        source: str,
        source_time_ns: int | np.ndarray,
        fixed: str = "world",
        max_extrapolation_ns: int = 0,
    ) -> Transform:
        """``target(target_time)_T_source(source_time)`` through a frame held still in between (tf2's fixed frame).

        Where something was in ``source`` at its own time, expressed in ``target`` at another: a cloud
        captured at its sensor's time, seen from the ego at the labels' time, with the ego's motion in
        between compensated. Equals ``lookup(target, fixed, target_time) @ lookup(fixed, source,
        source_time)``; where the two times are equal it is ``lookup(target, source, time)``, which
        needs no path through ``fixed``.

        Args:
            target: frame to express things in.
            target_time_ns: a time or (Q,) times of ``target``.
            source: frame the things are in.
            source_time_ns: a time or (Q,) times of ``source`` (broadcast against ``target_time_ns``).
            fixed: the frame assumed not to move between the two times (the scene's ``world``).
            max_extrapolation_ns: as for :meth:`lookup`.

        Returns:
            A single transform for two scalar times, else a batch of the broadcast shape.

        Raises:
            UnknownFrameError, ConnectivityError, ExtrapolationError: as :meth:`lookup` raises them.
        """
        target_times, source_times = np.broadcast_arrays(np.asarray(target_time_ns, dtype=np.int64),
                                                         np.asarray(source_time_ns, dtype=np.int64))
        same = target_times == source_times
        if same.all():
            return self.lookup(target, source, target_times, max_extrapolation_ns=max_extrapolation_ns)
        through = (self.lookup(target, fixed, target_times, max_extrapolation_ns=max_extrapolation_ns)
                   @ self.lookup(fixed, source, source_times, max_extrapolation_ns=max_extrapolation_ns))
        if not same.any():
            return through
        direct = self.lookup(target, source, target_times[same], max_extrapolation_ns=max_extrapolation_ns)
        rotation, translation = np.array(through.rotation), np.array(through.translation)
        rotation[same], translation[same] = direct.rotation, direct.translation
        return Transform(rotation=rotation, translation=translation)

    def _chain_to_root(self, frame: str) -> list[str]:
        chain = [frame]
        while chain[-1] in self._parent:
            chain.append(self._parent[chain[-1]])
        return chain

    def _chain_transform(
        self,
        chain: list[str],
        stop: str,
        times: np.ndarray | None,
        target: str,
        source: str,
        max_extrapolation_ns: int,
    ) -> Transform:
        batch = () if times is None else times.shape
        result = Transform.identity(batch)
        for child in chain:
            if child == stop:
                break
            edge = self._edge(child, times, target, source, max_extrapolation_ns)
            result = edge @ result
        return result

    def _edge(
        self, child: str, times: np.ndarray | None, target: str, source: str, max_extrapolation_ns: int
    ) -> Transform:
        if child in self._static:
            return self._static[child]
        edge = self._stamped[child]
        parent = self._parent[child]
        if times is None:
            raise ExtrapolationError(
                f"cannot look up {target!r} <- {source!r} without a time: edge {parent!r} -> {child!r} is time-stamped"
            )
        stamps = edge.timestamps_ns
        earliest, latest = int(stamps[0]), int(stamps[-1])
        too_early = times < earliest - max_extrapolation_ns
        too_late = times > latest + max_extrapolation_ns
        if np.any(too_early | too_late):
            bad = int(np.atleast_1d(times)[np.atleast_1d(too_early | too_late)][0])
            direction = "past" if bad < earliest else "future"
            raise ExtrapolationError(
                f"lookup {target!r} <- {source!r} would require extrapolation into the {direction} on edge "
                f"{parent!r} -> {child!r}: requested time {bad} ns, data covers [{earliest}, {latest}] ns "
                f"(tolerance {max_extrapolation_ns} ns)"
            )
        clamped = np.clip(times, earliest, latest)
        upper = np.clip(np.searchsorted(stamps, clamped, side="left"), 1, max(len(stamps) - 1, 1))
        if len(stamps) == 1:
            return edge.parent_T_child[np.zeros(clamped.shape, dtype=np.int64)]
        lower = upper - 1
        span = (stamps[upper] - stamps[lower]).astype(np.float64)
        fraction = (clamped - stamps[lower]).astype(np.float64) / span
        if np.all((fraction == 0.0) | (fraction == 1.0)):
            # Every query hits a recorded sample (the usual case: sensor times = pose times); skip slerp.
            return edge.parent_T_child[np.where(fraction == 1.0, upper, lower)]
        return edge.parent_T_child[lower].interpolate(edge.parent_T_child[upper], fraction)

    def _require_known(self, frame: str) -> None:
        if frame not in self._frames:
            known = ", ".join(sorted(self._frames)) or "none"
            raise UnknownFrameError(f"unknown frame {frame!r}; the graph holds: {known}")

    def edges(self) -> list[tuple[str, str, str]]:
        """(parent, child, "static" | "stamped") for every edge, sorted by child."""
        return [
            (self._parent[child], child, "static" if child in self._static else "stamped")
            for child in sorted(self._parent)
        ]

    def describe(self) -> str:
        """The tree as indented text, roots first, e.g. for ``avdata info``."""
        lines: list[str] = []
        roots = sorted(frame for frame in self._frames if frame not in self._parent)

        def walk(frame: str, depth: int) -> None:
            if frame in self._stamped:
                kind = f" (stamped, {len(self._stamped[frame].timestamps_ns)} samples)"
            elif frame in self._static:
                kind = " (static)"
            else:
                kind = ""
            lines.append("  " * depth + frame + kind)
            for child in self.children(frame):
                walk(child, depth + 1)

        for root in roots:
            walk(root, 0)
        return "\n".join(lines)


def _check_name(frame: str) -> None:
    if not isinstance(frame, str) or not frame or frame != frame.strip() or frame.startswith("/"):
        raise AvdataError(f"expected a frame name like 'ego/lidar_top', got {frame!r}")
