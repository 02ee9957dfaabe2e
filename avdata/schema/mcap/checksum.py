"""CRC-32 (zlib's polynomial), as the MCAP spec defines every chunk, data-section and summary CRC.

libdeflate's CRC-32 (``deflate``) is the fastest of the libraries at hand on data in the CPU cache (zlib's and
ISA-L's are slower), which is what keeps checksummed writes and verified reads near plain file speed.
libdeflate has no CRC combination; ISA-L's chains a chunk's CRC into the data section's without a second pass.
"""

from __future__ import annotations

import deflate
from isal import isal_zlib

from avdata.schema.mcap.records import Buffer


def crc32(data: Buffer, value: int = 0) -> int:
    """CRC-32 (zlib's polynomial) of ``data`` (a C-contiguous buffer), continuing from ``value``."""
    return deflate.crc32(data, value)


def crc32_combine(crc1: int, crc2: int, length2: int) -> int:
    """The CRC-32 of two buffers in a row from their CRCs (``crc2`` of ``length2`` bytes)."""
    return int(isal_zlib.crc32_combine(crc1, crc2, length2))

