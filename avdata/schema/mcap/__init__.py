"""MCAP reading and writing for avdata scenes, over one set of record layouts.

Every record layout of the MCAP spec that avdata writes or reads is declared once, in
:mod:`~avdata.schema.mcap.records` (``RECORD_LAYOUTS``, the ``struct`` formats of the hot records), and
both the writer and the reader use them.

Integrity: every chunk carries the CRC-32 of its uncompressed records (also the large chunks
written straight from the caller's buffers), the DataEnd record carries the CRC-32 of the whole
data section and the Footer that of the summary, exactly as the MCAP spec defines them, so the
stock ``mcap`` reader with ``validate_crcs=True`` checks the same bytes :meth:`~avdata.schema.mcap.reader.McapReader.verify_file`
does. Together they cover every byte of the file but the two magics, which are compared. The
writer computes each byte's CRC once (:mod:`~avdata.schema.mcap.checksum`): a
chunk's CRC is chained into the data-section CRC with :func:`~avdata.schema.mcap.checksum.crc32_combine` instead of a
second pass. A large message's CRC is computed just before the ``writev`` that copies it to the
file, which then reads the payload (a few MB: a cloud, an image) from the CPU cache.

Reading: the file is memory-mapped; a message of an uncompressed chunk is a read-only zero-copy
view into the mapping, and a compressed chunk is decompressed only when a message in it is read.
Every failure caused by the file's bytes is an :class:`~avdata.errors.InputError` naming the file,
the record and the value.

Modules: :mod:`~avdata.schema.mcap.records` (layouts, encode/decode), :mod:`~avdata.schema.mcap.checksum`
(CRC-32), :mod:`~avdata.schema.mcap.compression` (chunk codecs), :mod:`~avdata.schema.mcap.chunk_index`
(chunk and message indexes), :mod:`~avdata.schema.mcap.fileio` (OS-level writes and the page cache),
:mod:`~avdata.schema.mcap.writer` (:class:`~avdata.schema.mcap.writer.McapWriter`) and
:mod:`~avdata.schema.mcap.reader` (:class:`~avdata.schema.mcap.reader.McapReader`).
"""
