"""Where data lives: plain paths, ``file://``, ``s3://bucket/prefix`` and ``gs://bucket/prefix``, through ``pyarrow.fs``.

# Interface

- :func:`location` ``(uri) -> Location``: any path or URI as a :class:`Location` (a frozen dataclass):
  ``fs`` (a ``pyarrow.fs.FileSystem``), ``path`` (that filesystem's path: an absolute local path, or
  ``bucket/key``), ``uri`` (what messages show: the path as given for local files, ``s3://bucket/key``
  otherwise; never credentials). ``loc / "a" / "b"`` and :meth:`Location.join` append parts,
  :attr:`Location.parent`, :attr:`Location.name`, :attr:`Location.suffix`, :attr:`Location.stem` as in
  ``pathlib``; :attr:`Location.is_local` and :attr:`Location.local_path` (a ``Path``, None on a store).
  ``str(loc)`` is its ``uri``; a Location pickles as its URI (a worker builds its own filesystem from its own
  environment, so no credential travels with a task).
- :func:`is_remote` ``(uri) -> bool``: whether a string or path names an object store (``s3://``, ``gs://``).
- :func:`path_or_location` ``(uri) -> Path | Location``: a ``Path`` for local paths (every local reader keeps
  its ``os``-level code), a :class:`Location` on a store. Converters' ``SRC``/``DST`` are this.
- On a Location: :meth:`~Location.exists`, :meth:`~Location.is_file`, :meth:`~Location.is_dir`,
  :meth:`~Location.size`, :meth:`~Location.iterdir`, :meth:`~Location.read_bytes` (whole object),
  :meth:`~Location.open_input` (a seekable ``pyarrow.NativeFile``: ranged reads), :meth:`~Location.write_bytes`,
  :meth:`~Location.upload` (a local file), :meth:`~Location.download` (to a local file),
  :meth:`~Location.copy_to` (server-side), :meth:`~Location.delete`, :meth:`~Location.listing` (one request per
  1000 objects); they raise
  :class:`~avdata.errors.InputError` / :class:`~avdata.errors.OutputError` with one line naming the URI.
- :func:`filesystem` ``(scheme, bucket)``: the process's one filesystem object per (scheme, bucket) (cached).
- :func:`s3_options` / :func:`gcs_options` ``(environ)``: the constructor options taken from the environment
  (for tests and docs: nothing else feeds them).
- :func:`scrub` ``(text)``: ``text`` with the credential values of the environment replaced by ``***``.
- :data:`SMALL_OBJECT_BYTES`: the size up to which source readers fetch a columnar object whole.
- :func:`read_range` ``(stream, size, offset) -> pyarrow.Buffer``: one ranged read in Arrow-owned memory, for
  bytes that pyarrow goes on to parse.

Credentials and endpoints come only from each store's standard environment and configuration, never from
command-line arguments:

- S3: the AWS SDK's default chain (``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``, ``AWS_SESSION_TOKEN``,
  ``AWS_PROFILE`` and ``~/.aws``, instance roles); ``AWS_REGION`` (or ``AWS_DEFAULT_REGION``); an endpoint
  override (MinIO, Ceph, a test server) from ``AWS_ENDPOINT_URL_S3`` or ``AWS_ENDPOINT_URL``, as the AWS CLI
  and SDKs read them.
- GCS: Google's application default credentials (``GOOGLE_APPLICATION_CREDENTIALS``, ``gcloud auth
  application-default login``, the metadata server); ``STORAGE_EMULATOR_HOST`` points at an emulator
  (anonymous, over http), as Google's client libraries read it.

A URI holding credentials (``s3://KEY:SECRET@bucket/...``) is refused with one line that does not repeat them.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

from avdata.errors import InputError, OutputError, one_line

if TYPE_CHECKING:  # pyarrow is imported at first use: ``avdata --help`` and local-only commands do not pay for it
    import pyarrow as pa
    import pyarrow.fs as pafs

#: What :meth:`Location.info` finds: an object (file), a prefix holding objects (folder), or nothing.
FILE, FOLDER, MISSING = "file", "folder", "missing"


@dataclass(frozen=True)
class ObjectInfo:
    """What is at a location: ``kind`` (:data:`FILE`, :data:`FOLDER`, :data:`MISSING`), size and mtime of a file."""

    kind: str
    size: int = 0
    mtime_ns: int = 0

#: A columnar source object (Parquet, feather) up to this size is fetched whole in one request: finding its columns
#: first takes a request for its footer (pyarrow's first read of a Parquet footer is the last 64 KiB, all of such an
#: object), then one per column read.
SMALL_OBJECT_BYTES = 64 << 10

#: URI schemes of the object stores avdata reads and writes.
STORE_SCHEMES = ("s3", "gs")

#: Environment variables whose values are secrets: never printed (see :func:`scrub`).
SECRET_VARIABLES = ("AWS_SECRET_ACCESS_KEY", "AWS_SESSION_TOKEN", "AWS_ACCESS_KEY_ID")


def scrub(text: str) -> str:
    """``text`` with the value of every credential variable of the environment replaced by ``***``.

    Messages never include credentials on purpose; this covers a library's error text that might.
    """
    for name in SECRET_VARIABLES:
        value = os.environ.get(name)
        if value and len(value) >= 4:
            text = text.replace(value, "***")
    return text


def read_range(stream: pa.NativeFile, size: int, offset: int) -> pa.Buffer:
    """``size`` bytes at ``offset`` of ``stream`` (one ranged request on a store), in Arrow-owned memory.

    For bytes that pyarrow parses: ``read_at`` gives Python bytes, and an Arrow pool worker that drops the last
    reference to those after the read returned takes the GIL, which during interpreter exit aborts the process
    (docs/decisions.md, "Arrow's thread pools never hold Python memory").
    """
    stream.seek(offset)
    return stream.read_buffer(size)


def is_remote(uri: str | os.PathLike[str]) -> bool:
    """Whether ``uri`` names an object in a store (``s3://`` or ``gs://``), not a local path."""
    return isinstance(uri, Location) and not uri.is_local or (
        isinstance(uri, str) and uri.split("://", 1)[0].lower() in STORE_SCHEMES and "://" in uri)


def _endpoint(url: str, variable: str) -> tuple[str, str]:
    """(``host[:port]``, scheme) of an endpoint URL given in ``variable``."""
    parts = urlsplit(url if "://" in url else f"http://{url}")
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise InputError(f"{variable}: expected an endpoint URL such as http://127.0.0.1:9000, got {url!r}")
    if parts.username or parts.password:
        raise InputError(f"{variable}: expected an endpoint URL without credentials (use the store's credential "
                         "variables or configuration)")
    return parts.netloc, parts.scheme


def s3_options(environ: Mapping[str, str]) -> dict[str, Any]:
    """Options of ``pyarrow.fs.S3FileSystem`` from the environment: region and endpoint override only.

    Credentials are left to the AWS SDK's default chain (environment, ``AWS_PROFILE`` and ``~/.aws``, instance
    role), so they never pass through avdata's arguments.
    """
    options: dict[str, Any] = {}
    region = environ.get("AWS_REGION") or environ.get("AWS_DEFAULT_REGION")
    if region:
        options["region"] = region
    for variable in ("AWS_ENDPOINT_URL_S3", "AWS_ENDPOINT_URL"):
        if environ.get(variable):
            options["endpoint_override"], options["scheme"] = _endpoint(environ[variable], variable)
            break
    return options


def gcs_options(environ: Mapping[str, str]) -> dict[str, Any]:
    """Options of ``pyarrow.fs.GcsFileSystem`` from the environment.

    ``STORAGE_EMULATOR_HOST`` (an emulator such as fake-gcs-server): that endpoint, anonymous. Otherwise Google's
    application default credentials (``GOOGLE_APPLICATION_CREDENTIALS`` ...), which Arrow's GCS client reads
    itself; ``GOOGLE_CLOUD_PROJECT`` sets the project.
    """
    options: dict[str, Any] = {}
    emulator = environ.get("STORAGE_EMULATOR_HOST")
    if emulator:
        options["endpoint_override"], options["scheme"] = _endpoint(emulator, "STORAGE_EMULATOR_HOST")
        options["anonymous"] = True
    if environ.get("GOOGLE_CLOUD_PROJECT"):
        options["project_id"] = environ["GOOGLE_CLOUD_PROJECT"]
    return options


@functools.cache
def _cached_filesystem(scheme: str, bucket: str, options: tuple[tuple[str, Any], ...], pid: int) -> pafs.FileSystem:
    import pyarrow.fs as pafs

    kwargs = dict(options)
    if scheme == "s3":
        if "region" not in kwargs and "endpoint_override" not in kwargs:
            try:  # the bucket's own region: requests to another one are redirected errors
                kwargs["region"] = pafs.resolve_s3_region(bucket)
            except (OSError, ValueError) as error:
                raise InputError(f"s3://{bucket}: cannot find the bucket's region ({scrub(one_line(error))}); "
                                 "set AWS_REGION") from None
        return pafs.S3FileSystem(**kwargs)
    return pafs.GcsFileSystem(**kwargs)


def filesystem(scheme: str, bucket: str) -> pafs.FileSystem:
    """The filesystem of ``scheme`` ("s3" or "gs") for ``bucket``: one object per (scheme, bucket) per process.

    Built from the environment at first use (:func:`s3_options`, :func:`gcs_options`); a changed endpoint or
    region (a test's server) gets a new one.
    """
    options = s3_options(os.environ) if scheme == "s3" else gcs_options(os.environ)
    # One per process: a forked worker must not use the client its parent built, whose pooled connections it
    # inherits as sockets shared with the parent and its sibling workers (seen on GCS with two workers: a request
    # stalled about 2 minutes before it failed or was retried).
    return _cached_filesystem(scheme, bucket, tuple(sorted(options.items())), os.getpid())


@functools.cache
def _local_filesystem() -> pafs.FileSystem:
    import pyarrow.fs as pafs

    return pafs.LocalFileSystem()


def _errors() -> tuple[type[BaseException], ...]:
    """What a pyarrow filesystem call raises for a failed request (and OSError, its base for I/O)."""
    import pyarrow as pa

    return (OSError, pa.ArrowException)


@dataclass(frozen=True)
class Location:
    """A file or folder on the local disk or in an object store (see the module's Interface)."""

    fs: pafs.FileSystem = field(compare=False)  # equal locations are equal paths and URIs (filesystems do not hash)
    path: str
    uri: str
    #: What :meth:`info` found, kept: a converter asks "present?", "a file?", "its size?" of one object in a row,
    #: one request each in a store. This object's own writes and deletes forget it.
    _found: dict[str, ObjectInfo] = field(default_factory=dict, compare=False, repr=False)

    def __str__(self) -> str:
        return self.uri

    def __fspath__(self) -> str:
        if not self.is_local:  # os-level code must not take an object key for a local path
            raise TypeError(f"{self.uri} is in an object store, not a local path")
        return self.path

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        return location, (self.uri,)

    @property
    def is_local(self) -> bool:
        """Whether this is a local path."""
        return type(self.fs).__name__ == "LocalFileSystem"

    @property
    def local_path(self) -> Path | None:
        """The local path, None in an object store."""
        return Path(self.path) if self.is_local else None

    @property
    def scheme(self) -> str:
        """"s3", "gs" or "file"."""
        return self.uri.split("://", 1)[0] if not self.is_local else "file"

    @property
    def bucket(self) -> str:
        """The bucket (empty for local paths)."""
        return "" if self.is_local else self.path.split("/", 1)[0]

    @property
    def name(self) -> str:
        """The last part of the path, as ``Path.name``."""
        return PurePosixPath(self.path).name

    @property
    def suffix(self) -> str:
        """As ``Path.suffix``."""
        return PurePosixPath(self.path).suffix

    @property
    def stem(self) -> str:
        """As ``Path.stem``."""
        return PurePosixPath(self.path).stem

    @property
    def parent(self) -> Location:
        """The folder (prefix) holding this one; a bucket is its own parent."""
        if not self.is_local and "/" not in self.path:
            return self
        parent = str(PurePosixPath(self.path).parent)
        return Location(self.fs, parent, parent if self.is_local else f"{self.scheme}://{parent}")

    def join(self, *parts: str) -> Location:
        """This location with ``parts`` appended (each may hold ``/``)."""
        path = "/".join([self.path.rstrip("/"), *(str(p).strip("/") for p in parts)])
        return Location(self.fs, path, path if self.is_local else f"{self.scheme}://{path}")

    def __truediv__(self, part: str) -> Location:
        return self.join(part)

    def with_name(self, name: str) -> Location:
        """As ``Path.with_name``."""
        return self.parent.join(name)

    # ----------------------------------------------------------------- reading
    def info(self) -> ObjectInfo:
        """What is at this location (one HEAD request, and a listing when no object has this key), asked once."""
        if "info" not in self._found:
            try:
                found = self.fs.get_file_info(self.path)
            except _errors() as error:
                raise InputError(f"{self.uri}: cannot reach ({scrub(one_line(error))})") from None
            self._found["info"] = _object_info(found)
        return self._found["info"]

    def exists(self) -> bool:
        """Whether an object or a prefix with objects is here."""
        return self.info().kind != MISSING

    def is_file(self) -> bool:
        """Whether an object (a regular file) is here."""
        return self.info().kind == FILE

    def is_dir(self) -> bool:
        """Whether a folder (a prefix holding objects) is here."""
        return self.info().kind == FOLDER

    def size(self) -> int:
        """The object's size in bytes; InputError when it is not a file."""
        info = self.info()
        if info.kind != FILE:
            raise InputError(f"{self.uri}: expected a file, got {'nothing' if info.kind == MISSING else 'a folder (prefix)'}")
        return info.size

    def listing(self, recursive: bool = False) -> dict[str, ObjectInfo]:
        """Path relative to this folder -> what is there, for everything in it (one request per 1000 objects)."""
        import pyarrow.fs as pafs

        try:
            infos = self.fs.get_file_info(pafs.FileSelector(self.path, allow_not_found=True, recursive=recursive))
        except _errors() as error:
            raise InputError(f"{self.uri}: cannot list ({scrub(one_line(error))})") from None
        prefix = self.path.rstrip("/") + "/"
        return {info.path.removeprefix(prefix): _object_info(info) for info in infos}

    def iterdir(self) -> Iterator[Location]:
        """The files and folders directly in this folder, sorted by name (each knows what it is: no more requests)."""
        for name, info in sorted(self.listing().items()):
            child = self.join(name)
            child._found["info"] = info
            yield child

    def read_bytes(self, max_bytes: int | None = None) -> bytes:
        """The whole object; InputError naming the URI if it is missing, a folder or too large.

        Two requests whatever the size: the size (HEAD), then one ranged GET of every byte (a stream's ``read()``
        would fetch it in 256 KiB requests).
        """
        with self.open_input() as stream:
            try:
                size = stream.size()
                if max_bytes is not None and size > max_bytes:
                    raise InputError(f"{self.uri}: expected a file of at most {max_bytes} bytes, got {size} bytes")
                return bytes(stream.read_at(size, 0))
            except _errors() as error:
                raise InputError(f"{self.uri}: unreadable ({scrub(one_line(error))})") from None

    def open_input(self) -> pa.NativeFile:
        """A seekable reader of the object: each ``read_at``/``seek`` + ``read`` is one ranged request."""
        try:
            return self.fs.open_input_file(self.path)
        except FileNotFoundError:
            raise InputError(f"{self.uri}: no such object") from None
        except _errors() as error:
            raise InputError(f"{self.uri}: unreadable ({scrub(one_line(error))})") from None

    def download(self, local: Path) -> None:
        """Copies the object to the local file ``local`` through a hidden temporary name beside it, streamed."""
        local.parent.mkdir(parents=True, exist_ok=True)
        staged = local.with_name(f".{local.name}.{os.getpid()}.download.tmp")
        try:
            with self.open_input() as stream, open(staged, "wb") as out:
                while block := stream.read(8 << 20):
                    out.write(block)
            os.replace(staged, local)
        except _errors() as error:
            raise InputError(f"{self.uri}: cannot download to {local} ({scrub(one_line(error))})") from None
        finally:
            staged.unlink(missing_ok=True)

    # ----------------------------------------------------------------- writing
    def write_bytes(self, data: bytes | str) -> None:
        """Writes the object whole (a single PUT is atomic on S3 and GCS: readers see the old object or the new)."""
        self._found.clear()
        try:
            with self.fs.open_output_stream(self.path) as stream:
                stream.write(data.encode() if isinstance(data, str) else data)
        except _errors() as error:
            raise OutputError(f"{self.uri}: cannot write ({scrub(one_line(error))})") from None

    def upload(self, local: Path) -> None:
        """Copies the local file ``local`` to this object, streamed (a multipart upload above Arrow's part size).

        No folder marker objects are made (``pyarrow.fs.copy_files`` would add empty ``prefix/`` keys).
        """
        self._found.clear()
        try:
            with open(local, "rb") as source, self.fs.open_output_stream(self.path) as stream:
                while block := source.read(8 << 20):
                    stream.write(block)
        except _errors() as error:
            raise OutputError(f"{self.uri}: cannot write ({scrub(one_line(error))})") from None

    def copy_to(self, target: Location) -> None:
        """A server-side copy of this object to ``target`` (same store): no byte passes through this machine."""
        target._found.clear()
        try:
            self.fs.copy_file(self.path, target.path)
        except _errors() as error:
            raise OutputError(f"{target.uri}: cannot copy {self.uri} there ({scrub(one_line(error))})") from None

    def delete(self, missing_ok: bool = True) -> None:
        """Deletes the object."""
        self._found.clear()
        try:
            self.fs.delete_file(self.path)
        except FileNotFoundError:
            if not missing_ok:
                raise InputError(f"{self.uri}: no such object") from None
        except _errors() as error:
            raise OutputError(f"{self.uri}: cannot delete ({scrub(one_line(error))})") from None


def _object_info(info: pafs.FileInfo) -> ObjectInfo:
    import pyarrow.fs as pafs

    if info.type == pafs.FileType.File:
        return ObjectInfo(FILE, int(info.size), int(info.mtime_ns or 0))
    return ObjectInfo(FOLDER if info.type == pafs.FileType.Directory else MISSING)


def location(uri: str | os.PathLike[str]) -> Location:
    """``uri`` (a path, ``file://``, ``s3://bucket/key`` or ``gs://bucket/key``) as a :class:`Location`.

    Raises:
        InputError: an unknown scheme, a store URI without a bucket, or one holding credentials, control
            characters or '.' / '..' segments.
    """
    if isinstance(uri, Location):
        return uri
    text = os.fspath(uri)
    if "://" not in text:
        return Location(_local_filesystem(), os.path.abspath(text), text)
    scheme, rest = text.split("://", 1)
    scheme = scheme.lower()
    if scheme == "file":
        path = urlsplit(text).path
        return Location(_local_filesystem(), os.path.abspath(path), path)
    netloc = rest.split("/", 1)[0]
    if "@" in netloc:
        shown = f"{scheme}://{netloc.rsplit('@', 1)[1]}/{rest.split('/', 1)[1] if '/' in rest else ''}"
        raise InputError(f"{shown}: expected a URI without credentials (user:secret@); give them through the "
                         "store's environment or configuration")
    if scheme not in STORE_SCHEMES:
        raise InputError(f"{scheme}://...: expected a local path or a URI of {', '.join(s + '://' for s in STORE_SCHEMES)} "
                         f"or file://, got scheme {scheme!r}")
    if not netloc:
        raise InputError(f"{text}: expected {scheme}://BUCKET/PREFIX, got no bucket")
    control = [c for c in text if ord(c) < 0x20 or c == "\x7f"]
    if control:  # the S3 client cut a key at its NUL: s3://b/d<NUL> read the dataset at s3://b/d
        raise InputError(f"{text!r}: expected a URI without control characters, got {control[0]!r}")
    parts = [part for part in rest.split("/")[1:] if part]
    if "." in parts or ".." in parts:  # the store client resolves them: s3://b/x/../d read the dataset at s3://b/d
        raise InputError(f"{text}: expected a URI without '.' or '..' segments (a store has no folders to climb)")
    key = "/".join(parts)
    path = f"{netloc}/{key}" if key else netloc
    return Location(filesystem(scheme, netloc), path, f"{scheme}://{path}")


def path_or_location(uri: str | os.PathLike[str]) -> Path | Location:
    """A ``Path`` for a local path or ``file://`` URI, a :class:`Location` on a store (see the module's Interface)."""
    if isinstance(uri, Path):
        return uri
    found = location(uri)
    return found if not found.is_local else Path(found.uri)
