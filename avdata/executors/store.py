"""A dataset written to an object store (``s3://``, ``gs://``) under the same trust rules as on a disk.

A store has no rename and no ``flock``, so each rule has its store form:

- **Whole objects or none.** A scene is written to a local file first (as on a disk), then uploaded to a
  temporary key of the one naming scheme (:func:`avdata.outputs.temporary_path`: ``scenes/.<name>.<pid>.<random>.tmp``),
  copied server-side to its final key and the temporary key deleted (:func:`publish`). A copy is atomic on S3 and
  GCS: a reader sees the old object or the new one, never part of one. A run killed between the upload and the
  delete leaves a temporary key, which the next run deletes under the lock (:func:`remove_temporary_keys`);
  an upload cut short ends under its temporary key or as an unfinished multipart upload, invisible under every
  key (a bucket lifecycle rule reclaims its parts): never under the final key.
- **The manifest last.** The driver builds the index and manifest in a local staging folder from the scene objects,
  fetched one at a time (:class:`StoreScenes`), then uploads the index tables, ``errors.jsonl`` and the manifest,
  in that order (:func:`upload_outputs`).
- **Honest resume.** A scene's fingerprint is read from its object by ranged reads of the MCAP summary and the
  metadata record (:func:`recorded_fingerprint`), never the whole scene.
- **One writer.** ``DST/.avdata.lock`` is created by a conditional PUT that fails when the key exists
  (:func:`store_lock`): S3 ``If-None-Match: *`` (through botocore, the ``s3`` extra), GCS
  ``ifGenerationMatch=0`` (through google-cloud-storage). It names the holder's host and PID; a lock left by a
  killed run on this host (its PID gone) is taken over, one left from another host is deleted by hand (the
  message names it).
"""

from __future__ import annotations

import fnmatch
import json
import os
import secrets
import socket
import tempfile
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from avdata.errors import InputError, OutputError, one_line
from avdata.outputs import TEMPORARY_GLOB, temporary_path
from avdata.storage import FILE, Location, gcs_options, s3_options, scrub

LOCK_NAME = ".avdata.lock"


def temporary_key(target: Location) -> Location:
    """The temporary key ``target`` is uploaded under before its copy (:func:`avdata.outputs.temporary_path`)."""
    return target.with_name(temporary_path(Path(target.name)).name)


#: S3's ``CopyObject`` copies at most 5 GiB; a larger object is copied part by part (``UploadPartCopy``).
S3_COPY_LIMIT_BYTES = 5 * 1024**3
#: Part size of such a copy: 10,000 parts (S3's most) of 512 MiB reach 5 TiB, S3's largest object.
S3_COPY_PART_BYTES = 512 * 1024**2


def publish(local: Path, target: Location) -> None:
    """Puts the complete local file ``local`` under ``target``: upload to a temporary key, server-side copy, delete.

    On S3 an object above :data:`S3_COPY_LIMIT_BYTES` is copied as a multipart upload of server-side part copies;
    it appears under ``target`` only when ``CompleteMultipartUpload`` succeeds, as a single copy's would.

    Raises:
        OutputError: the store refused a step (the temporary key is deleted; the final key is untouched).
    """
    staged = temporary_key(target)
    try:
        staged.upload(local)
        if target.scheme == "s3" and local.stat().st_size > S3_COPY_LIMIT_BYTES:
            _copy_in_parts(staged, target, S3_COPY_PART_BYTES)
        else:
            staged.copy_to(target)
    finally:
        staged.delete()


def publish_bytes(data: bytes, target: Location) -> None:
    """Puts ``data`` under ``target`` as :func:`publish` puts a file: a temporary key, a server-side copy, a delete."""
    staged = temporary_key(target)
    try:
        staged.write_bytes(data)
        staged.copy_to(target)
    finally:
        staged.delete()


def _copy_in_parts(source: Location, target: Location, part_bytes: int) -> None:
    """A server-side multipart copy on S3 (boto3's managed copy: ``UploadPartCopy`` of ``part_bytes`` each)."""
    from boto3.s3.transfer import TransferConfig
    from botocore.exceptions import BotoCoreError, ClientError

    config = TransferConfig(multipart_threshold=1, multipart_chunksize=part_bytes, use_threads=False)
    source_key, target_key = source.path.split("/", 1)[1], target.path.split("/", 1)[1]
    try:
        _s3_client().copy({"Bucket": source.bucket, "Key": source_key}, target.bucket, target_key, Config=config)
    except (BotoCoreError, ClientError) as error:
        raise OutputError(f"{target.uri}: cannot copy {source.uri} there ({scrub(one_line(error))})") from None


def remove_temporary_keys(root: Location) -> None:
    """Deletes the temporary keys an interrupted run left anywhere under ``root`` (only safe under its lock)."""
    for relative, info in root.listing(recursive=True).items():
        if info.kind == FILE and fnmatch.fnmatch(relative.rsplit("/", 1)[-1], TEMPORARY_GLOB):
            root.join(relative).delete()


def scene_names(root: Location) -> list[str]:
    """The names of the scene objects under ``root/scenes``."""
    return sorted(name[:-len(".mcap")] for name, info in (root / "scenes").listing().items()
                  if info.kind == FILE and name.endswith(".mcap") and not name.startswith("."))


def remove_stale_scenes(root: Location, keep: Iterable[str]) -> list[str]:
    """Deletes the scene objects of ``root`` this run does not produce (as on a disk)."""
    removed = [name for name in scene_names(root) if name not in set(keep)]
    for name in removed:
        (root / "scenes" / f"{name}.mcap").delete()
    return removed


def recorded_fingerprint(target: Location, key: str) -> dict[str, Any] | None:
    """The scene metadata's ``key`` of the scene object ``target``, by ranged reads; None if absent or unreadable.

    Reads the footer (with the summary when it is in the last 64 KiB), the summary, and the metadata record:
    two or three requests, whatever the scene's size. The summary CRC is checked as the local reader does.
    """
    from avdata.schema import topics
    from avdata.schema.mcap.checksum import crc32
    from avdata.schema.mcap.records import (
        FOOTER,
        MAGIC,
        RECORD_PREFIX,
        MetadataIndexRecord,
        MetadataRecord,
        Opcode,
        RecordError,
        decode_record,
    )

    try:
        if not target.is_file():
            return None
        with target.open_input() as stream:
            size = stream.size()
            tail_size = min(size, 1 << 16)
            tail = stream.read_at(tail_size, size - tail_size)
            if size < 2 * len(MAGIC) + FOOTER.size or tail[-len(MAGIC):] != MAGIC:
                return None
            footer_offset = size - len(MAGIC) - FOOTER.size
            _, _, summary_start, summary_offset_start, summary_crc = FOOTER.unpack_from(tail, footer_offset - (size - tail_size))
            if not len(MAGIC) < summary_start <= summary_offset_start <= footer_offset:
                return None
            if summary_start < size - tail_size:
                tail = stream.read_at(size - summary_start, summary_start)
            summary = memoryview(tail)[summary_start - (size - len(tail)):]
            if crc32(summary[: footer_offset + FOOTER.size - 4 - summary_start]) != summary_crc:
                return None
            position, end = 0, summary_offset_start - summary_start
            while position + RECORD_PREFIX.size <= end:
                opcode, length = RECORD_PREFIX.unpack_from(summary, position)
                body = summary[position + RECORD_PREFIX.size: position + RECORD_PREFIX.size + length]
                position += RECORD_PREFIX.size + length
                if opcode != Opcode.METADATA_INDEX:
                    continue
                located = decode_record(MetadataIndexRecord, body)
                if located.name != topics.SCENE_METADATA:
                    continue
                record = stream.read_at(located.length, located.offset)
                metadata = decode_record(MetadataRecord, memoryview(record)[RECORD_PREFIX.size:]).metadata
                value = json.loads(metadata["json"]).get(key)
                return value if isinstance(value, dict) else None
    except (InputError, OSError, RecordError, KeyError, ValueError, AttributeError):
        return None
    return None


# ----------------------------------------------------------------------------------------------- the lock
def _lock_text() -> str:
    return json.dumps({"host": socket.gethostname(), "pid": os.getpid(), "token": secrets.token_hex(8),
                       "since": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}, sort_keys=True)


def _s3_client() -> Any:
    try:
        import boto3
    except ImportError:
        raise InputError("s3://: the writer lock of a dataset on S3 needs botocore: pip install 'avdata[s3]'") from None
    options = s3_options(os.environ)
    endpoint = f"{options['scheme']}://{options['endpoint_override']}" if "endpoint_override" in options else None
    return boto3.client("s3", endpoint_url=endpoint, region_name=options.get("region"))


def _gcs_client(storage: Any) -> Any:
    """A client of ``google.cloud.storage`` (the module) reaching the store pyarrow's ``GcsFileSystem`` reaches.

    With ``STORAGE_EMULATOR_HOST``: the endpoint :func:`gcs_options` reads from it (a bare ``host:port`` is http, as
    for pyarrow; google-cloud-storage alone would take it for a URL), anonymous. Otherwise the default client:
    application default credentials, as Arrow's client reads them.
    """
    options = gcs_options(os.environ)
    if "endpoint_override" not in options:
        return storage.Client()
    from google.auth.credentials import AnonymousCredentials

    return storage.Client(project=options.get("project_id"), credentials=AnonymousCredentials(),
                          client_options={"api_endpoint": f"{options['scheme']}://{options['endpoint_override']}"})


def create_exclusively(target: Location, text: str) -> bool:
    """Creates the object ``target`` holding ``text`` unless it exists (one conditional PUT); whether it did.

    S3: ``PutObject`` with ``If-None-Match: *`` (412 when the key exists). GCS: an upload with
    ``ifGenerationMatch=0``. A local path: ``O_CREAT | O_EXCL``.
    """
    if target.is_local:
        try:
            fd = os.open(target.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            return False
        with os.fdopen(fd, "w") as stream:
            stream.write(text)
        return True
    bucket, _, key = target.path.partition("/")
    if target.scheme == "s3":
        from botocore.exceptions import BotoCoreError, ClientError

        try:
            _s3_client().put_object(Bucket=bucket, Key=key, Body=text.encode(), IfNoneMatch="*")
        except ClientError as error:
            if error.response.get("Error", {}).get("Code") in ("PreconditionFailed", "ConditionalRequestConflict", "412"):
                return False
            raise OutputError(f"{target}: cannot create the writer lock ({scrub(one_line(error))})") from None
        except BotoCoreError as error:
            raise OutputError(f"{target}: cannot create the writer lock ({scrub(one_line(error))})") from None
        return True
    try:
        from google.api_core.exceptions import GoogleAPIError, PreconditionFailed
        from google.auth.exceptions import GoogleAuthError
        from google.cloud import storage
    except ImportError:
        raise InputError(f"{target}: the writer lock of a dataset on GCS needs google-cloud-storage: "
                         "pip install 'avdata[gcs]'") from None
    try:
        _gcs_client(storage).bucket(bucket).blob(key).upload_from_string(text, if_generation_match=0)
    except PreconditionFailed:
        return False
    except (GoogleAPIError, GoogleAuthError, OSError) as error:  # a refused request, no credentials, no connection
        raise OutputError(f"{target}: cannot create the writer lock ({scrub(one_line(error))})") from None
    return True


def _holder(lock: Location) -> dict[str, Any]:
    try:
        found = json.loads(lock.read_bytes(4096))
    except (InputError, ValueError):
        return {}
    return found if isinstance(found, dict) else {}


def _gone(holder: dict[str, Any]) -> bool:
    """Whether the lock's holder was a process of this host that no longer runs."""
    if holder.get("host") != socket.gethostname() or not isinstance(holder.get("pid"), int):
        return False
    try:
        os.kill(holder["pid"], 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


@contextmanager
def store_lock(root: Location) -> Iterator[None]:
    """Holds ``root``'s writer lock object for the ``with`` block (see the module docstring).

    Raises:
        InputError: another avdata process holds it (the message names its host, PID and start, and the key to
            delete if that process is gone).
    """
    lock = root / LOCK_NAME
    text = _lock_text()
    if not create_exclusively(lock, text):
        holder = _holder(lock)
        if not _gone(holder):
            raise InputError(f"{root}: another avdata process (PID {holder.get('pid', 'unknown')} on host "
                             f"{holder.get('host', 'unknown')}, since {holder.get('since', 'unknown')}) is writing "
                             f"this dataset; wait for it to end or stop it (if it was killed, delete {lock})")
        lock.delete()  # a killed run of this host: its PID is gone
        if not create_exclusively(lock, text):
            raise InputError(f"{root}: another avdata process took the writer lock {lock} meanwhile")
    try:
        yield
    finally:
        if _holder(lock).get("token") == json.loads(text)["token"]:
            lock.delete()


# ----------------------------------------------------------------------------------------------- staging
@contextmanager
def staging_folder() -> Iterator[Path]:
    """A local folder where the driver builds the index and manifest of a dataset in a store."""
    with tempfile.TemporaryDirectory(prefix="avdata-staging-") as folder:
        yield Path(folder)


class StoreScenes:
    """The scene objects of a dataset in a store, fetched one at a time into the staging folder for the index.

    The local disk holds one scene at a time, whatever the dataset's size.
    """

    def __init__(self, root: Location, staging: Path):
        self.root = root
        self.staging = staging

    def names(self) -> list[str]:
        """The names of the scene objects (only complete scenes ever have a final key)."""
        return scene_names(self.root)

    @contextmanager
    def fetched(self, name: str) -> Iterator[Path]:
        """Scene ``name`` downloaded into the staging folder for the ``with`` block."""
        path = self.staging / "scenes" / f"{name}.mcap"
        (self.root / "scenes" / f"{name}.mcap").download(path)
        try:
            yield path
        finally:
            path.unlink(missing_ok=True)


def mirror_state(root: Location, staging: Path, names: Iterable[str]) -> None:
    """Copies the small files ``names`` (manifest, ``errors.jsonl``) of ``root`` into ``staging`` if present."""
    for name in names:
        if (root / name).is_file():
            (root / name).download(staging / name)


def upload_outputs(staging: Path, root: Location, index_tables: Iterable[str], log_name: str,
                   manifest: str | None) -> None:
    """Uploads the index tables, the problem log (deleted when the run has none) and the manifest (if any) last."""
    for name in index_tables:
        publish(staging / "index" / f"{name}.parquet", root / "index" / f"{name}.parquet")
    if (staging / log_name).is_file():
        publish(staging / log_name, root / log_name)
    else:
        (root / log_name).delete()
    if manifest is not None:
        publish(staging / manifest, root / manifest)
