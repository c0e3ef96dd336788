"""Packing of sample and estimate blocks: float64 little-endian in a zlib stream. Large
blocks (uploads, estimates) at level 1 (fast; IMU rows compress to about half); small
ones (a live message's 10 rows) at level 0, stored: they do not compress (a simulated
10-row block came out 808 bytes from 800) and deflate's set-up alone took 18 µs a block,
most of the group commit's time. Both read back with the same ``zlib.decompress``."""

from __future__ import annotations

import zlib

import numpy as np

#: Columns of a sample block (``spec/recording.md``'s, without ``sensor``).
SAMPLE_COLUMNS = ("t", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz")


#: Blocks with fewer rows than this are stored without compression (zlib level 0).
COMPRESS_FROM_ROWS = 100


def pack(rows: np.ndarray) -> bytes:
    """(n, k) float64 → bytes."""
    level = 1 if len(rows) >= COMPRESS_FROM_ROWS else 0
    return zlib.compress(np.ascontiguousarray(rows, dtype="<f8").tobytes(), level)


def unpack(data: bytes, width: int) -> np.ndarray:
    """bytes → (n, width) float64 (a fresh, writable array)."""
    return np.frombuffer(zlib.decompress(data), dtype="<f8").reshape(-1, width).copy()


def unpack_many(blobs: list[bytes], width: int) -> np.ndarray:
    """Several blocks → one (n, width) float64 array, in the given order."""
    if not blobs:
        return np.empty((0, width))
    raw = b"".join(zlib.decompress(b) for b in blobs)
    return np.frombuffer(raw, dtype="<f8").reshape(-1, width).copy()
