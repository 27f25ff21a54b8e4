"""Registry times: UTC, ISO 8601 basic format ``YYYYMMDDTHHMMSSZ``, as int ns."""

from datetime import datetime, timezone

TIME_FORMAT = '%Y%m%dT%H%M%SZ'


def iso(ns):
    """Return the registry time string of an int ns UTC stamp."""
    return datetime.fromtimestamp(ns // 10 ** 9, timezone.utc).strftime(TIME_FORMAT)


def parse_time(text):
    """Return int ns of a registry time string (raises ValueError when malformed)."""
    dt = datetime.strptime(text, TIME_FORMAT).replace(tzinfo=timezone.utc)
    return int(dt.timestamp()) * 10 ** 9
