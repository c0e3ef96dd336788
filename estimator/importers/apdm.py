"""APDM Opal ``.h5`` files (Motion Studio / Mobility Lab), read with h5py (the optional
``armtrack[apdm]`` extra).

Layout read (file format version 5, the ``FileFormatVersion`` root attribute):
``/Sensors/<id>/{Accelerometer [m/s², N×3], Gyroscope [rad/s], Magnetometer [µT],
Time [µs since 1970 UTC, uint64]}``, the sensor's label in the attribute ``Label 0`` of
``/Sensors/<id>/Configuration`` (bytes, NUL-padded). Older files (format versions 3–4,
``/<case id>/Calibrated/…``) are refused naming their version. All sensors of a file
share its time base (``unix``). A sensor is named ``<label> (<id>)``; LABEL in
``SENSOR=FILE:LABEL`` may be either.
"""

from __future__ import annotations

import io
import multiprocessing
import threading
from typing import Any

import numpy as np

from .base import ImportFailure, ReadOptions, Signal, SourceFile, TooLarge

NAME = "apdm"
TITLE = "APDM Opal .h5"
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
READ_VERSIONS = (5,)
#: The longest one file's reader may take, its process's start included [s]: a file made
#: to loop libhdf5 must not hold the caller (a server's worker) for good.
READ_TIME_LIMIT_S = 120.0
#: Readers (processes of ~100 MB: numpy and h5py) running at once in this program; more
#: files wait their turn (a server's workers would otherwise start one each).
READERS_AT_ONCE = 2
_readers = threading.BoundedSemaphore(READERS_AT_ONCE)


def sniff(source: SourceFile) -> bool:
    return source.data[:8] == HDF5_MAGIC


def _text(value) -> str:
    if isinstance(value, np.ndarray):
        value = value.flat[0] if value.size else b""
    if isinstance(value, bytes):
        value = value.decode("utf-8", errors="replace")
    return str(value).replace("\x00", "").strip()


def read(sources: list[SourceFile], options: ReadOptions) -> list[Signal]:
    """The sensors of the ``.h5`` files, each file read in a process of its own (spawned):
    libhdf5 parses a crafted or damaged file in C, and some such files crash it (SIGSEGV);
    that must end the reader, not the program that asked (a server)."""
    try:
        import h5py  # noqa: F401  (the reader's process imports it again)
    except ImportError:
        raise ImportFailure(sources[0].name, "reading APDM .h5 files needs h5py: "
                            "pip install 'armtrack[apdm]'") from None
    signals = []
    left = options.max_bytes  # what the datasets may still unpack to [bytes]
    for source in sources:
        if not sniff(source):
            continue
        with _readers:
            found, used = _read_apart(source, left, options.max_bytes)
        signals.extend(found)
        left -= used
    if not signals:
        raise ImportFailure(sources[0].name if sources else "?", "no APDM sensors found")
    return signals


def _read_apart(source: SourceFile, left: int, total: int) -> tuple[list[Signal], int]:
    """:func:`_read_file` in a spawned process: its signals and the bytes they unpacked
    to, or its refusal raised here; a reader that died or did not finish within
    ``READ_TIME_LIMIT_S`` is stopped and names the file."""
    context = multiprocessing.get_context("spawn")  # a fork would copy a server's threads
    receive, send = context.Pipe(duplex=False)
    reader = context.Process(target=_read_into, args=(send, source, left, total),
                             name="armtrack-h5-reader", daemon=True)
    reader.start()
    send.close()  # the reader holds the only sending end: its death reads as EOF
    try:
        if not receive.poll(READ_TIME_LIMIT_S):
            raise ImportFailure(source.name, f"reading it took longer than "
                                f"{READ_TIME_LIMIT_S:g} s and was stopped (a damaged or "
                                "crafted HDF5 file, or a machine too busy: try again)")
        try:
            ok, value = receive.recv()
        except EOFError:
            raise ImportFailure(source.name, "not a readable HDF5 file: reading it stopped "
                                "the HDF5 library (damaged or crafted)") from None
    finally:
        receive.close()
        if reader.is_alive():
            reader.kill()
        reader.join()
    if not ok:
        too_large, file, problem, line, place = value
        raise (TooLarge if too_large else ImportFailure)(file, problem, line, place)
    return value


def _read_into(send, source: SourceFile, left: int, total: int) -> None:
    """The reader process's body: :func:`_read_file`'s answer sent back."""
    send.send(_read_file(source, left, total))
    send.close()


def _read_file(source: SourceFile, left: int, total: int) -> tuple[bool, Any]:
    """In the reader's process: ``(True, (signals, bytes used))`` or ``(False, the
    refusal's fields)`` (an ImportFailure does not pickle back whole)."""
    import h5py

    budget = [left, total]
    try:
        try:
            h5 = h5py.File(io.BytesIO(source.data), "r")
        except OSError as exc:
            raise ImportFailure(source.name, f"not a readable HDF5 file, truncated or "
                                f"damaged ({exc})") from None
        try:
            with h5:
                signals = _sensors(source, h5, budget)
        except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
            # what h5py raises on a damaged file's structure (a bad heap, an address
            # past the end …)
            raise ImportFailure(source.name, f"cannot be read, the file is damaged "
                                f"({exc})") from None
    except ImportFailure as exc:
        return False, (isinstance(exc, TooLarge), exc.file, exc.problem, exc.line, exc.place)
    return True, (signals, left - budget[0])


def _declared_bytes(group, names) -> int:
    """What the datasets ``names`` of ``group`` hold unpacked [bytes], from their declared
    shapes and types (nothing is read; read as float64 they take at most twice that)."""
    return sum(group[name].dtype.itemsize * int(np.prod(group[name].shape, dtype=object))
               for name in names if name in group)


def _inside(source: SourceFile, parent, name: str, where: str):
    """``parent[name]``, refused unless its data are in this file: HDF5 lets a link
    (external, soft) or a dataset (external raw storage, virtual) name another file by
    its path, which would read a file of the reading machine's disk."""
    import h5py

    link = parent.get(name, getlink=True)
    if not isinstance(link, h5py.HardLink):
        raise ImportFailure(source.name, f"{where} is a link ({type(link).__name__}); "
                            "an import reads only what the file holds")
    item = parent[name]
    if isinstance(item, h5py.Dataset) and (
            item.is_virtual or item.id.get_create_plist().get_external_count()):
        raise ImportFailure(source.name, f"{where} keeps its data in another file "
                            "(external or virtual); an import reads only what the file holds")
    return item


def _sensors(source: SourceFile, h5, budget: list[int]) -> list[Signal]:
    version = h5.attrs.get("FileFormatVersion")
    version = int(np.asarray(version).flat[0]) if version is not None else None
    if "Sensors" not in h5:
        raise ImportFailure(source.name, f"no /Sensors group (file format version {version}); "
                            f"armtrack reads APDM file format version(s) "
                            f"{', '.join(map(str, READ_VERSIONS))}: export again from a "
                            "current Motion Studio or Mobility Lab")
    out = []
    sensors = _inside(source, h5, "Sensors", "/Sensors")
    for sid in sensors:
        group = _inside(source, sensors, sid, f"/Sensors/{sid}")
        where = f"{source.name}:/Sensors/{sid}"
        label = ""
        if "Configuration" in group:
            config = _inside(source, group, "Configuration", f"/Sensors/{sid}/Configuration")
            label = _text(config.attrs.get("Label 0", b""))
        missing = [d for d in ("Time", "Accelerometer", "Gyroscope") if d not in group]
        if missing:
            raise ImportFailure(where, f"dataset {', '.join(missing)} is missing (Time, "
                                "Accelerometer and Gyroscope are needed)")
        names = [n for n in ("Time", "Accelerometer", "Gyroscope", "Magnetometer") if n in group]
        data = {n: _inside(source, group, n, f"/Sensors/{sid}/{n}") for n in names}
        size = _declared_bytes(group, names)
        if size > budget[0]:
            raise TooLarge(source.name, f"/Sensors/{sid} declares datasets of {size} bytes "
                           f"unpacked, more than the {budget[0]} left of the {budget[1]} "
                           "bytes the files of an import may unpack to "
                           "(ARMTRACK_MAX_UPLOAD_BYTES on a server)")
        budget[0] -= size
        try:
            time_us = np.asarray(data["Time"][()], dtype=np.int64)
            acc = np.asarray(data["Accelerometer"][()], dtype=np.float64)
            gyr = np.asarray(data["Gyroscope"][()], dtype=np.float64)
            mag = (np.asarray(data["Magnetometer"][()], dtype=np.float64)
                   if "Magnetometer" in data else None)
        except (OSError, KeyError) as exc:
            raise ImportFailure(where, f"cannot be read, the file is truncated or damaged "
                                f"({exc})") from None
        n = len(time_us)
        for name, values in (("Accelerometer", acc), ("Gyroscope", gyr), ("Magnetometer", mag)):
            if values is not None and values.shape != (n, 3):
                raise ImportFailure(where, f"{name} has shape {values.shape}, Time has {n} "
                                    "samples: expected (samples, 3)")
        # µs since the epoch: keep the integers' precision, then seconds
        t = (time_us - time_us[0]) / 1e6 if n else np.zeros(0)
        out.append(Signal(format=NAME, label=f"{label} ({sid})" if label else str(sid),
                          files=(where,), t=t, epoch=time_us[0] / 1e6 if n else 0.0,
                          acc=acc, gyr=gyr, mag=mag, clock="unix",
                          lines=np.arange(1, n + 1), place="sample",
                          metadata={"apdm_file_format_version": str(version)}))
    return out
