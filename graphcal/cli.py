"""`graphcal` command line. Bad input ends with one clear line and exit code 2."""

from __future__ import annotations

import functools
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(help="Target-free lidar self-calibration with a GTSAM factor graph.", no_args_is_help=True,
                  pretty_exceptions_enable=False)

def _clear_errors(command):
    """Turn graphcal's own errors into one line on stderr and exit code 2."""
    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        from graphcal.errors import GraphcalError

        try:
            return command(*args, **kwargs)
        except GraphcalError as error:
            typer.echo(f"error: {error}", err=True)
            raise typer.Exit(2) from None
    return wrapper


@app.command()
@_clear_errors
def simulate(scenario: Annotated[str, typer.Argument(help="scenario name (sim6_turn, ...) or script path")],
             out: Annotated[Path | None, typer.Option(help="recording directory to write")] = None,
             size: Annotated[float, typer.Option(help="fraction of the sensor's firings kept")] = 1.0,
             seed: Annotated[int, typer.Option(help="seed of every random draw")] = 0,
             quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """Simulate a scenario and write its recording (with truth/)."""
    from graphcal.sim.script import load_scenario_builder
    from graphcal.sim.simulator import simulate as run

    build = load_scenario_builder(scenario)
    started = time.perf_counter()
    recording = run(build(size=size, seed=seed), quiet=quiet)
    out = out or Path("out") / recording.name
    recording.save(out)
    if not quiet:
        typer.echo(f"{len(recording.points):,} returns written to {out} in {time.perf_counter() - started:.1f} s")


@app.command()
@_clear_errors
def info(recording: Annotated[Path, typer.Argument(help="recording directory")]) -> None:
    """Validate a recording (every return, in batches) and summarise it."""
    from graphcal.recording import Recording

    rec = Recording.load(recording, validate=False)
    summary = rec.validate()
    world = rec.world
    typer.echo(f"{rec.name}: {summary.n_points:,} returns from a {rec.sensor.model} "
               f"({rec.sensor.n_fibres} fibres, reference {rec.sensor.reference_fibre}) over "
               f"{summary.time_max - summary.time_min:.2f} s")
    typer.echo(f"world frame {world.crs.to_string()}, grid scale factor {world.scale_factor.mean():.6f}, "
               f"meridian convergence {world.convergence_deg.mean():+.4f} deg")
    typer.echo(f"odometry: {'yes' if rec.odometry is not None else 'no'}; truth: "
               f"{'yes' if (recording / 'truth').is_dir() else 'no'}")


@app.command()
@_clear_errors
def calibrate(recording: Annotated[Path, typer.Argument(help="recording directory")],
              mode: Annotated[str, typer.Option(help="intrinsic, extrinsic, trajectory, joint, joint_trajectory, "
                                                     "extrinsic_then_intrinsic, intrinsic_then_extrinsic")] = "intrinsic",
              config: Annotated[Path | None, typer.Option(help="YAML file of CalibrationConfig settings")] = None,
              out: Annotated[Path | None, typer.Option(help="run folder (default runs/<name>-<UTC time>)")] = None,
              quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """Self-calibrate a recording; writes calibration.yaml, config, history and residuals."""
    import datetime

    from graphcal.calibration.calibrate import calibrate as run
    from graphcal.recording import Recording

    chosen = _calibration_config(mode, config)
    rec = Recording.load(recording)
    result = run(rec, chosen, quiet=quiet)
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%SZ")
    folder = out or Path("runs") / f"{rec.name}-{stamp}"
    path = result.save(folder, command=" ".join(["graphcal"] + sys.argv[1:]))
    if not quiet:
        before, after = result.energy_cm2
        typer.echo(f"J {before:.3g} -> {after:.3g} cm^2 in {result.seconds:.1f} s; wrote {path}")
        if result.unobservable:
            typer.echo(f"unobservable (held at nominal): {', '.join(result.unobservable)}")


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
             out: Annotated[Path | None, typer.Option(help="output folder (default runs/<name>-diagnose-<UTC time>)")] = None,
             quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """Find where the model and the recording disagree, name the physics left out, model it, show the
    fit improve; writes diagnosis.json (and the re-solved calibration)."""
    import datetime

    from graphcal.recording import Recording

    chosen = _calibration_config(mode, config)
    rec = Recording.load(recording)
    if simulation is not None:
        from graphcal.diagnosis.compare import compare

        result = compare(rec, Recording.load(simulation), max_points=chosen.max_points)
    elif rescan:
        from graphcal.calibration.calibrate import calibrate as fit
        from graphcal.diagnosis.compare import compare
        from graphcal.diagnosis.rescan import rescan as simulate_on_mesh

        estimate = fit(rec, chosen, quiet=quiet).calibration.estimate
        result = compare(rec, simulate_on_mesh(rec, estimate, chosen.max_points), max_points=chosen.max_points,
                         estimate=estimate)
    else:
        from graphcal.diagnosis.diagnose import diagnose as run

        result = run(rec, chosen, max_effects=max_effects, quiet=quiet)
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%SZ")
    path = result.save(out or Path("runs") / f"{rec.name}-diagnose-{stamp}")
    if not quiet:
        typer.echo(result.summary())
        typer.echo(f"wrote {path} in {result.seconds:.1f} s")


def _calibration_config(mode: str, config: Path | None):
    """CalibrationConfig from --mode and an optional YAML file, or ConfigError naming the setting."""
    import pydantic

    from graphcal.calibration.config import CalibrationConfig
    from graphcal.errors import ConfigError
    from graphcal.yamlfile import read_yaml

    settings = (read_yaml(config) or {}) if config is not None else {}
    if not isinstance(settings, dict):
        raise ConfigError(f"{config}: not a mapping of CalibrationConfig settings (name: value per line)")
    try:
        return CalibrationConfig(**{"mode": mode, **settings})
    except pydantic.ValidationError as error:
        first = error.errors()[0]
        raise ConfigError(f"{config or '--mode'}: {'.'.join(map(str, first['loc']))}: {first['msg']}") from None


@app.command()
@_clear_errors
def deskew(recording: Annotated[Path, typer.Argument(help="recording directory")],
           source: Annotated[str, typer.Option(help="motion during the sweep: ins, odometry, or none (raw scans)")] = "ins",
           cloud_format: Annotated[str, typer.Option("--format", help="ply, las, laz, or uos (3DTK .3d)")] = "ply",
           out: Annotated[Path | None, typer.Option(help="output folder (default out/<name>-deskew-<source>)")] = None,
           gyro: Annotated[bool, typer.Option(help="odometry: yaw from the gyro column when there is one")] = True,
           quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """Deskew every revolution into its end-of-scan lidar frame (seed 002): one cloud and one 3DTK
    pose per revolution, poses.csv and deskew.yaml."""
    from graphcal.cloud_io import FORMATS
    from graphcal.deskewing import SOURCES, iter_scans
    from graphcal.errors import ConfigError
    from graphcal.recording import Recording
    from graphcal.scan_files import save_scans

    if source not in SOURCES:
        raise ConfigError(f"--source {source!r}: expected one of {', '.join(SOURCES)}")
    if cloud_format not in FORMATS:
        raise ConfigError(f"--format {cloud_format!r}: expected one of {', '.join(FORMATS)}")
    started = time.perf_counter()
    rec = Recording.load(recording)
    folder = out or Path("out") / f"{rec.name}-deskew-{source}"
    manifest = {"recording": str(recording), "source": source, "gyro": gyro, "crs": rec.world.crs.to_string()}
    save_scans(iter_scans(rec, source, use_gyro=gyro, quiet=quiet), folder, cloud_format, manifest)
    if not quiet:
        typer.echo(f"{len(rec.points):,} returns deskewed ({source}) into {folder} in "
                   f"{time.perf_counter() - started:.1f} s")


@app.command()
@_clear_errors
def demo(out: Annotated[Path, typer.Option(help="where to write the demo recording")] = Path("out/demo"),
         size: Annotated[float, typer.Option(help="fraction of the sensor's firings kept")] = 1.0,
         quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """Flagship demo: simulate sim6_turn and measure how blurred the nominal cloud is."""
    from graphcal.demo import run_demo

    run_demo(out, size=size, quiet=quiet)


import_app = typer.Typer(help="Import real data into the recording format (docs/importers.md).", no_args_is_help=True)
app.add_typer(import_app, name="import")


def _numbers(text: str | None, option: str, count: int = 3) -> tuple[float, ...] | None:
    """'a,b,c' -> (a, b, c), or ConfigError naming the option."""
    from graphcal.errors import ConfigError

    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count:
        raise ConfigError(f"{option}: {text!r} is not {count} comma-separated numbers")
    return values


def _print_notes(recording, out: Path, quiet: bool) -> None:
    if not quiet:
        for note in recording.source["notes"]:
            typer.echo(f"  {note}")
        typer.echo(f"{len(recording.points):,} returns written to {out}")


@import_app.command("pcap")
@_clear_errors
def import_pcap_command(
        pcap: Annotated[Path, typer.Argument(help="Velodyne capture (HDL-32E, VLP-16, HDL-64E): libpcap file or "
                                                   "ROS bag of velodyne_msgs/VelodyneScan")],
        out: Annotated[Path | None, typer.Option(help="recording directory (default out/<pcap name>)")] = None,
        model: Annotated[str | None, typer.Option(help="force the model: HDL-32E, VLP-16 or HDL-64E")] = None,
        calibration: Annotated[Path | None, typer.Option(help="db.xml or ROS velodyne YAML of the unit")] = None,
        trajectory: Annotated[Path | None, typer.Option(help="SBET (.out) or trajectory.csv, GPS seconds of week")] = None,
        crs: Annotated[str, typer.Option(help="world CRS (needed for a projected trajectory.csv)")] = "auto",
        position: Annotated[str | None, typer.Option(help="static position LAT,LON,ALT (deg, deg, m)")] = None,
        attitude: Annotated[str, typer.Option(help="static attitude ROLL,PITCH,YAW (deg, ENU)")] = "0,0,0",
        lever_arm: Annotated[str | None, typer.Option(help="nominal lever arm X,Y,Z (m, body frame)")] = None,
        boresight: Annotated[str | None, typer.Option(help="nominal boresight ROLL,PITCH,YAW (deg)")] = None,
        block_azimuth: Annotated[bool, typer.Option(help="one azimuth per firing sequence (VeloView 3) instead "
                                                         "of each laser's own")] = False,
        topic: Annotated[str | None, typer.Option(help="ROS bag: the VelodyneScan topic (default: the only one)")] = None,
        quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """Velodyne pcap (or ROS bag) -> recording. Without --trajectory the sensor is taken as STATIC
    at the GPRMC fix of its position packets (or --position).

    Example: graphcal import pcap drive.pcap --trajectory sbet.out --lever-arm 0.8,0,1.9 --boresight 0,0,90
    """
    from graphcal.extrinsic import Extrinsic
    from graphcal.importers.velodyne_calibration import read_velodyne_calibration
    from graphcal.importers.velodyne_pcap import import_pcap

    extrinsic = None
    if lever_arm is not None or boresight is not None:
        extrinsic = Extrinsic(lever_arm_m=_numbers(lever_arm, "--lever-arm") or (0.0, 0.0, 0.0),
                              boresight_deg=_numbers(boresight, "--boresight") or (0.0, 0.0, 0.0))
    options = {"model": model, "calibration": read_velodyne_calibration(calibration) if calibration else None,
               "trajectory": _read_trajectory(trajectory) if trajectory else None,
               "position": _numbers(position, "--position"), "attitude_deg": _numbers(attitude, "--attitude"),
               "extrinsic": extrinsic, "interpolate_azimuth": not block_azimuth, "quiet": quiet}
    if pcap.is_dir() or pcap.suffix.lower() in (".bag", ".db3", ".mcap"):
        from graphcal.importers.velodyne_rosbag import import_rosbag

        recording = import_rosbag(pcap, topic=topic, **options)
    else:
        recording = import_pcap(pcap, **options)
    recording.crs = crs
    out = out or Path("out") / recording.name
    recording.save(out)
    _print_notes(recording, out, quiet)


def _read_trajectory(path: Path):
    from graphcal.importers.sbet import import_sbet
    from graphcal.trajectory import Trajectory

    return Trajectory.load_csv(path) if path.suffix.lower() == ".csv" else import_sbet(path)


@import_app.command("kitti")
@_clear_errors
def import_kitti_command(
        drive: Annotated[Path, typer.Argument(help="KITTI raw drive folder (..._drive_NNNN_sync)")],
        out: Annotated[Path | None, typer.Option(help="recording directory (default out/<drive name>)")] = None,
        calibration: Annotated[Path | None, typer.Option(help="db.xml or ROS YAML to start the fibre fit from")] = None,
        quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """KITTI raw drive -> recording. Per-return times are DERIVED from the azimuth (KITTI has none)."""
    from graphcal.importers.kitti import import_kitti
    from graphcal.importers.velodyne_calibration import read_velodyne_calibration

    recording = import_kitti(drive, calibration=read_velodyne_calibration(calibration) if calibration else None,
                             quiet=quiet)
    out = out or Path("out") / recording.name
    recording.save(out)
    _print_notes(recording, out, quiet)


@import_app.command("sbet")
@_clear_errors
def import_sbet_command(sbet: Annotated[Path, typer.Argument(help="Applanix SBET file (17 float64 per record)")],
                        out: Annotated[Path, typer.Option(help="trajectory.csv to write")] = Path("trajectory.csv"),
                        start: Annotated[float | None, typer.Option(help="first GPS second of week to keep")] = None,
                        end: Annotated[float | None, typer.Option(help="last GPS second of week to keep")] = None,
                        quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """Applanix SBET -> trajectory.csv (geodetic, ENU attitude, GPS seconds of week)."""
    from graphcal.importers.sbet import import_sbet

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
        columns: Annotated[str, typer.Option(help="FIELD=COLUMN,... e.g. time=gps_s,lat=latitude,heading=hdg")] = "",
        position: Annotated[str, typer.Option(help="geodetic (lat, lon, alt) or projected (x, y, z)")] = "geodetic",
        attitude: Annotated[str, typer.Option(help="enu (roll, pitch, yaw) or ned (roll, pitch, heading)")] = "enu",
        radians: Annotated[bool, typer.Option(help="angles in radians (default degrees)")] = False,
        delimiter: Annotated[str, typer.Option(help="column separator")] = ",",
        time_offset: Annotated[float, typer.Option(help="seconds added to the time column")] = 0.0,
        quiet: Annotated[bool, typer.Option("--quiet", "-q")] = False) -> None:
    """A CSV trajectory with your own column names and units -> trajectory.csv of the recording format."""
    from graphcal.errors import ConfigError
    from graphcal.importers.trajectory_csv import (
        CsvTrajectoryFormat,
        import_trajectory_csv,
    )

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


def main() -> None:  # pragma: no cover - console entry
    sys.exit(app())
