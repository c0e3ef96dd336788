"""Large answers written to a temporary file, then streamed from it: a finished export waits
for its download on disk, not in the server's memory. The file is unnamed (gone with the
answer, or a crash) in the data folder, kept in memory up to ``SPOOL_BYTES``."""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import io
import logging
import tempfile
from collections.abc import Callable, Iterator
from contextlib import AbstractAsyncContextManager
from pathlib import Path
from typing import BinaryIO, TextIO

from fastapi.responses import JSONResponse, StreamingResponse

log = logging.getLogger("armtrack.access")

#: An answer is kept in memory up to this size, then in a temporary file [B].
SPOOL_BYTES = 1 << 20
#: An answer is sent this many bytes at a time [B].
CHUNK_BYTES = 1 << 20

#: Set in the request's task once ``SpooledResponse`` cut its download on purpose: the
#: server then leaves the answer unfinished, which uvicorn logs as an error
#: (``DeliberateCutNotError`` keeps that line out).
download_cut: contextvars.ContextVar[bool] = contextvars.ContextVar("download_cut",
                                                                   default=False)

#: uvicorn's words for an answer its application left unfinished.
UNFINISHED_ANSWER = "ASGI callable returned without completing response."


class DeliberateCutNotError(logging.Filter):
    """For uvicorn's error logger: drops its "returned without completing response" line
    when the answer was a download cut off on purpose (the ``armtrack.access`` line before
    it says why); any other unfinished answer is still logged as the error it is."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not (record.msg == UNFINISHED_ANSWER and download_cut.get())


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


#: What cuts a download short: ``guard(cut)`` is held while the answer is sent and calls
#: ``cut(code, reason)`` once the right to it is gone (``deps.in_export_turn``).
Guard = Callable[[Callable[[int, str], None]], AbstractAsyncContextManager[None]]


class SpooledResponse(StreamingResponse):
    """The spool's bytes; the spool is closed (its file gone) when the answer ends,
    however it ends. Left to the end of the chunks or the garbage collector, a client
    that went away before reading held each export's file on disk (ten of a 360k-row
    session's angles.csv: 220 MB still there 40 s after the clients closed).

    With a ``guard``, the answer is sent only while its right holds: gone before the first
    byte, the answer is the refusal (401 or 404, in words); gone later, the rest is not
    sent and the connection closes, the body left without its end (a client sees the
    download fail, never a file cut short that looks whole). What the network already
    holds (the sockets' buffers, a few MB) still arrives."""

    def __init__(self, spool: BinaryIO, **kwargs) -> None:
        super().__init__(chunks(spool), **kwargs)
        self.spool = spool
        #: called once the answer has ended, however it ended (``deps.in_export_turn``)
        self.on_end: Callable[[], None] = lambda: None
        self.guard: Guard | None = None

    async def __call__(self, scope, receive, send) -> None:
        try:
            if self.guard is None:
                await super().__call__(scope, receive, send)
            else:
                await self._guarded(self.guard, scope, receive, send)
        finally:
            self.spool.close()
            self.on_end()

    async def _guarded(self, guard: Guard, scope, receive, send) -> None:
        gone: asyncio.Future[tuple[int, str]] = asyncio.get_running_loop().create_future()

        def cut(code: int, reason: str) -> None:
            if not gone.done():
                gone.set_result((code, reason))
        async with guard(cut):
            if gone.done():  # the right went before anything was sent
                code, reason = gone.result()
                await JSONResponse({"detail": reason}, status_code=401 if code == 4401
                                   else 404)(scope, receive, send)
                return
            sending = asyncio.ensure_future(super().__call__(scope, receive, send))
            try:
                await asyncio.wait((sending, gone), return_when=asyncio.FIRST_COMPLETED)
            finally:
                if not sending.done():
                    sending.cancel()
                    with contextlib.suppress(asyncio.CancelledError):
                        await sending
        if not sending.cancelled():
            sending.result()  # sent whole (or failed on its own)
            return
        code, reason = gone.result()
        download_cut.set(True)  # read by DeliberateCutNotError in this request's task
        log.info("cut off a download of %s: %s (%s); the rest is not sent and the "
                 "connection is closed", scope.get("path"), reason, code)


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
