"""One plain line on what a drive could not observe and which manoeuvre or scene would show it.

A calibration names every parameter the data cannot see (calibration.yaml `unobservable`, with a reason each).
On a degenerate drive (a standstill, a straight line, a flat plain) that is tens of names; a user needs the
verdict: which groups of parameters, and what to record next time. The manoeuvres follow from the geometry
(docs/reference/math.md "Observability"): the lever arm and the boresight yaw move the cloud differently only
when the vehicle turns; the lever arm's height only when it rolls or pitches; a fibre's range offset, elevation
and height only when it sees surfaces at several ranges and orientations.
"""

from __future__ import annotations

from graphcal.calibration.observability import TRAJECTORY_GAUGE

RIGID_REASON = "a static sensor: the whole cloud moves rigidly with it"

# what shows each extrinsic axis, in the words of the verdict
EXTRINSIC_MANOEUVRE = {
    "roll_deg": "turns", "pitch_deg": "turns", "yaw_deg": "turns", "lever_arm_x_m": "turns",
    "lever_arm_y_m": "turns", "lever_arm_z_m": "slopes or banked turns (the vehicle rolling or pitching)",
}
EXTRINSIC_WORDS = {"roll_deg": "boresight roll", "pitch_deg": "boresight pitch", "yaw_deg": "boresight yaw",
                   "lever_arm_x_m": "lever arm x", "lever_arm_y_m": "lever arm y", "lever_arm_z_m": "lever arm z"}
INTRINSIC_WORDS = {"d_range_m": "range offsets", "d_azimuth_deg": "azimuth offsets",
                   "d_elevation_deg": "elevations", "h_z_m": "heights"}
INTRINSIC_SCENE = "surfaces at several ranges and orientations (facades beside the road, not only flat ground)"


def verdict(unobservable: tuple[str, ...] | list[str], reasons: dict[str, str]) -> str | None:
    """The line for a calibration that names `unobservable` with `reasons` ({name: why}), None when it names
    nothing beyond the drive's common motion (which no self-calibration sees)."""
    names = [name for name in unobservable if name not in TRAJECTORY_GAUGE]
    intrinsic = [name for name in names if name.startswith("fibre_")]
    extrinsic = [name.removeprefix("extrinsic.") for name in names if name.startswith("extrinsic.")]
    if not names:
        return None
    if any(reasons.get(name) == RIGID_REASON for name in names):
        return (f"static sensor: the extrinsic and the trajectory are unobservable; {len(intrinsic)} intrinsic "
                f"parameters held (a drive with turns past facades would show them)")
    parts = []
    by_manoeuvre: dict[str, list[str]] = {}
    for axis in extrinsic:
        by_manoeuvre.setdefault(EXTRINSIC_MANOEUVRE[axis], []).append(EXTRINSIC_WORDS[axis])
    for manoeuvre, axes in by_manoeuvre.items():
        parts.append(f"the {_listed(axes)} (a drive with {manoeuvre} would show {'it' if len(axes) == 1 else 'them'})")
    if intrinsic:
        kinds = {}
        for name in intrinsic:
            kind = name.partition(".")[2]
            kinds[kind] = kinds.get(kind, 0) + 1
        counted = _listed([f"{count} fibre {INTRINSIC_WORDS.get(kind, kind)}" for kind, count in kinds.items()])
        parts.append(f"{counted} (fibres that see {INTRINSIC_SCENE} would show them)")
    other = [name for name in names if not name.startswith(("fibre_", "extrinsic."))]
    if other:
        parts.append(_listed(other))
    return "this drive cannot observe " + "; ".join(parts) + ": held at nominal or bound by the prior"


def _listed(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]
