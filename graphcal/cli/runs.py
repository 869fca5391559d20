"""What the commands that produce a run do, beyond parsing their options (graphcal/cli/main.py).

Each writes a run folder (graphcal/common/run_folder.py) with its results, run.rrd for the viewer and,
for a calibration, report.html; each stage is timed into run.yaml.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from graphcal.calibration.config import CalibrationConfig
from graphcal.common.lock import held_alone
from graphcal.common.progress import status
from graphcal.recording.directory import Recording
from graphcal.common.run_folder import RUNS, RunFolder, folder_name
from graphcal.viewer.stream import RRD, recording_stream
from graphcal.common.yamlfile import read_yaml, write_yaml

if TYPE_CHECKING:
    from graphcal.calibration.before_after import BeforeAfter
    from graphcal.calibration.evaluate import Evaluation
    from graphcal.calibration.result import CalibrationResult
    from graphcal.diagnosis.diagnose import Diagnosis


@dataclass(frozen=True)
class CalibrationRun:
    """A finished calibration run: its folder and what it computed (evaluation None without truth)."""

    folder: Path
    result: CalibrationResult
    residuals: BeforeAfter
    evaluation: Evaluation | None


def calibration_run(recording_path: Path, config: CalibrationConfig, out: Path | None = None, spawn: bool = False,
                    evaluate: bool = True, viewer_points: int | None = None, evaluation_points: int = 500_000,
                    command: str = "calibrate", quiet: bool = False, dask: str | None = None,
                    resume: bool = False) -> CalibrationRun:
    """Calibrate (the tiles' work on the Dask cluster `dask` names, graphcal.common.cluster), save the results,
    the residuals before/after, the evaluation against truth/ (when the recording has one and evaluate), run.rrd
    and report.html into the run folder. The calibration's checkpoint is the run folder's (checkpoint_path):
    resume goes on from it, else it starts again."""
    from graphcal.calibration.before_after import residuals_before_after
    from graphcal.calibration.calibrate import calibrate
    from graphcal.calibration.evaluate import evaluate as against_truth
    from graphcal.calibration.problem import enough_returns
    from graphcal.viewer.calibration import log_calibration
    from graphcal.viewer.log import VIEWER_POINTS

    run, recording = start_run(recording_path, out, command, quiet, check=enough_returns)
    with resumable(out, recording.name, command, resume, quiet) as checkpoint:
        result = calibrate(recording, config, quiet=quiet, dask=dask, checkpoint=checkpoint)
    run.timings_s.update({f"calibrate: {name}": seconds for name, seconds in result.timings_s.items()})
    with run.stage("save results"):
        result.save(run.path, command=" ".join(["graphcal"] + sys.argv[1:]))
    with run.stage("residuals before/after"), status("pairing the returns before and after", quiet):
        residuals = residuals_before_after(recording, result)
        residuals.save(run.path)
    evaluation = None
    if evaluate and recording.truth is not None:
        with run.stage("evaluate against truth"), status("comparing with truth/", quiet):
            evaluation = against_truth(result, recording, max_points=evaluation_points)
            write_yaml(run.path / "evaluation.yaml", evaluation.to_dict())
    with (run.stage("viewer file"), status(f"writing {run.path / RRD}", quiet),
          recording_stream(run.path / RRD, recording.name, spawn) as rec):
        log_calibration(rec, recording, result, residuals, evaluation, run.final, viewer_points or VIEWER_POINTS)
    _finish_with_report(run, recording_path, quiet)
    return CalibrationRun(run.publish(), result, residuals, evaluation)


def deskew_run(recording_path: Path, source: str, cloud_format: str, out: Path | None = None, use_gyro: bool = True,
               spawn: bool = False, viewer_points: int | None = None, quiet: bool = False) -> tuple[Path, int]:
    """Deskew every revolution into the run folder (graphcal/deskewing/scan_files.py layout), then run.rrd
    with the raw and deskewed revolutions. Returns (folder, revolutions)."""
    from graphcal.deskewing.deskew import iter_scans, motion_track
    from graphcal.deskewing.scan_files import save_scans
    from graphcal.viewer.deskew import deskew_summary, log_deskew
    from graphcal.viewer.log import VIEWER_POINTS, log_summary

    run, recording = start_run(recording_path, out, f"deskew-{source}", quiet,
                               check=lambda rec: motion_track(rec, source, use_gyro))
    manifest = {"recording": str(recording_path), "source": source, "gyro": use_gyro,
                "crs": recording.world.crs.to_string()}
    with run.stage("deskew and write scans"):
        save_scans(iter_scans(recording, source, use_gyro=use_gyro, quiet=quiet), run.path, cloud_format, manifest)
    scans = int(read_yaml(run.path / "deskew.yaml")["scans"])
    with (run.stage("viewer file"), status(f"writing {run.path / RRD}", quiet),
          recording_stream(run.path / RRD, recording.name, spawn) as rec):
        shown, origin = log_deskew(rec, iter_scans(recording, "none", quiet=True),
                                   iter_scans(recording, source, use_gyro=use_gyro, quiet=True),
                                   len(recording.points), recording.world.poses.position_m,
                                   viewer_points or VIEWER_POINTS)
        log_summary(rec, deskew_summary(recording, source, scans, shown, origin, run.final))
    run.finish(recording=str(Path(recording_path).resolve()))
    return run.publish(), scans


@dataclass(frozen=True)
class DiagnosisRun:
    """A finished diagnosis run: its folder and what graphcal.diagnose (or the comparison) found."""

    folder: Path
    diagnosis: Diagnosis


@dataclass(frozen=True)
class DiagnoseOptions:
    """How to diagnose: against a simulation of the same drive (its recording directory), or (rescan) against the
    recording's own returns raycast on a mesh of its calibrated cloud, or else against graphcal's model
    (graphcal.diagnose) with at most max_effects added, each re-solved with refit_iterations outer iterations,
    and with open_world the generic discrepancies tested too."""

    simulation: Path | None = None
    rescan: bool = False
    max_effects: int = 3
    refit_iterations: int = 4
    open_world: bool = True
    resume: bool = False


def diagnosis_run(recording_path: Path, config: CalibrationConfig, how: DiagnoseOptions = DiagnoseOptions(),
                  out: Path | None = None, spawn: bool = False, viewer_points: int | None = None,
                  quiet: bool = False) -> DiagnosisRun:
    """Diagnose the recording as `how` says, the nominal model calibrated with config; save diagnosis.json
    (and the re-solved calibration in calibration/), report.html and run.rrd into the run folder."""
    from graphcal.diagnosis.compare import compare
    from graphcal.report.diagnosis_html import write_diagnosis_report
    from graphcal.viewer.diagnosis import log_diagnosis
    from graphcal.viewer.log import VIEWER_POINTS

    simulation = how.simulation

    loaded = []

    def load_simulation(_recording: Recording) -> None:  # a bad simulation path fails before the folder is made
        if simulation is not None:
            loaded.append(Recording.load(simulation))

    run, recording = start_run(recording_path, out, "diagnose", quiet, check=load_simulation)
    if simulation is not None:
        with run.stage("compare with the simulation"), status("comparing with the simulation", quiet):
            diagnosis = compare(recording, loaded[0], max_points=config.max_points)
    elif how.rescan:
        from graphcal.calibration.calibrate import calibrate
        from graphcal.diagnosis.rescan import rescan as simulate_on_mesh

        result = calibrate(recording, config, quiet=quiet)
        run.timings_s.update({f"calibrate: {name}": seconds for name, seconds in result.timings_s.items()})
        estimate = result.calibration.estimate
        with run.stage("rescan on a mesh of the cloud"), status("raycasting the returns on the mesh", quiet):
            simulated = simulate_on_mesh(recording, estimate, config.max_points)
        with run.stage("compare with the rescan"), status("comparing with the rescan", quiet):
            diagnosis = compare(recording, simulated, max_points=config.max_points, estimate=estimate)
    else:
        from graphcal.diagnosis.diagnose import diagnose

        with run.stage("diagnose"), resumable(out, recording.name, "diagnose", how.resume, quiet) as checkpoint:
            diagnosis = diagnose(recording, config, max_effects=how.max_effects, refit_iterations=how.refit_iterations,
                                 quiet=quiet, open_world=how.open_world, checkpoint=checkpoint)
    with run.stage("save results"):
        diagnosis.save(run.path, command=" ".join(["graphcal"] + sys.argv[1:]))
    with run.stage("report"), status("writing report.html", quiet):
        write_diagnosis_report(run.path, run.final)
    with (run.stage("viewer file"), status(f"writing {run.path / RRD}", quiet),
          recording_stream(run.path / RRD, recording.name, spawn) as rec):
        log_diagnosis(rec, recording, diagnosis, run.final, viewer_points or VIEWER_POINTS)
    references = {"simulation": str(Path(simulation).resolve())} if simulation is not None else {}
    run.finish(recording=str(Path(recording_path).resolve()), **references)
    return DiagnosisRun(run.publish(), diagnosis)


def evaluation_run(calibration_path: Path, recording_path: Path, quiet: bool = False) -> tuple[Evaluation, Path]:
    """Evaluate a calibration (run folder or calibration.yaml) against the recording's truth/;
    writes evaluation.yaml next to calibration.yaml and refreshes report.html if there is one. Against another
    drive than the one it was made on (calibration.yaml's `drive`), the evaluation is written beside it as
    evaluation-<recording>.yaml and the run's own evaluation and report are left as they are."""
    from graphcal.calibration.corrected_cloud import corrections_cover
    from graphcal.calibration.evaluate import evaluate
    from graphcal.calibration.result import Calibration, calibration_file, drive_of
    from graphcal.common.errors import RecordingError
    from graphcal.common.run_folder import folder_name
    from graphcal.report.html import EVALUATION, REPORT, write_report

    recording = Recording.load(recording_path)
    if recording.truth is None:
        raise RecordingError(Path(recording_path) / "truth", "not found",
                             expected="a simulated recording's truth/ to evaluate against (real data has none)")
    calibration = Calibration.load(calibration_path, recording.sensor)
    corrections_cover(calibration, recording, calibration_file(calibration_path))
    effects_not_applied(calibration_path, quiet)
    folder = calibration_file(calibration_path).parent
    with status("comparing with truth/", quiet):
        evaluation = evaluate(calibration, recording)
    # trajectory corrections passed corrections_cover only on their own drive: its fingerprint is not made again
    own_drive = (len(calibration.control_times_s) > 0 or calibration.drive is None
                 or calibration.drive == drive_of(recording))
    energy = (read_yaml(calibration_file(calibration_path)) or {}).get("energy_cm2") or {}
    if own_drive and "before" in energy:  # J of the drive it was made on: not this one's
        evaluation = replace(evaluation, energy_cm2=(energy["before"], energy["after"]))
    path = folder / (EVALUATION if own_drive else f"evaluation-{folder_name(recording.name)}.yaml")
    write_yaml(path, {**evaluation.to_dict(), "recording": str(recording_path)})
    if own_drive and (folder / REPORT).is_file():
        write_report(folder)
    return evaluation, path


def apply_run(calibration_path: Path, recording_path: Path, out: Path | None = None, quiet: bool = False) -> Path:
    """The corrected cloud (graphcal/calibration/corrected_cloud.py) at `out` (.las, .laz or .ply), or in a
    run folder as cloud.laz; with the calibration's residuals when it was made from this recording. The effects
    a diagnosis added to calibration.yaml are not applied: said on stderr (unless quiet) and in run.yaml."""
    from graphcal.calibration.result import Calibration, calibration_file
    from graphcal.clouds.formats import STREAMED_SUFFIXES
    from graphcal.calibration.corrected_cloud import (
        RESIDUALS,
        read_residuals,
        write_corrected_cloud,
    )
    from graphcal.common.errors import ConfigError
    from graphcal.common.run_folder import MANIFEST

    if out is not None and out.suffix.lower() not in STREAMED_SUFFIXES:  # before any work
        raise ConfigError(f"--out {out}: expected a {', '.join(STREAMED_SUFFIXES)} file name")
    if out is not None and out.is_dir():
        raise ConfigError(f"--out {out}: a directory; expected a {', '.join(STREAMED_SUFFIXES)} file name")
    if out is None:
        run, recording = start_run(recording_path, None, "apply", quiet)
    else:
        run, recording = None, Recording.load(recording_path)
    calibration = Calibration.load(calibration_path, recording.sensor)
    not_applied = effects_not_applied(calibration_path, quiet)
    folder = calibration_file(calibration_path).parent
    made_from = (read_yaml(folder / MANIFEST) or {}).get("recording") if (folder / MANIFEST).is_file() else None
    residuals = None
    if made_from and Path(made_from).resolve() == Path(recording_path).resolve() and (folder / RESIDUALS).is_file():
        residuals = read_residuals(folder / RESIDUALS, len(recording.points))
    path, named = out or run.path / "cloud.laz", calibration_file(calibration_path)
    if run is None:
        write_corrected_cloud(path, calibration, recording, residuals, quiet, named)
    else:
        with run.stage("apply and write"):
            write_corrected_cloud(path, calibration, recording, residuals, quiet, named)
        run.finish(recording=str(Path(recording_path).resolve()), calibration=str(Path(calibration_path).resolve()),
                   cloud=path.name, residuals="from the calibration's final fit" if residuals else "none (NaN)",
                   effects_not_applied=not_applied)
        path = run.publish() / path.name
    return path


def effects_not_applied(calibration_path: Path, quiet: bool) -> list[str]:
    """The effects a diagnosis listed in calibration.yaml, which apply and evaluate leave out (said on stderr
    unless quiet): the cloud is corrected by the offsets, the extrinsic and the trajectory corrections only."""
    from graphcal.calibration.result import calibration_file, read_calibration_yaml

    path = calibration_file(calibration_path)
    names = [row["effect"] if isinstance(row, dict) else row for row in read_calibration_yaml(path).get("effects") or []]
    if names and not quiet:
        print(f"note: {path} lists effects found by graphcal diagnose ({', '.join(names)}): the cloud is corrected "
              "by the offsets, the extrinsic and the trajectory corrections only; these effects are not applied",
              file=sys.stderr)
    return names


@contextmanager
def resumable(out: Path | None, recording_name: str, command: str, resume: bool, quiet: bool) -> Iterator[Path]:
    """The checkpoint of a run's calibration (checkpoint_path), held by this run alone (a second run of the same
    recording and command without another --out is refused, not let to replace it): removed first unless resume
    (a fresh start); on Ctrl-C, a line saying where it is kept."""
    checkpoint = checkpoint_path(out, recording_name, command)
    checkpoint.parent.mkdir(parents=True, exist_ok=True)
    with held_alone(checkpoint, f"graphcal {command}"):
        if not resume:
            checkpoint.unlink(missing_ok=True)
        elif not checkpoint.is_file() and not quiet:
            print(f"note: no checkpoint at {checkpoint}: calibrating from the start", file=sys.stderr)
        try:
            yield checkpoint
        except KeyboardInterrupt:
            if checkpoint.is_file():
                print(f"the calibration's state is kept in {checkpoint}: the same command with --resume goes on "
                      "from there", file=sys.stderr)
            raise


def checkpoint_path(out: Path | None, recording_name: str, command: str) -> Path:
    """Where the calibration of a run keeps its checkpoint: beside --out (.<out>.checkpoint.npz), else in runs/
    (.<recording>-<command>.checkpoint.npz, the run folder's name without its time stamp)."""
    if out is not None:
        return Path(out).parent / f".{Path(out).name}.checkpoint.npz"
    return RUNS / f".{folder_name(recording_name)}-{command}.checkpoint.npz"


def start_run(recording_path: Path, out: Path | None, command: str, quiet: bool,
              check=None) -> tuple[RunFolder, Recording]:
    """Load and validate the recording (timed), check(recording) if given, then create the run
    folder: bad input fails before any folder is made."""
    import time

    started = time.perf_counter()
    with status(f"reading {recording_path}", quiet):
        recording = Recording.load(recording_path)
    if check is not None:
        check(recording)
    run = RunFolder.create(out, recording.name, command)
    run.timings_s["load and validate the recording"] = time.perf_counter() - started
    return run, recording


def _finish_with_report(run: RunFolder, recording_path: Path, quiet: bool) -> None:
    """run.yaml, then report.html (which shows run.yaml's timings), then run.yaml with the report's time."""
    from graphcal.report.html import write_report

    run.finish(recording=str(Path(recording_path).resolve()))
    with run.stage("report"), status("writing report.html", quiet):
        write_report(run.path, run.final)
    run.finish(recording=str(Path(recording_path).resolve()))
