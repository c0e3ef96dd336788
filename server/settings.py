"""Server settings, read from the environment with the prefix ``ARMTRACK_``
(``ARMTRACK_DATABASE_URL``, ``ARMTRACK_DATA_DIR``, ``ARMTRACK_HOST``, ``ARMTRACK_PORT``, …).

The defaults need nothing: an SQLite file ``armtrack.db`` in the data folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """Everything the server can be told; each field is ``ARMTRACK_<NAME>``."""

    model_config = SettingsConfigDict(env_prefix="ARMTRACK_", extra="ignore")

    data_dir: Path = Field(Path("armtrack-data"),
                           description="folder for the SQLite file and other server files")
    database_url: str | None = Field(
        None, description="SQLAlchemy URL; default sqlite:///<data_dir>/armtrack.db")
    host: str = Field("127.0.0.1", description="address to listen on (0.0.0.0: every "
                      "interface; needs TLS or ARMTRACK_BEHIND_PROXY)")
    port: int = Field(8000, ge=0, le=65535, description="port to listen on")
    access_token_hours: float = Field(12.0, gt=0, description="lifetime of a sign-in [h]")
    max_message_bytes: int = Field(1 << 20, gt=0, description="largest ingest message [B]")
    ack_interval_s: float = Field(0.1, gt=0, le=1.0,
                                  description="longest wait to group commits before acking [s]")
    refused_limit: int = Field(50, gt=0, description="refused messages per window before 4429")
    refused_window_s: float = Field(10.0, gt=0, description="window of ARMTRACK_REFUSED_LIMIT [s]")
    processing_threads: int = Field(2, ge=1, description="threads for estimation work "
                                    "done in the server process")
    processing_processes: int = Field(1, ge=0, le=1, description="processes estimating "
                                      "closed sessions, at a lower CPU priority (0: threads "
                                      "of the server process)")
    processing_share_live: float = Field(
        0.25, gt=0, le=1, description="most share of the time the processing process works "
        "while streams are live: it rests after each session (1: no rest)")
    live_poses_hz: float = Field(30.0, gt=0, description="most live poses published per second")
    live_processes: int = Field(1, ge=0, le=64, description="processes computing the live "
                                "estimates (0: threads of the server process)")
    live_batch_s: float = Field(0.01, gt=0, le=0.5,
                                description="how long live messages gather before a batch [s]")
    broker_url: str | None = Field(
        None, description="Redis URL of the live broker shared by several server instances "
        "(README \"Scaling out\"); unset: live updates stay in this process")
    viewer_port: int = Field(0, ge=0, le=65535,
                             description="loopback port of the 3D viewer (viser); 0: any free one")
    viewer_grant_s: float = Field(60.0, gt=0, le=3600,
                                  description="lifetime of a one-time viewer address [s]")

    # -- security (README "Security") ----------------------------------------------------
    demo_mode: bool = Field(False, description="set by `armtrack demo`: the demo account "
                            "(user demo) signs in only in demo mode")
    tls_cert: Path | None = Field(None, description="TLS certificate (PEM) for uvicorn")
    tls_key: Path | None = Field(None, description="TLS private key (PEM) for uvicorn")
    behind_proxy: bool = Field(False, description="a reverse proxy in front terminates TLS: "
                               "a non-loopback host without ARMTRACK_TLS_CERT is allowed")
    public_url: str | None = Field(
        None, pattern=r"^https?://[^/?#\s]+(/[^?#\s]*)?$",
        description="the address patients' phones reach this server by, e.g. "
        "https://rehab.example.org (the phone kit's link and QR code); phones need https "
        "for motion sensors. Unset: the address the therapist's browser used")
    cors_origins: str = Field("", description="comma-separated origins allowed to call the "
                              "API from a browser (CORS); empty: none (closed)")
    max_upload_bytes: int = Field(200 << 20, gt=0,
                                  description="largest recording upload [B] (else 413)")
    max_body_bytes: int = Field(1 << 20, gt=0,
                                description="largest body of any other request [B] (else 413)")
    body_timeout_s: float = Field(30.0, gt=0, description="longest wait for the next part of "
                                  "a request body [s] (else 408)")
    max_streams_per_kit: int = Field(4, ge=1, description="most ingest connections one kit "
                                     "token holds open at once (more: 4429)")
    kit_messages_per_s: float = Field(
        3000.0, gt=0, description="most ingest messages the server reads from one kit "
        "token a second, all its streams together (60x real time of a kit of 5 sensors "
        "at 100 Hz sending 10 rows a message, 50 a second): past it the server reads "
        "the kit's sockets no faster (TCP pushes back; nothing refused, nothing acked "
        "lost)")
    kit_rows_per_s: float = Field(
        50000.0, gt=0, description="most sample rows the server reads from one kit token "
        "a second, all its streams and sensors together (100x real time of 5 sensors at "
        "100 Hz): past it the server reads the kit's sockets no faster")
    ingest_messages_per_s: float = Field(
        8000.0, gt=0, description="most ingest messages the server reads a second from all "
        "kits together, shared among their therapists, each therapist's streams in turn (200 "
        "kits of 3 sensors at 100 Hz sending 10 rows a message send 6,000): past it every "
        "stream is read one message at a time in turn, no faster (TCP pushes back; nothing "
        "refused, nothing acked lost)")
    ingest_rows_per_s: float = Field(
        100000.0, gt=0, description="most sample rows the server reads a second from all "
        "kits together (200 kits of 3 sensors at 100 Hz send 60,000): past it every "
        "stream is read in turn, no faster")
    max_new_sessions_per_kit_hour: int = Field(
        20, ge=1, description="most new sessions one kit token starts in an hour (the "
        "next hello without resume or session: error naming the limit, close 4429; the kit "
        "keeps its data and tries again); resumes and new streams of a session are not "
        "new sessions")
    max_session_samples: int = Field(
        2_000_000, ge=1, description="most samples (rows, all sensors and points together) "
        "one session holds, streamed or uploaded: a closed session's estimation holds them "
        "all in memory (about 0.6 kB a row); a stream's message that would pass it is "
        "refused (error naming it, the stream stays open), an upload over it is 413")
    max_kit_samples_per_day: int = Field(
        10_000_000, ge=1, description="most samples (rows, all sensors and points "
        "together) one kit token stores in its sessions of the last 24 hours, streamed and "
        "uploaded (~5.5 h of five sensors at 100 Hz): a stream's message that would pass it "
        "is refused (error naming it, the stream stays open), an upload over it is 429; "
        "nothing stored in part")
    max_live_feeds_per_user: int = Field(
        20, ge=1, description="most live feeds one therapist account holds open at once, "
        "all its sign-ins together, in one server instance: /ws/live feeds, open 3D views "
        "and viewer grants not yet used (a live session page holds 2); more: /ws/live "
        "closes 4429, POST /api/viewer answers 429, both naming the limit")
    login_max_failures: int = Field(10, gt=0, description="failed sign-ins per user name and "
                                    "per client address within the window that cost "
                                    "nothing; each one after slows the next attempt down")
    login_window_s: float = Field(300.0, gt=0, description="window of failed sign-ins [s]")
    login_max_delay_s: float = Field(60.0, gt=0, description="longest wait a failed sign-in "
                                     "imposes on its user name or address [s] (1, 2, 4 … s)")
    trusted_proxies: str = Field("", description="comma-separated addresses or networks of "
                                 "the reverse proxies whose X-Forwarded-For names the client "
                                 "(sign-in limit, audit log); empty: none, the peer is the "
                                 "client")
    reset_token_hours: float = Field(24.0, gt=0,
                                     description="lifetime of an admin-issued reset token [h]")
    retention_days: float | None = Field(None, gt=0, description="erase closed sessions "
                                         "this long after they ended; unset: keep them")
    retention_check_s: float = Field(3600.0, gt=0,
                                     description="how often the retention task runs [s]")
    close_interrupted_after_hours: float = Field(
        168.0, ge=0, description="close an interrupted session whose kit sent nothing for "
        "this long, and estimate it (docs/extensions/closed-after-silence.md); 0: never")
    close_interrupted_check_s: float = Field(
        600.0, gt=0, description="how often interrupted sessions are checked for that [s]")
    access_check_s: float = Field(5.0, gt=0, description="how often open live feeds, 3D "
                                  "views and downloads, and kits' streams, are checked "
                                  "against rights changed elsewhere (the command line, "
                                  "another instance) [s]")
    audit_repeat_s: float = Field(60.0, ge=0, description="a repeated view of the same data "
                                  "by the same person within this time is logged once [s]")

    # -- the clinic (pages, reports; docs/operator.md "Settings") -------------------------------
    clinic_name: str = Field("", max_length=200, description="the clinic's name, printed "
                             "on reports and shown on pages")
    clinic_address: str = Field("", max_length=500, description="the clinic's address, "
                                "printed on reports (lines separated by ', ' or '\\n')")
    clinic_timezone: str = Field("UTC", description="the clinic's IANA time zone "
                                 "(Europe/Paris): pages and reports show local times in it")
    clinic_clock: Literal["24h", "12h"] = Field(
        "24h", description="the clinic's clock: 24h (22:39) or 12h (10:39 PM), for the "
        "times on pages and in reports alike")

    @field_validator("clinic_timezone")
    @classmethod
    def _known_zone(cls, value: str) -> str:
        try:
            ZoneInfo(value)
        except (ZoneInfoNotFoundError, ValueError):
            raise ValueError(f"ARMTRACK_CLINIC_TIMEZONE: unknown time zone {value!r}; give an "
                             "IANA name such as Europe/Paris or America/New_York") from None
        return value

    def clinic_zone(self) -> ZoneInfo:
        """The clinic's time zone."""
        return ZoneInfo(self.clinic_timezone)

    # -- programs (docs/programs.md) ------------------------------------------------------
    flag_no_session_days: int = Field(3, ge=1, le=365, description="flag a patient with a "
                                      "program after this many days without a session")
    flag_window_days: int = Field(14, ge=2, le=365, description="days (counting today) of "
                                  "sessions the range and pain flags look at")
    flag_min_sessions: int = Field(3, ge=2, le=100, description="sessions in the window a "
                                   "range or pain flag needs")
    flag_range_drop_deg_per_week: float = Field(5.0, gt=0, description="flag an exercise "
                                                "whose range falls this fast [deg/week]")
    flag_pain_rise_per_week: float = Field(1.0, gt=0, description="flag pain rising this "
                                           "fast [points of 0-10 per week]")

    def cors_origin_list(self) -> list[str]:
        return [o.strip() for o in self.cors_origins.split(",") if o.strip()]

    def resolved_database_url(self) -> str:
        """The database URL, the default SQLite file made absolute."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'armtrack.db').resolve()}"
