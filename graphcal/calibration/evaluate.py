"""Apply a calibration to a recording, and compare a calibration with the simulator's truth/."""

from __future__ import annotations

from dataclasses import dataclass, replace

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from graphcal.calibration.observability import TRAJECTORY_GAUGE
from graphcal.calibration.returns import (
    Estimate,
    ReturnData,
    pose_of,
    prepare,
    world_at,
)
from graphcal.calibration.result import Calibration, CalibrationResult
from graphcal.common.errors import GraphcalError
from graphcal.calibration.observability import EXTRINSIC_NAMES, intrinsic_mask
from graphcal.recording.intrinsics import (
    DISPLAY_FROM_FILE_UNITS,
    DISPLAY_NAMES,
    offsets_to_file_units,
)
from graphcal.clouds.metrics import DistanceStats, cloud_to_cloud
from graphcal.recording.directory import Recording


REFERENCE_MAX_POINTS = 20_000_000  # evaluate's true cloud: all of it up to this many returns, else a subset


def apply_calibration(calibration: Calibration, recording: Recording) -> np.ndarray:
    """World coordinates [m, the recording's projected CRS] of every return with the
    calibration's offsets, extrinsic and trajectory corrections (interpolated at each return's
    time; held at the first/last control outside their span). Shape (N, 3), recording order."""
    return world_of(calibration, returns_for(calibration, recording))


def returns_for(calibration: Calibration, recording: Recording, max_points: int | None = None,
                seed: int = 0, range_noise_m: float | None = None) -> ReturnData:
    """Every return of the recording (or the random subset of max_points that calibrate draws
    with this seed), placed between the calibration's control times; the head's range noise [m] as
    calibrate resolved it if given (else measured, problem.prepare)."""
    if calibration.sensor_model != recording.sensor.model:
        raise GraphcalError(f"calibration is for a {calibration.sensor_model}, the recording has a "
                            f"{recording.sensor.model}")
    corrected = len(calibration.control_times_s) >= 2
    return prepare(recording, np.inf, max_points, np.random.default_rng(seed),
                   control_times_s=calibration.control_times_s if corrected else None, range_noise_m=range_noise_m)


def world_of(calibration: Calibration, data: ReturnData, rows: np.ndarray | None = None) -> np.ndarray:
    """World coordinates [m] of the given rows (all if None) with the calibration; identity
    corrections at data's control times when it has none."""
    estimate = calibration.estimate
    if len(estimate.corrections) != len(data.control_times_s):
        estimate = replace(estimate, corrections=tuple(gtsam.Pose3() for _ in data.control_times_s))
    return world_at(data, estimate, pose=True, rows=rows) + data.origin_m


def nominal_calibration(recording: Recording) -> Calibration:
    """Zero offsets, the extrinsic of extrinsic.yaml, no trajectory correction."""
    sensor = recording.sensor
    return Calibration(sensor.model, sensor.reference_fibre,
                       Estimate(np.zeros((sensor.n_fibres, 4)), pose_of(recording.extrinsic), ()), np.zeros(0))


@dataclass(frozen=True)
class Evaluation:
    """A calibration against truth/: eq. 4.6 RMS of the intrinsic offsets (cm, deg, deg, cm) over
    the fibres but the reference, before (nominal) and after; extrinsic errors (lever arm m over
    the axes the result does not name unobservable, rotation deg) before/after; cloud-to-cloud
    distance to the true cloud before/after; J [cm^2]. common_offset_m: mean of (calibrated -
    true) position over the returns [m, world]; the trajectory's common translation (and, with
    pose corrections, common rotation) is a gauge no self-consistency energy observes, and so is
    an unobservable extrinsic axis (the result names them): cloud_after_gauge_free is the
    distance once that rigid motion, fitted to truth, is removed (the plain after distance when
    the result has no such gauge)."""

    intrinsic_rms_before: np.ndarray
    intrinsic_rms_after: np.ndarray
    lever_arm_error_m: tuple[float, float]
    rotation_error_deg: tuple[float, float]
    cloud_before: DistanceStats
    cloud_after: DistanceStats
    energy_cm2: tuple[float, float]
    common_offset_m: np.ndarray
    cloud_after_gauge_free: DistanceStats

    def table(self) -> str:
        lines = [f"{'':18}{'before':>12}{'after':>12}"]
        lines += [f"{n:18}{b:12.3g}{a:12.3g}" for n, b, a in zip(DISPLAY_NAMES, self.intrinsic_rms_before,
                                                                 self.intrinsic_rms_after)]
        lines.append(f"{'lever arm m *':18}{self.lever_arm_error_m[0]:12.3g}{self.lever_arm_error_m[1]:12.3g}")
        lines.append(f"{'rotation deg':18}{self.rotation_error_deg[0]:12.3g}{self.rotation_error_deg[1]:12.3g}")
        lines.append(f"{'c2c mean cm':18}{self.cloud_before.mean * 100:12.3g}{self.cloud_after.mean * 100:12.3g}")
        lines.append(f"{'c2c median cm':18}{self.cloud_before.median * 100:12.3g}{self.cloud_after.median * 100:12.3g}")
        lines.append(f"{'c2c p95 cm':18}{self.cloud_before.p95 * 100:12.3g}{self.cloud_after.p95 * 100:12.3g}")
        lines.append(f"{'c2c mean* cm':18}{'':>12}{self.cloud_after_gauge_free.mean * 100:12.3g}")
        lines.append(f"{'J cm2':18}{self.energy_cm2[0]:12.3g}{self.energy_cm2[1]:12.3g}")
        lines.append("* lever arm: over its observable axes; c2c mean*: once the rigid motion of the unobservable "
                     "parameters is removed")
        return "\n".join(lines)

    def cloud_line(self) -> str:
        """One line of the mean cloud-to-cloud distances to the true cloud [cm]: before, and after with the rigid
        motion of the unobservable parameters fitted out first (the common motion no self-calibration observes,
        which may leave the cloud as placed further from the truth than before; that distance follows in brackets
        when it differs)."""
        before, after = self.cloud_before.mean * 100, self.cloud_after.mean * 100
        gauge_free = self.cloud_after_gauge_free.mean * 100
        if abs(after - gauge_free) <= 0.05 * gauge_free:
            return f"cloud-to-cloud mean against truth: {before:.3g} cm before, {after:.3g} cm after"
        return (f"cloud-to-cloud mean against truth: {before:.3g} cm before, {gauge_free:.3g} cm after once the common "
                f"motion no self-calibration observes is fitted out ({after:.3g} cm as placed)")

    def to_dict(self) -> dict:
        """Plain numbers for evaluation.yaml (lengths m, angles deg; intrinsic RMS in cm, deg, deg,
        cm), and the table as printed."""
        def stats(d: DistanceStats) -> dict:
            return {"mean": d.mean, "median": d.median, "p95": d.p95, "max": d.max}

        return {"intrinsic_rms": {"before": dict(zip(DISPLAY_NAMES, map(float, self.intrinsic_rms_before))),
                                  "after": dict(zip(DISPLAY_NAMES, map(float, self.intrinsic_rms_after)))},
                "lever_arm_error_m": list(map(float, self.lever_arm_error_m)),
                "rotation_error_deg": list(map(float, self.rotation_error_deg)),
                "cloud_to_cloud_m": {"before": stats(self.cloud_before), "after": stats(self.cloud_after),
                                     "after_gauge_free": stats(self.cloud_after_gauge_free)},
                "common_offset_m": [float(v) for v in self.common_offset_m],
                "energy_cm2": [float(v) for v in self.energy_cm2], "table": self.table()}


@dataclass(frozen=True)
class Scorecard:
    """The intrinsics against truth over the parameters the result does not name unobservable: RMS error
    per type (cm, deg, deg, cm; NaN where every one of a type is named), the fraction of their errors
    within 3 of the reported 1-sigmas, and the fraction of all intrinsic parameters named; the extrinsic's
    error over its reported sigma per estimated axis (roll, pitch, yaw, lever arm x, y, z about body axes)
    that is not named unobservable; the same RMS and fraction within 3 sigmas over the determined ones (named
    neither unobservable nor imprecise: calibration/accuracy.py), and the fraction of all named imprecise."""

    rms_observable: np.ndarray
    within_3_sigma: float
    named_fraction: float
    extrinsic_z: dict
    rms_determined: np.ndarray
    within_3_sigma_determined: float
    imprecise_fraction: float

    def to_dict(self) -> dict:
        return {"rms_observable": dict(zip(DISPLAY_NAMES, map(float, self.rms_observable))),
                "within_3_sigma": self.within_3_sigma, "named_fraction": self.named_fraction,
                "extrinsic_z": self.extrinsic_z,
                "rms_determined": dict(zip(DISPLAY_NAMES, map(float, self.rms_determined))),
                "within_3_sigma_determined": self.within_3_sigma_determined,
                "imprecise_fraction": self.imprecise_fraction}


def scorecard(result: CalibrationResult, recording: Recording) -> Scorecard:
    """The intrinsics of a calibration result against the recording's truth (Scorecard), over the estimated ones
    (a sigma reported: not the gauges held, not a fixed reference fibre's) and the named ones."""
    sensor = recording.sensor
    unobservable = set(result.unobservable)
    named = intrinsic_mask(unobservable, sensor.n_fibres)
    imprecise = intrinsic_mask(set(result.calibration.imprecise), sensor.n_fibres)
    sigma = result.sigmas.intrinsics
    free = np.isfinite(sigma) & ~named
    error = offsets_to_file_units(result.calibration.estimate.offsets - recording.truth.intrinsics)

    def rms_within(over: np.ndarray) -> tuple[np.ndarray, float]:
        rms = [np.sqrt(np.mean(error[over[:, k], k] ** 2)) if over[:, k].any() else np.nan for k in range(4)]
        within = float(np.mean(np.abs(error[over]) <= 3 * sigma[over])) if over.any() else np.nan
        return np.array(rms) * DISPLAY_FROM_FILE_UNITS, within

    rms, within = rms_within(free)
    rms_determined, within_determined = rms_within(free & ~imprecise)
    total = int((free | named).sum())
    extrinsic_z = {}
    if result.sigmas.extrinsic is not None:
        truth = recording.truth.extrinsic
        estimate = result.calibration.estimate.extrinsic
        turn = Rotation.from_matrix(estimate.rotation().matrix() @ truth.R_body_lidar.T).as_rotvec(degrees=True)
        error = np.r_[turn, estimate.translation() - np.asarray(truth.lever_arm_m)]
        extrinsic_z = {name: float(e / s) for name, e, s in zip(EXTRINSIC_NAMES, error, result.sigmas.extrinsic)
                       if f"extrinsic.{name}" not in unobservable}
    named_fraction = float((total - free.sum()) / total) if total else np.nan
    imprecise_fraction = float((free & imprecise).sum() / total) if total else np.nan
    return Scorecard(rms, within, named_fraction, extrinsic_z, rms_determined, within_determined, imprecise_fraction)


def intrinsic_rms(offsets: np.ndarray, truth: np.ndarray, reference_fibre: int) -> np.ndarray:
    """Eq. 4.6: RMS over the fibres but the reference of offset - truth, in (cm, deg, deg, cm)."""
    error = np.delete(np.asarray(offsets) - truth, reference_fibre, axis=0)
    return offsets_to_file_units(np.sqrt(np.mean(error ** 2, axis=0))) * DISPLAY_FROM_FILE_UNITS


def evaluate(result: CalibrationResult | Calibration, recording: Recording, max_points: int = 500_000,
             seed: int = 0) -> Evaluation:
    """Compare with truth/ (simulated recordings only). Cloud distances on a random subset of
    max_points returns (seeded, the only returns read) against the whole true cloud, or against a seeded
    subset of REFERENCE_MAX_POINTS of it for a longer recording (its spacing then adds to the distances). A
    Calibration alone (read from calibration.yaml) has no J: energy_cm2 is then NaN."""
    truth = recording.truth
    if truth is None:
        raise GraphcalError(f"{recording.path or recording.name}: no truth/ folder, nothing to evaluate against")
    cal = result if isinstance(result, Calibration) else result.calibration
    energy = (np.nan, np.nan) if isinstance(result, Calibration) else result.energy_cm2
    sensor = recording.sensor
    n_returns = len(recording.points)
    data = returns_for(cal, recording, max_points, seed)  # the sampled returns only
    if n_returns <= REFERENCE_MAX_POINTS:
        reference_cloud = truth.world_points()
        true_cloud = reference_cloud[data.rows]
    else:  # the reference's rows and the sampled ones, in one pass over truth/points.parquet
        reference_rows = np.sort(np.random.default_rng(seed + 1).choice(n_returns, REFERENCE_MAX_POINTS, replace=False))
        rows = np.union1d(reference_rows, data.rows)
        read = truth.world_points_at(rows)
        reference_cloud, true_cloud = (read[np.searchsorted(rows, wanted)] for wanted in (reference_rows, data.rows))
    nominal_cloud = world_of(nominal_calibration(recording), data)
    after_cloud = world_of(cal, data)
    true_R, true_t = truth.extrinsic.R_body_lidar, np.asarray(truth.extrinsic.lever_arm_m)
    ext = cal.estimate.extrinsic
    nominal = recording.extrinsic

    def rotation_error(R):
        return float(np.degrees(Rotation.from_matrix(R.T @ true_R).magnitude()))

    def lever_arm_error(t):  # over the axes the data observe: an unobservable one keeps its start error
        seen = [f"extrinsic.lever_arm_{axis}_m" not in result.unobservable for axis in "xyz"]
        return float(np.linalg.norm((np.asarray(t) - true_t)[seen]))

    offset = np.mean(after_cloud - true_cloud, axis=0)
    gauge_free = remove_gauge(after_cloud, true_cloud, cal.unobservable)
    return Evaluation(
        intrinsic_rms(np.zeros_like(truth.intrinsics), truth.intrinsics, sensor.reference_fibre),
        intrinsic_rms(cal.estimate.offsets, truth.intrinsics, sensor.reference_fibre),
        (lever_arm_error(nominal.lever_arm_m), lever_arm_error(ext.translation())),
        (rotation_error(nominal.R_body_lidar), rotation_error(ext.rotation().matrix())),
        DistanceStats.of(cloud_to_cloud(nominal_cloud, reference_cloud)),
        DistanceStats.of(cloud_to_cloud(after_cloud, reference_cloud)),
        energy, offset,
        DistanceStats.of(cloud_to_cloud(gauge_free, reference_cloud)))


def remove_gauge(points_m: np.ndarray, truth_m: np.ndarray, unobservable) -> np.ndarray:
    """points (N,3) [m, world] moved by the rigid motion, fitted to their true positions (N,3),
    that the unobservable names allow: a translation for trajectory.common_translation or an
    unobservable lever-arm axis (which moves the cloud rigidly: that is why no energy sees it),
    a rotation about the centroid too for trajectory.common_rotation or an unobservable boresight
    angle (Kabsch, scipy)."""
    translation, rotation = TRAJECTORY_GAUGE
    names = set(unobservable)
    if translation not in names and not names & {f"extrinsic.lever_arm_{axis}_m" for axis in "xyz"}:
        return points_m
    centre, true_centre = points_m.mean(axis=0), truth_m.mean(axis=0)
    moved = points_m - centre
    if rotation in names or names & {f"extrinsic.{angle}_deg" for angle in ("roll", "pitch", "yaw")}:
        moved = Rotation.align_vectors(truth_m - true_centre, moved)[0].apply(moved)
    return moved + true_centre
