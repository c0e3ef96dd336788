"""Packing of sample and estimate blocks: float64 little-endian in a zlib stream. Large
blocks (uploads, estimates) at level 1 (fast; IMU rows compress to about half); small
ones (a live message's 10 rows) stored as they are: they do not compress (a simulated
10-row block came out 808 bytes from 800), and so are the group commit's blocks of a
live stream (its messages of one sensor in one commit, ``pack_stored``). Those are
written here, byte for byte what ``zlib.compress(raw, 0)`` gives (a zlib header, one
stored deflate block, the Adler-32; compared for every length up to ``STORED_MAX_BYTES``
when written, and on a sample of lengths in the tests), in 1.3 µs instead of zlib's 54:
zlib sets up its whole deflate state for each call, and lets go of the interpreter lock
around it, which beside the busy event loop cost the group commit a wait of up to 5 ms a
block. Both read back with the same ``zlib.decompress``."""

from __future__ import annotations

import struct
import zlib

import numpy as np

#: Columns of a sample block (``docs/spec/recording.md``'s, without ``sensor``).
SAMPLE_COLUMNS = ("t", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz")


#: Blocks with fewer rows than this are stored without compression (zlib level 0).
COMPRESS_FROM_ROWS = 100


#: Longest data written as one stored block by ``stored_zlib`` (zlib's level 0 splits
#: from 65,532 bytes on).
STORED_MAX_BYTES = 65_531


def pack(rows: np.ndarray) -> bytes:
    """(n, k) float64 → bytes."""
    raw = np.ascontiguousarray(rows, dtype="<f8").tobytes()
    if len(rows) >= COMPRESS_FROM_ROWS:
        return zlib.compress(raw, 1)
    return stored_zlib(raw) if len(raw) <= STORED_MAX_BYTES else zlib.compress(raw, 0)


def pack_stored(rows: np.ndarray) -> bytes:
    """(n, k) float64 → bytes, uncompressed up to ``STORED_MAX_BYTES`` of data whatever
    the number of rows (the group commit's blocks: compressing them there would hand the
    interpreter lock to the event loop and wait for it back, block after block)."""
    raw = np.ascontiguousarray(rows, dtype="<f8").tobytes()
    return stored_zlib(raw) if len(raw) <= STORED_MAX_BYTES else zlib.compress(raw, 1)


def stored_zlib(raw: bytes) -> bytes:
    """``zlib.compress(raw, 0)`` for ``len(raw) <= STORED_MAX_BYTES``, without zlib's
    deflate state: header (deflate, 32 KiB window, no dictionary, fastest), one final
    stored block (length and its complement, little-endian), the data, Adler-32
    (big-endian)."""
    n = len(raw)
    return b"\x78\x01\x01" + struct.pack("<HH", n, n ^ 0xFFFF) + raw + struct.pack(
        ">I", zlib.adler32(raw))


def unpack(data: bytes, width: int) -> np.ndarray:
    """bytes → (n, width) float64 (a fresh, writable array)."""
    return np.frombuffer(zlib.decompress(data), dtype="<f8").reshape(-1, width).copy()


def unpack_many(blobs: list[bytes], width: int) -> np.ndarray:
    """Several blocks → one (n, width) float64 array, in the given order."""
    if not blobs:
        return np.empty((0, width))
    raw = b"".join(zlib.decompress(b) for b in blobs)
    return np.frombuffer(raw, dtype="<f8").reshape(-1, width).copy()
