"""Tensor packing: every array of a batch of items in one buffer, clouds read and moved straight into it.

Every tensor of an item is a view of one buffer. Clouds are read from the scene's mapped file and moved
on the way into the buffer (one 4x4 per sensor, whatever the frame): each byte of a cloud is read once.
Inside a DataLoader worker the batch is assembled in memory the worker reuses, then written into a
fresh shared-memory file with ``writev``, so it crosses to the main process as one handle and is never
copied again; a cloud that needs no change is not assembled at all, ``writev`` takes it from the mapped
file (``benchmarks/loaders.py`` measures why this matters).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import torch
from torch.utils.data import get_worker_info

from avdata.frames import Transform
from avdata.loaders.options import agent_of
from avdata.loaders.transforms import is_identity
from avdata.schema.mcap.fileio import write_all

_XYZ = ("x", "y", "z")


_ALIGN = 64
_TORCH_DTYPES = {np.dtype(np.float32): torch.float32, np.dtype(np.float64): torch.float64,
                 np.dtype(np.int64): torch.int64, np.dtype(bool): torch.bool, np.dtype(np.uint8): torch.uint8}



@dataclass(frozen=True, slots=True, kw_only=True)
class SensorCloud:
    """One sensor's cloud of an item: its stored points and its pose in the item's frame.

    Attributes:
        sensor: the sensor frame.
        time_ns: the message time.
        stored: (N,) structured read-only view of the stored cloud (zero-copy into the mapped scene
            file when its chunk is uncompressed): the bytes the item's rows are made from.
        frame_T_sensor: the pose of the sensor in the item's frame.
    """

    sensor: str
    time_ns: int
    stored: np.ndarray
    frame_T_sensor: Transform


@dataclass(frozen=True, slots=True, kw_only=True)
class PendingCloud:
    """A cloud to write into the item's buffer: its sensors' clouds, the fields kept, the agents (fused only)."""

    members: list[SensorCloud]
    names: tuple[str, ...]
    agents: list[str] | None

    @property
    def fields(self) -> tuple[str, ...]:
        """The F field names of the rows written (``agent_index`` last in a fused cloud)."""
        return self.names + (("agent_index",) if self.agents is not None else ())

    @property
    def shape(self) -> tuple[int, int]:
        """(N, F): the points of every member, the fields."""
        return sum(len(member.stored) for member in self.members), len(self.fields)

    def fill(self, out: np.ndarray, noise_std_m: Mapping[str, float], seeds: Mapping[str, list[int]],
             scratch: Scratch, kept: list[tuple[np.ndarray, np.ndarray]] | None) -> None:
        """Writes the clouds into ``out`` (N, F): fields, point noise in the sensor frame, pose, agent index.

        A packed float32 cloud whose fields are exactly the rows' (KITTI's x, y, z, intensity) and that
        neither moves nor gets noise is its rows as stored: appended to ``kept`` as (rows, stored (N, F)
        float32) when the caller takes the bytes from there itself, else copied in. A moved cloud is
        moved from the stored bytes into its rows (:func:`_write_moved`); any other cloud is copied
        (:func:`_copy_fields`). Whether a pose moves anything and whether a cloud is packed are
        decided once per cloud, here.
        """
        start = 0
        for member in self.members:
            sensor, frame_T_sensor = member.sensor, member.frame_T_sensor
            rows = out[start : start + len(member.stored)]
            start += len(member.stored)
            noisy = noise_std_m.get(sensor, 0.0) > 0.0
            packed = _packed_float32(member.stored, self.names)
            moves = not is_identity(frame_T_sensor)
            if noisy:
                _copy_fields(member.stored, packed, self.names, rows)
                rng = np.random.default_rng(seeds[sensor])
                rows[:, :3] += rng.normal(0.0, noise_std_m[sensor], size=(len(rows), 3)).astype(np.float32)
                if moves:
                    transform_xyz_inplace(rows, frame_T_sensor)
            elif moves:
                _write_moved(member.stored, packed, self.names, rows, frame_T_sensor, scratch)
            elif packed is not None and rows.shape[1] == len(self.names) and kept is not None:
                kept.append((rows, packed))
            else:
                _copy_fields(member.stored, packed, self.names, rows)
            if self.agents is not None:
                rows[:, -1] = self.agents.index(agent_of(sensor))


class Scratch:
    """Process-local byte buffers reused from item to item (grown when too small, never shared).

    A fresh buffer costs a page fault per 4 KiB page on first write; these are paid once per process.
    """

    def __init__(self) -> None:
        self._buffers: dict[str, np.ndarray] = {}

    def take(self, name: str, nbytes: int) -> np.ndarray:
        """(nbytes,) uint8 view of the buffer ``name``, 64-byte aligned; its former contents are garbage."""
        buffer = self._buffers.get(name, np.empty(0, dtype=np.uint8))
        if len(buffer) < nbytes + _ALIGN:
            # A quarter more than asked: batches of varying size reallocate rarely.
            buffer = self._buffers[name] = np.empty(nbytes + nbytes // 4 + _ALIGN, dtype=np.uint8)
        skip = -buffer.ctypes.data % _ALIGN
        return buffer[skip : skip + nbytes]


@dataclass(frozen=True, slots=True, kw_only=True)
class Unpacked:
    """An item whose array leaves (and pending clouds) are not yet in a tensor buffer, with its point noise."""

    item: dict[str, Any]
    noise_std_m: Mapping[str, float]
    seeds: Mapping[str, list[int]]


def pack(unpacked: list[Unpacked], scratch: Scratch) -> list[dict[str, Any]]:
    """The items with every array leaf turned into a tensor view of one buffer, clouds written in place.

    One buffer for all of them: inside a DataLoader worker it is put in shared memory, so the items
    reach the main process as one handle (torch passes one file descriptor per storage, a per-handle
    cost that dominates small tensors) and are never copied again (torch moves any other tensor into
    shared memory when it leaves the worker: a further copy). In a worker the items are assembled in
    ``scratch``, except the clouds kept as stored and the fused ones, and then written into the shared
    memory (see :func:`_to_shared_memory`).
    """
    leaves: list[tuple[dict[str, Any], str, np.ndarray | PendingCloud, Unpacked]] = []
    for one in unpacked:
        _collect(one.item, one, leaves)
    offsets, total = [], 0
    for _, _, value, _ in leaves:
        if isinstance(value, PendingCloud):
            rows, width = value.shape
            nbytes = 4 * rows * width
        else:
            nbytes = value.nbytes
        offsets.append((total, nbytes))
        total += -(-nbytes // _ALIGN) * _ALIGN
    in_worker = get_worker_info() is not None
    if in_worker:
        target = scratch.take("batch", total)
    else:
        buffer = torch.empty(total, dtype=torch.uint8)
        target = buffer.numpy()
    kept: list[tuple[np.ndarray, np.ndarray]] | None = [] if in_worker else None
    streamed: list[tuple[int, PendingCloud, Unpacked]] = []
    for (_, _, value, owner), (offset, nbytes) in zip(leaves, offsets, strict=True):
        array = target[offset : offset + nbytes].view(
            np.float32 if isinstance(value, PendingCloud) else value.dtype).reshape(value.shape)
        if isinstance(value, PendingCloud) and in_worker and len(value.members) > 1:
            streamed.append((offset, value, owner))  # written sensor by sensor by _to_shared_memory
        elif isinstance(value, PendingCloud):
            value.fill(array, owner.noise_std_m, owner.seeds, scratch, kept)
        else:
            array[...] = value
    if in_worker:
        holes = [(offset, 4 * cloud.shape[0] * cloud.shape[1]) for offset, cloud, _ in streamed]
        buffer = _to_shared_memory(_runs(target, kept or [], holes), total, streamed, scratch)
    for (node, key, value, _), (offset, nbytes) in zip(leaves, offsets, strict=True):
        dtype = torch.float32 if isinstance(value, PendingCloud) else _TORCH_DTYPES[value.dtype]
        node[key] = buffer[offset : offset + nbytes].view(dtype).view(value.shape)
    return [one.item for one in unpacked]


def _collect(node: dict[str, Any], owner: Unpacked,
             leaves: list[tuple[dict[str, Any], str, np.ndarray | PendingCloud, Unpacked]]) -> None:
    """Appends (dict, key, value, owner) of every array or pending cloud in ``node`` and its nested dicts to ``leaves``.

    A module-level function, not a closure over ``leaves``: a recursive closure is a reference cycle,
    which would keep the batch (its shared memory too) alive until the garbage collector runs.
    """
    for key, value in node.items():
        if isinstance(value, dict):
            _collect(value, owner, leaves)
        elif isinstance(value, (np.ndarray, PendingCloud)):
            leaves.append((node, key, value, owner))


def _runs(batch: np.ndarray, kept: list[tuple[np.ndarray, np.ndarray]],
          holes: list[tuple[int, int]]) -> list[tuple[int, list[np.ndarray]]]:
    """The bytes of ``batch`` (B,) uint8 to write, as (offset, consecutive pieces) runs.

    Its own bytes, except where rows were kept as stored (``kept``: (rows, stored) pairs, rows views
    of ``batch``), whose bytes come from ``stored``, so a cloud that needs no change is copied once,
    by the kernel, from the mapped scene file into shared memory; and except ``holes`` ((offset,
    bytes) written elsewhere), which end a run.
    """
    events = sorted([(rows.ctypes.data - batch.ctypes.data, rows.nbytes, stored) for rows, stored in kept]
                    + [(offset, nbytes, None) for offset, nbytes in holes], key=lambda event: event[0])
    runs: list[tuple[int, list[np.ndarray]]] = []
    run_start = done = 0
    pieces: list[np.ndarray] = []
    for start, nbytes, stored in events:
        pieces.append(batch[done:start])
        if stored is None:
            runs.append((run_start, pieces))
            run_start, pieces = start + nbytes, []
        else:
            pieces.append(stored.reshape(-1).view(np.uint8))
        done = start + nbytes
    pieces.append(batch[done:])
    runs.append((run_start, pieces))
    runs = [(offset, [piece for piece in run if piece.nbytes]) for offset, run in runs]
    return [(offset, run) for offset, run in runs if run]


def _to_shared_memory(runs: list[tuple[int, list[np.ndarray]]], total: int,
                      streamed: list[tuple[int, PendingCloud, Unpacked]], scratch: Scratch) -> torch.Tensor:
    """(B,) uint8 tensor in shared memory (B = ``total`` bytes): ``runs`` ((offset, 1-D uint8 pieces)), then ``streamed``.

    ``streamed`` holds (offset, cloud, owner) of clouds of several sensors (fused): their rows are not
    in ``runs`` and are written here one sensor at a time from ``scratch``, while still in the CPU's
    cache (a fused batch is many times the cache's size).

    With torch's default ``file_descriptor`` sharing on Linux the bytes go into a fresh ``memfd`` with
    ``writev`` (a ``pwrite`` per fused sensor) and the storage maps that file: the kernel fills the
    pages as it allocates them.
    Writing through a mapping instead costs a page fault per 4 KiB page, and torch's own
    ``UntypedStorage._new_shared`` also zero-fills every page first (``benchmarks/loaders.py`` measures
    the difference on KITTI-sized clouds). Another sharing strategy gets
    torch's own shared storage (which the strategy can pass on), filled through its mapping.
    """
    if not total:
        return torch.empty(0, dtype=torch.uint8)  # torch sends empty storages without shared memory
    # torch leaves these two unannotated
    strategy = torch.multiprocessing.get_sharing_strategy()  # type: ignore[no-untyped-call]  # torch leaves it unannotated
    if not hasattr(os, "memfd_create") or strategy != "file_descriptor":
        storage = torch.UntypedStorage._new_shared(total)  # type: ignore[no-untyped-call]  # torch leaves it unannotated
        buffer = torch.empty(0, dtype=torch.uint8).set_(storage)
        target = buffer.numpy()
        for offset, pieces in runs:
            for piece in pieces:
                target[offset : offset + piece.nbytes] = piece
                offset += piece.nbytes
        for offset, cloud, owner in streamed:
            rows, width = cloud.shape
            array = target[offset : offset + 4 * rows * width].view(np.float32).reshape(rows, width)
            cloud.fill(array, owner.noise_std_m, owner.seeds, scratch, None)
        return buffer
    fd = os.memfd_create("avdata-items", os.MFD_CLOEXEC)
    try:
        os.ftruncate(fd, total)
        for offset, pieces in runs:
            os.lseek(fd, offset, os.SEEK_SET)
            write_all(fd, [piece.data for piece in pieces], sum(piece.nbytes for piece in pieces))
        for offset, cloud, owner in streamed:
            for member in cloud.members:
                part = PendingCloud(members=[member], names=cloud.names, agents=cloud.agents)
                rows, width = part.shape
                array = scratch.take("rows", 4 * rows * width).view(np.float32).reshape(rows, width)
                part.fill(array, owner.noise_std_m, owner.seeds, scratch, None)
                _pwrite_all(fd, array, offset)
                offset += array.nbytes
        # torch's own receiving side (rebuild_storage_fd) builds its storage the same way; it maps a duplicate of fd
        storage = torch.UntypedStorage._new_shared_fd_cpu(fd, total)  # type: ignore[attr-defined]  # private torch API, not in torch's annotations
    finally:
        os.close(fd)
    return torch.empty(0, dtype=torch.uint8).set_(storage)


def _pwrite_all(fd: int, array: np.ndarray, offset: int) -> None:
    """Writes the bytes of a C-contiguous ``array`` at ``offset`` of ``fd``, continuing after short writes."""
    data = array.reshape(-1).view(np.uint8).data
    written = 0
    while written < len(data):
        written += os.pwrite(fd, data[written:], offset + written)


def _write_moved(cloud: np.ndarray, packed: np.ndarray | None, names: tuple[str, ...], out: np.ndarray,
                 target_T_sensor: Transform, scratch: Scratch) -> None:
    """Writes fields ``names`` of a stored cloud (N,) into the first columns of ``out`` (N, F), x, y, z moved.

    ``packed`` is the cloud's (N, len(names)) float32 view (:func:`_packed_float32`), None if it has none.
    A packed float32 cloud of at most 4 fields is moved by one ``cv2.transform`` pass from where it
    is stored: straight into ``out`` when the widths agree, else into ``scratch`` and then copied in
    (OpenCV would write rows of another width one call per row); other clouds are copied, then moved
    in place.
    """
    if packed is None or len(names) > 4:
        _copy_fields(cloud, packed, names, out)
        transform_xyz_inplace(out, target_T_sensor)
    elif out.shape[1] == len(names):
        transform_xyz_inplace(packed, target_T_sensor, out=out)
    else:
        moved = scratch.take("cloud", packed.nbytes).view(np.float32).reshape(packed.shape)
        transform_xyz_inplace(packed, target_T_sensor, out=moved)
        _copy_columns(moved, out)


def _copy_fields(cloud: np.ndarray, packed: np.ndarray | None, names: tuple[str, ...], out: np.ndarray) -> None:
    """Writes fields ``names`` of a structured cloud (N,) into the first columns of ``out`` (N, F) as float32.

    ``packed`` is the cloud's (N, len(names)) float32 view, None if it has none.
    """
    if packed is not None:
        _copy_columns(packed, out)
        return
    for i, name in enumerate(names):
        out[:, i] = cloud[name]


def _copy_columns(packed: np.ndarray, out: np.ndarray) -> None:
    """Writes rows (N, F) into the first F columns of ``out`` (N, G), both C-contiguous float32.

    Rows wider than the source (fused clouds: F = 4 fields and an agent index) are copied as one
    field of F * 4 bytes of a structured view of ``out``: one strided copy of whole rows, cheaper
    than OpenCV's ``mixChannels`` or numpy's column slice (which copy channel by channel).
    """
    n_fields, width = packed.shape[1], out.shape[1]
    if n_fields == width:
        np.copyto(out, packed)
    elif len(packed):
        head = np.dtype((np.void, 4 * n_fields))
        rows = out.view(np.dtype([("head", head), ("tail", np.void, 4 * (width - n_fields))])).reshape(-1)
        rows["head"] = packed.view(head).reshape(-1)


def _packed_float32(cloud: np.ndarray, names: tuple[str, ...]) -> np.ndarray | None:
    """(N, F) float32 view of a structured cloud whose fields are exactly ``names``, packed float32; else None."""
    fields: Mapping[str, Any] = cloud.dtype.fields or {}
    packed = cloud.dtype.itemsize == 4 * len(names) and all(
        name in fields and fields[name][0] == np.dtype("<f4") and fields[name][1] == 4 * i for i, name in enumerate(names)
    )
    if not packed or not cloud.flags.c_contiguous:
        return None
    return cloud.view(np.float32).reshape(len(cloud), len(names))


def common_fields(clouds: Iterable[np.ndarray]) -> tuple[str, ...]:
    """The fields every cloud has, in the first cloud's order (x, y, z at least)."""
    names = [tuple(cloud.dtype.names or ()) for cloud in clouds]
    if not names:
        return _XYZ
    return tuple(name for name in names[0] if all(name in other for other in names[1:]))


def transform_xyz_inplace(array: np.ndarray, target_T_source: Transform, out: np.ndarray | None = None) -> None:
    """Moves the x, y, z columns of ``array`` (N, F) float32 into the target frame, in place or into ``out`` (N, F).

    One pass of OpenCV's ``cv2.transform`` (SIMD, one (F, F + 1) matrix acting on each row) when the
    rows are contiguous and F <= 4 (OpenCV's channel limit), faster than column-wise numpy.
    Otherwise element-wise float32 arithmetic, column by column: an (N, 3) @ (3, 3) product would go
    to BLAS, whose threads oversubscribe the CPU when several DataLoader workers each run one.
    Callers skip the identity (e.g. KITTI's ego = velodyne): it moves nothing.
    """
    target = array if out is None else out
    n_fields = array.shape[1]
    if n_fields <= 4 and array.flags.c_contiguous and target.flags.c_contiguous and len(array):
        rows = target.reshape(-1, 1, n_fields)
        moved = cv2.transform(array.reshape(-1, 1, n_fields), _affine(target_T_source, n_fields), dst=rows)
        if moved is not rows:  # OpenCV allocated instead of writing in place
            rows[...] = moved
        return
    if out is not None:
        np.copyto(out, array)
    rotation = target_T_source.rotation.astype(np.float32)
    translation = target_T_source.translation.astype(np.float32)
    columns = [np.ascontiguousarray(target[:, j]) for j in range(3)]
    for i in range(3):
        row = columns[0] * rotation[i, 0]
        row += columns[1] * rotation[i, 1]
        row += columns[2] * rotation[i, 2]
        row += translation[i]
        target[:, i] = row


def _affine(target_T_source: Transform, n_fields: int) -> np.ndarray:
    """(F, F + 1) matrix moving x, y, z by ``target_T_source`` and keeping the other F - 3 fields."""
    matrix = np.eye(n_fields, n_fields + 1)
    matrix[:3, :3] = target_T_source.rotation
    matrix[:3, n_fields] = target_T_source.translation
    return matrix

