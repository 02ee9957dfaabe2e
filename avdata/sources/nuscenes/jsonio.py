"""Reading nuScenes-schema JSON tables (nuScenes, Lyft Level 5, V2X-Sim): streamed arrays and timestamps.

A table may be an object in a store (:class:`~avdata.storage.Location`): it is streamed the same way, fetched
:data:`STORE_READ_BYTES` at a time (one ranged request each).
"""


import io
import json
import math
import re
from collections.abc import Iterator
from decimal import ROUND_HALF_EVEN, Decimal
from typing import Any, TextIO

from avdata.errors import InputError, one_line
from avdata.inputs import Source, first_conflict, refuse_special_file
from avdata.storage import Location, scrub


def us_to_ns(timestamp_us: int | float) -> int:
    """Microseconds as the tables store them -> int64 nanoseconds, exactly.

    nuScenes stores integers: ``× 1000``. Lyft stores floats such as ``1556675185903083.2``. Their
    JSON text is Python's ``repr`` of the float (the shortest decimal that round-trips), so the
    text is recovered from the float with ``repr``; that decimal × 1000 is rounded half to even to
    whole nanoseconds: ``1556675185903083.2`` -> ``1556675185903083200`` (the float's binary value,
    ...083.25, would give ...083250).
    """
    if isinstance(timestamp_us, bool) or not isinstance(timestamp_us, (int, float)):
        raise InputError(f"expected a timestamp in microseconds, got {timestamp_us!r}")
    if isinstance(timestamp_us, int):
        return timestamp_us * 1000
    if not math.isfinite(timestamp_us):
        raise InputError(f"expected a finite timestamp in microseconds, got {timestamp_us!r}")
    if timestamp_us.is_integer():
        return int(timestamp_us) * 1000
    return int((Decimal(repr(timestamp_us)) * 1000).quantize(Decimal(1), rounding=ROUND_HALF_EVEN))


class RepeatedKeyRecord(dict[str, Any]):
    """A record in which a key is given twice with different values (JSON leaves which one counts open).

    :func:`iter_json_chunks` yields it in the record's place, so that the table's checks drop that record alone
    and name it; ``repeated`` is (key, first value, other value).
    """

    __slots__ = ("repeated",)
    repeated: tuple[str, Any, Any]


def _marked_object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``object_pairs_hook``: the object as a dict, or a :class:`RepeatedKeyRecord` when a key repeats."""
    out = dict(pairs)
    if len(out) < len(pairs) and (conflict := first_conflict(pairs)) is not None:
        out = RepeatedKeyRecord(out)
        out.repeated = conflict
    return out


def _keys_may_be_lost(text: str, records: list[dict[str, Any]]) -> bool:
    """Whether decoding ``text`` into ``records`` may have merged a repeated key (False: it did not).

    ``json.loads`` keeps the last value of a repeated key without a word. Every key in the text is followed by
    one colon, and the text holds colons elsewhere only inside strings, so it holds at least one per key; the
    records hold exactly one key per key they kept. Equal counts prove that none was merged. A mismatch (a
    repeat, a nested object, a colon inside a string) only means decoding again with every pair seen. Counting
    one character is cheap beside decoding the text (``str.count`` of one character has a fast path that a
    two-character pattern such as ``":`` lacks).
    """
    return text.count(":") != sum(map(len, records))


#: Characters read and decoded at a time. A chunk's text and its decoded records are a conversion's
#: largest transient while the tables are parsed, so chunks are small; at this size the per-chunk
#: overhead is still lost in the parsing (figures in docs/performance.md).
CHUNK_CHARS = 1 << 18
#: Bytes of a table in a store fetched by one ranged request (a table of a few MB: one request).
STORE_READ_BYTES = 8 << 20


def iter_json_array(path: Source, chunk_chars: int = CHUNK_CHARS) -> Iterator[dict[str, Any]]:
    """The objects of a JSON array file (a nuScenes table), parsed a chunk at a time with bounded memory.

    Each chunk read is cut after its last ``}``. nuScenes records are flat objects, so that cut is a
    record boundary unless a string holds a ``}``; the records before it are then decoded by one
    ``json.loads`` call, otherwise one at a time with ``raw_decode`` up to the last complete one.

    Args:
        path: a file holding one JSON array of objects.
        chunk_chars: characters read at a time.
    """
    for records in iter_json_chunks(path, chunk_chars):
        yield from records


def iter_json_chunks(path: Source, chunk_chars: int = CHUNK_CHARS) -> Iterator[list[dict[str, Any]]]:
    """The objects of a JSON array file as :func:`iter_json_array` parses them, a list per chunk read.

    A caller can then check a chunk's values a column at a time (C loops) instead of a record at a time.
    """
    try:
        yield from _records(path, chunk_chars)
    except UnicodeDecodeError as error:
        raise InputError(f"{path}: expected UTF-8 JSON (as nuScenes writes it), got bytes that are not UTF-8 "
                         f"({error.reason} at byte {error.start} of a chunk; a UTF-16 file?)") from None
    except OSError as error:
        raise InputError(f"{path}: unreadable ({error.strerror or scrub(one_line(error))})") from None


def _open_text(path: Source) -> TextIO:
    """The table as UTF-8 text, read a buffer at a time (from a store: :data:`STORE_READ_BYTES` per request)."""
    if isinstance(path, Location):
        import pyarrow as pa

        return io.TextIOWrapper(pa.BufferedInputStream(path.open_input(), STORE_READ_BYTES), encoding="utf-8")
    return open(path, encoding="utf-8")


def _records(path: Source, chunk_chars: int) -> Iterator[list[dict[str, Any]]]:
    """The body of :func:`iter_json_chunks`."""
    decoder = json.JSONDecoder()
    refuse_special_file(path)  # opening a FIFO waits for a writer
    with _open_text(path) as stream:
        buffer = stream.read(chunk_chars).lstrip()
        if not buffer.startswith("["):
            raise InputError(f"{path}: expected a JSON array, got {buffer[:20]!r}")
        buffer = buffer[1:]
        at_end = False
        first = True  # the array's first record has no ',' before it; every later one has exactly one
        while not at_end:
            more = stream.read(chunk_chars)
            at_end = not more
            buffer += more
            cut = buffer.rfind("}") + 1
            text = buffer[:cut].lstrip(" \t\r\n")
            if not first and text.startswith(","):
                text = text[1:]
            try:
                records = json.loads("[" + text + "]") if cut else None
            except json.JSONDecodeError:
                records = None
            if records is not None:
                buffer = buffer[cut:]
            else:
                records, rest = _decode_records(decoder, buffer, path, at_end, first)
                text, buffer = buffer[: len(buffer) - len(rest)].strip(" \t\r\n,"), rest
            first = first and not records
            for record in records:
                if not isinstance(record, dict):
                    raise InputError(f"{path}: expected an array of objects, got {type(record).__name__}")
            if records and _keys_may_be_lost(text, records):
                records = json.loads("[" + text + "]", object_pairs_hook=_marked_object)
            if records:
                yield records
            if not at_end and buffer.lstrip(" \t\r\n,").startswith("]"):
                # The array ended: what follows must be white space, checked a chunk at a time (bounded
                # memory; a 10 GB file of zeros after a valid array is refused at its first chunk).
                tail = buffer.lstrip(" \t\r\n,")[1:]
                while tail or not at_end:
                    if tail.strip():
                        raise InputError(f"{path}: expected only white space after the array, got "
                                         f"{tail.strip()[:20]!r}")
                    tail = stream.read(chunk_chars)
                    at_end = not tail
                buffer = "]"
    rest = buffer.strip(" \t\r\n,")
    if rest != "]":
        raise InputError(f"{path}: expected the array to end with ']', got {rest[:20]!r}")


_SPACE = re.compile(r"[ \t\r\n]*")


def _decode_records(decoder: json.JSONDecoder, buffer: str, path: Source, at_end: bool,
                    first: bool) -> tuple[list[Any], str]:
    """(the complete records at the start of ``buffer``, what follows them), one ``raw_decode`` each.

    Records are separated by exactly one ',' (``first``: the buffer starts at the array's first record, which
    has none before it): records without one are not JSON, and Python's ``json`` refuses them too.
    """
    records: list[Any] = []
    position = 0
    need_comma = not first
    while True:
        # The pattern matches the empty string, so match() never returns None here.
        start = _SPACE.match(buffer, position).end()  # type: ignore[union-attr]  # the pattern matches ""
        if start >= len(buffer) or buffer[start] == "]":
            return records, buffer[position:]
        if need_comma:
            if buffer[start] != ",":
                raise InputError(f"{path}: malformed JSON: expected ',' between records, got {buffer[start:start + 20]!r}")
            start = _SPACE.match(buffer, start + 1).end()  # type: ignore[union-attr]  # the pattern matches ""
            if start >= len(buffer):
                return records, buffer[position:]
        try:
            record, position = decoder.raw_decode(buffer, start)
        except json.JSONDecodeError as error:
            if at_end:
                raise InputError(f"{path}: malformed JSON near character {error.pos}: {error.msg}") from None
            return records, buffer[position:]
        records.append(record)
        need_comma = True


