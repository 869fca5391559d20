"""NMEA $GPRMC / $GNRMC sentences (the fixes Velodyne position packets carry)."""

from __future__ import annotations

import calendar
import re
from dataclasses import dataclass

_RMC = re.compile(rb"\$(?:GP|GN)RMC,[^*\r\n]*\*[0-9A-Fa-f]{2}")


@dataclass(frozen=True)
class RmcFix:
    """One recommended-minimum fix: UTC time (s since 1970), WGS 84 lat/lon [deg], status A (valid)."""

    utc_s: float
    lat_deg: float
    lon_deg: float
    valid: bool


def find_rmc(payload: bytes) -> RmcFix | None:
    """The first well-formed RMC sentence in a byte string (checksum checked), or None."""
    match = _RMC.search(payload)
    if match is None:
        return None
    sentence = match.group().decode("ascii")
    body, checksum = sentence[1:].split("*")
    computed = 0
    for char in body.encode("ascii"):
        computed ^= char
    if computed != int(checksum, 16):
        return None
    return _parse(body.split(","))


def _parse(fields: list[str]) -> RmcFix | None:
    # RMC: hhmmss.ss, status, lat ddmm.mm, N/S, lon dddmm.mm, E/W, speed kn, course deg, date ddmmyy, ...
    try:
        clock, status, lat, ns, lon, ew, date = fields[1], fields[2], fields[3], fields[4], fields[5], fields[6], fields[9]
        day, month, year = int(date[0:2]), int(date[2:4]), 2000 + int(date[4:6])
        hours, minutes, seconds = int(clock[0:2]), int(clock[2:4]), float(clock[4:])
        lat_deg = (int(lat[:2]) + float(lat[2:]) / 60.0) * (-1.0 if ns == "S" else 1.0)
        lon_deg = (int(lon[:3]) + float(lon[3:]) / 60.0) * (-1.0 if ew == "W" else 1.0)
    except (IndexError, ValueError):
        return None
    if year > 2079:  # two-digit years: 80-99 are the 1900s (GPS starts in 1980)
        year -= 100
    utc_s = calendar.timegm((year, month, day, hours, minutes, 0)) + seconds
    return RmcFix(utc_s=utc_s, lat_deg=lat_deg, lon_deg=lon_deg, valid=status == "A")
