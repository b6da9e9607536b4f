"""A Chunk record's fields, and its records decompressed within a bounded size.

Package-internal to :mod:`toolkit.mcapio`, used by the walk (:mod:`toolkit.mcapio.walk`).
"""

from __future__ import annotations

import io
import struct

import lz4.frame
import zstandard

from toolkit.mcapio.damage import BAD_RECORD, CHUNK_DECOMPRESS, UNSUPPORTED_COMPRESSION
from toolkit.mcapio.records import CHUNK_FIXED, MalformedError

#: Largest decompressed chunk accepted. Writers cut chunks at a few MiB; a header or a
#: compression frame claiming more is damage or a decompression bomb, and decompression stops
#: here, so memory stays bounded whatever the file claims.
MAX_CHUNK_BYTES = 256 * 1024**2


def chunk_fields(record: bytes, length: int) -> tuple[str, int, int, bytes]:
    """(compression, uncompressed_size, uncompressed_crc, compressed records) of a Chunk record
    whose first ``length`` bytes (header included) are in ``record``; raises MalformedError."""
    fixed_end = 9 + CHUNK_FIXED.size
    if length < fixed_end + 8 or len(record) < fixed_end:
        raise MalformedError(BAD_RECORD, "Chunk record too short for its fixed fields")
    _start, _end, usize, crc, clen = CHUNK_FIXED.unpack_from(record, 9)
    at = fixed_end + clen
    if at + 8 > min(length, len(record)):
        raise MalformedError(BAD_RECORD, "Chunk compression field overruns the record")
    compression = record[fixed_end:at].decode("utf-8", errors="replace")
    rlen = struct.unpack_from("<Q", record, at)[0]
    if at + 8 + rlen > length:
        raise MalformedError(BAD_RECORD, f"Chunk records ({rlen} bytes) overrun the record")
    return compression, usize, crc, record[at + 8 : at + 8 + rlen]


def _too_big(what: str, n: int | str) -> MalformedError:
    return MalformedError(
        CHUNK_DECOMPRESS, f"{what} {n} bytes, more than the {MAX_CHUNK_BYTES} byte chunk limit"
    )


def decompress(compression: str, data: bytes, zstd: zstandard.ZstdDecompressor) -> bytes:
    """The chunk's records, at most :data:`MAX_CHUNK_BYTES` of them whatever the frame or the
    header claims; raises MalformedError. The caller compares the length with the header."""
    if compression == "":
        return data
    if compression == "zstd":
        try:
            declared = zstandard.frame_content_size(data)
            if declared > MAX_CHUNK_BYTES:
                raise _too_big("zstd frame declares", declared)
            if declared >= 0:  # a known size within the limit: one allocation
                return bytes(zstd.decompress(data, max_output_size=max(declared, 1)))
            # No size in the frame: stream at most one byte past the limit, so a bomb costs
            # the limit and is named as one.
            with zstd.stream_reader(io.BytesIO(data)) as stream:
                out = stream.read(MAX_CHUNK_BYTES + 1)
        except zstandard.ZstdError as exc:
            raise MalformedError(CHUNK_DECOMPRESS, f"zstd: {exc}") from exc
        if len(out) > MAX_CHUNK_BYTES:
            raise _too_big("zstd frame holds over", MAX_CHUNK_BYTES)
        return bytes(out)
    if compression == "lz4":
        try:
            lz4d = lz4.frame.LZ4FrameDecompressor()
            out = lz4d.decompress(data, max_length=MAX_CHUNK_BYTES)
            if not lz4d.eof:
                if len(out) >= MAX_CHUNK_BYTES:
                    raise _too_big("lz4 frame holds over", MAX_CHUNK_BYTES)
                raise MalformedError(CHUNK_DECOMPRESS, "lz4: the frame ends early")
        except (RuntimeError, ValueError, TypeError) as exc:
            raise MalformedError(CHUNK_DECOMPRESS, f"lz4: {exc}") from exc
        return bytes(out)
    raise MalformedError(UNSUPPORTED_COMPRESSION, f"unsupported compression {compression!r}")


def decompress_prefix(compression: str, data: bytes, zstd: zstandard.ZstdDecompressor) -> bytes:
    """As much of a cut-off chunk's records as its compressed prefix yields (b"" if none)."""
    try:
        if compression == "":
            return data
        if compression == "zstd":
            return zstd.decompressobj().decompress(data)
        if compression == "lz4":
            out = lz4.frame.LZ4FrameDecompressor().decompress(data)
            return out if isinstance(out, bytes) else b""
    except (zstandard.ZstdError, RuntimeError, ValueError, TypeError):
        return b""
    return b""
