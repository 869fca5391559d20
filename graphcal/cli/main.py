"""`graphcal` command line. Bad input ends with one clear line and exit code 2."""

from __future__ import annotations

import functools
import math
import shutil
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(help="Target-free lidar self-calibration with a GTSAM factor graph.\n\n"
                       "Commands that produce results write a run folder (runs/<recording>-<command>-<UTC time>/, "
                       "runs/latest points at the last one): run.yaml, the results, run.rrd, report.html.\n\n"
                       "Exit codes: 0 done; 2 bad input or an unusable environment (one line on stderr says what); "
                       "3 a result graphcal recognises as wrong and refuses (e.g. collapsed fibres; one line says "
                       "what); 1 an unexpected failure (a bug: the traceback is printed).",
                  no_args_is_help=True, pretty_exceptions_enable=False)

def _version(value: bool) -> None:
    if value:
        from graphcal import __version__

        typer.echo(f"graphcal {__version__}")
        raise typer.Exit()


@app.callback()
def _options(version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True,
                                                   help="print graphcal's version and exit")] = False) -> None:
    """Target-free lidar self-calibration with a GTSAM factor graph."""


_IMPORTING: list[Path] = []  # the recording folder an import is writing (none once it ends)


def _clear_errors(command):
    """Turn graphcal's own errors into one line on stderr and exit code 2 (3 for a refused result); Ctrl-C into
    "interrupted" and exit code 130."""
    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        from pydantic import ValidationError

        from graphcal.common.errors import CalibrationError, GraphcalError
        from graphcal.common.run_folder import abandon_unpublished

        def abandon() -> None:  # what a refused or interrupted command had begun to write
            abandon_unpublished()
            for folder in _IMPORTING:
                shutil.rmtree(folder, ignore_errors=True)

        try:
            return command(*args, **kwargs)
        except GraphcalError as error:
            abandon()
            typer.echo(f"error: {error}", err=True)
            raise typer.Exit(3 if isinstance(error, CalibrationError) else 2) from None
        except ValidationError as error:  # a setting out of range (simulate --size 0, a scenario's field)
            first = error.errors()[0]
            where = ".".join(str(part) for part in first["loc"]) or error.title
            typer.echo(f"error: {error.title} {where}: {first['msg']} (got {first.get('input')!r})", err=True)
            raise typer.Exit(2) from None
        except KeyboardInterrupt:  # Ctrl-C: what the command had begun to write goes, without a traceback
            abandon()
            typer.echo("interrupted", err=True)
            raise typer.Exit(130) from None
        finally:
            _IMPORTING.clear()
    return wrapper


Force = Annotated[bool, typer.Option("--force", help="replace what --out names (once the new result is complete)")]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="no progress bars or summary")]


@app.command()
@_clear_errors
def simulate(scenario: Annotated[str, typer.Argument(help="scenario name (sim6_turn, ...) or script path")],
             out: Annotated[Path | None, typer.Option(help="recording directory to write")] = None,
             size: Annotated[float, typer.Option(help="fraction of the sensor's firings kept")] = 1.0,
             seed: Annotated[int, typer.Option(help="seed of every random draw")] = 0,
             force: Force = False,
             quiet: Quiet = False) -> None:
    """Simulate a scenario and write its recording (with truth/)."""
    from graphcal.simulation.script import built, load_scenario_builder
    from graphcal.simulation.simulator import simulate as run

    if out is not None:  # before the simulation's work
        _not_taken(out, force)
    build = load_scenario_builder(scenario)
    started = time.perf_counter()
    recording = run(built(build, size=size, seed=seed), quiet=quiet)
    out = out or _not_taken(Path("out") / recording.name, force)
    recording.save(out)
    if not quiet:
        typer.echo(f"{len(recording.points):,} returns written to {out} in {time.perf_counter() - started:.1f} s")


@app.command()
@_clear_errors
def info(recording: Annotated[Path, typer.Argument(help="recording directory")],
         quiet: Annotated[bool, typer.Option("--quiet", "-q", help="validate only: no summary (the exit code "
                                                                   "says whether the recording is valid)")] = False
         ) -> None:
    """Validate a recording (every return, in batches) and summarise it."""
    from graphcal.recording.directory import Recording

    rec = Recording.load(recording, validate=False)
    summary = rec.validate()
    if quiet:
        return
    world = rec.world
    typer.echo(f"{rec.name}: {summary.n_points:,} returns from a {rec.sensor.model} "
               f"({rec.sensor.n_fibres} fibres, reference {rec.sensor.reference_fibre}) over "
               f"{summary.time_max - summary.time_min:.2f} s")
    typer.echo(f"world frame {world.crs.to_string()}, grid scale factor {world.scale_factor.mean():.6f}, "
               f"meridian convergence {world.convergence_deg.mean():+.4f} deg")
    typer.echo(f"odometry: {'yes' if rec.odometry is not None else 'no'}; truth: "
               f"{'yes' if (recording / 'truth').is_dir() else 'no'}")


Spawn = Annotated[bool, typer.Option("--spawn", help="also stream to a live rerun viewer (needs a display)")]
ViewerPoints = Annotated[int, typer.Option(help="returns drawn per cloud in run.rrd (a random subset)", min=1000)]


def calibration_config(mode: str, config: Path | None, overrides: dict | None = None):
    """CalibrationConfig from --mode, the YAML file of settings and overrides, or ConfigError."""
    import pydantic

    from graphcal.calibration.config import CalibrationConfig
    from graphcal.common.errors import ConfigError
    from graphcal.common.yamlfile import read_yaml

    settings = (read_yaml(config) or {}) if config is not None else {}
    if not isinstance(settings, dict):
        raise ConfigError(f"{config}: not a mapping of CalibrationConfig settings (name: value per line)")
    try:
        return CalibrationConfig(**{"mode": mode, **settings, **(overrides or {})})
    except pydantic.ValidationError as error:
        first = error.errors()[0]
        message = first["msg"].removeprefix("Value error, ")  # pydantic's prefix for a validator's ValueError
        where = ".".join(map(str, first["loc"]))
        raise ConfigError(f"{config or '--mode'}: {where + ': ' if where else ''}{message}") from None


@app.command()
@_clear_errors
def calibrate(recording: Annotated[Path, typer.Argument(help="recording directory")],
              mode: Annotated[str, typer.Option(help="auto (what a mapping drive needs) or a mode listed above")]
              = "auto",
              config: Annotated[Path | None, typer.Option(help="YAML file of CalibrationConfig settings")] = None,
              out: Annotated[Path | None, typer.Option(help="run folder (default: a new one in runs/)")] = None,
              evaluate: Annotated[bool, typer.Option(help="compare with truth/ when the recording has one")] = True,
              dask: Annotated[str | None, typer.Option(help="compute the features and pairs tile by tile on Dask: "
                                                            "local, local:N (N worker processes here) or a "
                                                            "scheduler address tcp://HOST:PORT")] = None,
              resume: Annotated[bool, typer.Option(help="go on from where an interrupted calibration of the same "
                                                        "recording, settings and --out stopped (its checkpoint)")]
              = False,
              spawn: Spawn = False, viewer_points: ViewerPoints = 1_000_000, force: Force = False,
              quiet: Quiet = False) -> None:
    """Self-calibrate a recording into a run folder: results, run.rrd, report.html.

    Modes: intrinsic, extrinsic, trajectory, joint, joint_trajectory, extrinsic_then_intrinsic,
    intrinsic_then_extrinsic (docs/reference/command-line.md).

    The run folder gets calibration.yaml (estimates, 1-sigmas, unobservable parameters),
    config.yaml, history.csv, residuals.parquet, pairs_nominal.parquet, pairs_calibrated.parquet,
    evaluation.yaml (with truth), run.rrd, report.html and run.yaml (seconds per stage).

    The calibration's state is saved after every outer iteration (a checkpoint beside the run folder, removed at
    the end); after an interruption, the same command with --resume goes on from there.

    Example: graphcal calibrate out/sim6_turn --mode trajectory --spawn
    """
    from graphcal.cli.runs import calibration_run
    from graphcal.common.cluster import check_address

    if out is not None:
        _not_taken(out, force)
    if dask is not None:
        check_address(dask)
    run = calibration_run(recording, calibration_config(mode, config), out, spawn, evaluate, viewer_points,
                          quiet=quiet, dask=dask, resume=resume)
    if not quiet:
        _print_calibration(run)


def _print_calibration(run) -> None:
    result, evaluation = run.result, run.evaluation
    before, after = result.energy_cm2
    typer.echo(f"J {before:.3g} -> {after:.3g} cm^2 in {result.seconds:.1f} s ({len(result.history)} outer iterations)")
    noise_m = result.config.weighting.range_noise_m
    if noise_m is not None:
        voxel_m = result.config.features.voxel_m
        measured = ("unknown" if math.isnan(noise_m) else f"{noise_m * 1000:.2g} mm" if noise_m >= 1e-6
                    else "none (below 1 micrometre)")
        typer.echo(f"range noise {measured}: pairs {result.config.weighting.pair_noise}, features from "
                   + (f"{voxel_m} m voxels" if voxel_m else "every return"))
    smoothed = result.trajectory_noise
    if smoothed.interval_s > 0:
        typer.echo(f"trajectory white noise {smoothed.position_m * 1000:.2g} mm, "
                   f"{math.degrees(smoothed.attitude_rad):.2g} deg a pose: smoothed out before the calibration")
    if len(result.ins_steps_s):
        from graphcal.report.html import steps_line

        typer.echo(f"steps of the recorded positions: {steps_line(result.ins_steps_s)}")
    if result.verdict is not None:
        imprecise = len(result.calibration.imprecise)
        typer.echo(f"{result.verdict}; {len(result.unobservable)} names, each with its reason, in calibration.yaml "
                   "unobservable_reasons" + (f", {imprecise} in imprecise" if imprecise else ""))
    if evaluation is not None:
        typer.echo(evaluation.cloud_line())
    typer.echo(f"wrote {run.folder}: calibration.yaml, report.html, run.rrd")
    typer.echo(f"open {run.folder / 'report.html'} in a browser; graphcal view {run.folder}")


@app.command()
@_clear_errors
def diagnose(recording: Annotated[Path, typer.Argument(help="recording directory")],
             simulation: Annotated[Path | None, typer.Option(help="a simulation of the same drive with nominal "
                                                                   "physics: name the effect explaining the difference")] = None,
             rescan: Annotated[bool, typer.Option(help="no scene model: simulate the drive on a mesh of the "
                                                       "calibrated cloud, then compare with it")] = False,
             mode: Annotated[str, typer.Option(help="calibration mode of the nominal model (see calibrate)")] = "joint",
             config: Annotated[Path | None, typer.Option(help="YAML file of CalibrationConfig settings")] = None,
             max_effects: Annotated[int, typer.Option(help="most effects added")] = 3,
             refit_iterations: Annotated[int, typer.Option(help="outer iterations of each re-solve with an effect "
                                                                "added", min=1)] = 4,
             open_world: Annotated[bool, typer.Option("--open-world/--named-only",
                                                      help="also test a smooth error of every channel against every "
                                                           "regressor, reported as discovered (default), or only the "
                                                           "named candidates")] = True,
             out: Annotated[Path | None, typer.Option(help="run folder (default: a new one in runs/)")] = None,
             resume: Annotated[bool, typer.Option(help="go on from the baseline calibration an interrupted "
                                                       "diagnosis of the same recording, settings and --out saved")]
             = False,
             spawn: Spawn = False, viewer_points: ViewerPoints = 1_000_000, force: Force = False,
             quiet: Quiet = False) -> None:
    """Find where the model and the recording disagree, name the physics left out, model it, show the
    fit improve (docs/howto/diagnose.md).

    The run folder gets diagnosis.json, the re-solved calibration in calibration/ (its effects
    listed), report.html (findings, discovered curves over the binned residuals), run.rrd (the
    residual field) and run.yaml (seconds per stage).

    Example: graphcal diagnose out/concealed --mode joint
    """
    from graphcal.cli.runs import DiagnoseOptions, diagnosis_run

    from graphcal.diagnosis.diagnose import default_subset
    from graphcal.recording.directory import Recording

    if out is not None:
        _not_taken(out, force)
    how = DiagnoseOptions(simulation, rescan, max_effects, refit_iterations, open_world, resume)
    # a settings file says how many returns; else the diagnosis's default subset
    settings = calibration_config(mode, config, None if config is not None else
                                  default_subset(Recording.load(recording)))
    run = diagnosis_run(recording, settings, how, out, spawn, viewer_points, quiet)
    if not quiet:
        typer.echo(run.diagnosis.summary())
        typer.echo(f"wrote {run.folder}: diagnosis.json, report.html, run.rrd in {run.diagnosis.seconds:.1f} s; "
                   f"graphcal view {run.folder}")


@app.command()
@_clear_errors
def deskew(recording: Annotated[Path, typer.Argument(help="recording directory")],
           source: Annotated[str, typer.Option(help="motion during the sweep: ins, odometry, or none (raw scans)")] = "ins",
           cloud_format: Annotated[str, typer.Option("--format", help="ply, las, laz, or uos (3DTK .3d)")] = "ply",
           out: Annotated[Path | None, typer.Option(help="run folder (default: a new one in runs/)")]
           = None,
           gyro: Annotated[bool, typer.Option(help="odometry: yaw from the gyro column when there is one")] = True,
           spawn: Spawn = False, viewer_points: ViewerPoints = 1_000_000, force: Force = False,
           quiet: Quiet = False) -> None:
    """Deskew every revolution into its end-of-scan lidar frame (seed 002).

    The run folder gets one cloud and one 3DTK pose per revolution, poses.csv, deskew.yaml,
    run.rrd (raw vs deskewed) and run.yaml."""
    from graphcal.clouds.formats import FORMATS
    from graphcal.deskewing.deskew import SOURCES
    from graphcal.common.errors import ConfigError
    from graphcal.cli.runs import deskew_run

    if source not in SOURCES:
        raise ConfigError(f"--source {source!r}: expected one of {', '.join(SOURCES)}")
    if cloud_format not in FORMATS:
        raise ConfigError(f"--format {cloud_format!r}: expected one of {', '.join(FORMATS)}")
    if out is not None:
        _not_taken(out, force)
    started = time.perf_counter()
    folder, scans = deskew_run(recording, source, cloud_format, out, gyro, spawn, viewer_points, quiet)
    if not quiet:
        typer.echo(f"{scans} revolutions deskewed ({source}) into {folder} in {time.perf_counter() - started:.1f} s; "
                   f"graphcal view {folder}")


@app.command("evaluate")
@_clear_errors
def evaluate_command(calibration: Annotated[Path, typer.Argument(help="run folder or calibration.yaml")],
                     recording: Annotated[Path, typer.Argument(help="simulated recording directory (with truth/)")],
                     quiet: Quiet = False) -> None:
    """Compare a calibration with the recording's truth/ and print the table.

    Writes evaluation.yaml next to calibration.yaml (and refreshes report.html when there is one)."""
    from graphcal.cli.runs import evaluation_run

    evaluation, path = evaluation_run(calibration, recording, quiet)
    typer.echo(evaluation.table())
    if not quiet:
        typer.echo(f"wrote {path}")


@app.command("apply")
@_clear_errors
def apply_command(calibration: Annotated[Path, typer.Argument(help="run folder or calibration.yaml")],
                  recording: Annotated[Path, typer.Argument(help="recording directory")],
                  out: Annotated[Path | None, typer.Option(help=".las, .laz or .ply file (default: cloud.laz in "
                                                                 "a new run folder in runs/)")] = None,
                  force: Force = False, quiet: Quiet = False) -> None:
    """Write the recording's cloud corrected by a calibration (LAS, LAZ or PLY).

    World CRS coordinates (the CRS in the LAS header), GPS time, intensity, and fibre and
    residual_m as extra dimensions."""
    from graphcal.cli.runs import apply_run

    if out is not None:
        _not_taken(out, force)
    path = apply_run(calibration, recording, out, quiet)
    if not quiet:
        typer.echo(f"wrote {path}")


@app.command("export")
@_clear_errors
def export_command(run: Annotated[Path, typer.Argument(help="calibration run folder (or its calibration.yaml)")],
                   export_format: Annotated[str, typer.Option("--format", help="velodyne-xml (db.xml), ros-yaml "
                                                                               "(velodyne_pointcloud) or ouster-json")],
                   out: Annotated[Path, typer.Option(help="file to write (not an existing one)")],
                   original: Annotated[Path | None, typer.Option("--from", help="the unit's own calibration file: "
                                                                                "only the calibrated fields change")]
                   = None,
                   quiet: Quiet = False) -> None:
    """Write a calibration's intrinsics in the vendor's format (docs/howto/export-calibration.md).

    Example: graphcal export runs/latest --format velodyne-xml --from db.xml --out db-calibrated.xml
    """
    from graphcal.cli.export import export_run

    notes = export_run(run, export_format, out, original)
    if not quiet:
        for note in notes:
            typer.echo(f"  {note}")
        typer.echo(f"wrote {out}")


@app.command()
@_clear_errors
def report(run_folder: Annotated[Path, typer.Argument(help="calibration or diagnosis run folder")],
           quiet: Quiet = False) -> None:
    """Write report.html (self-contained: figures inside) from a calibration or a diagnosis run folder."""
    from graphcal.report.diagnosis_html import DIAGNOSIS_FILE, write_diagnosis_report
    from graphcal.report.html import write_report

    diagnosis = (run_folder / DIAGNOSIS_FILE).is_file() and not (run_folder / "calibration.yaml").is_file()
    path = write_diagnosis_report(run_folder) if diagnosis else write_report(run_folder)
    if not quiet:
        typer.echo(f"wrote {path}")


@app.command()
@_clear_errors
def view(run: Annotated[Path, typer.Argument(help="run folder (its run.rrd) or an .rrd file")],
         web: Annotated[bool, typer.Option(help="serve the web viewer over HTTP instead (no display needed)")] = False,
         port: Annotated[int, typer.Option(help="--web: HTTP port of the web viewer")] = 9090,
         quiet: Annotated[bool, typer.Option("--quiet", "-q", help="no message")] = False) -> None:
    """Open a run in the rerun viewer (its layout is in the file)."""
    import subprocess

    from graphcal.common.errors import ConfigError, RecordingError
    from graphcal.viewer.stream import RRD, no_viewer_reason, viewer_executable

    path = run / RRD if run.is_dir() else run
    if not path.is_file():
        raise RecordingError(path, "file not found", expected="a run folder with run.rrd, or an .rrd file")
    if web:
        if viewer_executable() is None:
            raise ConfigError("the rerun viewer executable is not installed (pip install rerun-sdk)")
        if not quiet:
            typer.echo(f"serving {path} at http://localhost:{port} (Ctrl-C stops)")
        sys.exit(subprocess.call([viewer_executable(), "--web-viewer", "--web-viewer-port", str(port), str(path)]))
    reason = no_viewer_reason()
    if reason is not None:
        raise ConfigError(f"cannot open the viewer here: {reason}; use graphcal view {run} --web, or open {path} "
                          "with `rerun` on a machine with a screen")
    subprocess.Popen([viewer_executable(), str(path)], start_new_session=True)
    if not quiet:
        typer.echo(f"opened {path} in the rerun viewer")


@app.command()
@_clear_errors
def demo(out: Annotated[Path, typer.Option(help="folder of the demo: its recording and its run")] = Path("out/demo"),
         size: Annotated[float, typer.Option(help="fraction of the sensor's firings kept")] = 0.5,
         max_points: Annotated[int, typer.Option(help="returns the calibration draws", min=1000)] = 250_000,
         spawn: Spawn = False, quiet: Quiet = False) -> None:
    """Flagship demo, end to end: simulate, calibrate, evaluate, run.rrd, report.

    Simulates sim6_turn, calibrates its trajectory, compares with truth, writes run.rrd and
    report.html, and says what to open (2 to 2.5 minutes on 2 shared cores)."""
    from graphcal.cli.demo import run_demo

    run_demo(out, size=size, max_points=max_points, spawn=spawn, quiet=quiet)


import_app = typer.Typer(help="Import real data into the recording format (docs/howto/import.md).", no_args_is_help=True)
app.add_typer(import_app, name="import")


def _numbers(text: str | None, option: str, count: int = 3) -> tuple[float, ...] | None:
    """'a,b,c' -> (a, b, c) of finite numbers, or ConfigError naming the option."""
    import math

    from graphcal.common.errors import ConfigError

    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise ConfigError(f"{option}: {text!r} is not {count} comma-separated finite numbers")
    return values


def _position(text: str | None) -> tuple[float, float, float] | None:
    """--position 'LAT,LON,ALT' (deg, deg, m), or ConfigError naming it when a value is beyond trajectory.csv's
    limits (GEODETIC_LIMITS)."""
    from graphcal.common.errors import ConfigError
    from graphcal.recording.trajectory import GEODETIC_LIMITS

    values = _numbers(text, "--position")
    if values is not None and any(abs(v) > limit for v, limit in zip(values, GEODETIC_LIMITS)):
        lat, lon, height = GEODETIC_LIMITS
        raise ConfigError(f"--position: {text!r}: latitude within +-{lat:g} deg, longitude within +-{lon:g} deg "
                          f"and height within +-{height:g} m expected")
    return values


def _print_import(recording, out: Path, quiet: bool) -> None:
    """The notes of an imported recording and where it was written, unless quiet."""
    if not quiet:
        for note in recording.source["notes"]:
            typer.echo(f"  {note}")
        typer.echo(f"{len(recording.points):,} returns written to {out}")


@import_app.command("pcap")
@_clear_errors
def import_pcap_command(
        pcap: Annotated[Path, typer.Argument(help="Velodyne capture (HDL-32E, VLP-16, HDL-64E, VLP-32C, VLS-128): libpcap file or "
                                                   "ROS bag of velodyne_msgs/VelodyneScan")],
        out: Annotated[Path | None, typer.Option(help="recording directory (default out/<pcap name>)")] = None,
        model: Annotated[str | None, typer.Option(help="force the model: HDL-32E, VLP-16, HDL-64E, VLP-32C or VLS-128")] = None,
        calibration: Annotated[Path | None, typer.Option(help="db.xml or ROS velodyne YAML of the unit (needed for "
                                                                    "HDL-64E, VLP-32C, VLS-128)")] = None,
        trajectory: Annotated[Path | None, typer.Option(help="SBET (.out) or trajectory.csv, GPS seconds of week")] = None,
        crs: Annotated[str, typer.Option(help="world CRS (needed for a projected trajectory.csv)")] = "auto",
        position: Annotated[str | None, typer.Option(help="static position LAT,LON,ALT (deg, deg, m)")] = None,
        attitude: Annotated[str, typer.Option(help="static attitude ROLL,PITCH,YAW (deg, ENU)")] = "0,0,0",
        lever_arm: Annotated[str | None, typer.Option(help="nominal lever arm X,Y,Z (m, body frame)")] = None,
        boresight: Annotated[str | None, typer.Option(help="nominal boresight ROLL,PITCH,YAW (deg)")] = None,
        block_azimuth: Annotated[bool, typer.Option(help="one azimuth per firing sequence (VeloView 3) instead "
                                                         "of each laser's own")] = False,
        topic: Annotated[str | None, typer.Option(help="ROS bag: the VelodyneScan topic (default: the only one)")] = None,
        body_frame: Annotated[str | None, typer.Option(help="ROS bag: the body's frame in the bag's tf, where the "
                                                            "extrinsic is read from when --lever-arm and --boresight "
                                                            "are not given (default: the frame of the bag's Odometry "
                                                            "or Imu)")] = None,
        quiet: Quiet = False) -> None:
    """Velodyne pcap (or ROS bag) -> recording. Without --trajectory the sensor is taken as STATIC
    at the GPRMC fix of its position packets (or --position). From a bag, the extrinsic is the bag's
    /tf_static chain from the body frame to the packets' frame unless --lever-arm/--boresight give one.

    Example: graphcal import pcap drive.pcap --trajectory sbet.out --lever-arm 0.8,0,1.9 --boresight 0,0,90
    """
    from graphcal.common.errors import ConfigError
    from graphcal.importers.velodyne_calibration import read_velodyne_calibration
    from graphcal.importers.velodyne_pcap import import_pcap

    out = _imported_recording_folder(out, pcap.stem)  # before the import's work
    extrinsic = _extrinsic(lever_arm, boresight)
    options = {"model": model, "calibration": read_velodyne_calibration(calibration) if calibration else None,
               "trajectory": _read_trajectory(trajectory) if trajectory else None,
               "position": _position(position), "attitude_deg": _numbers(attitude, "--attitude"),
               "extrinsic": extrinsic, "interpolate_azimuth": not block_azimuth, "crs": crs, "quiet": quiet}
    if pcap.is_dir() or pcap.suffix.lower() in (".bag", ".db3", ".mcap"):
        from graphcal.importers.velodyne_rosbag import import_rosbag

        recording = import_rosbag(pcap, out, topic=topic, body_frame=body_frame, **options)
    else:
        if body_frame is not None or topic is not None:
            raise ConfigError(f"{'--body-frame' if body_frame is not None else '--topic'}: only for a ROS bag, and "
                              f"{pcap} is a libpcap file")
        recording = import_pcap(pcap, out, **options)
    _print_import(recording, out, quiet)


def _imported_recording_folder(out: Path | None, name: str) -> Path:
    """Where an import writes: `out`, or out/<name> (a plain folder name); never over an existing recording. The
    folder is removed if the import is then refused (_clear_errors), unless it was there, empty, before."""
    from graphcal.common.run_folder import folder_name

    out = _not_taken(out or Path("out") / folder_name(name))
    if not out.exists():
        _IMPORTING.append(out)
    return out


def _not_taken(path: Path, force: bool | None = None) -> Path:
    """path, or ConfigError when something is there already: graphcal replaces nothing silently. force: the
    command's --force (True: replace it); None: the command has none (an import never replaces a recording)."""
    from graphcal.common.errors import ConfigError

    if not force and path.exists() and (not path.is_dir() or any(path.iterdir())):
        if force is None:
            raise ConfigError(f"{path}: already exists; an import does not replace it (remove it or choose another "
                              "--out)")
        raise ConfigError(f"{path}: already exists; graphcal does not replace it without --force (remove it, choose "
                          "another --out, or add --force)")
    return path


def _read_trajectory(path: Path):
    from graphcal.importers.sbet import import_sbet
    from graphcal.recording.trajectory import Trajectory

    return Trajectory.load_csv(path) if path.suffix.lower() == ".csv" else import_sbet(path)


@import_app.command("ouster")
@_clear_errors
def import_ouster_command(
        pcap: Annotated[Path, typer.Argument(help="Ouster capture (libpcap file; single-return lidar profile)")],
        metadata: Annotated[Path, typer.Option(help="the unit's metadata JSON (beam intrinsics, data format)")],
        out: Annotated[Path | None, typer.Option(help="recording directory (default out/<pcap name>)")] = None,
        trajectory: Annotated[Path | None, typer.Option(help="SBET (.out) or trajectory.csv, GPS seconds of week")] = None,
        crs: Annotated[str, typer.Option(help="world CRS (needed for a projected trajectory.csv)")] = "auto",
        position: Annotated[str | None, typer.Option(help="static position LAT,LON,ALT (deg, deg, m)")] = None,
        attitude: Annotated[str, typer.Option(help="static attitude ROLL,PITCH,YAW (deg, ENU)")] = "0,0,0",
        lever_arm: Annotated[str | None, typer.Option(help="Ouster sensor frame -> body lever arm X,Y,Z (m)")] = None,
        boresight: Annotated[str | None, typer.Option(help="Ouster sensor frame -> body ROLL,PITCH,YAW (deg)")] = None,
        quiet: Quiet = False) -> None:
    """Ouster pcap + metadata JSON -> recording (docs/howto/import-ouster.md). Without --trajectory the
    sensor is taken as STATIC at --position.

    Example: graphcal import ouster drive.pcap --metadata drive.json --trajectory sbet.out --lever-arm 0.8,0,1.9
    """
    from graphcal.importers.ouster_metadata import read_ouster_metadata
    from graphcal.importers.ouster_pcap import import_ouster

    out = _imported_recording_folder(out, pcap.stem)  # before the import's work
    recording = import_ouster(pcap, read_ouster_metadata(metadata), out,
                              trajectory=_read_trajectory(trajectory) if trajectory else None,
                              position=_position(position), attitude_deg=_numbers(attitude, "--attitude"),
                              mount=_extrinsic(lever_arm, boresight), crs=crs, quiet=quiet)
    _print_import(recording, out, quiet)


@import_app.command("kitti")
@_clear_errors
def import_kitti_command(
        drive: Annotated[Path, typer.Argument(help="KITTI raw drive folder (..._drive_NNNN_sync)")],
        out: Annotated[Path | None, typer.Option(help="recording directory (default out/<drive name>)")] = None,
        calibration: Annotated[Path | None, typer.Option(help="db.xml or ROS YAML to start the fibre fit from")] = None,
        quiet: Quiet = False) -> None:
    """KITTI raw drive -> recording. Per-return times are DERIVED from the azimuth (KITTI has none)."""
    from graphcal.importers.kitti import import_kitti
    from graphcal.importers.velodyne_calibration import read_velodyne_calibration

    out = _imported_recording_folder(out, drive.name)  # before the import's work
    recording = import_kitti(drive, out, calibration=read_velodyne_calibration(calibration) if calibration else None,
                             quiet=quiet)
    _print_import(recording, out, quiet)


@import_app.command("sbet")
@_clear_errors
def import_sbet_command(sbet: Annotated[Path, typer.Argument(help="Applanix SBET file (17 float64 per record)")],
                        out: Annotated[Path, typer.Option(help="trajectory.csv to write")] = Path("trajectory.csv"),
                        start: Annotated[float | None, typer.Option(help="first GPS second of week to keep")] = None,
                        end: Annotated[float | None, typer.Option(help="last GPS second of week to keep")] = None,
                        quiet: Quiet = False) -> None:
    """Applanix SBET -> trajectory.csv (geodetic, ENU attitude, GPS seconds of week)."""
    from graphcal.importers.sbet import import_sbet

    _not_taken(out)  # before the import's work
    span = None if start is None and end is None else (start if start is not None else -float("inf"),
                                                       end if end is not None else float("inf"))
    trajectory = import_sbet(sbet, span)
    trajectory.save_csv(out)
    if not quiet:
        typer.echo(f"{len(trajectory.time):,} poses over [{trajectory.time[0]:.3f}, {trajectory.time[-1]:.3f}] s "
                   f"written to {out}")


@import_app.command("csv")
@_clear_errors
def import_csv_command(
        csv: Annotated[Path, typer.Argument(help="trajectory CSV with a header line")],
        out: Annotated[Path, typer.Option(help="trajectory.csv to write")] = Path("trajectory.csv"),
        columns: Annotated[str, typer.Option(help="FIELD=COLUMN pairs, comma-separated (e.g. time=gps_s, lat=latitude)")] = "",
        position: Annotated[str, typer.Option(help="geodetic (lat, lon, alt) or projected (x, y, z)")] = "geodetic",
        attitude: Annotated[str, typer.Option(help="enu (roll, pitch, yaw) or ned (roll, pitch, heading)")] = "enu",
        radians: Annotated[bool, typer.Option(help="angles in radians (default degrees)")] = False,
        delimiter: Annotated[str, typer.Option(help="column separator")] = ",",
        time_offset: Annotated[float, typer.Option(help="seconds added to the time column")] = 0.0,
        quiet: Quiet = False) -> None:
    """A CSV trajectory with your own column names and units -> trajectory.csv of the recording format."""
    from graphcal.common.errors import ConfigError
    from graphcal.importers.trajectory_csv import (
        CsvTrajectoryFormat,
        import_trajectory_csv,
    )

    _not_taken(out)  # before the import's work
    mapping = {}
    for pair in filter(None, columns.split(",")):
        field, sep, column = pair.partition("=")
        if not sep or not field.strip() or not column.strip():
            raise ConfigError(f"--columns: {pair!r} is not FIELD=COLUMN")
        mapping[field.strip()] = column.strip()
    fmt = CsvTrajectoryFormat(columns=mapping, position=position, attitude=attitude, radians=radians,
                              delimiter=delimiter, time_offset_s=time_offset)
    trajectory = import_trajectory_csv(csv, fmt)
    trajectory.save_csv(out)
    if not quiet:
        typer.echo(f"{len(trajectory.time):,} poses written to {out}")


@import_app.command("pcd")
@_clear_errors
def import_pcd_command(
        folder: Annotated[Path, typer.Argument(help="folder of per-scan PCD files (x y z intensity ring time)")],
        poses: Annotated[Path, typer.Option(help="3x4 row-major pose per frame (KITTI poses.txt or OpenCalib "
                                                 "'name r00 ... t2' lines)")],
        out: Annotated[Path | None, typer.Option(help="recording directory (default out/<folder name>)")] = None,
        calibration: Annotated[Path | None, typer.Option(help="db.xml or ROS velodyne YAML the driver used")] = None,
        crs: Annotated[str | None, typer.Option(help="projected CRS of the poses (default: a local frame)")] = None,
        origin: Annotated[str, typer.Option(help="local frame: its centre LAT,LON (deg)")] = "0,0",
        lever_arm: Annotated[str | None, typer.Option(help="poses of a body, not the lidar: lever arm X,Y,Z (m)")]
        = None,
        boresight: Annotated[str | None, typer.Option(help="poses of a body, not the lidar: ROLL,PITCH,YAW (deg)")]
        = None,
        pose_at: Annotated[str, typer.Option(help="a frame's pose is at its scan's first (start) or last (end) "
                                                  "return")] = "end",
        quiet: Quiet = False) -> None:
    """PCD scans with ring and per-point time + per-frame poses -> recording (docs/howto/import-pcd.md).

    Example: graphcal import pcd top_center_lidar --poses top_center_lidar-enu.txt
    """
    from graphcal.common.errors import ConfigError
    from graphcal.importers.pcd_folder import import_pcd_folder
    from graphcal.importers.velodyne_calibration import read_velodyne_calibration

    out = _imported_recording_folder(out, folder.name)  # before the import's work
    if pose_at not in ("start", "end"):
        raise ConfigError(f"--pose-at {pose_at!r}: expected start or end")
    recording = import_pcd_folder(folder, poses, out, calibration=read_velodyne_calibration(calibration)
                                  if calibration else None, crs=crs, origin=_numbers(origin, "--origin", 2),
                                  extrinsic=_extrinsic(lever_arm, boresight), pose_at=pose_at, quiet=quiet)
    _print_import(recording, out, quiet)


def _extrinsic(lever_arm: str | None, boresight: str | None):
    """Extrinsic of --lever-arm / --boresight, or None when neither is given."""
    from graphcal.recording.extrinsic import Extrinsic

    if lever_arm is None and boresight is None:
        return None
    return Extrinsic(lever_arm_m=_numbers(lever_arm, "--lever-arm") or (0.0, 0.0, 0.0),
                     boresight_deg=_numbers(boresight, "--boresight") or (0.0, 0.0, 0.0))


@import_app.command("pointcloud2")
@_clear_errors
def import_pointcloud2_command(
        bag: Annotated[Path, typer.Argument(help="rosbag1 (.bag), rosbag2 folder, or .mcap / .db3 file")],
        topic: Annotated[str | None, typer.Option(help="the PointCloud2 topic (default: the only one)")] = None,
        calibration: Annotated[Path | None, typer.Option(help="db.xml or ROS velodyne YAML the driver used")] = None,
        trajectory: Annotated[Path | None, typer.Option(help="SBET (.out) or trajectory.csv, GPS seconds of week "
                                                             "(default: the bag's NavSatFix + Imu or Odometry)")]
        = None,
        pose_topic: Annotated[str | None, typer.Option(help="the bag's NavSatFix or Odometry topic to use")] = None,
        out: Annotated[Path | None, typer.Option(help="recording directory (default out/<bag name>)")] = None,
        crs: Annotated[str, typer.Option(help="world CRS (needed for a projected trajectory.csv)")] = "auto",
        origin: Annotated[str, typer.Option(help="Odometry's local frame: its centre LAT,LON (deg)")] = "0,0",
        lever_arm: Annotated[str | None, typer.Option(help="lidar -> body lever arm X,Y,Z (m); default: the bag's "
                                                           "/tf_static, else 0")] = None,
        boresight: Annotated[str | None, typer.Option(help="lidar -> body ROLL,PITCH,YAW (deg); default: the bag's "
                                                           "/tf_static, else 0")] = None,
        body_frame: Annotated[str | None, typer.Option(help="the body's frame in the bag's tf, where the extrinsic "
                                                            "is read from (default: the bag trajectory's frame; "
                                                            "needed with --trajectory)")] = None,
        quiet: Quiet = False) -> None:
    """ROS PointCloud2 scans with ring and per-point time -> recording (docs/howto/import-pointcloud2.md).

    Example: graphcal import pointcloud2 drive.bag --topic /velodyne_points --calibration VLP16db.yaml
    """
    from graphcal.importers.pointcloud2 import import_pointcloud2
    from graphcal.importers.velodyne_calibration import read_velodyne_calibration

    out = _imported_recording_folder(out, bag.stem)  # before the import's work
    recording = import_pointcloud2(bag, out, topic=topic, calibration=read_velodyne_calibration(calibration)
                                   if calibration else None, trajectory=_read_trajectory(trajectory)
                                   if trajectory else None, crs=crs, pose_topic=pose_topic,
                                   extrinsic=_extrinsic(lever_arm, boresight), origin=_numbers(origin, "--origin", 2),
                                   body_frame=body_frame, quiet=quiet)
    _print_import(recording, out, quiet)


@import_app.command("las")
@_clear_errors
def import_las_command(
        las: Annotated[Path, typer.Argument(help="georeferenced LAS or LAZ file with GPS time")],
        trajectory: Annotated[Path, typer.Option(help="the SBET (.out) or trajectory.csv the cloud was made with, "
                                                      "GPS seconds of week")],
        out: Annotated[Path | None, typer.Option(help="recording directory (default out/<file name>)")] = None,
        crs: Annotated[str | None, typer.Option(help="the file's projected CRS (default: from its header)")] = None,
        lever_arm: Annotated[str | None, typer.Option(help="lidar -> body lever arm X,Y,Z (m) the cloud was made "
                                                           "with")] = None,
        boresight: Annotated[str | None, typer.Option(help="lidar -> body ROLL,PITCH,YAW (deg) the cloud was made "
                                                           "with (default: fitted for a single beam)")] = None,
        calibration: Annotated[Path | None, typer.Option(help="db.xml or ROS velodyne YAML the producer used")] = None,
        ring_field: Annotated[str | None, typer.Option(help="dimension holding the laser (default: ring, channel, "
                                                            "laser_id, laser, else point_source_id)")] = None,
        quiet: Quiet = False) -> None:
    """Georeferenced LAS/LAZ + its trajectory -> recording, raw values by undoing the georeferencing
    (docs/howto/import-las.md).

    Example: graphcal import las points.las --trajectory sbet.out
    """
    from graphcal.importers.las_cloud import import_las
    from graphcal.importers.velodyne_calibration import read_velodyne_calibration

    out = _imported_recording_folder(out, las.stem)  # before the import's work
    recording = import_las(las, _read_trajectory(trajectory), out, crs=crs,
                           lever_arm_m=_numbers(lever_arm, "--lever-arm") or (0.0, 0.0, 0.0),
                           boresight_deg=_numbers(boresight, "--boresight"),
                           calibration=read_velodyne_calibration(calibration) if calibration else None,
                           ring_field=ring_field)
    _print_import(recording, out, quiet)


def main() -> None:  # pragma: no cover - console entry
    sys.exit(app())
