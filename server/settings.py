"""Server settings, read from the environment with the prefix ``ARMTRACK_``
(``ARMTRACK_DATABASE_URL``, ``ARMTRACK_DATA_DIR``, ``ARMTRACK_HOST``, ``ARMTRACK_PORT``, …).

The defaults need nothing: an SQLite file ``armtrack.db`` in the data folder.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """Everything the server can be told; each field is ``ARMTRACK_<NAME>``."""

    model_config = SettingsConfigDict(env_prefix="ARMTRACK_", extra="ignore")

    data_dir: Path = Field(Path("armtrack-data"),
                           description="folder for the SQLite file and other server files")
    database_url: str | None = Field(
        None, description="SQLAlchemy URL; default sqlite:///<data_dir>/armtrack.db")
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    access_token_hours: float = Field(12.0, gt=0, description="lifetime of a sign-in [h]")
    max_message_bytes: int = Field(1 << 20, gt=0, description="largest ingest message [B]")
    ack_interval_s: float = Field(0.1, gt=0, le=1.0,
                                  description="longest wait to group commits before acking [s]")
    refused_limit: int = Field(50, gt=0, description="refused messages per window before 4429")
    refused_window_s: float = Field(10.0, gt=0)
    processing_threads: int = Field(2, ge=1, description="threads for estimation work")
    live_poses_hz: float = Field(30.0, gt=0, description="most live poses published per second")
    viewer_port: int = Field(0, ge=0, le=65535,
                             description="loopback port of the 3D viewer (viser); 0: any free one")
    viewer_grant_s: float = Field(60.0, gt=0, le=3600,
                                  description="lifetime of a one-time viewer address [s]")

    def resolved_database_url(self) -> str:
        """The database URL, the default SQLite file made absolute."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'armtrack.db').resolve()}"
