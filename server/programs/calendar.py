"""Days and ISO weeks in the clinic's time zone (``docs/programs.md``, "Days and weeks"):
a session counts on the day it started; weeks run Monday to Sunday."""

from __future__ import annotations

from datetime import UTC, date, datetime, timedelta
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from .. import clock


def clinic_zone(name: str) -> ZoneInfo:
    """The clinic's time zone from its IANA name; a clear error for an unknown one."""
    try:
        return ZoneInfo(name)
    except (ZoneInfoNotFoundError, ValueError):
        raise ValueError(f"ARMTRACK_CLINIC_TIMEZONE: unknown time zone {name!r} (an IANA "
                         "name such as Europe/Zurich)") from None


def aware(moment: datetime) -> datetime:
    """SQLite gives naive datetimes back; they were stored in UTC."""
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


def local_day(moment: datetime, zone: ZoneInfo) -> date:
    """The clinic's calendar day of ``moment``."""
    return aware(moment).astimezone(zone).date()


def today(zone: ZoneInfo) -> date:
    return local_day(clock.now(), zone)


def monday(day: date) -> date:
    return day - timedelta(days=day.weekday())


def week_name(day: date) -> str:
    """``2026-W49``: the ISO year and week of ``day``."""
    year, week, _ = day.isocalendar()
    return f"{year}-W{week:02d}"


def start_of_day(day: date, zone: ZoneInfo) -> datetime:
    """The moment the clinic's day begins [UTC]."""
    return datetime(day.year, day.month, day.day, tzinfo=zone).astimezone(UTC)
