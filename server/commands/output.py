"""Where a command writes its table: a file (written whole, then renamed into place) or
standard output."""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TextIO


@contextlib.contextmanager
def open_output(path: Path | None) -> Iterator[TextIO]:
    """A text stream to ``path``, or standard output when ``path`` is None. A file appears
    only once complete, so an error midway never leaves half a table behind."""
    if path is None:
        yield sys.stdout
        return
    directory = Path(path).resolve().parent
    fd, tmp = tempfile.mkstemp(prefix=f".{Path(path).name}.", dir=directory)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as file:
            yield file
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_angles_csv(out: TextIO, columns: list[str], values) -> None:
    """``armtrack estimate``'s table: t and angles [deg] to 4 decimals, positions [m] to 5
    (the last 12 columns)."""
    import numpy as np

    out.write(",".join(columns) + "\n")
    np.savetxt(out, values, delimiter=",",
               fmt=["%.4f"] * (len(columns) - 12) + ["%.5f"] * 12)
