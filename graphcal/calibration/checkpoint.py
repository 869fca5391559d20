"""A calibration's checkpoint: its state after each step and each outer iteration, so that an interrupted
calibration (a SIGKILL, a lost node, Ctrl-C) resumes where it stopped instead of from the start.

One .npz file, written atomically (graphcal.common.atomic) after every outer iteration:
    meta        JSON: the format, what it was written for (recording, returns, settings, graphcal version),
                the steps of CalibrationPipeline.run done, where inside the next one, the outer iterations
                each stage has run, whether the weak directions grew at the end, the parameters the final
                fit's sigmas found weak (with their reasons), the seconds so far
    history     JSON: the history's rows (graphcal.calibration.problem.History)
    offsets     (n_fibres, 4) in (m, rad, rad, m); extrinsic (4, 4) T_body_lidar; corrections (n, 4, 4) at the
                control times; effect.<name>; the same prefixed features_at. for the estimate the features in
                use were computed at, and prefixed window.<k>. for the fine phase's last outer iterations'
                estimates (Problem.fit averages them); weak_basis, weak_eigenvalues (weak_directions.WeakDirections)

A checkpoint written for another recording, other settings or another version of graphcal is refused with a
ConfigError naming what differs: resuming from it would mix two calibrations.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import gtsam
import numpy as np

from graphcal.calibration.config import CalibrationConfig
from graphcal.calibration.returns import Estimate
from graphcal.common.atomic import atomic_path
from graphcal.common.errors import ConfigError
from graphcal.common.jsonable import plain
from graphcal.recording.directory import Recording

FORMAT = "graphcal-checkpoint/2"


def written_for(recording: Recording, config: CalibrationConfig) -> dict:
    """What a checkpoint belongs to: the recording (its folder and number of returns), the settings (a digest of
    their JSON) and graphcal's version."""
    from graphcal import __version__

    settings = hashlib.sha256(config.model_dump_json().encode()).hexdigest()[:16]
    return {"recording": str(Path(recording.path).resolve()) if recording.path else recording.name,
            "returns": len(recording.points), "settings": settings, "graphcal": __version__}


@dataclass
class PipelineState:
    """What CalibrationPipeline carries from one step to the next: the estimate, the history's rows, the steps of
    run() done (done), inside the next one (a solve) the stage being solved and the outer iterations of it run
    (inside: None between steps), the outer iterations each stage has run (used), the weak directions held
    ((P, k) basis and eigenvalues), whether the end's analysis added some (grown), the parameters the final fit's
    sigmas found weak with their reasons (seen_weakly: weak_directions.seen_weakly), the seconds spent (in all and
    per step) and, inside a solve, the estimate its features were computed at (features_at) and the fine phase's last
    outer iterations' estimates (window: Problem.fit)."""

    estimate: Estimate
    rows: list = field(default_factory=list)
    done: int = 0
    inside: tuple[int, int] | None = None
    used: dict = field(default_factory=dict)
    weak_basis: np.ndarray | None = None
    weak_eigenvalues: np.ndarray | None = None
    grown: bool = False
    seen_weakly: dict = field(default_factory=dict)
    seconds: float = 0.0
    timings: dict = field(default_factory=dict)
    features_at: Estimate | None = None
    window: tuple = ()


@dataclass(frozen=True)
class Checkpoint:
    """The checkpoint file of one calibration (path) and what it is written for (written_for)."""

    path: Path
    owner: dict

    @classmethod
    def of(cls, path: str | Path, recording: Recording, config: CalibrationConfig) -> Checkpoint:
        return cls(Path(path), written_for(recording, config))

    def save(self, state: PipelineState) -> None:
        """Write the state, replacing the previous one whole."""
        meta = {"format": FORMAT, **self.owner, "done": state.done, "inside": state.inside, "used": state.used,
                "grown": state.grown, "seen_weakly": state.seen_weakly, "seconds": state.seconds,
                "timings": state.timings}
        arrays = _arrays(state.estimate) | {"weak_basis": state.weak_basis, "weak_eigenvalues": state.weak_eigenvalues}
        if state.features_at is not None:
            arrays |= _arrays(state.features_at, "features_at.")
        for k, estimate in enumerate(state.window):
            arrays |= _arrays(estimate, f"window.{k}.")
        with atomic_path(self.path) as tmp, open(tmp, "wb") as file:
            np.savez(file, meta=np.array(json.dumps(meta)), history=np.array(json.dumps(state.rows, default=plain)),
                     **{name: value for name, value in arrays.items() if value is not None})

    def load(self) -> PipelineState | None:
        """The state saved, None when there is no checkpoint; ConfigError naming the file when it is not a
        checkpoint or belongs to another calibration."""
        if not self.path.is_file():
            return None
        try:
            with np.load(self.path) as saved:
                meta, rows = json.loads(str(saved["meta"])), json.loads(str(saved["history"]))
                arrays = {name: saved[name] for name in saved.files if name not in ("meta", "history")}
        except (OSError, ValueError, KeyError) as error:
            raise ConfigError(f"{self.path}: not a graphcal checkpoint ({error}); remove it to start again") from None
        if meta.get("format") != FORMAT:
            raise ConfigError(f"{self.path}: format {meta.get('format')!r}, expected {FORMAT!r}; remove it to start "
                              "again")
        differs = [f"{name} {meta.get(name)!r} (now {value!r})" for name, value in self.owner.items()
                   if meta.get(name) != value]
        if differs:
            raise self.of_another(differs)
        inside = None if meta["inside"] is None else tuple(meta["inside"])
        features_at = _estimate(arrays, "features_at.") if "features_at.offsets" in arrays else None
        window = tuple(_estimate(arrays, f"window.{k}.") for k in range(len(arrays))
                       if f"window.{k}.offsets" in arrays)
        return PipelineState(_estimate(arrays), rows, meta["done"], inside, meta["used"], arrays.get("weak_basis"),
                             arrays.get("weak_eigenvalues"), meta["grown"], meta["seen_weakly"], meta["seconds"],
                             meta["timings"], features_at, window)

    def of_another(self, differences: list[str]) -> ConfigError:
        """The error of a checkpoint written for another calibration: what differs ("<what> <then> (now <now>)")."""
        return ConfigError(f"{self.path}: a checkpoint of another calibration: {', '.join(differences)}; remove it "
                           "(or run without --resume) to start again")

    def remove(self) -> None:
        self.path.unlink(missing_ok=True)


def _arrays(estimate: Estimate, prefix: str = "") -> dict[str, np.ndarray]:
    """An estimate as named arrays (names after prefix: offsets, extrinsic, corrections, effect.<name>)."""
    arrays = {"offsets": estimate.offsets, "extrinsic": estimate.extrinsic.matrix(),
              "corrections": np.array([c.matrix() for c in estimate.corrections]).reshape(-1, 4, 4)}
    arrays |= {f"effect.{name}": np.asarray(value) for name, value in estimate.effects.items()}
    return {prefix + name: value for name, value in arrays.items()}


def _estimate(arrays: dict[str, np.ndarray], prefix: str = "") -> Estimate:
    """The estimate _arrays wrote with prefix."""
    effects = {name.removeprefix(prefix + "effect."): value for name, value in arrays.items()
               if name.startswith(prefix + "effect.")}
    return Estimate(arrays[prefix + "offsets"], gtsam.Pose3(arrays[prefix + "extrinsic"]),
                    tuple(gtsam.Pose3(m) for m in arrays[prefix + "corrections"]), effects)
