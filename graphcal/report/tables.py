"""Parameter tables (estimate ± 1-sigma, marked when the data cannot observe it or determine it to the accuracy
required, 'held at nominal' where it is held) from a calibration.yaml mapping: shared by the HTML report and the
viewer's parameters table."""

from __future__ import annotations

from graphcal.calibration.observability import EXTRINSIC_NAMES, INTRINSIC_NAMES
from graphcal.recording.intrinsics import DISPLAY_FROM_FILE_UNITS

UNOBSERVABLE = "held at nominal"
WEAK = " (unobservable)"  # a value the prior decides, not the data
IMPRECISE = " (imprecise)"  # fitted, to a sigma above the accuracy required (calibration/accuracy.py)
# calibration.yaml intrinsic field -> (shown name, factor from the file unit)
INTRINSIC_COLUMNS = tuple(zip(INTRINSIC_NAMES, ("d_range [cm]", "d_azimuth [deg]", "d_elevation [deg]", "Hz [cm]"),
                              DISPLAY_FROM_FILE_UNITS.tolist()))
EXTRINSIC_ROWS = (("roll [deg]", "boresight_deg", 0, 1.0), ("pitch [deg]", "boresight_deg", 1, 1.0),
                  ("yaw [deg]", "boresight_deg", 2, 1.0), ("lever arm x [cm]", "lever_arm_m", 0, 100.0),
                  ("lever arm y [cm]", "lever_arm_m", 1, 100.0), ("lever arm z [cm]", "lever_arm_m", 2, 100.0))


def with_sigma(value: float | None, sigma: float | None, factor: float = 1.0) -> str:
    """'1.234 ± 0.012' in the display unit (value and sigma times factor); 'held at nominal' for a
    parameter held at its nominal value (None); the value alone when it has no sigma."""
    if value is None:
        return UNOBSERVABLE
    text = f"{value * factor:.4g}"
    return text if sigma is None else f"{text} ± {sigma * factor:.2g}"


def intrinsics_estimated(calibration: dict) -> bool:
    return any(row.get("sigma") for row in calibration.get("intrinsics") or [])


def parameter_rows(calibration: dict) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, rows of cells) per table: extrinsic, intrinsics per fibre (when estimated),
    trajectory corrections per control (when estimated)."""
    tables = []
    extrinsic = calibration["extrinsic"]
    sigma = extrinsic.get("sigma")
    weak, imprecise = set(calibration.get("unobservable") or []), set(calibration.get("imprecise") or {})
    rows = [[name, with_sigma(extrinsic[key][k] if sigma is None or sigma[key][k] is not None else None,
                              None if sigma is None else sigma[key][k], factor)
             + (WEAK if sigma is not None and sigma[key][k] is not None and f"extrinsic.{full}" in weak else "")
             + (IMPRECISE if f"extrinsic.{full}" in imprecise else "")]
            for (name, key, k, factor), full in zip(EXTRINSIC_ROWS, EXTRINSIC_NAMES)]
    title = "Extrinsic T_body_lidar" + ("" if sigma else " (not estimated: the nominal of extrinsic.yaml)")
    tables.append((title, ["parameter", "estimate"], rows))
    if intrinsics_estimated(calibration):
        rows = []
        for row in calibration["intrinsics"]:
            sigmas = row.get("sigma")
            cells = ["0 (reference)" if sigmas is None else with_sigma(row[key], sigmas[key], factor)
                     + (WEAK if row[key] is not None and f"fibre_{row['fibre']}.{key}" in weak else "")
                     + (IMPRECISE if f"fibre_{row['fibre']}.{key}" in imprecise else "")
                     for key, _, factor in INTRINSIC_COLUMNS]
            rows.append([str(row["fibre"])] + cells)
        tables.append(("Intrinsic offsets per fibre (from the nominal model)",
                       ["fibre"] + [name for _, name, _ in INTRINSIC_COLUMNS], rows))
    corrections = calibration.get("trajectory_corrections") or []
    if corrections:
        rotations = any(row["sigma"].get("rotation_x_deg") is not None for row in corrections)
        header = ["control", "time [s]", "dx [cm]", "dy [cm]", "dz [cm]"]
        header += ["rx [deg]", "ry [deg]", "rz [deg]"] if rotations else []
        rows = []
        for c, row in enumerate(corrections):
            cells = [str(c), f"{row['time']:.3f}"]
            cells += [with_sigma(v, row["sigma"][f"{axis}_m"], 100.0) + (WEAK if f"control_{c}.{axis}_m" in weak else "")
                      for v, axis in zip(row["d_position_m"], "xyz")]
            if rotations:
                cells += [with_sigma(v, row["sigma"][f"rotation_{axis}_deg"])
                          + (WEAK if f"control_{c}.rotation_{axis}_deg" in weak else "")
                          for v, axis in zip(row["d_rotation_deg"], "xyz")]
            rows.append(cells)
        tables.append(("Trajectory corrections per control time (world axes)", header, rows))
    return tables
