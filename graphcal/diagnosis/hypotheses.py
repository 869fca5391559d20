"""Physics that produces a discrepancy of one channel against one regressor, in plain words, most likely
first: what a `discovered` finding (diagnosis.json, RECORDING.md "Discovered effects") offers as its
hypotheses. Wider than the named candidates: most entries have no model in graphcal, which is why a
discovered finding needs them (sources: the shared notes' catalogue of left-out physics, the Velodyne
manuals, Glennie & Lichti 2010-2011, Laconte et al. 2018)."""

from __future__ import annotations

CATALOGUE: dict[tuple[str, str], tuple[str, ...]] = {
    ("range", "intensity"): (
        "range walk: the detector's threshold fires later on weak returns, so they read long",
        "intensity-dependent range correction of the firmware wrong or missing (lane paint and signs read off)",
        "laser power switching between levels, each with its own range offset"),
    ("range", "range"): (
        "a range-dependent offset beyond a linear scale: the factory calibration's two-point correction "
        "(near and far targets) leaves a curve between them",
        "the time-of-flight clock's non-linearity",
        "beam divergence: the footprint grows with range and its centroid moves on oblique surfaces"),
    ("range", "incidence"): (
        "the footprint spreads on oblique surfaces and the pulse detector fires late (a bias growing with tan "
        "of the incidence)",
        "mixed pixels on grazing surfaces: part of the footprint returns from further away"),
    ("range", "time"): (
        "thermal drift of the range offset since power-on (the head warms over the first minutes)",
        "the time-of-flight clock drifting with temperature (a range scale changing in time)"),
    ("range", "azimuth"): (
        "the spinning head's window or cover adding a path length that varies around the turn",
        "a reflection or blockage by the vehicle in part of the turn",
        "runout of the spinning head: the optical centre moving on a small circle as it turns"),
    ("range", "speed"): (
        "the vehicle's motion during the pulse's flight not compensated (Doppler-like delay)",
        "vibration of the mount growing with speed"),
    ("range", "yaw_rate"): (
        "a rotation of the vehicle not compensated inside a firing: the lever arm moves during the flight",),
    ("azimuth", "azimuth"): (
        "the encoder disc off the spin axis (eccentricity, one cycle per turn) or out of round (two or more)",
        "wobble of the spinning head: its axis tilted and precessing, seen as an azimuth error per turn",
        "the encoder's graduation errors (a harmonic of the number of marks)"),
    ("azimuth", "range"): (
        "the lasers sit beside the spin axis (a horizontal offset): the angle error shrinks as 1/range",
        "the beam leaves the head off its nominal direction by a fixed distance rather than an angle"),
    ("azimuth", "time"): (
        "the spin rate drifting in time while times inside the revolution are derived at the nominal rate",
        "the encoder's zero drifting with temperature"),
    ("azimuth", "speed"): (
        "a latency between the encoder reading and the firing, converted to an angle by the spin rate",),
    ("azimuth", "yaw_rate"): (
        "the vehicle's rotation during a firing cycle not compensated (the beam leaves at a turned azimuth)",
        "a time offset of the attitude (the yaw lags the position)"),
    ("azimuth", "intensity"): (
        "per-laser timing inside a firing: lasers fired one after another at the spin rate look turned",),
    ("elevation", "azimuth"): (
        "wobble of the spinning head (bearing play, an out-of-round bearing): the elevation nods as it turns",
        "runout of the spinning head",
        "the spin axis tilted against the head's base (once per turn; the boresight takes most of it)"),
    ("elevation", "range"): (
        "the lasers sit above or below their nominal height (a vertical offset): the angle error shrinks "
        "as 1/range",
        "the beam's divergence clipped on near surfaces"),
    ("elevation", "time"): (
        "thermal expansion of the head tilting its lasers since power-on",
        "the mount settling or flexing during the drive"),
    ("elevation", "speed"): (
        "the mount pitching with speed (aerodynamic load, suspension squat)",),
    ("elevation", "yaw_rate"): (
        "the vehicle rolling in turns beyond what the INS attitude reports (the lidar's mount flexes)",),
    ("elevation", "incidence"): (
        "mixed pixels at edges: returns from two surfaces blended near grazing incidence",),
    ("time", "azimuth"): (
        "times inside the revolution derived from the azimuth with the wrong spin rate or cut",
        "per-laser or per-block firing times the driver does not apply"),
    ("time", "time"): (
        "the lidar's clock drifting against the INS clock (no PPS lock)",
        "a time offset that changes when the GNSS fix changes"),
    ("time", "speed"): (
        "a latency that depends on the data rate (a buffer filling with the point rate)",),
    ("time", "fibre"): (
        "per-laser firing times inside a block that the driver does not apply",),
    ("time", "range"): (
        "the time of flight not removed from the stamp (a delay proportional to range)",),
}
GENERIC = ("an error of the {channel} that depends on the {regressor}; no catalogued physics has this pairing",)


def hypotheses(channel: str, regressor: str) -> list[str]:
    """Physics for a discrepancy of channel against regressor, most likely first."""
    return list(CATALOGUE.get((channel, regressor), tuple(h.format(channel=channel, regressor=regressor)
                                                          for h in GENERIC)))
