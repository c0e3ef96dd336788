"""Packing of sample and estimate blocks: float64 little-endian, zlib level 1 (fast;
IMU rows compress to about half)."""

from __future__ import annotations

import zlib

import numpy as np

#: Columns of a sample block (``spec/recording.md``'s, without ``sensor``).
SAMPLE_COLUMNS = ("t", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz")


def pack(rows: np.ndarray) -> bytes:
    """(n, k) float64 → bytes."""
    return zlib.compress(np.ascontiguousarray(rows, dtype="<f8").tobytes(), 1)


def unpack(data: bytes, width: int) -> np.ndarray:
    """bytes → (n, width) float64 (a fresh, writable array)."""
    return np.frombuffer(zlib.decompress(data), dtype="<f8").reshape(-1, width).copy()


def unpack_many(blobs: list[bytes], width: int) -> np.ndarray:
    """Several blocks → one (n, width) float64 array, in the given order."""
    if not blobs:
        return np.empty((0, width))
    raw = b"".join(zlib.decompress(b) for b in blobs)
    return np.frombuffer(raw, dtype="<f8").reshape(-1, width).copy()
