"""Files as the user gives them: a file, a folder of files, or a zip of files (a Sensor
Logger export, a MetaBase session) → :class:`SourceFile` objects."""

from __future__ import annotations

import io
import zipfile
import zlib
from pathlib import Path

from .base import MAX_UNPACKED_BYTES, ImportFailure, SourceFile, TooLarge

#: Most files a zip may hold (an export holds a few dozen; listing a zip of millions of
#: empty members costs minutes and gigabytes).
MAX_ZIP_MEMBERS = 1000
#: What a damaged or unusual zip raises when opened or read (a name that is not the
#: UTF-8 it says it is, a password, a compression zipfile cannot undo, broken data).
_UNZIP_ERRORS = (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, zlib.error,
                 UnicodeDecodeError, RuntimeError, NotImplementedError, ValueError)


def is_zip(data: bytes) -> bool:
    return data[:4] == b"PK\x03\x04"


def unzip(name: str, data: bytes, limit: int = MAX_UNPACKED_BYTES) -> list[SourceFile]:
    """The regular files inside a zip (macOS resource forks and hidden files left out)."""
    # every member has a central directory entry starting so: a bound read in C
    if data.count(b"PK\x01\x02") > MAX_ZIP_MEMBERS:
        raise ImportFailure(name, f"holds more than {MAX_ZIP_MEMBERS} files; zip the "
                            "recording's files alone")
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except _UNZIP_ERRORS as exc:
        raise ImportFailure(name, f"not a readable zip file ({exc})") from None
    members = [m for m in archive.infolist() if not m.is_dir()
               and not m.filename.startswith("__MACOSX/")
               and not m.filename.rsplit("/", 1)[-1].startswith(".")]
    total = sum(m.file_size for m in members)
    if total > limit:
        raise TooLarge(name, f"unpacks to {total} bytes, more than {limit}")
    out = []
    for m in sorted(members, key=lambda m: m.filename):
        try:
            out.append(SourceFile(f"{name}/{m.filename}", archive.read(m)))
        except _UNZIP_ERRORS as exc:
            raise ImportFailure(f"{name}/{m.filename}", f"cannot be unpacked ({exc})") from None
    return out


def expand(path: Path) -> list[SourceFile]:
    """A path's files: itself, a folder's regular files (not recursive), or a zip's."""
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.is_file() and not p.name.startswith("."))
        if not files:
            raise ImportFailure(str(path), "the folder holds no files")
        return [s for p in files for s in expand(p)]
    data = path.read_bytes()
    if is_zip(data):
        return unzip(str(path), data)
    return [SourceFile(str(path), data)]


def expand_upload(name: str, data: bytes, limit: int = MAX_UNPACKED_BYTES) -> list[SourceFile]:
    """An uploaded file's files: itself, or a zip's members (unpacking to at most
    ``limit`` bytes)."""
    return unzip(name, data, limit) if is_zip(data) else [SourceFile(name, data)]
