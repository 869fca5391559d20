"""The returns a calibration uses (per-return arrays) and its estimate: world points at an estimate.

World frame minus a local origin [m] (float precision); control times ~control_interval_s
apart span the returns (seed 001: about 1 s); each return sits between controls c and c+1
with weight alpha (eq. 5.4).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import gtsam
import numpy as np
from scipy.spatial import cKDTree

from factors.spherical import beam_directions
from factors.world_point import Corrections, Returns, world_points
from graphcal.calibration.association import Sight, stand_in_shifts
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.poses import PoseTrack
from graphcal.recording.range_noise import measured_range_noise_m, noisy
from graphcal.recording.directory import Recording
from graphcal.recording.sensor import SensorModel
from graphcal.recording.subset import subset_rows
from graphcal.recording.trajectory_noise import PoseNoise
from graphcal.recording.trajectory_steps import position_steps, step_vectors_m

STATIC_BELOW_M = 1.0  # a sensor whose positions span less than this sees from one viewpoint ...
TURNED_DEG = 45.0  # ... and is static unless its heading spans this much [deg]: then it turned on the spot
REVISIT_WITHIN_M = 5.0  # a drive revisits a place when it passes within this of where it was ...
REVISIT_AFTER_S = 20.0  # ... at least this much earlier
STEP_CONTROL_APART_S = 1e-3  # a control of the grid this close to a step's control [s] gives way to it


@dataclass(frozen=True)
class ReturnData:
    """Per-return arrays (N) of the returns used (rows: their row in points.parquet), the control
    times [s], the head's range noise [m] (1-sigma; NaN: unknown), the recorded trajectory's white
    noise (trajectory_noise.PoseNoise), the nominal lever arm [m, body frame], which places the sensor
    on the vehicle, and the spans [s] (k, 2) of the drive the returns were drawn in (recording.subset; None:
    the whole drive); smoothing_error: the error smoothing left in the recorded poses, shared by the returns fired
    within its interval_s (WorldTrajectory.smoothing_error); control_steps_m ((C, 3) [m, world axes], None: no
    step): what the recorded position steps by between the previous control and this one (zero where it does not:
    controls_about_steps), so that E_def ties their corrections across the step by minus that, each component
    to step_sigma_m [m]; shift_m: the stand-ins' shifts (stand_in_shift_m) when known beforehand (a subset keeps
    those of the whole drive, whose firing neighbours it has lost: sample), None: computed from these rows."""

    sensor: SensorModel
    rows: np.ndarray
    fibre: np.ndarray
    range_m: np.ndarray
    azimuth_rad: np.ndarray
    time_s: np.ndarray
    R_nav: np.ndarray
    X_nav: np.ndarray
    control: np.ndarray
    alpha: np.ndarray
    control_times_s: np.ndarray
    origin_m: np.ndarray
    range_noise_m: float
    pose_noise: PoseNoise = PoseNoise.none()
    lever_arm_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    spans_s: np.ndarray | None = None
    smoothing_error: PoseNoise = PoseNoise.none()
    control_steps_m: np.ndarray | None = None
    step_sigma_m: float = 0.0
    shift_m: np.ndarray | None = None

    @property
    def one_viewpoint(self) -> bool:
        """The sensor's positions, lever arm included, span less than STATIC_BELOW_M: no parallax (a tripod, a
        parked car, a sensor on the turning axis of a vehicle turning on the spot; a vehicle turning on the spot
        moves a sensor mounted off its turning axis around a circle)."""
        sensor_m = self.X_nav + self.R_nav @ self.lever_arm_m
        return bool(np.ptp(sensor_m, axis=0).max() < STATIC_BELOW_M)

    @property
    def turned(self) -> bool:
        """The vehicle's heading spans TURNED_DEG or more."""
        return heading_span_deg(self.R_nav) >= TURNED_DEG

    @property
    def static(self) -> bool:
        """One viewpoint and an attitude that does not turn: the whole cloud moves rigidly with the extrinsic and
        the trajectory. A sensor that stays in place while its heading turns (on the turning axis of a vehicle
        turning on the spot) is a rotation on the spot, not a static sensor: the turn shows the boresight's roll
        and pitch and the lever arm across the axis."""
        return self.one_viewpoint and not self.turned

    def sample(self, n: int, rng: np.random.Generator) -> ReturnData:
        """A random subset of n of the returns (all of them when there are no more), same control times; a noisy
        head's with the stand-ins' shifts of the whole drive (its returns' firing neighbours are not in the subset)."""
        if len(self.rows) <= n:
            return self
        keep = np.sort(rng.choice(len(self.rows), n, replace=False))
        per_return = ("rows", "fibre", "range_m", "azimuth_rad", "time_s", "R_nav", "X_nav", "control", "alpha")
        shift_m = self.stand_in_shift_m[keep] if noisy(self.range_noise_m) else None
        return replace(self, **{name: getattr(self, name)[keep] for name in per_return}, shift_m=shift_m)

    def on_knots(self, knots: np.ndarray) -> ReturnData:
        """The same returns between the controls `knots` (indices into control_times_s, increasing, the first and
        the last among them, and both controls about each break): fewer trajectory keys, each return interpolated
        between the knots about it."""
        control_times = self.control_times_s[knots]
        control, alpha = between_controls(self.time_s, control_times)
        steps = None if self.control_steps_m is None else self.control_steps_m[knots]
        return replace(self, control=control, alpha=alpha, control_times_s=control_times, control_steps_m=steps)

    @property
    def control_breaks(self) -> np.ndarray | None:
        """(C,) True at the controls the recorded position steps into (None: no step)."""
        return None if self.control_steps_m is None else np.any(self.control_steps_m != 0, axis=1)

    @property
    def about_breaks(self) -> np.ndarray:
        """The controls on either side of a break (indices, sorted)."""
        after = self._after_breaks()
        return np.union1d(after - 1, after)

    @property
    def steps_s(self) -> np.ndarray:
        """(S, 2) the times [s] of the controls on either side of each break (the recorded trajectory's steps)."""
        after = self._after_breaks()
        return np.column_stack([self.control_times_s[after - 1], self.control_times_s[after]])

    def _after_breaks(self) -> np.ndarray:
        breaks = self.control_breaks
        return np.zeros(0, np.int64) if breaks is None else np.flatnonzero(breaks)

    def returns(self, rows: np.ndarray | slice | None = None) -> Returns:
        """The factor-side view of some rows (None or a slice: views of the arrays, not copies)."""
        rows = slice(None) if rows is None else rows
        return Returns(self.range_m[rows], self.azimuth_rad[rows], self.sensor.factory_terms(self.fibre[rows]),
                       self.R_nav[rows], self.X_nav[rows], self.alpha[rows])

    @cached_property
    def stand_in_shift_m(self) -> np.ndarray:
        """(N,) [m] each return's shift along its line of sight to its stand-in (association.stand_in_shifts): from the
        measured ranges and encoder azimuths alone, computed once (shift_m when given)."""
        return stand_in_shifts(self.fibre, self.range_m, self.azimuth_rad) if self.shift_m is None else self.shift_m


@dataclass(frozen=True)
class Estimate:
    """Current calibration: offsets (n_fibres, 4) in (m, rad, rad, m), T_body_lidar, the trajectory
    corrections at each control time (Pose3; identity rotation when translation-only), and the values of
    the candidate effects modelled (graphcal.diagnosis; {name: vector}, empty when none)."""

    offsets: np.ndarray
    extrinsic: gtsam.Pose3
    corrections: tuple
    effects: dict = field(default_factory=dict)


def mean_estimate(estimates) -> Estimate:
    """The mean of estimates close to one another (the fine phase's last outer iterations): offsets and effects
    averaged, the extrinsic and each control's correction averaged in the tangent space of the last one's."""
    last = estimates[-1]

    def mean_pose(poses) -> gtsam.Pose3:
        return poses[-1].retract(np.mean([poses[-1].localCoordinates(pose) for pose in poses], axis=0))

    return Estimate(np.mean([e.offsets for e in estimates], axis=0), mean_pose([e.extrinsic for e in estimates]),
                    tuple(mean_pose(poses) for poses in zip(*(e.corrections for e in estimates))),
                    {name: np.mean([np.asarray(e.effects[name]) for e in estimates], axis=0) for name in last.effects})


def prepare(recording: Recording, control_interval_s: float, max_points: int | None = None,
            rng: np.random.Generator | None = None, control_times_s: np.ndarray | None = None,
            range_noise_m: float | None = None, points_per_s: float | None = None) -> ReturnData:
    """Read the returns (a random subset of max_points if given, in spans of the drive at points_per_s returns
    a second when the whole drive would be thinner: recording.subset.subset_rows) and the INS pose at each one's
    time; control times control_interval_s apart from the trajectory's first pose span them,
    unless given; the head's range noise [m] measured from the first returns (range_noise.measured_range_noise_m)
    unless given; the white noise left in the trajectory's poses (WorldTrajectory.pose_noise: none once smoothed out)
    and the error the smoothing left (WorldTrajectory.smoothing_error).
    points.parquet is read row group by row group: only the subset is held, whatever the recording's length."""
    rows, spans_s = subset_rows(recording.points, max_points, rng or np.random.default_rng(0), points_per_s)
    columns = recording.points.take(["time", "fibre", "range", "azimuth"], rows) | {"rows": rows}
    if range_noise_m is None:  # firing order: the first row group's returns
        first = next(recording.points.iter_batches(["fibre", "range", "azimuth"]))
        range_noise_m = measured_range_noise_m(first["fibre"], first["range"], first["azimuth"])
    time = columns["time"]
    position, rotation = recording.world.poses.interpolate(time)
    origin = np.round(position.mean(axis=0))
    steps_m, step_sigma_m = None, 0.0
    if control_times_s is None:
        poses = recording.world.poses
        steps_s = position_steps(poses)
        found_m, step_sigma_m = step_vectors_m(poses, steps_s, recording.world.smoothing_error.position_m)
        control_times, steps_m = controls_about_steps(control_grid(poses.span[0], time[0], time[-1],
                                                                   control_interval_s), steps_s, found_m)
    else:
        control_times = np.asarray(control_times_s, dtype=np.float64)
    control, alpha = between_controls(time, control_times)
    return ReturnData(recording.sensor, columns["rows"], columns["fibre"].astype(np.int64),
                      columns["range"].astype(np.float64), columns["azimuth"].astype(np.float64),
                      time, rotation.as_matrix(), position - origin, control, alpha, control_times, origin, range_noise_m,
                      recording.world.pose_noise,
                      np.asarray(recording.extrinsic.lever_arm_m, dtype=np.float64), spans_s,
                      recording.world.smoothing_error, steps_m, step_sigma_m)


def heading_span_deg(R_world_body: np.ndarray) -> float:
    """How far [deg] the heading (the body x axis's direction in the world's horizontal plane) of rotations
    (N, 3, 3) in time order turns, unwrapped: 360 for a full turn on the spot."""
    heading_rad = np.unwrap(np.arctan2(R_world_body[:, 1, 0], R_world_body[:, 0, 0]))
    return float(np.degrees(np.ptp(heading_rad))) if len(heading_rad) else 0.0


def revisits(poses: PoseTrack) -> bool:
    """Whether the drive comes back to where it was (within REVISIT_WITHIN_M of a position it held at least
    REVISIT_AFTER_S earlier): only then do pairs between two passes show the trajectory's errors."""
    times = np.arange(poses.span[0], poses.span[1], 1.0)
    if len(times) < 2:
        return False
    position, _ = poses.interpolate(times)
    tree = cKDTree(position)
    for a, b in tree.query_pairs(REVISIT_WITHIN_M):
        if abs(times[a] - times[b]) >= REVISIT_AFTER_S:
            return True
    return False


def between_controls(time_s: np.ndarray, control_times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each time [s], the control c before it and its weight alpha towards c + 1 (eq. 5.4), clipped to the
    controls' span."""
    control = np.clip(np.searchsorted(control_times_s, time_s, side="right") - 1, 0, len(control_times_s) - 2)
    gap = control_times_s[control + 1] - control_times_s[control]
    return control, np.clip((time_s - control_times_s[control]) / gap, 0, 1)


def knots_every(n_controls: int, most: int | None, kept: np.ndarray | None = None) -> np.ndarray | None:
    """Indices of every k-th of n_controls controls, the last one and the controls `kept` (those about a break),
    k the least that leaves at most `most` of them besides those kept (None: every control, when they are no more
    than that or most is None)."""
    if most is None or n_controls <= most:
        return None
    step = int(np.ceil((n_controls - 1) / (most - 1)))
    kept = np.zeros(0, np.int64) if kept is None else kept
    return np.unique(np.r_[np.arange(0, n_controls, step), n_controls - 1, kept]).astype(np.int64)


def knot_shares(control_times_s: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """How many of the controls each knot stands for (K,): the sum of its interpolation weights over them. A
    prior of sigma / sqrt(share) on each knot gives corrections that move together (the trajectory's common
    translation) what a prior of sigma on each control gives them."""
    control, alpha = between_controls(control_times_s, control_times_s[knots])
    return (np.bincount(control, 1 - alpha, len(knots))
            + np.bincount(control + 1, alpha, len(knots)))


def resampled(corrections: tuple, from_s: np.ndarray, to_s: np.ndarray) -> tuple:
    """Trajectory corrections (Pose3) given at the times from_s [s], at the times to_s: interpolated as eq. 5.4
    interpolates them for a return, (Log R, t) linear between the two controls about each time."""
    rotvec = np.array([gtsam.Rot3.Logmap(c.rotation()) for c in corrections])
    translation = np.array([c.translation() for c in corrections])
    control, alpha = between_controls(to_s, from_s)
    a = alpha[:, None]
    w = (1 - a) * rotvec[control] + a * rotvec[control + 1]
    t = (1 - a) * translation[control] + a * translation[control + 1]
    return tuple(gtsam.Pose3(gtsam.Rot3.Expmap(wi), ti) for wi, ti in zip(w, t))


def control_grid(anchor_s: float, first_s: float, last_s: float, interval_s: float) -> np.ndarray:
    """Control times [s] anchor_s + k interval_s (k integer) covering [first_s, last_s]: anchored
    at the trajectory's first pose, so they do not shift with the subset of returns used. An
    infinite interval gives the two controls [first_s, last_s] (one second apart when the returns
    share one time, e.g. a batch of one: interpolating between equal times would give NaN)."""
    if not np.isfinite(interval_s):
        return np.array([first_s, last_s if last_s > first_s else first_s + 1.0])
    k_first = np.floor((first_s - anchor_s) / interval_s + 1e-9)
    k_last = max(np.ceil((last_s - anchor_s) / interval_s - 1e-9), k_first + 1)
    return anchor_s + interval_s * np.arange(k_first, k_last + 1)


def controls_about_steps(control_times_s: np.ndarray, steps_s: np.ndarray,
                         steps_m: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """The control times [s] with a control at each side of each step of the recorded positions (steps_s (S, 2):
    the samples' times either side, trajectory_steps.position_steps; steps_m (S, 3) [m]: what the position steps
    by, trajectory_steps.step_vectors_m) inside their span, so that corrections interpolated between controls can
    step with the INS; a control of the grid between the two or within a millisecond of either is left out. Also
    (C, 3) [m] the step into each control (zero but at the control after a step; None without a step)."""
    inside = (steps_s[:, 0] > control_times_s[0]) & (steps_s[:, 1] < control_times_s[-1])
    steps_s, steps_m = steps_s[inside], steps_m[inside]
    if not len(steps_s):
        return control_times_s, None
    near = np.any((control_times_s[:, None] > steps_s[:, 0] - STEP_CONTROL_APART_S)
                  & (control_times_s[:, None] < steps_s[:, 1] + STEP_CONTROL_APART_S), axis=1)
    times = np.unique(np.r_[control_times_s[~near], steps_s.ravel()])  # two steps a sample apart share one
    into = np.zeros((len(times), 3))
    np.add.at(into, np.searchsorted(times, steps_s[:, 1]), steps_m)
    return times, into


def pose_of(extrinsic: Extrinsic) -> gtsam.Pose3:
    """T_body_lidar of an extrinsic.yaml / calibration.yaml extrinsic as a GTSAM Pose3."""
    return gtsam.Pose3(gtsam.Rot3(extrinsic.R_body_lidar), np.asarray(extrinsic.lever_arm_m, dtype=np.float64))


def initial_estimate(recording: Recording, data: ReturnData) -> Estimate:
    """Zero offsets, the nominal extrinsic of extrinsic.yaml, no trajectory correction."""
    return Estimate(np.zeros((recording.sensor.n_fibres, 4)), pose_of(recording.extrinsic),
                    tuple(gtsam.Pose3() for _ in data.control_times_s))


def corrections_at(estimate: Estimate, control: np.ndarray, pose: bool) -> Corrections:
    """Per-return corrections at the controls before/after each return."""
    translation = np.array([c.translation() for c in estimate.corrections])
    lo, hi = np.take(translation, control, axis=0), np.take(translation, control + 1, axis=0)
    if not pose:
        return Corrections(lo, hi)
    rotation = np.array([c.rotation().matrix() for c in estimate.corrections])
    rotvec = np.array([gtsam.Rot3.Logmap(c.rotation()) for c in estimate.corrections])
    return Corrections(lo, hi, rotation[control], rotation[control + 1],
                       rotvec[control], rotvec[control + 1])


def world_at(data: ReturnData, estimate: Estimate, pose: bool, rows: np.ndarray | None = None) -> np.ndarray:
    """World points minus the local origin [m] of the given rows (all if None) at an estimate."""
    R_E, t_E = estimate.extrinsic.rotation().matrix(), estimate.extrinsic.translation()
    rows = slice(None) if rows is None else rows
    p, _ = world_points(data.returns(rows), estimate.offsets[data.fibre[rows]], R_E, t_E,
                        corrections_at(estimate, data.control[rows], pose), jacobians=False)
    return p


def rays_at(data: ReturnData, estimate: Estimate, rows: np.ndarray | None = None) -> np.ndarray:
    """Unit line-of-sight direction (N,3) of the given rows (all if None) in world axes at an estimate
    (eq. 4.2's d xyz / d rho turned by the extrinsic and the INS attitude; a trajectory rotation
    correction, a fraction of a degree, is left out: the association and the noise model only
    compare these lines with surfaces)."""
    rows = slice(None) if rows is None else rows
    fibre = data.fibre[rows]
    direction_lidar = beam_directions(data.azimuth_rad[rows], data.sensor.factory_terms(fibre), estimate.offsets[fibre],
                                      data.sensor.elevation_trig(fibre, estimate.offsets))
    return np.einsum("nij,nj->ni", data.R_nav[rows], direction_lidar @ estimate.extrinsic.rotation().matrix().T)


def sight_at(data: ReturnData, estimate: Estimate) -> Sight | None:
    """The lines of sight and stand-ins (association.Sight) of the returns at an estimate (rows of a fibre are in
    firing order: time order); None when the head's range noise is known to be below range_noise.NOISY_ABOVE_M:
    the measured points are then their own best stand-ins (docs/reference/math.md "Which m")."""
    if not noisy(data.range_noise_m):
        return None
    return Sight(rays_at(data, estimate), data.stand_in_shift_m)
