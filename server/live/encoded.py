"""A live ``pose`` update as the live estimation process encodes it: its JSON text, made
once where the pose is computed. The server's event loop then passes the text on to every
viewer instead of unpickling a nested dict and encoding it again per viewer (at 200
patients those were a tenth of the event loop's time, ``bench/ingest.py``). It reads as
the update's dict (a ``Mapping``, parsed on first use) where the server looks inside:
the in-process 3D viewer and ``/api/patients/{id}/live``."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import orjson


class EncodedPose(Mapping[str, Any]):
    """A pose update: ``text`` its compact JSON (UTF-8, ``orjson``, the same bytes as
    ``orjson.dumps`` of the dict), ``warnings`` the estimator's warnings so far (also in
    the text)."""

    __slots__ = ("_parsed", "text", "warnings")

    def __init__(self, text: bytes, warnings: tuple[str, ...] = ()):
        self.text = text
        self.warnings = warnings
        self._parsed: dict[str, Any] | None = None

    @classmethod
    def encode(cls, pose: dict[str, Any]) -> EncodedPose:
        return cls(orjson.dumps(pose), tuple(pose.get("warnings", ())))

    def with_field(self, key: str, value: Any) -> EncodedPose:
        """The update with one more top-level field, appended to the text as ``orjson``
        would write it last (``key`` must not be in the update yet)."""
        extra = b"," + orjson.dumps(key) + b":" + orjson.dumps(value) + b"}"
        return EncodedPose(self.text[:-1] + extra, self.warnings)

    def __reduce__(self) -> tuple[Any, ...]:  # pickled as its text: no parsed dict
        return EncodedPose, (self.text, self.warnings)

    def _dict(self) -> dict[str, Any]:
        if self._parsed is None:
            self._parsed = orjson.loads(self.text)
        return self._parsed

    def __getitem__(self, key: str) -> Any:
        return self._dict()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._dict())

    def __len__(self) -> int:
        return len(self._dict())

    def __repr__(self) -> str:
        return f"EncodedPose({self.text[:60]!r}…)"
