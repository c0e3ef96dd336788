"""Large answers written to a temporary file, then streamed from it: a finished export waits
for its download on disk, not in the server's memory. The file is unnamed (gone with the
answer, or a crash) in the data folder, kept in memory up to ``SPOOL_BYTES``."""

from __future__ import annotations

import io
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO, TextIO

from fastapi.responses import StreamingResponse

#: An answer is kept in memory up to this size, then in a temporary file [B].
SPOOL_BYTES = 1 << 20
#: An answer is sent this many bytes at a time [B].
CHUNK_BYTES = 1 << 20


def spooled(write: Callable[[BinaryIO], None], data_dir: Path, media_type: str,
            filename: str) -> StreamingResponse:
    """The bytes ``write(file)`` writes, as an attachment named ``filename``."""
    spool = tempfile.SpooledTemporaryFile(SPOOL_BYTES, dir=data_dir)
    try:
        write(spool)
        spool.seek(0)
    except BaseException:
        spool.close()
        raise
    return SpooledResponse(spool, media_type=media_type, headers={
        "Content-Disposition": f'attachment; filename="{filename}"'})


class SpooledResponse(StreamingResponse):
    """The spool's bytes; the spool is closed (its file gone) when the answer ends,
    however it ends. Left to the end of the chunks or the garbage collector, a client
    that went away before reading held each export's file on disk (ten of a 360k-row
    session's angles.csv: 220 MB still there 40 s after the clients closed)."""

    def __init__(self, spool: BinaryIO, **kwargs) -> None:
        super().__init__(chunks(spool), **kwargs)
        self.spool = spool
        #: called once the answer has ended, however it ended (``deps.in_export_turn``)
        self.on_end: Callable[[], None] = lambda: None

    async def __call__(self, scope, receive, send) -> None:
        try:
            await super().__call__(scope, receive, send)
        finally:
            self.spool.close()
            self.on_end()


def as_text(write: Callable[[TextIO], None]) -> Callable[[BinaryIO], None]:
    """``write`` of text (UTF-8, ``\\n`` lines) as a writer of bytes."""
    def binary(out: BinaryIO) -> None:
        text = io.TextIOWrapper(out, encoding="utf-8", newline="\n")
        write(text)
        text.flush()
        text.detach()  # the spool stays open for the answer
    return binary


def chunks(spool: BinaryIO) -> Iterator[bytes]:
    """The file's bytes, CHUNK_BYTES at a time; closes it at the end."""
    with spool:
        while chunk := spool.read(CHUNK_BYTES):
            yield chunk
