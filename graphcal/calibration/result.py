"""What a calibration produces: the estimate with its 1-sigmas (calibration.yaml of
RECORDING.md), the per-iteration history and the per-point residuals; saved atomically."""

from __future__ import annotations

import csv
import datetime
import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import gtsam
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.spatial.transform import Rotation

from factors.effects import MODELLED
from graphcal.common.atomic import atomic_path
from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.observability import (
    CONTROL_NAMES,
    EXTRINSIC_NAMES,
    INTRINSIC_NAMES,
    Uncertainty,
    reported,
)
from graphcal.calibration.returns import Estimate, pose_of
from graphcal.common.errors import RecordingError, finite_number
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.intrinsics import offsets_from_file_units, offsets_to_file_units
from graphcal.recording.rotations import rpy_deg_from_rotation
from graphcal.recording.sensor import SensorModel
from graphcal.common.yamlfile import read_yaml, write_yaml
from graphcal.recording.trajectory_noise import PoseNoise

FORMAT = "graphcal-calibration/1"
CALIBRATION_FILE = "calibration.yaml"
HALVES_FILE = "halves.yaml"

# the largest intrinsic offset a calibration file may hold (file units): beyond, it is not a calibration of this head
OFFSET_BOUND_M = 1.0
# what a calibration.yaml's `effects` may name: graphcal.diagnose's findings and the constants solved beside them
KNOWN_EFFECTS = frozenset(MODELLED) | {"discovered", "unexplained"}
OFFSET_BOUND_DEG = 10.0



def calibration_file(path: str | Path) -> Path:
    """A calibration given as its calibration.yaml or as the folder holding it."""
    path = Path(path)
    return path / CALIBRATION_FILE if path.is_dir() else path

FINGERPRINT_RETURNS = 10_000
DRIVE_KEYS = ("name", "returns", "time_span_s", "fingerprint")


def drive_of(recording) -> dict:
    """What tells one recording from another in calibration.yaml (`drive`): its name, its number of returns, the
    time span of its returns [s] and a fingerprint of its first FINGERPRINT_RETURNS ranges and of its recorded
    trajectory (two simulations of one scenario with different seeds share the rest, and a noise-free head its
    ranges)."""
    first, last = recording.points.time_span_s()
    ranges = next(recording.points.iter_batches(["range"], FINGERPRINT_RETURNS))["range"]
    digest = hashlib.sha256(np.ascontiguousarray(ranges, dtype=np.float64).tobytes())
    digest.update(recording.trajectory.fingerprint().encode())
    fingerprint = digest.hexdigest()[:16]
    return {"name": recording.name, "returns": len(recording.points), "time_span_s": [first, last],
            "fingerprint": fingerprint}


@dataclass(frozen=True)
class Calibration:
    """The estimate alone, as calibration.yaml holds it: offsets (n_fibres, 4) in (m, rad, rad, m)
    from the nominal model, T_body_lidar, trajectory corrections at control_times_s (Pose3 about
    the vehicle in world axes; identity when none were estimated), the names of the parameters the
    data cannot observe (unobservable), of those held at their nominal value (held: calibration.yaml
    writes them null), and why each unobservable one is (reasons: {name: plain words}). An unobservable
    parameter that is not held keeps the value the fit gave it along what the data see of it in
    combination with others (weak_directions.py): its sigma is then close to its prior's
    (Uncertainty.with_nominal_held). imprecise: the
    intrinsic parameters the data do determine, more coarsely than required (accuracy.py), their reasons in
    reasons too: fitted, exported as fitted. drive: the recording it was made on (drive_of; None: not known),
    which its trajectory corrections belong to."""

    sensor_model: str
    reference_fibre: int
    estimate: Estimate
    control_times_s: np.ndarray
    unobservable: tuple[str, ...] = ()
    held: tuple[str, ...] = ()
    reasons: dict = field(default_factory=dict)
    drive: dict | None = None
    imprecise: tuple[str, ...] = ()

    def extrinsic(self) -> Extrinsic:
        pose = self.estimate.extrinsic
        rpy = rpy_deg_from_rotation(Rotation.from_matrix(pose.rotation().matrix()))
        return Extrinsic(tuple(float(v) for v in pose.translation()), tuple(float(v) for v in rpy))

    @classmethod
    def load(cls, path: str | Path, sensor: SensorModel) -> Calibration:
        """Read calibration.yaml (the file or its folder) for a recording with this sensor."""
        path = calibration_file(path)
        data = read_calibration_yaml(path)
        header = data["sensor"]
        model = header.get("model")
        if model != sensor.model:
            raise RecordingError(path, f"sensor model {model!r}", field="sensor.model",
                                 expected=f"{sensor.model!r}, the recording's sensor")
        if header.get("reference_fibre") != sensor.reference_fibre:
            raise RecordingError(path, f"reference fibre {header.get('reference_fibre')!r}", field="sensor.reference_fibre",
                                 expected=f"{sensor.reference_fibre}, the recording's (offsets are relative to it)")
        rows = data.get("intrinsics") or []
        if not isinstance(rows, list) or len(rows) != sensor.n_fibres:
            raise RecordingError(path, f"{len(rows)} intrinsic rows", field="intrinsics",
                                 expected=f"one row per fibre ({sensor.n_fibres})")
        offsets = np.zeros((sensor.n_fibres, 4))
        held = []
        for index, row in enumerate(rows):
            if not isinstance(row, dict) or row.get("fibre") != index:
                raise RecordingError(path, f"row {index} is {row!r}", field=f"intrinsics[{index}].fibre",
                                     expected=f"fibre: {index}")
            offsets[index] = [0.0 if row.get(name) is None  # held at its nominal value
                              else finite_number(row[name], path, f"intrinsics[{index}].{name}")
                              for name in INTRINSIC_NAMES]
            for name, value in zip(INTRINSIC_NAMES, offsets[index]):
                bound, unit = (OFFSET_BOUND_M, "m") if name.endswith("_m") else (OFFSET_BOUND_DEG, "deg")
                if abs(value) > bound:
                    raise RecordingError(path, f"{name} is {value}", field=f"intrinsics[{index}].{name}",
                                         expected=f"an offset within ±{bound:g} {unit}")
            held += [f"fibre_{index}.{name}" for name in INTRINSIC_NAMES
                     if row.get(name) is None and index != sensor.reference_fibre]
        extrinsic = _mapping(data.get("extrinsic"), path, "extrinsic", "lever_arm_m and boresight_deg")
        extrinsic = Extrinsic.from_dict({k: extrinsic.get(k) for k in ("lever_arm_m", "boresight_deg")}, path)
        corrections, times = [], []
        for index, row in enumerate(data.get("trajectory_corrections") or []):
            where = f"trajectory_corrections[{index}]"
            row = _mapping(row, path, where, "time, d_position_m, d_rotation_deg")
            times.append(finite_number(row.get("time"), path, f"{where}.time"))
            d_position, d_rotation = (_vector3(row.get(name, [0, 0, 0]), path, f"{where}.{name}")
                                      for name in ("d_position_m", "d_rotation_deg"))
            corrections.append(gtsam.Pose3(gtsam.Rot3.Expmap(np.radians(d_rotation)), np.asarray(d_position)))
        if len(times) == 1 or np.any(np.diff(times) <= 0):
            raise RecordingError(path, "control times not increasing", field="trajectory_corrections.time",
                                 expected="none, or at least two strictly increasing times")
        drive = data.get("drive")
        if drive is not None and (not isinstance(drive, dict) or set(drive) != set(DRIVE_KEYS)):
            raise RecordingError(path, f"drive is {drive!r}", field="drive",
                                 expected=f"{', '.join(DRIVE_KEYS)} of the recording it was made on")
        imprecise = dict(data.get("imprecise") or {})
        return cls(model, sensor.reference_fibre,
                   Estimate(offsets_from_file_units(offsets), pose_of(extrinsic), tuple(corrections)), np.asarray(times),
                   tuple(data.get("unobservable") or ()), tuple(held),
                   dict(data.get("unobservable_reasons") or {}) | imprecise, drive, tuple(imprecise))


SIGMA_MARGINALS = "gtsam.Marginals at the final pairs, sigma0 the noise of one pair"
SIGMA_SHARED = ("range noise of each return, and the error smoothing left in the poses (where smoothed), counted once "
                "over the pairs that share it (sandwich, docs/reference/math.md)")
SIGMA_WIDENED = (", each widened to the pairs' own residual spread over 0.5 s blocks where larger (cluster-robust "
                 "sandwich), and by the disagreement between ground, walls and other surfaces")


@dataclass(frozen=True)
class CalibrationResult:
    """graphcal.calibrate's answer: the calibration, 1-sigmas (file units, see Uncertainty),
    which parameter groups were estimated, the history (one dict per outer iteration: J [cm^2]
    before/after the solve, weight sum, pairs, gate, step), and the final per-point residuals
    (row of the return p in the recording, signed point-to-plane distance [m], weight), the
    total seconds and the seconds of each step (prepare, solve <stage>, final fit and marginals ...);
    effects: the extra physics modelled (graphcal.diagnose's findings, calibration.yaml's `effects`);
    halves: a static sensor's azimuth-halves check (static_sensor.HalvesCheck.to_yaml_dict), saved as
    halves.yaml; shared_returns_uncertainty: for pairs whitened by the range noise, the 1-sigmas with
    each return's noise counted once over all the pairs it serves in (shared_returns.py), which
    calibration.yaml writes as `sigma`; cluster_robust_uncertainty: the 1-sigmas from the pairs' own
    residuals clustered by time, the intrinsics' and the extrinsic's widened where the surface classes disagree
    (cluster_robust.py; None on a drive too short for it); uncertainty stays
    gtsam.Marginals' (pairs as independent), which names the unobservable parameters; verdict: one plain line on what
    the drive could not observe and which manoeuvre or scene would show it (verdict.py; None when it names nothing
    beyond the trajectory's common motion); trajectory_noise: the white noise smoothed out of the recorded poses
    before the calibration used them (recording.world.white_noise); ins_steps_s (S, 2): the times [s] of the
    recorded poses on either side of each step of the recorded positions, with a control at each
    (ReturnData.steps_s); held_shares: {parameter name: its share of prior variance in the weak directions held at
    nominal} (WeakDirections.held_shares), which bound its reported sigma (sigmas)."""

    calibration: Calibration
    uncertainty: Uncertainty
    estimated: tuple[bool, bool, bool]
    history: list[dict]
    residual_rows: np.ndarray
    residual_m: np.ndarray
    residual_weight: np.ndarray
    config: CalibrationConfig
    seconds: float
    timings_s: dict[str, float] = field(default_factory=dict)
    effects: tuple[dict, ...] = ()
    halves: dict | None = None
    shared_returns_uncertainty: Uncertainty | None = None
    cluster_robust_uncertainty: Uncertainty | None = None
    verdict: str | None = None
    trajectory_noise: PoseNoise = field(default_factory=PoseNoise.none)
    ins_steps_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    held_shares: dict[str, float] = field(default_factory=dict)

    @property
    def energy_cm2(self) -> tuple[float, float]:
        """J [cm^2] before the first solve and after the last."""
        return self.history[0]["energy_cm2"], self.history[-1]["energy_after_cm2"]

    @property
    def sigmas(self) -> Uncertainty:
        """The 1-sigmas to report (observability.reported), bounded where the weak directions hold a part of a
        parameter at its nominal value (Uncertainty.with_nominal_held), NaN for the parameters held at nominal."""
        return reported(self.uncertainty, self.shared_returns_uncertainty, self.cluster_robust_uncertainty,
                        self.held_shares).without(set(self.calibration.held))

    @property
    def unobservable(self) -> tuple[str, ...]:
        return self.calibration.unobservable

    def save(self, directory: str | Path, command: str = "graphcal.calibrate") -> Path:
        """calibration.yaml, config.yaml, history.csv, residuals.parquet (and halves.yaml) into directory."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        write_yaml(directory / CALIBRATION_FILE, self.to_yaml_dict(command))
        write_yaml(directory / "config.yaml", self.config.model_dump())
        if self.halves is not None:
            write_yaml(directory / HALVES_FILE, self.halves)
        with atomic_path(directory / "history.csv") as tmp, tmp.open("w", newline="") as stream:
            writer = csv.DictWriter(stream, fieldnames=list(self.history[0]))
            writer.writeheader()
            writer.writerows(self.history)
        table = pa.table({"row": self.residual_rows.astype(np.int64), "residual_m": self.residual_m.astype(np.float32),
                          "weight": self.residual_weight.astype(np.float32)})
        with atomic_path(directory / "residuals.parquet") as tmp:
            pq.write_table(table, tmp)
        return directory / CALIBRATION_FILE

    def to_yaml_dict(self, command: str) -> dict:
        cal, unc = self.calibration, self.sigmas
        unobservable, held = set(cal.unobservable), set(cal.held)
        offsets = offsets_to_file_units(cal.estimate.offsets)
        rows = []
        for fibre, values in enumerate(offsets):
            row = {"fibre": fibre}
            names = [f"fibre_{fibre}.{name}" for name in INTRINSIC_NAMES]
            row.update({name: (None if full in held else float(v))
                        for name, full, v in zip(INTRINSIC_NAMES, names, values)})
            row["sigma"] = (None if not self.estimated[0] or np.isnan(unc.intrinsics[fibre]).all() else
                            {name: (None if full in held else float(s))
                             for name, full, s in zip(INTRINSIC_NAMES, names, unc.intrinsics[fibre])})
            rows.append(row)
        extrinsic = cal.extrinsic().to_dict()
        if unc.extrinsic is not None:
            sigma = [None if f"extrinsic.{name}" in held else float(s)
                     for name, s in zip(EXTRINSIC_NAMES, unc.extrinsic)]
            extrinsic["sigma"] = {"boresight_deg": sigma[:3], "lever_arm_m": sigma[3:]}
        corrections = []
        if self.estimated[2]:
            for c, (time, pose) in enumerate(zip(cal.control_times_s, cal.estimate.corrections)):
                row = {"time": float(time), "d_position_m": [float(v) for v in pose.translation()],
                       "d_rotation_deg": [float(v) for v in np.degrees(gtsam.Rot3.Logmap(pose.rotation()))]}
                sigma = unc.controls[c]
                row["sigma"] = {name: (None if np.isnan(s) else float(s)) for name, s in zip(CONTROL_NAMES, sigma)}
                corrections.append(row)
        before, after = self.energy_cm2
        from graphcal import __version__
        return {"format": FORMAT, "sensor": {"model": cal.sensor_model, "reference_fibre": cal.reference_fibre},
                "intrinsics": rows, "extrinsic": extrinsic, "trajectory_corrections": corrections,
                "ins_steps_s": [[float(t) for t in pair] for pair in self.ins_steps_s],
                "effects": list(self.effects), "unobservable": sorted(unobservable),
                "unobservable_reasons": {name: cal.reasons[name] for name in sorted(cal.reasons)
                                         if name not in cal.imprecise},
                "imprecise": {name: cal.reasons[name] for name in sorted(cal.imprecise)},
                "verdict": self.verdict, **({} if cal.drive is None else {"drive": cal.drive}),
                "energy_cm2": {"before": float(before), "after": float(after)},
                "provenance": {"sigma": (SIGMA_MARGINALS if self.shared_returns_uncertainty is None else SIGMA_SHARED)
                               + ("" if self.cluster_robust_uncertainty is None else SIGMA_WIDENED),
                               "command": command, "graphcal": __version__, "gtsam": _gtsam_version(),
                               "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
                               "seconds": round(self.seconds, 2)}}


def _gtsam_version() -> str:
    from importlib.metadata import version
    return version("gtsam")


def read_calibration_yaml(path: Path) -> dict:
    """calibration.yaml's mapping with its format, sensor (model, reference_fibre), intrinsics
    (a list) and extrinsic (a mapping) checked: RecordingError naming the field otherwise."""
    data = read_yaml(path)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise RecordingError(path, f"format is {data.get('format') if isinstance(data, dict) else data!r}",
                             field="format", expected=FORMAT)
    header = _mapping(data.get("sensor"), path, "sensor", "model and reference_fibre")
    for key in ("model", "reference_fibre"):
        if key not in header:
            raise RecordingError(path, "missing", field=f"sensor.{key}", expected="the sensor's model and reference fibre")
    if not isinstance(data.get("intrinsics"), list):
        raise RecordingError(path, f"intrinsics is {data.get('intrinsics')!r}", field="intrinsics",
                             expected="a list, one row per fibre")
    _mapping(data.get("extrinsic"), path, "extrinsic", "lever_arm_m and boresight_deg")
    unobservable = data.get("unobservable") or []
    if not isinstance(unobservable, list) or not all(isinstance(name, str) for name in unobservable):
        raise RecordingError(path, f"unobservable is {unobservable!r}", field="unobservable",
                             expected="a list of parameter names")
    effects = data.get("effects") or []
    for index, row in enumerate(effects if isinstance(effects, list) else [effects]):
        name = row.get("effect") if isinstance(row, dict) else row
        if not isinstance(effects, list) or name not in KNOWN_EFFECTS:
            raise RecordingError(path, f"effect {name!r}", field=f"effects[{index}].effect",
                                 expected=f"one of {', '.join(sorted(KNOWN_EFFECTS))}")
    for key in ("unobservable_reasons", "imprecise"):
        reasons = data.get(key) or {}
        if not isinstance(reasons, dict) or not all(isinstance(v, str) for v in reasons.values()):
            raise RecordingError(path, f"{key} is {reasons!r}", field=key,
                                 expected="a mapping of parameter name to plain words")
    if not isinstance(data.get("verdict"), str | None):
        raise RecordingError(path, f"verdict is {data['verdict']!r}", field="verdict",
                             expected="one line of plain words, or nothing")
    return data


def _mapping(value, path: Path, field: str, expected: str) -> dict:
    if not isinstance(value, dict):
        raise RecordingError(path, f"{field} is {value!r}", field=field, expected=f"a mapping with {expected}")
    return value


def _vector3(value, path: Path, field: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != 3:
        raise RecordingError(path, f"{field} is {value!r}", field=field, expected="a list of 3 numbers")
    return np.array([finite_number(v, path, field) for v in value])
