"""One plain line on what a drive could not observe and which manoeuvre or scene would show it.

A calibration names every parameter the data cannot see (calibration.yaml `unobservable`, with a reason each).
On a degenerate drive (a standstill, a straight line, a turn on the spot, a flat plain) that is tens of names; a
user needs the verdict: which groups of parameters, and what to record next time. The manoeuvres follow from the
geometry (docs/reference/math.md "Weak directions", its examples): the lever arm and the boresight roll move the
cloud differently only when the vehicle turns, the boresight yaw only when it travels (on the spot, turning the
extrinsic about the vertical turns the whole cloud), the lever arm's height only when it rolls or pitches; what a
drive that made them all still did not show needs upright surfaces facing several ways; a fibre's range offset,
elevation and height need surfaces at several ranges and orientations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graphcal.calibration.observability import TRAJECTORY_GAUGE
from graphcal.calibration.returns import STATIC_BELOW_M, TURNED_DEG, heading_span_deg

RIGID_REASON = "a static sensor: the whole cloud moves rigidly with it"
TILTED_DEG = 2.0  # ... whose up axis swings this far has rolled or pitched [deg]

# what the vehicle must do for each extrinsic axis to move the cloud other than rigidly (the pitch: travel or a turn,
# either; a turn on the spot shows the lever arm's x, its y only once travel shows the yaw it trades with)
EXTRINSIC_NEEDS = {"roll_deg": ("turned",), "pitch_deg": (), "yaw_deg": ("travelled",), "lever_arm_x_m": ("turned",),
                   "lever_arm_y_m": ("turned", "travelled"), "lever_arm_z_m": ("tilted",)}
MANOEUVRE_WORDS = {"turned": "a drive with turns", "travelled": "a drive along a road",
                   "tilted": "a drive with slopes or banked turns (the vehicle rolling or pitching)"}
# what shows an extrinsic axis that the drive's manoeuvres did not
EXTRINSIC_SCENE = "facades or poles beside the road, not only flat ground,"
EXTRINSIC_WORDS = {"roll_deg": "boresight roll", "pitch_deg": "boresight pitch", "yaw_deg": "boresight yaw",
                   "lever_arm_x_m": "lever arm x", "lever_arm_y_m": "lever arm y", "lever_arm_z_m": "lever arm z"}
INTRINSIC_WORDS = {"d_range_m": "range offset", "d_azimuth_deg": "azimuth offset",
                   "d_elevation_deg": "elevation", "h_z_m": "height"}
INTRINSIC_SCENE = "surfaces at several ranges and orientations (facades beside the road, not only flat ground)"
# what decides the lever arm when trajectory corrections are estimated: they take up what a drive shows of it
# (on the foreign drives at 15 s its sigmas grow from under 1 cm to 1-7 cm: docs/benchmarks.md)
LEVER_ARM_WITH_TRAJECTORY = "a surveyed lever arm as the nominal, its sigma in priors.extrinsic_lever_arm_m,"
# what shows a trajectory correction where the drive saw too little structure (unseen_controls.py)
CONTROL_SCENE = "surfaces facing several ways along those stretches (facades, poles, parked cars)"
# what shows them when the vehicle only turned on the spot
INTRINSIC_DRIVE = "a drive past facades, each surface seen from many places,"


@dataclass(frozen=True)
class Motion:
    """What the vehicle did while the lidar recorded: travelled (its positions span STATIC_BELOW_M or more), turned
    (its heading spans TURNED_DEG or more), tilted (its up axis swings TILTED_DEG or more: slopes, banked turns)."""

    travelled: bool
    turned: bool
    tilted: bool

    @classmethod
    def of(cls, R_world_body: np.ndarray, X_world_body_m: np.ndarray) -> Motion:
        """From the vehicle's poses in time order: rotations (N, 3, 3) and positions (N, 3) [m]."""
        up_swing_rad = np.ptp(R_world_body[:, :2, 2], axis=0).max()  # the up axis's horizontal part, small angles
        return cls(travelled=bool(np.ptp(X_world_body_m, axis=0).max() >= STATIC_BELOW_M),
                   turned=heading_span_deg(R_world_body) >= TURNED_DEG,
                   tilted=bool(np.degrees(up_swing_rad) >= TILTED_DEG))

    def shows_with(self, axis: str) -> str:
        """What would show an extrinsic axis this drive did not: the first manoeuvre it needs that the vehicle did
        not make, else the scene."""
        missing = [need for need in EXTRINSIC_NEEDS[axis] if not getattr(self, need)]
        return MANOEUVRE_WORDS[missing[0]] if missing else EXTRINSIC_SCENE


def verdict(unobservable: tuple[str, ...] | list[str], reasons: dict[str, str], motion: Motion,
            imprecise: tuple[str, ...] | list[str] = ()) -> str | None:
    """The line for a calibration of a drive that made `motion` and names `unobservable` with `reasons`
    ({name: why}) and `imprecise` (determined more coarsely than required: accuracy.py); None when it names
    nothing beyond the drive's common motion (which no self-calibration sees)."""
    names = [name for name in unobservable if name not in TRAJECTORY_GAUGE]
    # the trajectory's gauge is named when corrections are estimated (and for a static sensor, whose extrinsic is held)
    trajectory = len(names) < len(unobservable)
    coarse = ""
    if imprecise:
        intrinsic = [name for name in imprecise if name.startswith("fibre_")]
        parts = [f"{_counted(intrinsic)} ({_intrinsic_remedy(motion)} would sharpen them)"] if intrinsic else []
        parts += _extrinsic_parts(imprecise, motion, "sharpen", trajectory)
        kept = "its fitted value" if len(imprecise) == 1 else "their fitted values"
        coarse = f"determines {_listed(parts)} more coarsely than required: {kept} kept"
    if not names:
        return f"this drive {coarse}" if coarse else None
    seen = _cannot_observe(names, reasons, motion, trajectory)
    return f"{seen}; it {coarse}" if coarse else seen


def _cannot_observe(names: list[str], reasons: dict[str, str], motion: Motion, trajectory: bool) -> str:
    """What the drive cannot observe of `names` (at least one), and what would show it (trajectory: corrections
    estimated)."""
    intrinsic = [name for name in names if name.startswith("fibre_")]
    if any(reasons.get(name) == RIGID_REASON for name in names):
        return (f"static sensor: the extrinsic and the trajectory are unobservable; {len(intrinsic)} intrinsic "
                f"parameters held (a drive with turns past facades would show them)")
    parts = _extrinsic_parts(names, motion, "show", trajectory)
    if intrinsic:
        parts.append(f"{_counted(intrinsic)} ({_intrinsic_remedy(motion)} would show them)")
    controls = sorted({int(name.partition(".")[0].removeprefix("control_")) for name in names
                       if name.startswith("control_")})
    if controls:
        parts.append(f"the trajectory corrections at {len(controls)} control time{'s' if len(controls) > 1 else ''} "
                     f"(control {_spans(controls)}: {CONTROL_SCENE} would show them)")
    other = [name for name in names if not name.startswith(("fibre_", "extrinsic.", "control_"))]
    if other:
        parts.append(_listed(other))
    return "this drive cannot observe " + "; ".join(parts) + ": held at nominal or bound by the prior"


def _extrinsic_parts(names, motion: Motion, verb: str, trajectory: bool) -> list[str]:
    """The extrinsic axes among names grouped by what would show them: ['the boresight pitch (a drive with turns
    would <verb> it)', ...]; with trajectory corrections estimated (trajectory) a surveyed lever arm."""
    by_remedy: dict[str, list[str]] = {}
    for name in names:
        if name.startswith("extrinsic."):
            axis = name.removeprefix("extrinsic.")
            remedy = (LEVER_ARM_WITH_TRAJECTORY if trajectory and axis.startswith("lever_arm")
                      else motion.shows_with(axis))
            by_remedy.setdefault(remedy, []).append(EXTRINSIC_WORDS[axis])
    return [f"the {_listed(axes)} ({remedy} would {verb} {'it' if len(axes) == 1 else 'them'})"
            for remedy, axes in by_remedy.items()]


def _counted(intrinsic: list[str] | tuple[str, ...]) -> str:
    """Intrinsic parameter names counted by kind: '3 fibre elevations and 1 fibre height'."""
    kinds: dict[str, int] = {}
    for name in intrinsic:
        kind = name.partition(".")[2]
        kinds[kind] = kinds.get(kind, 0) + 1
    return _listed([f"{count} fibre {INTRINSIC_WORDS.get(kind, kind)}{'s' if count > 1 else ''}"
                    for kind, count in kinds.items()])


def _intrinsic_remedy(motion: Motion) -> str:
    return f"fibres that see {INTRINSIC_SCENE}" if motion.travelled else INTRINSIC_DRIVE


def _spans(indices: list[int]) -> str:
    """Sorted integers as runs: [3, 4, 5, 9] -> '3-5, 9'."""
    runs, start = [], indices[0]
    for previous, index in zip(indices, indices[1:] + [None]):
        if index != previous + 1:
            runs.append(str(start) if start == previous else f"{start}-{previous}")
            start = index
    return ", ".join(runs)


def _listed(words: list[str]) -> str:
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]
