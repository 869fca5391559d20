"""UTC <-> GPS time: the time base of imported recordings is GPS seconds of week (as in SBET files).

GPS time = UTC + the leap seconds accumulated since 1980-01-06 (IERS Bulletin C; 18 s since
2017-01-01, none announced after it). A recording keeps the week of its first return: its times
are seconds since the start of that week, so a recording that runs past Sunday 00:00 GPS goes
on above 604800 s instead of wrapping.
"""

from __future__ import annotations

import calendar

import numpy as np

GPS_EPOCH_UTC = calendar.timegm((1980, 1, 6, 0, 0, 0))  # s since 1970 UTC
WEEK_S = 604800.0
# UTC instants (s since 1970) from which GPS - UTC = index + 1 s
_LEAPS = [calendar.timegm((y, m, 1, 0, 0, 0)) for y, m in (
    (1981, 7), (1982, 7), (1983, 7), (1985, 7), (1988, 1), (1990, 1), (1991, 1), (1992, 7), (1993, 7),
    (1994, 7), (1996, 1), (1997, 7), (1999, 1), (2006, 1), (2009, 1), (2012, 7), (2015, 7), (2017, 1))]


def leap_seconds(utc_s) -> np.ndarray:
    """GPS - UTC [s] at UTC times (s since 1970)."""
    return np.searchsorted(_LEAPS, np.asarray(utc_s, dtype=np.float64), side="right").astype(np.float64)


def seconds_of_week(utc_base_s: float, offset_s, week: int | None = None) -> tuple[np.ndarray, int]:
    """UTC times utc_base_s + offset_s (s since 1970; a whole-second base keeps float64 precision)
    -> (GPS seconds since the start of `week`, week); week defaults to that of the first time."""
    offset_s = np.asarray(offset_s, dtype=np.float64)
    ends = leap_seconds(utc_base_s + np.ravel(offset_s)[[0, -1]])
    leap = ends[0] if ends[0] == ends[1] else leap_seconds(utc_base_s + offset_s)  # one value unless a leap inside
    base = float(utc_base_s) - GPS_EPOCH_UTC
    first = base + float(np.ravel(leap)[0]) + float(np.ravel(offset_s)[0])
    week = int(np.floor(first / WEEK_S)) if week is None else week
    return (base - week * WEEK_S) + leap + offset_s, week
