"""When a result was made: the date written into reports and calibrated files.

The date is the only field that differs between two runs with the same inputs and seed. Like
reproducible-build tools, pkmcal takes it from ``SOURCE_DATE_EPOCH`` (whole seconds since
1970-01-01 UTC) when that variable is set, so two runs can give byte-identical files.
"""

from __future__ import annotations

import datetime
import os

from ..errors import InputError

__all__ = ["pinned_date", "run_date"]


def run_date() -> str:
    """The date of this run, ISO 8601 in UTC to the second.

    Returns
    -------
    str
        ``SOURCE_DATE_EPOCH`` when set (e.g. ``'2026-01-01T00:00:00+00:00'``), else now.

    Raises
    ------
    InputError
        When ``SOURCE_DATE_EPOCH`` is set but not a whole number of seconds in range.
    """
    pinned = os.environ.get("SOURCE_DATE_EPOCH")
    if pinned is None:
        when = datetime.datetime.now(datetime.UTC)
    else:
        text = pinned.strip()
        try:
            if not text.isdigit():
                raise ValueError
            when = datetime.datetime.fromtimestamp(int(text), datetime.UTC)
        except (ValueError, OverflowError, OSError):
            raise InputError(f"SOURCE_DATE_EPOCH={pinned!r}: not a whole number of seconds "
                             "since 1970-01-01 UTC (e.g. SOURCE_DATE_EPOCH=$(date +%s))"
                             ) from None
    return when.isoformat(timespec="seconds")


def pinned_date() -> bool:
    """Whether this run's date is pinned (``SOURCE_DATE_EPOCH`` set): a reproducible build,
    whose outputs then hold nothing that varies from run to run - no time stamp, and no
    measured duration (a Monte Carlo's timing is left out of its files, printed only).

    Returns
    -------
    bool
        ``SOURCE_DATE_EPOCH`` is set (its value is checked by :func:`run_date`).
    """
    return os.environ.get("SOURCE_DATE_EPOCH") is not None
